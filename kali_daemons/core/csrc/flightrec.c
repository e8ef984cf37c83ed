/* SIO's row of the flight recorder (flightrec.py).
 * Part of a library's one translation unit (controller.c), after common.h. */

/* ---------------------------------------------------------------- the flight recorder's row
 *
 * flightrec.py's FlightRecorder.record_reference, field for field: one servo tick's row of
 * the ring (its timing, the six per-joint columns, the shadow torque in single precision,
 * each robot's wrench), then the header's count, published last. */

int64_t kali_flight_row(FlightArgs *a) {
    uint64_t next = *a->count;
    char *row = a->ring + (int64_t)(next % (uint64_t)a->rows) * a->row_size;
    *(int64_t *)(row + a->off_tick) = a->tick;
    *(int64_t *)(row + a->off_t) = a->t_read;
    *(int64_t *)(row + a->off_lat) = a->latency;
    *(int64_t *)(row + a->off_late) = a->t_read - *a->release;
    *(int64_t *)(row + a->off_wait) = a->wait;
    *(int64_t *)(row + a->off_ran) = a->ran;
    for (int64_t c = 0; c < a->n_cols; c++) {
        double *dst = (double *)(row + a->off_cols[c]);
        for (int64_t i = 0; i < a->n; i++) dst[i] = AT(double, a->cols[c], i);
    }
    float *shadow = (float *)(row + a->off_shadow);
    for (int64_t i = 0; i < a->n; i++) shadow[i] = (float)AT(double, a->shadow, i);
    double *w = (double *)(row + a->off_wrench);
    for (int64_t k = 0; k < a->n_robots; k++)
        for (int64_t j = 0; j < 6; j++)
            w[k * 6 + j] = *(const double *)(a->wrench + k * a->wrench_row + j * a->wrench_col);
    __atomic_store_n(a->count, next + 1u, __ATOMIC_RELEASE); /* last */
    return 0;
}
