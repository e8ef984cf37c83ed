/* The SVs' kernels: the built-in servos, the units, the robot-level built-ins and the serve
 * (servo/, sv/).
 * Part of a library's one translation unit (controller.c), after common.h. */

/* ================================================================ the built-in servos
 *
 * The PID of thesis figure 3.4 and the PD (servo/builtins.py), over many joints in one call.
 * Each algorithm's private data for the cell is one arena block of a record per slot; its
 * struct (PidRecord, PdRecord, SlotRecord in kernel_args.h) is generated from the record's
 * numpy dtype and kali_fields() lists its fields, so that kernels.load() refuses a library
 * whose structs differ from the dtypes.  pid_row and pd_row are pid_step and
 * pd_step: the same operations in the same order (no contraction), so the same numbers. */

/* pid_step on one record (written in place): the torque, the filtered error into *error. */
static inline double pid_row(PidRecord *d, double demand, double position, double *error) {
    if (d->primed == 0) { /* first step after init: start at rest here (_prime) */
        d->error = demand - position;
        d->old_position = position;
        d->old_velocity = 0.0;
        d->primed = 1;
    }
    double e = d->lpfe2 * (d->lpfe1 * (demand - position) + d->error);
    double v_raw = (position - d->old_position) * d->inv_period;
    double v = d->lpfv2 * (d->lpfv1 * v_raw + d->old_velocity);
    d->error = e;
    d->old_position = position;
    d->old_velocity = v;
    double integral = d->integral, band = d->integration_band;
    if (-band <= e && e <= band) {
        integral += d->ki_t * e;
        double reset = d->integration_reset;
        if (integral > reset)
            integral = reset;
        else if (integral < -reset)
            integral = -reset;
        d->integral = integral;
    }
    double bias = d->bias;
    d->bias = bias * d->bias_decay;
    *error = e;
    return d->kp * e + integral - d->kv * v + bias;
}

/* pd_step on one record (written in place): the torque, the error into *error. */
static inline double pd_row(PdRecord *d, double demand, double position, double *error) {
    if (d->primed == 0) {
        d->error = demand - position;
        d->old_position = position;
        d->old_velocity = 0.0;
        d->primed = 1;
    }
    double e = demand - position;
    double v_raw = (position - d->old_position) * d->inv_period;
    double v = d->lpfv2 * (d->lpfv1 * v_raw + d->old_velocity);
    d->error = e;
    d->old_position = position;
    d->old_velocity = v;
    double bias = d->bias;
    d->bias = bias * d->bias_decay;
    *error = e;
    return d->kp * e - d->kv * v + bias;
}

/* The PID on records rows[0..n-1] of data, with demand[k] and position[k]: torques, errors
 * and statuses out (servo.vector.pid_vector_step). */
int64_t kali_pid_vector(VectorArgs *a) {
    PidRecord *data = (PidRecord *)a->data;
    for (int64_t k = 0; k < a->n; k++) {
        double e;
        AT(double, a->torque, k) = pid_row(&data[AT(int64_t, a->rows, k)],
                                           AT(double, a->demand, k),
                                           AT(double, a->position, k), &e);
        AT(double, a->error, k) = e;
        AT(int32_t, a->status, k) = (int32_t)a->ok;
    }
    return 0;
}

/* The PD, like kali_pid_vector. */
int64_t kali_pd_vector(VectorArgs *a) {
    PdRecord *data = (PdRecord *)a->data;
    for (int64_t k = 0; k < a->n; k++) {
        double e;
        AT(double, a->torque, k) = pd_row(&data[AT(int64_t, a->rows, k)],
                                          AT(double, a->demand, k),
                                          AT(double, a->position, k), &e);
        AT(double, a->error, k) = e;
        AT(int32_t, a->status, k) = (int32_t)a->ok;
    }
    return 0;
}

/* ---------------------------------------------------------------- an SV's unit */

#define SHADOW_RUNNING 1u /* layout.ShadowState.RUNNING */

/* Whether a slot can run in a unit: nothing to do before or after its step (a shadow
 * trial's step follows the active one's on the per-slot path). */
static inline int joins(SlotRecord *s, uint32_t pid_a, uint32_t pd_a) {
    uint32_t algo = LOAD(s->algo);
    return LOAD(s->op) == 0 && LOAD(s->reset) == 0 && LOAD(s->enabled) != 0 &&
           LOAD(s->shadow_state) != SHADOW_RUNNING && (algo == pid_a || algo == pd_a);
}

