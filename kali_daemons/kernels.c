/* The servo path's per-tick arithmetic, compiled (issue 26 item 2): see kernels.py.
 *
 * Every kernel takes one pointer to its argument block, laid out once at configure time
 * (the arrays never move: arena views and preallocated arrays), so a call costs ~0.3 us.
 * The blocks' structs are generated from their one declaration (kernel_args.py) into
 * kernel_args.h, as are their ctypes classes; kali_layout() lists each one's fields, and
 * kernels.load() refuses a library whose layout is not the ctypes classes'.
 * A per-joint array is a View: its first element and its stride in bytes, so arena record
 * fields (strided) and private arrays (contiguous) are read alike.  The arithmetic is the
 * reference numpy implementation's, operation for operation, built with -ffp-contract=off
 * so no multiply-add is fused: the results are bit for bit numpy's. */

#define _POSIX_C_SOURCE 200809L /* clock_gettime */

#include <errno.h>
#include <math.h>
#include <semaphore.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>
#include <time.h>

#include "kernel_args.h" /* every block's and record's struct: kernel_args.py */

#define AT(type, v, i) (*(type *)((v).p + (int64_t)(i) * (v).stride))

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

/* ---------------------------------------------------------------- the plant's drives
 *
 * The plant's amplifiers and motors each cycle (plant/motor.py: drive_reference, the
 * MotorBank's cycle and the plant's writes into MuJoCo): the current the loop drives to,
 * the range the bus voltage leaves it at the motor's speed ([0, 0] with the amplifier off),
 * the asymmetric Coulomb remainder; then MuJoCo's actuator ranges, controls, activations
 * (the currents, cut into the range at once) and applied joint forces.  numpy's minimum
 * and maximum propagate NaN: so do np_min and np_max.  tanh is libm's: numpy's differs in
 * the last bit for some values, so this equals its reference to ~1e-15, not bit for bit. */

static inline double np_max(double a, double b) { return (a >= b || a != a) ? a : b; }
static inline double np_min(double a, double b) { return (a <= b || a != a) ? a : b; }

int64_t kali_motors(MotorArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double b = a->qd[i] * a->gear[i] * a->kt_r[i]; /* back-EMF / R */
        double hi = np_min(a->vbus_r[i] - b, a->i_max[i]);
        double lo = np_max(-(a->vbus_r[i] + b), -a->i_max[i]);
        hi = np_max(hi, lo);
        lo = lo * a->enabled[i]; /* an amplifier that is off: [0, 0] */
        hi = hi * a->enabled[i];
        double c = np_min(np_max(a->volts[i] * a->gain[i], lo), hi);
        double t = tanh(a->qd[i] * a->w_scale[i]);
        double f = np_min(t, 0.0) * a->g_extra_neg[i] - np_max(t, 0.0) * a->g_extra_pos[i];
        a->ctrl[i] = c;
        a->range[2 * i] = lo;
        a->range[2 * i + 1] = hi;
        a->friction[i] = f;
        int64_t u = a->acts[i];
        a->mj_actrange[2 * u] = lo;
        a->mj_actrange[2 * u + 1] = hi;
        a->mj_ctrl[u] = c;
        a->mj_act[a->act_adr[i]] = np_min(np_max(a->current[i], lo), hi);
        a->mj_qfrc[a->dofs[i]] = f;
    }
    return 0;
}

/* ---------------------------------------------------------------- the plant's encoders
 *
 * The HCTL-2000 counters of every board each plant cycle (plant/board.py: EncoderBank.sample,
 * the reference, bit for bit): each joint's motor angle in quadrature counts, the index
 * pulse captured where the motor passed it (the counter's reference moved there and the
 * channel's bit set in its board's index register, unless CSR_INDEX_OFF), the count modulo
 * 4096 into the board's counter register.  Returns the indexes captured. */

/* numpy's float -> int64 cast of a whole number: the minimum for NaN and out of range */
static inline int64_t to_int64(double f) {
    return (f >= -9223372036854775808.0 && f < 9223372036854775808.0) ? (int64_t)f : INT64_MIN;
}

