/* A robot's demand from its FIFO (channels.py).
 * Part of a library's one translation unit (controller.c), after common.h. */

/* ---------------------------------------------------------------- the demand
 *
 * SIO's end of a robot's Type 2 FIFO (channels.py, thesis 2.2.2): this servo tick's
 * interpolated demand.  InterpolatingFifo.pop_into is the reference, step for step; the
 * consumer's ratio (num, den, its stamp) lives here once a FIFO is popped by this kernel. */

int64_t kali_fifo_pop(FifoPopArgs *a) {
    int64_t n = a->n;
    size_t bytes = (size_t)n * sizeof(double);
    uint32_t done = *a->seg_done, ticks = *a->seg_ticks;
    if (done >= ticks) { /* the segment is over: take the next set-point, if any */
        uint64_t head = __atomic_load_n(a->head, __ATOMIC_SEQ_CST);
        if (head == __atomic_load_n(a->tail, __ATOMIC_SEQ_CST)) {
            *a->underruns += 1u;
            if (!*a->primed) return 0;
            memcpy(a->cur, a->target, bytes);
            for (int64_t i = 0; i < n; i++) AT(double, a->out, i) = a->cur[i];
            return 0;
        }
        uint64_t slot = head % (uint64_t)a->capacity;
        const double *row = a->ring + slot * (uint64_t)n;
        uint64_t stamp = a->stamps[slot];
        if (stamp != a->stamp) { /* pushed under another ratio: switch, unless garbage */
            uint64_t num = stamp & 0xFFFFFFFFu, den = stamp >> 32;
            if (!(1u <= den && den <= num)) {
                *a->rejected += 1u;
            } else {
                a->num = (int64_t)num, a->den = (int64_t)den, a->stamp = stamp;
                *a->ratio_num = (uint32_t)num;
                *a->ratio_den = (uint32_t)den;
                *a->phase_acc = 0u;
            }
        }
        int good = 1;
        for (int64_t i = 0; i < n; i++) good = good && fabs(row[i]) < a->bound;
        if (!good) *a->rejected += 1u;
        if (!*a->primed) {
            __atomic_store_n(a->head, head + 1u, __ATOMIC_SEQ_CST);
            if (!good) return 0;
            memcpy(a->cur, row, bytes);
            memcpy(a->start, row, bytes);
            memcpy(a->target, row, bytes);
            *a->primed = 1u;
            for (int64_t i = 0; i < n; i++) AT(double, a->out, i) = a->cur[i];
            return 1;
        }
        memcpy(a->start, a->target, bytes);
        if (good) memcpy(a->target, row, bytes);
        __atomic_store_n(a->head, head + 1u, __ATOMIC_SEQ_CST);
        uint64_t acc = *a->phase_acc + (uint64_t)a->num;
        ticks = (uint32_t)(acc / (uint64_t)a->den);
        *a->phase_acc = acc % (uint64_t)a->den;
        *a->seg_ticks = ticks;
        done = 0;
    }
    done += 1u;
    *a->seg_done = done;
    if (done >= ticks) {
        memcpy(a->cur, a->target, bytes); /* the last tick lands exactly on B */
    } else {
        double k = (double)((uint64_t)done * (uint64_t)a->den), num = (double)a->num;
        for (int64_t i = 0; i < n; i++) a->cur[i] = a->start[i] + (a->target[i] - a->start[i]) * k / num;
    }
    for (int64_t i = 0; i < n; i++) AT(double, a->out, i) = a->cur[i];
    return 1;
}
