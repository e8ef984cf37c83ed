/* SIO's kernels: the boards' read and write, the checks, the feed, feed-forward, the wrist
 * sensors and the whole tick (sio/, boards/).
 * Part of a library's one translation unit (controller.c), after common.h. */

/* ---------------------------------------------------------------- encoders -> radians */

int64_t kali_read(ReadArgs *a) {
    uint32_t mask = (uint32_t)a->modulo - 1u, half = (uint32_t)a->half;
    for (int64_t i = 0; i < a->n; i++) {
        uint16_t word = *(uint16_t *)(a->encoders + AT(int64_t, a->enc_off, i));
        uint32_t raw = (uint32_t)word & mask;
        uint32_t prev = (uint32_t)AT(int32_t, a->prev, i);
        int32_t d = (int32_t)((raw - prev + half) & mask) - (int32_t)half;
        int32_t acc = (int32_t)((uint32_t)AT(int32_t, a->acc, i) + (uint32_t)d);
        AT(int32_t, a->acc, i) = acc;
        AT(int32_t, a->prev, i) = (int32_t)raw;
        AT(double, a->q, i) = (double)acc * AT(double, a->rad_per_count, i) + AT(double, a->offset, i);
    }
    return 0;
}

/* ---------------------------------------------------------------- velocity filter */

int64_t kali_velocity(VelocityArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double q = AT(double, a->q, i);
        double raw = (q - AT(double, a->q_prev, i)) * a->gain;
        AT(double, a->qd, i) = (AT(double, a->qd, i) + raw) * a->b;
        AT(double, a->q_prev, i) = q;
    }
    return 0;
}

/* ---------------------------------------------------------------- range and runaway */

/* -1: no fault; i: joint i beyond its range; n + i: joint i's tracking error beyond safe.
 * The first robot at fault, its range before its runaway, its first joint. */
int64_t kali_checks(ChecksArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double s = AT(double, a->safe, i);
        if (s > 0.0 && s <= a->pi) AT(double, a->safe_ok, i) = s;
    }
    for (int64_t k = 0; k < a->n_robots; k++) {
        int64_t lo = AT(int64_t, a->bounds, k), hi = AT(int64_t, a->bounds, k + 1);
        for (int64_t i = lo; i < hi; i++) {
            double q = AT(double, a->q, i);
            int out = q < AT(double, a->q_min, i) || q > AT(double, a->q_max, i);
            if (out && AT(uint8_t, a->range_check, i) && AT(uint8_t, a->fed, i)) return i;
        }
        for (int64_t i = lo; i < hi; i++) {
            double err = fabs(AT(double, a->demand, i) - AT(double, a->q, i));
            if (err > AT(double, a->safe_ok, i) && AT(uint8_t, a->fed, i)) return a->n + i;
        }
    }
    return -1;
}

/* ---------------------------------------------------------------- feed the slots */

/* Stores before this are issued before stores after it (x86 keeps them in order). */
#define ORDERED() __asm__ __volatile__("" ::: "memory")

/* The slots' inputs, then the count fed and done = 0, then busy: an SV still claiming
 * from a tick it was late for counts into this tick's done (as the numpy code did).
 * A fed slot's busy is its mark: 0, or for a robot fed whole ARM_FREE on its first slot
 * and ARM_HELD on the rest.  Returns the slots fed this tick. */
int64_t kali_feed(FeedArgs *a) {
    int64_t fed = 0;
    for (int64_t i = 0; i < a->n; i++) {
        AT(double, a->slot_demand, i) = AT(double, a->demand, i);
        AT(double, a->slot_position, i) = AT(double, a->q, i);
        AT(double, a->slot_velocity, i) = AT(double, a->qd, i);
        AT(double, a->slot_demand_vel, i) = AT(double, a->demand_vel, i);
        AT(double, a->slot_demand_acc, i) = AT(double, a->demand_acc, i);
        AT(double, a->slot_ff, i) = AT(double, a->ff, i);
        fed += AT(uint8_t, a->fed, i) != 0;
    }
    *a->ctrl_fed = (uint32_t)fed;
    *a->ctrl_done = 0u;
    ORDERED();
    for (int64_t i = 0; i < a->n; i++)
        AT(uint32_t, a->slot_busy, i) =
            AT(uint8_t, a->fed, i) ? AT(uint32_t, a->mark, i) : (uint32_t)a->not_fed;
    return fed;
}