int64_t kali_encoders(EncoderArgs *a) {
    int64_t captured = 0;
    for (int64_t i = 0; i < a->n; i++) {
        int64_t raw = to_int64(floor(a->angle[i] * a->cpr[i]));
        double rev = floor((a->angle[i] - a->phase[i]) / a->two_pi);
        double was = a->rev[i];
        if (rev != was) { /* rare: a few times per motor revolution */
            int64_t k = a->robot_of[i];
            if (!(AT(uint8_t, a->csr, k) & a->index_off)) {
                double passed = was > rev ? was : rev; /* the revolution whose index was passed */
                a->ref[i] = to_int64(floor((a->phase[i] + a->two_pi * passed) * a->cpr[i]));
                AT(uint8_t, a->index, k) |= (uint8_t)(1u << a->joint_of[i]);
                captured++;
            }
        }
        a->rev[i] = rev;
        int64_t c = (int64_t)((uint64_t)raw - (uint64_t)a->ref[i]) % a->modulo; /* wraps as numpy */
        if (c < 0) c += a->modulo;
        a->count[i] = c;
        *(uint16_t *)(a->encoders + a->enc_off[i]) = (uint16_t)c;
    }
    return captured;
}

/* ---------------------------------------------------------------- a cycle's statistics
 *
 * daemon.py's _CycleStats.record_reference, field for field: one cycle of a process-table
 * slot accounted (lateness and execution time, their maxima, the lateness histogram's bin
 * as layout.lateness_bin gives it, the heartbeat), then its acknowledgement, last: the
 * store the clock reads. */

/* layout.lateness_bin: a lateness's histogram bin */
static int64_t lateness_bin(int64_t ns, int64_t linear_us, int64_t log_bins) {
    int64_t us = ns >= 0 ? ns / 1000 : -((-ns + 999) / 1000); /* Python's floor // */
    if (us < linear_us) return us > 0 ? us : 0;
    int64_t b = (int64_t)(log2((double)us / (double)linear_us) * 8.0);
    return linear_us + (b < log_bins - 1 ? b : log_bins - 1);
}

int64_t kali_cycle_stats(StatsArgs *a) {
    int64_t late = a->woke - a->release, exe = a->done - a->woke;
    *a->late = late;
    if (late > *a->late_max) *a->late_max = late;
    *a->exec = exe;
    if (exe > *a->exec_max) *a->exec_max = exe;
    a->hist[lateness_bin(late, a->linear_us, a->log_bins)] += 1u;
    *a->heart = a->done;
    *a->acks += 1u;
    __atomic_store_n(a->ack, a->tick, __ATOMIC_RELEASE); /* last */
    return 0;
}

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

/* ---------------------------------------------------------------- the plant's I/O boards
 *
 * Every arm's I/O board each plant cycle (plant/board.py: IoBoardSim.update and .convert,
 * the references): the power switch, watchdog and brakes from the command/status register
 * and the e-stop at the plant's time, then the motors' enable and the brakes per joint; after
 * MuJoCo's step, the pot ADC's conversions and digital register.  A board's state is its row
 * of `state` (IoBoardSim.state: the same array the reference steps).  kali_boards_truth puts
 * the boards' flags into the arms' truth records. */

enum { B_AMPS, B_BRAKES, B_TRIPPED, B_SWITCH, B_SINCE, B_RETRIGGER, B_PREV_CSR, B_PREV_ADC, B_STATE };

static void set_amps(int64_t *s, int64_t on, int64_t now) {
    if (on != s[B_AMPS]) {
        s[B_AMPS] = on;
        s[B_SWITCH] = now;
    }
}

/* IoBoardSim.update for every board, then the joints' enable and brakes; 1 if a brake
 * changed (the plant then sets MuJoCo's friction). */