/* Claim and run the unit of slots lo..hi-1 (sv/units.py): each fed, unclaimed slot with
 * nothing to do first is claimed by compare-and-swap of busy 0 -> me (the same sequentially
 * consistent lock cmpxchg as atomic.CompareExchange32 through libatomic), re-checked (a
 * client's operation may have come meanwhile: then it goes into left), and stepped.
 * Returns the slots run; n_left, fault, bad and exec_ns are written into the block. */
int64_t kali_serve_unit(UnitArgs *a) {
    int64_t t0 = now_ns();
    uint32_t pid_a = (uint32_t)a->pid_a, pd_a = (uint32_t)a->pd_a, me = (uint32_t)a->me;
    int64_t ran = 0, n_left = 0, fault = -1;
    double bad = 0.0;
    for (int64_t i = a->lo; i < a->hi; i++) {
        SlotRecord *s = &a->slots[i];
        if (LOAD(s->busy) != 0) continue; /* not fed, or claimed already */
        if (!joins(s, pid_a, pd_a)) continue; /* the per-slot path's */
        uint32_t expected = 0;
        if (!__atomic_compare_exchange_n(&s->busy, &expected, me, 0, __ATOMIC_SEQ_CST,
                                         __ATOMIC_SEQ_CST))
            continue;
        if (!joins(s, pid_a, pd_a)) { /* a client's operation came meanwhile */
            a->left[n_left++] = i;
            continue;
        }
        double error, torque;
        if (LOAD(s->algo) == pid_a)
            torque = pid_row(&a->pid[i], s->demand, s->position, &error);
        else
            torque = pd_row(&a->pd[i], s->demand, s->position, &error);
        ran++;
        s->exec_ns = a->exec_ns;
        if (!isfinite(torque)) {
            s->torque = 0.0;
            if (fault < 0) {
                fault = i;
                bad = torque;
            }
            continue;
        }
        s->torque = torque;
        s->error = error;
        s->status = (int32_t)a->ok;
        s->ran_tick = a->tick;
        s->sv = (int32_t)a->sv;
    }
    a->n_left = n_left;
    a->fault = fault;
    a->bad = bad;
    if (ran) a->exec_ns = (now_ns() - t0) / ran;
    return ran;
}

/* ---------------------------------------------------------------- a robot-level servo's torques out
 *
 * The SV's last step for a robot under a robot-level servo (sv/arm.py's
 * ArmRunner._finish_reference, step for step): a disabled joint gets no torque; every
 * joint's slot then holds its torque, its tracking error q_d - q, status 0, the tick and the
 * SV, as a joint servo leaves them, and the step's duration since t0 (each slot its share);
 * the robot's record the same.  A torque that is not finite writes nothing: 1 (the SV halts,
 * naming the algorithm). */

int64_t kali_arm_finish(ArmFinishArgs *a) {
    int64_t n = a->n;
    for (int64_t i = 0; i < n; i++)
        if (!isfinite(a->tau[i])) return 1;
    for (int64_t i = 0; i < n; i++) {
        if (AT(uint32_t, a->enabled, i) == 0) a->tau[i] = 0.0;
        AT(double, a->torque, i) = a->tau[i];
        AT(double, a->error, i) = a->q_d[i] - a->q[i];
        AT(int32_t, a->status, i) = 0;
        AT(int64_t, a->ran, i) = a->tick;
        AT(int32_t, a->sv, i) = (int32_t)a->sv_index;
    }
    int64_t exe = now_ns() - a->t0;
    for (int64_t i = 0; i < n; i++) AT(int64_t, a->exec, i) = exe / n;
    *a->arm_status = 0;
    *a->arm_exec_ns = exe;
    *a->arm_ran_tick = a->tick;
    return 0;
}

/* ---------------------------------------------------------------- robot-level built-ins
 *
 * One step of a built-in robot-level servo (servo/armbuiltins.py: its module docstring gives
 * the laws) on one arm, its record the arena's, stepped in place; the inputs the SV's
 * ArmInput, contiguous.  Each equals its Python step to ~1e-12 (numpy's small products go
 * through BLAS, which sums in an order of its own). */

/* The drive's friction torque of joint j at velocity v (dynamics.inverse.DriveFriction:
 * viscous plus asymmetric Coulomb smoothed by tanh), term for term as numpy computes it. */