/* ---------------------------------------------------------------- torques out */

/* servo and feed-forward torques of the fed joints, and their sum */
int64_t kali_torques(TorquesArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double f = AT(uint8_t, a->fed, i) ? 1.0 : 0.0;
        double servo = AT(double, a->slot_torque, i) * f;
        double ff = AT(double, a->ff, i) * f;
        AT(double, a->servo_torque, i) = servo;
        AT(double, a->ff, i) = ff;
        AT(double, a->torque, i) = servo + ff;
    }
    return 0;
}

int64_t kali_dac(DacArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double limit = AT(double, a->current_limit, i);
        double c = AT(double, a->torque, i) / AT(double, a->gkt, i);
        AT(uint8_t, a->clamped, i) = fabs(c) > limit;
        if (c > limit) c = limit;
        if (c < -limit) c = -limit;
        AT(double, a->current, i) = c;
        double code = rint(c * AT(double, a->codes_per_amp, i) + a->zero);
        if (code < 0.0) code = 0.0;
        if (code > a->top) code = a->top;
        *(uint16_t *)(a->dacs + AT(int64_t, a->dac_off, i)) = (uint16_t)code;
    }
    return 0;
}

/* -1, or the first joint clamped for its current_ticks */
int64_t kali_current_check(CurrentArgs *a) {
    int64_t first = -1;
    for (int64_t i = 0; i < a->n; i++) {
        int fed = AT(uint8_t, a->fed, i) != 0;
        AT(double, a->torque, i) = AT(double, a->torque, i) * (fed ? 1.0 : 0.0);
        int64_t over = AT(uint8_t, a->clamped, i) ? AT(int64_t, a->over, i) + 1 : 0;
        over = fed ? over : 0;
        AT(int64_t, a->over, i) = over;
        if (first < 0 && over >= AT(int64_t, a->current_ticks, i)) first = i;
    }
    return first;
}

/* ---------------------------------------------------------------- the robots' common path
 *
 * SIO's per-robot step where nothing is happening to the robot (sio/cycle.py's
 * SioCycle._robot is the reference; this is its last branch): its pots read, powered ON with
 * its amplifiers on, no power or calibration command pending, no halt this tick, not
 * calibrating, no tripped guard, not guided by hand.  Such a robot's demand is this tick's
 * from its FIFO (kali_fifo_pop) and its joints are fed.  Every other robot is left as it is
 * for _robot: its bit is set in the result.  The fed mask is cleared first, every joint. */

int64_t kali_sio_robots(RobotsArgs *a) {
    for (int64_t i = 0; i < a->n; i++) AT(uint8_t, a->fed, i) = 0;
    int64_t others = 0;
    for (int64_t k = 0; k < a->n_robots; k++) {
        uint8_t calib = AT(uint8_t, a->calib_state, k);
        int common = !a->faulted && AT(uint8_t, a->pots_read, k)
                     && AT(uint8_t, a->power, k) == a->on && !AT(uint8_t, a->power_cmd, k)
                     && !AT(uint8_t, a->calib_cmd, k) && (AT(uint8_t, a->amps, k) & a->amps_bit)
                     && !(calib < 64 && (a->calib_active >> calib) & 1)
                     && AT(uint32_t, a->guard_state, k) != (uint32_t)a->tripped
                     && !AT(uint8_t, a->guided, k);
        if (!common) {
            others |= (int64_t)1 << k;
            continue;
        }
        kali_fifo_pop(a->pops[k]);
        int64_t hi = AT(int64_t, a->bounds, k + 1);
        for (int64_t i = AT(int64_t, a->bounds, k); i < hi; i++) AT(uint8_t, a->fed, i) = 1;
    }
    return others;
}