int64_t kali_boards_update(BoardArgs *a) {
    int64_t now = a->now_ns, changed = 0;
    for (int64_t k = 0; k < a->n_arms; k++) {
        int64_t *s = a->state + k * B_STATE;
        int64_t csr = AT(uint8_t, a->csr, k), prev = s[B_PREV_CSR];
        s[B_PREV_CSR] = csr;
        int64_t estop = AT(uint8_t, a->estop, k) != 0;
        int64_t fell = (prev & a->retrigger) && !(csr & a->retrigger);
        if (csr & a->timeout_on) {
            if (!(prev & a->timeout_on)) s[B_RETRIGGER] = now; /* the timer starts */
            if (fell) {
                s[B_RETRIGGER] = now;
                s[B_TRIPPED] = 0;
            } else if (now - s[B_RETRIGGER] > a->watchdog_ns) {
                s[B_TRIPPED] = 1;
            }
        } else if (s[B_TRIPPED] && fell) {
            s[B_TRIPPED] = 0;
        }
        int64_t disabled = !(csr & a->no_disable) || estop || s[B_TRIPPED];
        if (csr & a->enable) {
            if (s[B_SINCE] == a->never || !(prev & a->enable)) s[B_SINCE] = now;
        } else {
            s[B_SINCE] = a->never;
        }
        if (disabled) {
            s[B_SINCE] = a->never;
            set_amps(s, 0, now);
        } else if (s[B_SINCE] != a->never && now - s[B_SINCE] >= a->hold_ns) {
            set_amps(s, 1, now);
        }
        if (s[B_BRAKES] != s[B_AMPS] && now - s[B_SWITCH] >= a->brake_ns) s[B_BRAKES] = s[B_AMPS];
        if ((csr & a->index_off) && AT(uint8_t, a->index, k)) AT(uint8_t, a->index, k) = 0;
        AT(uint8_t, a->power, k) = (uint8_t)((s[B_AMPS] ? a->p_amps : 0) |
                                             (s[B_BRAKES] ? a->p_brakes : 0) |
                                             (s[B_TRIPPED] ? a->p_tripped : 0) |
                                             (estop ? a->p_estop : 0));
        double on = s[B_AMPS] ? 1.0 : 0.0;
        uint8_t braked = !s[B_BRAKES];
        int64_t lo = a->base[k], hi = lo + a->count[k];
        for (int64_t i = lo; i < hi; i++) a->enabled[i] = on;
        if (hi > lo && a->braked[lo] != braked) {
            for (int64_t i = lo; i < hi; i++) a->braked[i] = braked;
            changed = 1;
        }
    }
    return changed;
}

/* board.adc_code(board.pot_volts(q, lo, hi)): Python's round is half to even, as nearbyint */
static int64_t pot_code(const BoardArgs *a, double q, double lo, double hi) {
    double v = a->pot_v_min + (a->pot_v_max - a->pot_v_min) * (q - lo) / (hi - lo);
    v = v > 0.0 ? v : 0.0;
    v = v < a->adc_volts ? v : a->adc_volts;
    double code = nearbyint(v / a->adc_volts * a->adc_top);
    code = code > 0.0 ? code : 0.0;
    return (int64_t)(code < a->adc_top ? code : a->adc_top);
}

/* IoBoardSim.convert for every board at the angles now in q */
int64_t kali_boards_convert(BoardArgs *a) {
    for (int64_t k = 0; k < a->n_arms; k++) {
        int64_t *s = a->state + k * B_STATE;
        int64_t ctrl = AT(uint16_t, a->adc_control, k), start = (ctrl & a->adc_start) != 0;
        int64_t base = a->base[k], n = a->count[k];
        if (start && !s[B_PREV_ADC]) {
            int64_t ch = ctrl & a->channel_mask, code = 0; /* unconnected inputs read 0 */
            if (ch >= a->channels) {
                AT(uint32_t, a->clamped, k) += 1u;
                ch = a->channels - 1;
            }
            if (ch < n) {
                code = pot_code(a, a->q[base + ch], a->lo[base + ch], a->hi[base + ch]);
            } else if (ch == a->self_test) {
                double v = a->adc_volts / 2.0;
                code = (int64_t)nearbyint(v / a->adc_volts * a->adc_top);
            }
            AT(uint16_t, a->adc_analog, k) = (uint16_t)(a->adc_done | code);
        } else if (!start && s[B_PREV_ADC]) {
            AT(uint16_t, a->adc_analog, k) &= (uint16_t)a->value_mask;
        }
        s[B_PREV_ADC] = start;
        int64_t digital = 0; /* the channels above 2.5 V */
        for (int64_t j = 0; j < n; j++)
            if (a->q[base + j] > a->mid[base + j]) digital |= (int64_t)1 << j;
        AT(uint16_t, a->adc_digital, k) = (uint16_t)digital;
    }
    return 0;
}

