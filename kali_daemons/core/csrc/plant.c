/* The simulator's kernels: drives, encoders, I/O boards, joints and DACs, truth, wrist
 * gauges (plant/).
 * Part of a library's one translation unit (simulator.c), after common.h. */

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
        AT(uint32_t, a->scans, k) += 1u;
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
 * kali_copy's and kali_boards_truth's): whether each arm grasps (one of its welds active) and
 * which object, the weld's force and torque on the object, each wrist sensor's true wrench,
 * each push on a tool, the simulated time and cycles, every free object's pose and the
 * squeeze between the first two grasps of one object.  A weld's rows are in MuJoCo's
 * constraint arrays, which move as contacts come and go: while one is active the kernel
 * returns 1 before writing anything, the plant copies the rows (_weld_forces) and calls it
 * again with welds_read set. */

#define ROW(v, k) ((double *)((v).p + (int64_t)(k) * (v).stride))

static double internal_force(const PlantTruthArgs *a) {
    int64_t first = -1, second = -1;
    for (int64_t k = 0; k < a->n; k++) {
        if (a->held[k] && first < 0) first = k;
        else if (a->held[k] && a->held_object[k] == a->held_object[first]) { second = k; break; }
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
    for (int64_t k = 0; k < a->n; k++) {
        a->held[k] = 0;
        a->held_object[k] = -1;
        for (int64_t g = 0; g < a->welds; g++) {
            if (a->eq_active[k * a->welds + g]) {
                a->held[k] = 1;
                a->held_object[k] = a->graspable[g];
            }
        }
        any |= a->held[k];
    }
    if (any && !a->welds_read) return 1;
    a->welds_read = 0;
    for (int64_t k = 0; k < a->n; k++) {
        double *wrench = ROW(a->grasp_wrench, k), *ft = ROW(a->ft_wrench, k);
        double *push = ROW(a->push, k);
        const double *xfrc = a->xfrc + 6 * a->tool_body[k]; /* MuJoCo's 6 a body */
        for (int c = 0; c < WRENCH; c++) wrench[c] = a->held[k] ? a->weld[WRENCH * k + c] : 0.0;
        AT(uint8_t, a->grasped, k) = a->held[k];
        AT(int8_t, a->holding, k) = (int8_t)a->held_object[k];
        for (int c = 0; c < WRENCH; c++) ft[c] = a->ft_true[WRENCH * k + c];
        for (int c = 0; c < 3; c++) push[c] = xfrc[c];
    }
    *a->sim_time_ns = a->sim_ns;
    *a->ticks = (uint64_t)a->cycles;
    *a->internal_force = internal_force(a);
    memcpy(a->object_pose, a->object_qpos, (size_t)(7 * a->objects) * sizeof(double));
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