/* ---------------------------------------------------------------- feed-forward
 *
 * One robot's feed-forward as SIO applies it each servo tick (sio/feedforward.py, whose
 * RobotFeedforward.update is the reference, step for step): the dynamics process's rows of
 * the segment the FIFO interpolates (A = set-point b - 1, B = set-point b, a row's key 1 +
 * its index) by the same fraction as the demand; stale rows dropped, the weight ramped. */

#define FF_MAX_JOINTS 64 /* n <= layout.MAX_JOINTS <= this (asserted at binding) */

/* row of key into out (3 x n); 0 if it is not there or changed while being copied (the
 * dynamics process sets its key to FF_NO_KEY while writing) */
static int ff_row(const FfArgs *a, uint64_t key, double *out) {
    uint64_t row = key % (uint64_t)a->rows;
    if (__atomic_load_n(&a->keys[row], __ATOMIC_ACQUIRE) != key) return 0;
    int64_t n = a->n, at = (int64_t)row * a->row_len;
    memcpy(out, a->tau + at, (size_t)n * sizeof(double));
    memcpy(out + n, a->qd + at, (size_t)n * sizeof(double));
    memcpy(out + 2 * n, a->qdd + at, (size_t)n * sizeof(double));
    __atomic_thread_fence(__ATOMIC_ACQUIRE);
    return __atomic_load_n(&a->keys[row], __ATOMIC_RELAXED) == key;
}

int64_t kali_feedforward(FfArgs *a) {
    enum { OFF = 0, ON = 1, STALE = 2 };
    int64_t n = a->n, m = 3 * n;
    int64_t mode = *a->mode;
    if (mode <= a->mode_max) a->mode_ok = mode;
    else mode = a->mode_ok; /* a client's garbage: the last valid mode stays in force */
    if (mode == OFF && a->weight == 0.0 && !a->arm) {
        if (a->stale || *a->state != OFF) {
            a->stale = 0;
            *a->state = OFF;
            for (int64_t i = 0; i < n; i++) {
                AT(double, a->out, i) = 0.0;
                AT(double, a->vel, i) = 0.0;
                AT(double, a->acc, i) = 0.0;
            }
        }
        return 0;
    }
    int stale;
    int wanted = mode != OFF || a->arm;
    int64_t hb = *a->heartbeat, age; /* any word: a difference past int64 is far off */
    if (__builtin_sub_overflow(a->tick, hb, &age)) age = hb < 0 ? INT64_MAX : INT64_MIN;
    if (wanted && age <= a->heartbeat_limit) {
        double ra[3 * FF_MAX_JOINTS], rb[3 * FF_MAX_JOINTS], t[3 * FF_MAX_JOINTS];
        /* B: the set-point the FIFO moves to (key = its index + 1 = head); A: the one before
         * (none before the first set-point: key 0 - 1) */
        uint64_t key_b = __atomic_load_n(a->head, __ATOMIC_ACQUIRE);
        int has_b = ff_row(a, key_b, rb);
        int has_a = key_b > 0 && ff_row(a, key_b - 1, ra);
        if (has_a && has_b) { /* A + (B - A) * progress, as the demand */
            uint32_t ticks = *a->seg_ticks, done = *a->seg_done;
            double p = (0 < done && done < ticks) ? (double)done / (double)ticks : 1.0;
            for (int64_t i = 0; i < m; i++) t[i] = (rb[i] - ra[i]) * p + ra[i];
        } else if (has_b) {
            memcpy(t, rb, (size_t)m * sizeof(double));
        } else if (has_a) {
            memcpy(t, ra, (size_t)m * sizeof(double));
        }
        int good = has_a || has_b;
        if (good) {
            for (int64_t i = 0; i < m; i++) good = good && isfinite(t[i]);
            if (good) memcpy(a->last, t, (size_t)m * sizeof(double));
        }
        a->missing = good ? 0 : a->missing + 1;
        stale = !good && a->missing > a->missing_limit;
    } else {
        stale = wanted; /* the dynamics process is silent */
    }
    if (stale) /* no demand velocity or acceleration rather than an old one */
        for (int64_t i = n; i < m; i++) a->last[i] = 0.0;
    stale = stale && mode != OFF; /* only feed-forward asked for can be stale */
    if (stale) {
        if (!a->stale) *a->stale_events += 1u;
        *a->stale_ticks += 1u;
    }
    a->stale = stale;
    double want = (mode != OFF && !stale) ? 1.0 : 0.0;
    double w = a->weight;
    if (w < want) {
        double up = w + a->step;
        w = want < up ? want : up;
    } else if (w > want) {
        double down = w - a->step;
        w = want > down ? want : down;
    }
    a->weight = w;
    *a->weight_rec = w;
    for (int64_t i = 0; i < n; i++) {
        AT(double, a->out, i) = a->last[i] * w;
        AT(double, a->vel, i) = a->last[n + i];
        AT(double, a->acc, i) = a->last[2 * n + i];
    }
    *a->state = stale ? STALE : (mode != OFF ? ON : OFF);
    return 0;
}