int64_t kali_boards_truth(BoardArgs *a) {
    for (int64_t k = 0; k < a->n_arms; k++) {
        const int64_t *s = a->state + k * B_STATE;
        AT(uint8_t, a->amps_on, k) = (uint8_t)(s[B_AMPS] != 0);
        AT(uint8_t, a->brakes_engaged, k) = (uint8_t)(s[B_BRAKES] == 0);
        AT(uint8_t, a->watchdog_tripped, k) = (uint8_t)(s[B_TRIPPED] != 0);
        AT(uint8_t, a->truth_estop, k) = AT(uint8_t, a->estop, k);
    }
    return 0;
}

/* ---------------------------------------------------------------- the plant's joints and DACs
 *
 * plant/sim.py's PlantSim._read_dac and ._read_joints (the references, operation for
 * operation): the DAC boards' codes to amplifier volts (a code past 12 bits clamped and
 * counted on its arm's board), and after MuJoCo's step the joints' angles, velocities and
 * motor currents gathered from MuJoCo's arrays, the motor angles and joint torques. */

int64_t kali_plant_dac(PlantIoArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double v = (double)*(uint16_t *)(a->dacs + a->dac_off[i]);
        if (v > a->top) { /* rare: a bad register value */
            AT(uint32_t, a->clamped, a->robot_of[i]) += 1u;
            v = a->top;
        }
        a->volts[i] = (v - a->zero) * a->scale;
    }
    return 0;
}

int64_t kali_plant_joints(PlantIoArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double q = a->qpos[a->qpos_idx[i]], current = a->act[a->act_adr[i]];
        a->q[i] = q;
        a->qd[i] = a->qvel[a->dofs[i]];
        a->current[i] = current;
        a->motor_angle[i] = a->gear[i] * q;
        a->torque[i] = a->gkt[i] * current;
    }
    return 0;
}

/* ---------------------------------------------------------------- the plant's truth
 *
 * The arms' and the world's truth after each plant cycle (plant/sim.py's
 * PlantSim._write_truth_reference, step for step; the joints' truth and the boards' flags are
 * kali_copy's and kali_boards_truth's): whether each arm grasps (its weld active), the weld's
 * force and torque on the object, each wrist sensor's true wrench, each push on a tool, the
 * simulated time and cycles, the object's pose and the squeeze between the first two grasps.
 * A weld's rows are in MuJoCo's constraint arrays, which move as contacts come and go: while
 * one is active the kernel returns 1 before writing anything, the plant copies the rows
 * (_weld_forces) and calls it again with welds_read set. */

#define ROW(v, k) ((double *)((v).p + (int64_t)(k) * (v).stride))
#define WRENCH 6 /* layout.WRENCH: force and torque, a weld's constraint rows too */

static double internal_force(const PlantTruthArgs *a) {
    int64_t first = -1, second = -1;
    for (int64_t k = 0; k < a->n; k++) {
        if (a->held[k] && first < 0) first = k;
        else if (a->held[k]) { second = k; break; }
    }
    if (second < 0) return 0.0;
    const double *pa = a->site_xpos + 3 * a->grasp_site[first];
    const double *pb = a->site_xpos + 3 * a->grasp_site[second];
    double u0 = pb[0] - pa[0], u1 = pb[1] - pa[1], u2 = pb[2] - pa[2];
    double norm = sqrt(u0 * u0 + u1 * u1 + u2 * u2);
    if (norm == 0.0) return 0.0;
    u0 /= norm, u1 /= norm, u2 /= norm;
    const double *fa = a->weld + WRENCH * first, *fb = a->weld + WRENCH * second;
    return 0.5 * ((fb[0] * u0 + fb[1] * u1 + fb[2] * u2) - (fa[0] * u0 + fa[1] * u1 + fa[2] * u2));
}