static inline double drive_friction(const ArmArgs *a, int64_t j, double v) {
    double fr = v * a->viscous[j];
    double th = tanh(v * a->gear_w[j]);
    fr += (th > 0.0 ? th : 0.0) * a->coulomb_pos[j];
    fr -= (th < 0.0 ? th : 0.0) * a->coulomb_neg[j];
    return fr;
}

/* The drive's friction of joint j in the direction the impedance moves it: viscous at the
 * demand's velocity v, Coulomb at the sign of v plus the joint's drive s (N·m: all but the
 * damping) over band times its Coulomb level (servo.armbuiltins._friction_toward). */
static inline double friction_toward(const ArmArgs *a, int64_t j, double v, double s,
                                     double band) {
    int64_t n = a->n;
    const double *J = a->J;
    double lin = sqrt(J[j] * J[j] + J[n + j] * J[n + j] + J[2 * n + j] * J[2 * n + j]);
    double ang = sqrt(J[3 * n + j] * J[3 * n + j] + J[4 * n + j] * J[4 * n + j] +
                      J[5 * n + j] * J[5 * n + j]);
    double lever = lin + ang * 0.1; /* m: the joint's reach at the tool (0.1 m for turning) */
    double x = v * a->gear_w[j];
    double width = band * lever; /* N·m: band N at the tool */
    if (width > 0.0) x += s / width;
    double th = tanh(x);
    double fr = v * a->viscous[j];
    fr += (th > 0.0 ? th : 0.0) * a->coulomb_pos[j];
    fr -= (th < 0.0 ? th : 0.0) * a->coulomb_neg[j];
    return fr;
}

static inline double clamp(double x, double lim) { return x < -lim ? -lim : (x > lim ? lim : x); }

/* computed torque (thesis 2.2.3): tau = M (qdd_d + kd de + kp e + ki int e) + h
 * + friction(qd_d) + bias; then the bias decays and each joint's integral advances */
int64_t kali_computed_torque(ArmArgs *a) {
    CtRecord *d = (CtRecord *)a->d;
    int64_t n = a->n;
    double u[8];
    for (int64_t j = 0; j < n; j++) {
        double x = (a->q_d[j] - a->q[j]) * d->kp;
        x += (a->qd_d[j] - a->qd[j]) * d->kd;
        x += a->qdd_d[j];
        x += d->integral[j] * d->ki;
        u[j] = x;
    }
    for (int64_t j = 0; j < n; j++) {
        double t = 0.0;
        for (int64_t k = 0; k < n; k++) t += a->M[j * n + k] * u[k];
        t += a->h[j];
        if (d->friction != 0.0) t += drive_friction(a, j, a->qd_d[j]);
        t += d->bias[j];
        d->bias[j] *= d->decay;
        a->tau[j] = t;
        d->integral[j] = clamp(d->integral[j] + (a->q_d[j] - a->q[j]) * d->dt, d->ilimit);
    }
    return 0;
}

/* v (6: two halves of 3) into tool axes in place: each half times R as a row vector. */
static inline void to_tool(double *v, const double *r) {
    for (int h = 0; h < 6; h += 3) {
        double a = v[h], b = v[h + 1], c = v[h + 2];
        for (int j = 0; j < 3; j++) v[h + j] = a * r[j] + b * r[4 + j] + c * r[8 + j];
    }
}

/* Cartesian impedance about the tool point: the pose error in world axes (translation,
 * then the rotation vector of R_d R^T), the joint velocity error and the twist error J dq;
 * both into tool axes; F = k e + f, plus the squeeze along the line to the partner; with a
 * sensor the force feedback kf (R^T w + F) and its integral; damping d edot; tau = J^T R F +
 * M qdd_d + kq dq + h + friction(qd_d) + bias; then the bias decays and the integrals
 * advance. */