/* ---------------------------------------------------------------- a wrist sensor in Newtons
 *
 * One arm's force/torque sample, from its gauge codes to the contact wrench at the tool point
 * (sio/wrench.py; wrench.convert_reference is the reference, equal to ~1e-12: numpy's small
 * products go through BLAS).  In order: volts and the calibration matrix (raw: the wrench the
 * tool exerts on the sensor), or the wrench the hardware gives at the flange (given: an arm with
 * no gauges, its joint torques'); the sensor frame in the world (base * flange pose at q) and the
 * tool's weight there, [m g; c x m g]; a tare in progress sums raw - weight and, at its last
 * sample, sets the bias and restarts the filter; the reading less the bias (sensor); the
 * checks; the contact wrench (sensor - weight), its low-pass, and the wrench at the tool
 * point (0, 0, tip) in tool and world axes.  Returns WRENCH_OK or the first check that
 * failed; the message is Python's to build. */

enum { WRENCH_OK, WRENCH_SATURATED, WRENCH_RATED, WRENCH_CONTACT, WRENCH_SILENT };

/* The conversion alone, for the tests against convert_reference. */
int64_t kali_wrench_convert(WrenchArgs *a) {
    double v[6], pose[16], w[16], gs[3], c[6];
    if (a->given) { /* the hardware's wrench at the flange: no gauges */
        for (int i = 0; i < 6; i++) a->raw[i] = a->given[i];
    } else {
        for (int i = 0; i < 6; i++) v[i] = a->codes[i] * a->volts;
        for (int i = 0; i < 6; i++) {
            double s = 0.0;
            for (int j = 0; j < 6; j++) s += a->cal[6 * i + j] * v[j];
            a->raw[i] = s;
        }
    }
    chain_pose(a->n, a->origins, a->axes, a->q, pose);
    for (int i = 0; i < 3; i++) /* the rotation of base * pose */
        for (int j = 0; j < 3; j++)
            w[4 * i + j] = a->base[4 * i] * pose[j] + a->base[4 * i + 1] * pose[4 + j] +
                           a->base[4 * i + 2] * pose[8 + j];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++) a->rotation[3 * i + j] = w[4 * i + j];
    for (int j = 0; j < 3; j++) /* R^T g: gravity in the sensor frame */
        gs[j] = a->g[0] * w[j] + a->g[1] * w[4 + j] + a->g[2] * w[8 + j];
    double m = a->mass, gx = m * gs[0], gy = m * gs[1], gz = m * gs[2];
    double cx = a->com[0], cy = a->com[1], cz = a->com[2];
    double *grav = a->grav;
    grav[0] = gx, grav[1] = gy, grav[2] = gz;
    grav[3] = cy * gz - cz * gy, grav[4] = cz * gx - cx * gz, grav[5] = cx * gy - cy * gx;
    if (a->tare_left > 0) {
        for (int i = 0; i < 6; i++) a->sum[i] += a->raw[i] - grav[i];
        if (--a->tare_left == 0) {
            for (int i = 0; i < 6; i++) a->bias[i] = a->sum[i] / (double)a->tare_ticks;
            for (int i = 0; i < 6; i++) a->filt[i] = 0.0; /* no contact at the tare */
        }
    }
    for (int i = 0; i < 6; i++) a->sensor[i] = a->raw[i] - a->bias[i];
    for (int i = 0; i < 6 && !a->given; i++)
        if (a->codes[i] >= a->rail || a->codes[i] <= -a->rail) return WRENCH_SATURATED;
    for (int i = 0; i < 6; i++)
        if (fabs(a->sensor[i]) > a->rated[i]) return WRENCH_RATED;
    for (int i = 0; i < 6; i++) c[i] = a->sensor[i] - grav[i];
    a->force = sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    double limit = *a->limit;
    if (!(limit > 0.0 && limit <= a->limit_config)) limit = a->limit_config; /* NaN too */
    a->limit_used = limit;
    if (a->force > limit) return WRENCH_CONTACT;
    double *f = a->filt, *t = a->tool, tip = a->tip;
    for (int i = 0; i < 6; i++) f[i] += a->alpha * (c[i] - f[i]);
    t[0] = f[0], t[1] = f[1], t[2] = f[2]; /* torque at (0, 0, tip): tau - p x F */
    t[3] = f[3] + tip * f[1], t[4] = f[4] - tip * f[0], t[5] = f[5];
    for (int i = 0; i < 3; i++) {
        const double *r = a->rotation + 3 * i;
        a->world[i] = r[0] * t[0] + r[1] * t[1] + r[2] * t[2];
        a->world[3 + i] = r[0] * t[3] + r[1] * t[4] + r[2] * t[5];
    }
    return WRENCH_OK;
}