int64_t kali_plant_truth(PlantTruthArgs *a) {
    int any = 0;
    for (int64_t k = 0; k < a->n; k++) any |= a->held[k] = a->eq_active[k] != 0;
    if (any && !a->welds_read) return 1;
    a->welds_read = 0;
    for (int64_t k = 0; k < a->n; k++) {
        double *wrench = ROW(a->grasp_wrench, k), *ft = ROW(a->ft_wrench, k);
        double *push = ROW(a->push, k);
        const double *xfrc = a->xfrc + 6 * a->tool_body[k]; /* MuJoCo's 6 a body */
        for (int c = 0; c < WRENCH; c++) wrench[c] = a->held[k] ? a->weld[WRENCH * k + c] : 0.0;
        AT(uint8_t, a->grasped, k) = a->held[k];
        for (int c = 0; c < WRENCH; c++) ft[c] = a->ft_true[WRENCH * k + c];
        for (int c = 0; c < 3; c++) push[c] = xfrc[c];
    }
    *a->sim_time_ns = a->sim_ns;
    *a->ticks = (uint64_t)a->cycles;
    *a->internal_force = internal_force(a);
    memcpy(a->object_pose, a->object_qpos, 7 * sizeof(double));
    return 0;
}

/* ---------------------------------------------------------------- the wrist sensors' gauges
 *
 * One arm's wrist sensor and gauge ADC bank each plant cycle (plant/board.py: FtBank.cycle,
 * the reference, step for step): its offsets walk by the sheet's drift; a new request
 * samples the six bridges, v = C^-1 (w + noise) + offset, into signed 16-bit codes clipped at
 * the rails.  The normal draws are numpy's, drawn ahead into `normals` (a Generator fills an
 * array one element after another from its stream: the block holds the very numbers the
 * reference draws six at a time); the kernel takes them in order and returns 1 once fewer
 * than a cycle's most (12) are left, for FtBank to draw more outside the kernel. */

int64_t kali_ft_bank(FtArgs *a) {
    const double *r = a->normals + a->at;
    for (int i = 0; i < 6; i++) a->offset[i] += r[i] * a->drift;
    a->at += 6;
    int64_t ctrl = __atomic_load_n(a->control, __ATOMIC_ACQUIRE);
    int64_t seq = ctrl & a->seq_mask;
    if ((ctrl & a->request) && seq != a->served) {
        a->served = seq;
        r = a->normals + a->at;
        a->at += 6;
        double w[6];
        for (int i = 0; i < 6; i++) w[i] = r[i] * a->noise_sd[i] + a->wrench[i];
        for (int i = 0; i < 6; i++) {
            double v = 0.0;
            for (int j = 0; j < 6; j++) v += a->gauges[i * 6 + j] * w[j];
            v = nearbyint((v + a->offset[i]) / a->volts_per_code);
            v = v < -a->rail - 1.0 ? -a->rail - 1.0 : (v > a->rail ? a->rail : v);
            a->codes[i] = v == v ? (int16_t)v : 0;
        }
        __atomic_store_n(a->status, (uint16_t)(a->ready | seq), __ATOMIC_RELEASE); /* last */
    }
    return a->size - a->at < 12;
}

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

/* ---------------------------------------------------------------- the robots' common path
 *
 * SIO's per-robot step where nothing is happening to the robot (sio/daemon.py's
 * ServoIO._robot is the reference; this is its last branch): its pots read, powered ON with
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

/* ---------------------------------------------------------------- publish */

/* m flat arrays of n elements each into their records */
int64_t kali_copy(CopyArgs *a) {
    for (int64_t c = 0; c < a->m; c++) {
        Copy *k = &a->copies[c];
        for (int64_t i = 0; i < a->n; i++)
            memcpy(k->dst.p + i * k->dst.stride, k->src.p + i * k->src.stride, (size_t)k->size);
    }
    return 0;
}