int64_t kali_impedance(ArmArgs *a) {
    ImpRecord *d = (ImpRecord *)a->d;
    int64_t n = a->n;
    const double *p = a->pose, *pd = a->pose_d; /* R is p[0..2, 0..2]: row stride 4 */
    double e[6], edot[6], f[6], imb[6], dq[8];
    /* the pose error: translation, then log(R_d R^T) as a rotation vector */
    for (int i = 0; i < 3; i++) e[i] = pd[4 * i + 3] - p[4 * i + 3];
    double s[9];
    for (int i = 0; i < 3; i++)
        for (int j = 0; j < 3; j++)
            s[3 * i + j] = pd[4 * i] * p[4 * j] + pd[4 * i + 1] * p[4 * j + 1] +
                           pd[4 * i + 2] * p[4 * j + 2];
    e[3] = 0.5 * (s[7] - s[5]);
    e[4] = 0.5 * (s[2] - s[6]);
    e[5] = 0.5 * (s[3] - s[1]);
    double c = 0.5 * (s[0] + s[4] + s[8] - 1.0);
    c = c < -1.0 ? -1.0 : (c > 1.0 ? 1.0 : c);
    double angle = acos(c), sn = sin(angle);
    if (sn > 1e-9)
        for (int i = 3; i < 6; i++) e[i] *= angle / sn;
    for (int64_t j = 0; j < n; j++) dq[j] = a->qd_d[j] - a->qd[j];
    for (int i = 0; i < 6; i++) {
        double sum = 0.0;
        for (int64_t j = 0; j < n; j++) sum += a->J[i * n + j] * dq[j];
        edot[i] = sum;
    }
    to_tool(e, p);
    to_tool(edot, p);
    for (int i = 0; i < 6; i++) f[i] = e[i] * d->k[i] + d->f[i];
    int64_t partner = (int64_t)d->partner;
    int squeezing = partner > 0 && a->has_sensor && partner <= a->robots;
    if (squeezing) { /* push along the line to the partner (world: R u) */
        double line[3];
        for (int i = 0; i < 3; i++)
            line[i] = p[4 * i] * d->u[0] + p[4 * i + 1] * d->u[1] + p[4 * i + 2] * d->u[2];
        const double *other = (const double *)(a->wrenches + (partner - 1) * a->wrench_stride);
        double o = other[0] * line[0] + other[1] * line[1] + other[2] * line[2];
        double m = a->wrench[0] * line[0] + a->wrench[1] * line[1] + a->wrench[2] * line[2];
        double squeeze = 0.5 * (o - m);
        d->squeeze = squeeze;
        double push = d->fi + d->gi + d->kpi * (d->fi - squeeze);
        for (int i = 0; i < 3; i++) f[i] += d->u[i] * push;
    }
    if (a->has_sensor) { /* the imbalance R^T w + F fed back, with its integral */
        for (int i = 0; i < 6; i++) imb[i] = a->wrench[i];
        to_tool(imb, p);
        for (int i = 0; i < 6; i++) {
            imb[i] += f[i];
            f[i] += imb[i] * d->kf;
            f[i] += d->integral[i];
        }
    } else {
        for (int i = 0; i < 6; i++) imb[i] = 0.0;
    }
    double w[6]; /* R F (world axes), then with the sensed wrench: what drives the joints */
    for (int h = 0; h < 6; h += 3)
        for (int i = 0; i < 3; i++)
            w[h + i] = p[4 * i] * f[h] + p[4 * i + 1] * f[h + 1] + p[4 * i + 2] * f[h + 2];
    if (a->has_sensor)
        for (int i = 0; i < 6; i++) w[i] += a->wrench[i];
    double drive[8]; /* J^T (R F + w) */
    for (int64_t j = 0; j < n; j++) {
        double sum = 0.0;
        for (int i = 0; i < 6; i++) sum += w[i] * a->J[i * n + j];
        drive[j] = sum + (d->drive[j] - sum) * d->cdecay; /* low-passed */
        d->drive[j] = drive[j];
    }
    for (int i = 0; i < 6; i++) f[i] += edot[i] * d->d[i];
    for (int h = 0; h < 6; h += 3)
        for (int i = 0; i < 3; i++)
            w[h + i] = p[4 * i] * f[h] + p[4 * i + 1] * f[h + 1] + p[4 * i + 2] * f[h + 2];
    double kq = d->kq;
    for (int64_t j = 0; j < n; j++) {
        double t = 0.0, mq = 0.0;
        for (int i = 0; i < 6; i++) t += w[i] * a->J[i * n + j];
        for (int64_t k = 0; k < n; k++) mq += a->M[j * n + k] * a->qdd_d[k];
        t += mq;
        t += dq[j] * kq;
        t += a->h[j];
        if (d->friction != 0.0) t += friction_toward(a, j, a->qd_d[j], drive[j], d->cband);
        t += d->bias[j];
        d->bias[j] *= d->decay;
        a->tau[j] = t;
    }
    double gain = d->kfi * d->dt;
    for (int i = 0; i < 6; i++) {
        /* held while the imbalance or the damper's force is outside the band */
        int outside = fabs(imb[i]) > d->band[i] || fabs(edot[i] * d->d[i]) > d->band[i];
        double step = outside ? 0.0 : imb[i];
        d->integral[i] = clamp(d->integral[i] + step * gain, d->limit[i]);
    }
    if (squeezing) d->gi = clamp(d->gi + d->kii * d->dt * (d->fi - d->squeeze), d->imax);
    return 0;
}