/* A tick with no new sample: one more silent tick, if the hardware behind the gauges ran
 * since the last tick (cycles: a simulated board, whose plant may stall while SIO runs; a
 * plant that does not run is the wall clock's to judge, not a silent sensor). */
static int64_t wrench_silent(WrenchArgs *a) {
    if (a->cycles) {
        uint64_t cycles = LOAD(*a->cycles);
        if (cycles == a->cycles_seen) return WRENCH_OK;
        a->cycles_seen = cycles;
    }
    return ++*a->stale > (uint32_t)a->stale_limit ? WRENCH_SILENT : WRENCH_OK;
}

/* One servo tick of one arm's sensor: a sample the board has answered for is converted
 * (kali_wrench_convert) and the next asked for at once; a tare command starts a tare; a sensor
 * that has not answered for more than stale_limit ticks (of its hardware's running) is
 * WRENCH_SILENT. */
int64_t kali_wrench_tick(WrenchArgs *a) {
    if (a->given) { /* a new wrench from the hardware: its count moved */
        uint64_t count = *a->given_seq;
        if (count == a->given_seen) return wrench_silent(a);
        a->given_seen = count;
    } else {
        uint16_t status = *a->status;
        if (!(status & a->ready) || (int64_t)(status & a->seq_mask) != a->seq)
            return wrench_silent(a);
    }
    if (a->cycles) a->cycles_seen = LOAD(*a->cycles);
    *a->stale = 0;
    *a->present = 1;
    if (*a->tare_cmd) { /* a tare sums the samples from this one on */
        *a->tare_cmd = 0;
        for (int i = 0; i < 6; i++) a->sum[i] = 0.0;
        a->tare_left = a->tare_ticks;
        *a->tare_state = (uint8_t)a->averaging;
    }
    int64_t taring = a->tare_left;
    int64_t found = kali_wrench_convert(a);
    if (!a->given) {
        a->seq = (a->seq + 1) & a->seq_mask; /* the codes are read: ask for the next sample */
        *a->control = (uint16_t)(a->request | a->seq);
    }
    ++*a->samples;
    *a->sample_tick = a->tick;
    if (taring && !a->tare_left) {
        ++*a->tare_count;
        *a->tare_state = (uint8_t)a->done;
    }
    return found;
}