/* ---------------------------------------------------------------- the flange pose
 *
 * Forward kinematics of a robot type's serial chain (chain.py), for the servo I/O process:
 * the flange in the base frame, to turn a wrist force/torque reading into the world frame
 * and take the tool's gravity out.  chain_pose is for the kernels here to call each tick;
 * kali_chain_pose exposes it to Python and the tests (chain.flange_pose is its reference).
 * Unlike the kernels above it equals its reference to ~1e-15, not bit for bit: numpy's 4x4
 * products go through BLAS, which sums (and fuses) in an order of its own. */

/* t = t * m, t the top 3x4 of a rigid transform (its bottom row is 0 0 0 1), m a row-major
 * 4x4 rigid transform: the 4x4 product's terms in its order, less those times m's zeros. */
static inline void affine_times(double *t, const double *m) {
    for (int k = 0; k < 3; k++) {
        double *row = t + 4 * k;
        double t0 = row[0], t1 = row[1], t2 = row[2], t3 = row[3];
        for (int j = 0; j < 4; j++) row[j] = t0 * m[j] + t1 * m[4 + j] + t2 * m[8 + j];
        row[3] += t3;
    }
}

/* The flange pose of an n-joint chain at joint angles q[0..n-1] (rad) into out (16 doubles,
 * row-major 4x4): origins[0] Rot(axes[0], q[0]) ... origins[n-1] Rot(axes[n-1], q[n-1])
 * origins[n].  origins: n + 1 row-major 4x4 rigid transforms, 16 doubles each, contiguous
 * (chain.Chain.origins: joint i's frame in its parent's at zero angle; the last one the
 * flange in joint n-1's frame); axes: n unit axes, 3 doubles each, in the joints' own frames.
 * Rot is Rodrigues' c I + s [a]x + (1 - c) a a^T, entry for entry as chain._rotation has it.
 * Rigid transforms only: the bottom rows are taken as 0 0 0 1 and out's is written so.
 * Everything on the stack, no libm call but sin and cos; out is written last. */
static void chain_pose(int64_t n, const double *origins, const double *axes, const double *q,
                       double *out) {
    double t[12]; /* the product so far, its top 3x4 */
    memcpy(t, origins, sizeof t);
    for (int64_t i = 0; i < n; i++) {
        if (i > 0) affine_times(t, origins + 16 * i);
        const double *a = axes + 3 * i;
        double x = a[0], y = a[1], z = a[2];
        double c = cos(q[i]), s = sin(q[i]), u = 1.0 - c;
        double r[9] = {
            u * x * x + c,     u * x * y - s * z, u * x * z + s * y,
            u * x * y + s * z, u * y * y + c,     u * y * z - s * x,
            u * x * z - s * y, u * y * z + s * x, u * z * z + c,
        };
        for (int k = 0; k < 3; k++) { /* t = t * [r 0; 0 1]: the translation stays */
            double *row = t + 4 * k;
            double t0 = row[0], t1 = row[1], t2 = row[2];
            for (int j = 0; j < 3; j++) row[j] = t0 * r[j] + t1 * r[3 + j] + t2 * r[6 + j];
        }
    }
    affine_times(t, origins + 16 * n);
    memcpy(out, t, sizeof t);
    out[12] = 0.0;
    out[13] = 0.0;
    out[14] = 0.0;
    out[15] = 1.0;
}

int64_t kali_chain_pose(ChainPoseArgs *a) {
    chain_pose(a->n, a->origins, a->axes, a->q, a->out);
    return 0;
}