/* ---------------------------------------------------------------- an SV's serve
 *
 * sv/daemon.py: ServoWorker._serve_reference, step for step: note the tick whose feed this SV
 * took, then claim and run the robots fed whole, every robot's unit (kali_serve_unit), then
 * the single slots, counting each done (the tick's last posts SIO's done semaphore), and the
 * SV's execution-time record.  What runs Python (a robot fed whole: its model and its
 * robot-level servo; a unit's non-finite torque, which halts; the slots a unit left and every
 * single slot: a plugin, a mailbox operation, a reset, a disabled servo) is handed back as an
 * event, the claimed robot or slot in `at`; SIO's serve calls the kernel again, with `count`
 * the slots that Python ran, and it goes on. */

enum { SV_DONE, SV_ARM, SV_FAULT, SV_LEFT, SV_SLOT };
enum { SV_START, SV_ARMS, SV_UNITS, SV_UNIT_DONE, SV_UNIT_LEFT, SV_SLOTS, SV_END, SV_FEED };

static void sv_done(ServeArgs *a, int64_t count) {
    uint32_t before = __atomic_fetch_add(a->ctrl_done, (uint32_t)count, __ATOMIC_SEQ_CST);
    if ((int64_t)(before + (uint32_t)count) == a->fed) sem_post(a->done_sem); /* the last */
}

/* ServoWorker._learn_feed: note when SIO fed this tick and the longest the servos took from
 * a feed since the last time, and choose when to wake: before the earliest feed where they
 * are worth sharing (over share_ns in share_looks of the last history; while shared, over
 * half that), else once the SV on SIO's CPU has run them all, never later than the cap; and
 * how often: every tick where they are worth sharing, else every rest_ticks. */
static void sv_learn(ServeArgs *a) {
    int64_t k = a->feed_k;
    a->feed_seen[k] = LOAD(*a->fed_ns) - LOAD(*a->release);
    a->served[k] = __atomic_exchange_n(a->served_max, 0, __ATOMIC_RELAXED);
    a->feed_k = (k + 1) % a->history;
    int64_t lo = a->feed_seen[0], hi = a->feed_seen[0], heavy = 0;
    int64_t limit = a->sharing ? a->share_ns / 2 : a->share_ns; /* shared, they take ~half */
    for (int64_t m = 0; m < a->history; m++) {
        if (a->feed_seen[m] < lo) lo = a->feed_seen[m];
        if (a->feed_seen[m] > hi) hi = a->feed_seen[m];
        heavy += a->served[m] > limit;
    }
    int64_t share = a->sharing = heavy >= a->share_looks;
    int64_t after = share ? lo - a->margin_ns : hi + a->share_ns;
    if (after > a->cap_ns) after = a->cap_ns;
    *a->poll_after = after > 0 ? after : 0;
    a->want_ticks = share ? a->servo_ticks : a->rest_ticks;
}

/* ServoWorker._await_feed: SIO's fed tick says whether the tick wanted is fed; its posts
 * only wake.  Take every post there is, then read the fed tick (SIO writes it before it
 * posts, so a post taken here is of that tick or an older one: left by ticks this SV missed
 * or rested through); not yet fed: poll the value for poll_ns (an SV on another CPU than
 * SIO's: SIO's post then wakes nobody), sleep for a post, and look again, at most
 * feed_wait_ns in all.  1: fed (fed_tick), 0: no feed in time. */