/* ================================================================ SIO's tick
 *
 * The McGill boards' command registers for a tick (boards/mcgill.py: McGillBoards.control for
 * every arm, then end_tick, the reference).  The state between ticks (ticks, bit, prev_bit)
 * lives here, and the reference steps the same fields.
 * Returns 1 when this tick's writes were a retrigger (the level fell, C.4). */

static inline int64_t retrigger_level(const McgillArgs *a, int64_t tick) {
    return (tick / a->retrigger_ticks) % 2 == 0 ? a->retrigger : 0;
}

int64_t kali_mcgill_control(McgillArgs *a) {
    int halted = __atomic_load_n(a->fault_active, __ATOMIC_ACQUIRE) != 0;
    for (int64_t k = 0; k < a->n_arms; k++) {
        int64_t power = AT(uint8_t, a->power, k);
        int64_t csr = a->base_csr | a->bit;
        if (power == a->on && !halted) csr |= a->green_red;
        if (halted) csr &= ~a->no_disable;
        else if (power == a->enabling && AT(int32_t, a->enable_ticks, k) <= a->hold_ticks)
            csr |= a->enable;
        if (AT(uint8_t, a->capture, k)) csr &= ~a->index_off; /* the pulse resets the counter */
        if (power == a->off) {
            uint16_t *codes = (uint16_t *)(a->codes + k * a->codes_row);
            for (int64_t j = 0; j < AT(int64_t, a->n_joints, k); j++) codes[j] = (uint16_t)a->dac_zero;
            if (AT(uint8_t, a->power_reg, k) & a->amps_on) csr &= ~a->no_disable;
        }
        AT(uint8_t, a->csr, k) = (uint8_t)csr;
    }
    int64_t fell = a->prev_bit && !a->bit;
    a->ticks += 1;
    a->prev_bit = a->bit;
    a->bit = retrigger_level(a, a->ticks + 1);
    return fell;
}

/* SIO's tick in two passes (sio/cycle.py: SioCycle._tick_reference is what they do, step for
 * step; the kernels they call are the ones SIO binds).  kali_sio_front reads the encoders,
 * steps the velocity filter and the wrist sensors, steps every robot, checks the joints,
 * takes the feed-forward and feeds the slots, then posts the SVs' feed semaphores;
 * kali_sio_back, once the servos are done, acknowledges for the gang, sums the torques,
 * writes the DACs, checks the currents, drives the boards, publishes and records the tick.
 * Where the Python reference does something the common tick does not (an index pulse to catch
 * while calibrating, a sensor's halt or its
 * guard reached, a robot kali_sio_robots leaves, a joint beyond its range or runaway, a
 * current beyond its limit) a pass returns that event, with `stage` where it goes on: SIO
 * does that part in Python and calls the pass again.  The board-specific steps (the encoders,
 * the DACs, the command registers) are the boards' kernels, called through their pointers. */

enum { SIO_FED, SIO_DONE, SIO_CAPTURE, SIO_SENSOR, SIO_ROBOTS, SIO_CHECK, SIO_CURRENT, SIO_WAIT };
enum { ST_READ, ST_VELOCITY, ST_SENSORS, ST_ROBOTS, ST_CHECKS, ST_FEED, ST_WAIT, ST_BACK, ST_OUT };