/* ---------------------------------------------------------------- a wrist sensor in Newtons
 *
 * One arm's force/torque sample, from its gauge codes to the contact wrench at the tool point
 * (sio/wrench.py; wrench.convert_reference is the reference, equal to ~1e-12: numpy's small
 * products go through BLAS).  In order: volts and the calibration matrix (raw: the wrench the
 * tool exerts on the sensor); the sensor frame in the world (base * flange pose at q) and the
 * tool's weight there, [m g; c x m g]; a tare in progress sums raw - weight and, at its last
 * sample, sets the bias and restarts the filter; the reading less the bias (sensor); the
 * checks; the contact wrench (sensor - weight), its low-pass, and the wrench at the tool
 * point (0, 0, tip) in tool and world axes.  Returns WRENCH_OK or the first check that
 * failed; the message is Python's to build. */

enum { WRENCH_OK, WRENCH_SATURATED, WRENCH_RATED, WRENCH_CONTACT, WRENCH_SILENT };

/* The conversion alone, for the tests against convert_reference. */
int64_t kali_wrench_convert(WrenchArgs *a) {
    double v[6], pose[16], w[16], gs[3], c[6];
    for (int i = 0; i < 6; i++) v[i] = a->codes[i] * a->volts;
    for (int i = 0; i < 6; i++) {
        double s = 0.0;
        for (int j = 0; j < 6; j++) s += a->cal[6 * i + j] * v[j];
        a->raw[i] = s;
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
    for (int i = 0; i < 6; i++)
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

/* One servo tick of one arm's sensor: a sample the board has answered for is converted
 * (kali_wrench_convert) and the next asked for at once; a tare command starts a tare; a sensor
 * that has not answered for more than stale_limit ticks is WRENCH_SILENT. */
int64_t kali_wrench_tick(WrenchArgs *a) {
    uint16_t status = *a->status;
    if (!(status & a->ready) || (int64_t)(status & a->seq_mask) != a->seq)
        return ++*a->stale > (uint32_t)a->stale_limit ? WRENCH_SILENT : WRENCH_OK;
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
    a->seq = (a->seq + 1) & a->seq_mask; /* the codes are read: ask for the next sample */
    *a->control = (uint16_t)(a->request | a->seq);
    ++*a->samples;
    *a->sample_tick = a->tick;
    if (taring && !a->tare_left) {
        ++*a->tare_count;
        *a->tare_state = (uint8_t)a->done;
    }
    return found;
}

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

/* What a client writes while the SV looks: read from memory each time, never cached. */
#define LOAD(x) __atomic_load_n(&(x), __ATOMIC_RELAXED)

/* Whether a slot can run in a unit: nothing to do before or after its step (a shadow
 * trial's step follows the active one's on the per-slot path). */
static inline int joins(SlotRecord *s, uint32_t pid_a, uint32_t pd_a) {
    uint32_t algo = LOAD(s->algo);
    return LOAD(s->op) == 0 && LOAD(s->reset) == 0 && LOAD(s->enabled) != 0 &&
           LOAD(s->shadow_state) != SHADOW_RUNNING && (algo == pid_a || algo == pd_a);
}

static inline int64_t now_ns(void) {
    struct timespec t;
    clock_gettime(CLOCK_MONOTONIC, &t);
    return (int64_t)t.tv_sec * 1000000000 + t.tv_nsec;
}

/* sem_timedwait's deadline (CLOCK_REALTIME) ns from now */
static struct timespec realtime_in(int64_t ns) {
    struct timespec until;
    clock_gettime(CLOCK_REALTIME, &until);
    ns = (ns > 0 ? ns : 0) + until.tv_nsec;
    until.tv_sec += (time_t)(ns / 1000000000);
    until.tv_nsec = (long)(ns % 1000000000);
    return until;
}

/* rt.poll_semaphore: read (never take) sem's value until it is posted or deadline passes */
static void poll_posted(sem_t *sem, int64_t deadline) {
    int v = 0;
    while (sem_getvalue(sem, &v) == 0 && v == 0 && now_ns() < deadline)
        ;
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

/* SIO's tick in two passes (sio/daemon.py: ServoIO._tick_reference is what they do, step for
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
        for (int64_t k = 0; k < a->n_robots; k++) { /* ServoIO._arm_robot */
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
        for (int64_t k = 0; k < a->n_robots; k++) AT(int64_t, a->robots_tick, k) = a->tick;
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
 * period (ServoIO._wait_done goes on waiting in slices and judges, in Python). */
int64_t kali_sio_tick(SioArgs *a) {
    if (a->stage < ST_WAIT) {
        int64_t event = kali_sio_front(a);
        if (event != SIO_FED || !a->post) return event;
    }
    if (a->stage == ST_WAIT) {
        if (a->fed) {
            struct timespec until = realtime_in(a->slice_ns);
            while ((int64_t)__atomic_load_n(a->ctrl_done, __ATOMIC_ACQUIRE) < a->fed)
                if (sem_timedwait(a->done_sem, &until) != 0 && errno != EINTR) return SIO_WAIT;
        }
        while (sem_trywait(a->done_sem) == 0) /* a post that raced with the last look */
            ;
        a->ok = 1;
        a->stage = ST_BACK;
    }
    return kali_sio_back(a);
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
        struct timespec until = realtime_in(end - now_ns());
        int got;
        while ((got = sem_timedwait(a->feed_sem, &until)) != 0 && errno == EINTR)
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

/* ---------------------------------------------------------------- a clocked process's wait
 *
 * daemon.ClockWait.wait_reference, step for step: the base loop's wait for the wall clock's
 * signal (thesis 3.6.2).  Polling (an SV on another CPU than SIO's, real time), while the
 * clock keeps signalling: sleep on this CPU's timer to the next due tick (the clock's own
 * within a period, else this period's next: daemon.next_wake) plus *after, poll the
 * semaphore's value there for poll_ns, then take the post.  WAIT_IDLE when no signal came within idle_ns,
 * WAIT_INTR when a signal handler interrupted the wait (Python runs it and
 * calls again), WAIT_SHUTDOWN when the post came with the arena's shutdown flag.  Each call
 * first accounts and acknowledges the cycle the last signal ran (kali_clock_settle). */

enum { WAIT_SIGNAL, WAIT_IDLE, WAIT_INTR, WAIT_SHUTDOWN };

/* The cycle of the last signal has run: account it and acknowledge (kali_cycle_stats), then,
 * in lockstep, post the clock's acknowledgement. */
int64_t kali_clock_settle(WaitArgs *a) {
    if (!a->cycled) return 0;
    StatsArgs *st = a->stats;
    st->tick = a->tick;
    st->release = a->since;
    st->woke = a->woke;
    st->done = now_ns();
    kali_cycle_stats(st);
    if (a->ack_sem) sem_post(a->ack_sem);
    a->cycled = 0;
    return 0;
}

int64_t kali_clock_wait(WaitArgs *a) {
    kali_clock_settle(a);
    int64_t after = 0;
    if (a->poll_ns && a->signalled) {
        after = LOAD(*a->after);
        int64_t next = LOAD(*a->next_due); /* daemon.next_wake */
        if (next <= a->tick || next > a->tick + a->period_ticks)
            next = (a->tick / a->period_ticks + 1) * a->period_ticks;
        int64_t due = LOAD(*a->release) + (next - a->tick) * a->base_ns + after, t = now_ns();
        if (t < due) {
            struct timespec at = {(time_t)(due / 1000000000), (long)(due % 1000000000)};
            while (clock_nanosleep(CLOCK_MONOTONIC, TIMER_ABSTIME, &at, NULL) == EINTR)
                ;
            t = due;
        }
        poll_posted(a->sem, t + a->poll_ns);
    }
    struct timespec until = realtime_in(a->idle_ns);
    if (sem_timedwait(a->sem, &until) != 0) {
        if (errno == EINTR) return WAIT_INTR;
        a->signalled = 0;
        return WAIT_IDLE;
    }
    a->woke = now_ns();
    a->signalled = 1;
    if (LOAD(*a->shutdown)) return WAIT_SHUTDOWN;
    a->tick = __atomic_load_n(a->signal_tick, __ATOMIC_ACQUIRE);
    a->since = LOAD(*a->release) + after; /* lateness from when it meant to wake */
    a->cycled = 1; /* the caller runs the cycle; the next call (or settle) accounts it */
    return WAIT_SIGNAL;
}