static int sv_await_feed(ServeArgs *a) {
    int64_t t = now_ns(), end = t + a->feed_wait_ns, poll_end = t + a->poll_ns;
    for (;;) {
        while (sem_trywait(a->feed_sem) == 0)
            ;
        int64_t fed = __atomic_load_n(a->ctrl_tick, __ATOMIC_ACQUIRE);
        if (fed >= a->wanted) {
            if (a->learn) sv_learn(a);
            a->fed_tick = fed;
            return 1;
        }
        if (a->poll_ns) poll_posted(a->feed_sem, poll_end);
        int got;
        while ((got = sem_wait_until(a->feed_sem, end)) == EINTR)
            ;
        if (got != 0) return 0; /* else: the fed tick again, with any other post */
    }
}

int64_t kali_sv_serve(ServeArgs *a) {
    if (a->stage == SV_FEED) {
        if (!sv_await_feed(a)) {
            a->fed_tick = -1; /* SIO did not feed this tick: nothing to run */
            a->stage = SV_END;
            return SV_DONE;
        }
        a->stage = SV_START;
    }
    if (a->stage == SV_START) {
        *a->fed_tick_out = a->fed_tick; /* before any slot: SIO may acknowledge for it now */
        a->t0 = now_ns();
        a->fed = (int64_t)__atomic_load_n(a->ctrl_fed, __ATOMIC_ACQUIRE);
        if (a->fed == 0) {
            a->stage = SV_END;
            return SV_DONE;
        }
        a->tick_now = __atomic_load_n(a->ctrl_tick, __ATOMIC_ACQUIRE);
        a->ran = a->count = a->at = 0;
        a->stage = SV_ARMS;
    }
    if (a->stage == SV_ARMS) { /* robots fed whole: one SV runs each, in Python */
        if (a->count) { /* the robot Python just ran */
            a->ran += a->count;
            sv_done(a, a->count);
            a->count = 0;
        }
        while (a->at < a->n_arms) {
            uint32_t *busy = &a->slots[a->arm_lo[a->at++]].busy;
            uint32_t expected = (uint32_t)a->arm_free;
            if (LOAD(*busy) == expected
                && __atomic_compare_exchange_n(busy, &expected, (uint32_t)a->me, 0,
                                               __ATOMIC_SEQ_CST, __ATOMIC_SEQ_CST))
                return SV_ARM; /* robot at - 1 */
        }
        a->unit = 0;
        a->stage = SV_UNITS;
    }
    while (a->stage == SV_UNITS || a->stage == SV_UNIT_DONE || a->stage == SV_UNIT_LEFT) {
        if (a->unit >= a->n_units) {
            a->at = 0;
            a->stage = SV_SLOTS;
            break;
        }
        UnitArgs *u = a->units[a->unit];
        if (a->stage == SV_UNITS) {
            u->tick = a->tick_now;
            a->count = kali_serve_unit(u);
            a->stage = SV_UNIT_DONE;
            if (a->count && u->fault >= 0) return SV_FAULT; /* Python halts: slot u->fault */
        }
        if (a->stage == SV_UNIT_DONE) {
            if (a->count) {
                a->ran += a->count;
                sv_done(a, a->count);
            }
            a->count = 0;
            a->stage = SV_UNIT_LEFT;
            if (u->n_left) return SV_LEFT; /* Python runs them, each counted done there */
        }
        a->ran += u->n_left; /* SV_UNIT_LEFT */
        a->unit++;
        a->stage = SV_UNITS;
    }
    if (a->stage == SV_SLOTS) { /* every other fed slot, in Python */
        if (a->count) { /* the slot Python just ran */
            a->ran += a->count;
            sv_done(a, a->count);
            a->count = 0;
        }
        while (a->at < a->n) {
            uint32_t *busy = &a->slots[a->order[a->at++]].busy;
            uint32_t expected = 0;
            if (LOAD(*busy) != 0) continue; /* not fed, or another worker has it */
            if (__atomic_compare_exchange_n(busy, &expected, (uint32_t)a->me, 0, __ATOMIC_SEQ_CST,
                                            __ATOMIC_SEQ_CST))
                return SV_SLOT; /* slot order[at - 1] */
        }
        if (a->ran) {
            int64_t exe = now_ns() - a->t0;
            *a->exec_last = exe;
            if (exe > *a->exec_max) *a->exec_max = exe;
            *a->servos += (uint64_t)a->ran;
            a->exec_hist[lateness_bin(exe, a->linear_us, a->log_bins)] += 1u;
        }
        a->stage = SV_END;
    }
    return SV_DONE;
}