static inline int64_t thread_cpu_ns(void) { /* rt.thread_time_ns */
    struct timespec t;
    clock_gettime(CLOCK_THREAD_CPUTIME_ID, &t);
    return (int64_t)t.tv_sec * 1000000000 + t.tv_nsec;
}

int64_t kali_sio_front(SioArgs *a) {
    switch (a->stage) {
    case ST_READ: {
        a->t_read = now_ns();
        a->c_read = thread_cpu_ns();
        a->faulted = *a->fault_active != 0;
        int64_t count = (int64_t)*a->fault_count;
        if (count != a->faults_seen) { /* a halt since the last tick, maybe already cleared */
            a->faults_seen = count;
            a->faulted = 1;
        }
        a->read_fn(a->read_args);
        a->stage = ST_VELOCITY;
        for (int64_t k = 0; k < a->n_robots; k++)
            if (a->capture[k]) return SIO_CAPTURE; /* calibrating: a counter reset by its pulse */
    } /* fall through */
    case ST_VELOCITY:
        kali_velocity(a->velocity);
        a->at = 0;
        a->stage = ST_SENSORS;
        /* fall through */
    case ST_SENSORS:
        while (a->at < a->n_sensors) {
            int64_t s = a->at++;
            WrenchArgs *w = a->sensors[s];
            w->tick = a->tick;
            int64_t found = kali_wrench_tick(w);
            if (found != WRENCH_OK
                || (*a->guard_state[s] == (uint32_t)a->guard_armed && w->force >= *a->guard_n[s])) {
                a->result = found;
                return SIO_SENSOR; /* sensor at - 1 */
            }
        }
        a->stage = ST_ROBOTS;
        /* fall through */
    case ST_ROBOTS:
        a->robots->faulted = a->faulted;
        a->stage = ST_CHECKS;
        a->result = kali_sio_robots(a->robots);
        if (a->result) return SIO_ROBOTS;
        /* fall through */
    case ST_CHECKS:
        a->stage = ST_FEED;
        if (!a->faulted) {
            a->result = kali_checks(a->checks);
            if (a->result != -1) return SIO_CHECK; /* NO_FAULT */
        }
        /* fall through */
    case ST_FEED:
        for (int64_t k = 0; k < a->n_robots; k++) { /* SioCycle._arm_robot */
            int arm = AT(int32_t, a->arm_algo, k) != (int32_t)a->arm_none;
            int whole = arm || AT(uint32_t, a->arm_op, k) != 0 || AT(uint32_t, a->shadows, k) != 0;
            if (whole != a->whole[k]) {
                a->whole[k] = (uint8_t)whole;
                int64_t lo = AT(int64_t, a->bounds, k), hi = AT(int64_t, a->bounds, k + 1);
                for (int64_t i = lo; i < hi; i++)
                    AT(uint32_t, a->mark, i) = whole ? (uint32_t)a->arm_held : 0u;
                if (whole && hi > lo) AT(uint32_t, a->mark, lo) = (uint32_t)a->arm_free;
            }
            a->ff[k]->arm = arm;
            a->ff[k]->tick = a->tick;
            kali_feedforward(a->ff[k]);
        }
        a->fed = kali_feed(a->feed);
        a->t_fed = now_ns();
        *a->fed_ns = a->t_fed;
        __atomic_store_n(a->ctrl_tick, a->tick, __ATOMIC_RELEASE); /* last: its slots are out */
        if (a->post)
            for (int64_t s = 0; s < a->n_feeds; s++) sem_post(a->feeds[s]);
        a->stage = ST_WAIT;
        return SIO_FED;
    }
    return SIO_FED;
}

int64_t kali_sio_back(SioArgs *a) {
    switch (a->stage) {
    case ST_BACK:
        if (a->ok) /* every servo done: the SVs' acknowledgements before SIO's (gang.py) */
            for (int64_t g = 0; g < a->n_gang; g++) {
                int64_t slot = a->gang_slot[g];
                if (AT(int64_t, a->signal_tick, slot) != a->tick) continue;
                int64_t took = a->sv_fed_tick[a->gang_sv[g]];
                if (took == a->tick) {
                    AT(int64_t, a->ack_tick, slot) = a->tick;
                } else if (took >= a->tick - a->gang_lag[g]) {
                    AT(int64_t, a->vouched_tick, slot) = a->tick; /* first: see gang.py */
                    ORDERED();
                    AT(int64_t, a->ack_tick, slot) = a->tick;
                }
            }
        a->t_done = now_ns();
        for (int64_t s = 0; s < a->n_feeds; s++) /* each SV takes its own in sv_learn */
            if (a->t_done - a->t_fed > LOAD(a->served_max[s]))
                __atomic_store_n(&a->served_max[s], a->t_done - a->t_fed, __ATOMIC_RELAXED);
        for (int64_t k = 0; k < a->n_robots; k++) /* a robot-level servo's is the whole torque */
            if (AT(int32_t, a->arm_algo, k) != (int32_t)a->arm_none) {
                int64_t hi = AT(int64_t, a->bounds, k + 1);
                for (int64_t i = AT(int64_t, a->bounds, k); i < hi; i++) AT(double, a->ff_out, i) = 0.0;
            }
        kali_torques(a->torques);
        a->dac_fn(a->dac_args);
        a->stage = ST_OUT;
        a->result = kali_current_check(a->current);
        if (a->result >= 0) return SIO_CURRENT;
        /* fall through */
    case ST_OUT: {
        a->t_out = now_ns();
        a->c_out = thread_cpu_ns();
        if (a->control_fn(a->control_args)) a->retrigger_tick = *a->clock_tick;
        if (a->ack_early) *a->ack_early = a->tick; /* the I/O is done: bookkeeping follows */
        kali_copy(a->publish);
        for (int64_t k = 0; k < a->n_robots; k++) {
            AT(int64_t, a->robots_tick, k) = a->tick;
            AT(uint32_t, a->robots_faults, k) = (uint32_t)a->faults_seen;
        }
        int64_t late = a->t_out - a->t_read;
        *a->lat_last = late;
        if (late > *a->lat_max) *a->lat_max = late;
        a->hist[lateness_bin(late, a->linear_us, a->log_bins)] += 1u;
        FlightArgs *f = a->flight;
        f->tick = a->tick;
        f->t_read = a->t_read;
        f->latency = late;
        f->wait = a->t_done - a->t_fed;
        f->ran = a->c_out - a->c_read;
        kali_flight_row(f);
        a->stage = ST_READ;
        return SIO_DONE;
    }
    }
    return SIO_DONE;
}

/* The whole tick in one call: the front pass, then (where SIO posted the feeds) the sleep on
 * the done semaphore for one servo period at most, the done semaphore drained, then the back
 * pass.  SIO_FED is returned only where it did not post (the lockstep executive runs the
 * SVs in SIO's process, then calls again); SIO_WAIT when the servos were not done within a
 * period (SioCycle._wait_done goes on waiting in slices and judges, in Python). */
int64_t kali_sio_tick(SioArgs *a) {
    if (a->stage < ST_WAIT) {
        int64_t event = kali_sio_front(a);
        if (event != SIO_FED || !a->post) return event;
    }
    if (a->stage == ST_WAIT) {
        if (a->fed) {
            int64_t until = now_ns() + a->slice_ns;
            while ((int64_t)__atomic_load_n(a->ctrl_done, __ATOMIC_ACQUIRE) < a->fed) {
                int got = sem_wait_until(a->done_sem, until);
                if (got != 0 && got != EINTR) return SIO_WAIT;
            }
        }
        while (sem_trywait(a->done_sem) == 0) /* a post that raced with the last look */
            ;
        a->ok = 1;
        a->stage = ST_BACK;
    }
    return kali_sio_back(a);
}
