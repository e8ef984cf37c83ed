/* An FR3's kernels (hardware/franka/arms.py): the arm's record is the hardware.  Read: each
 * joint's angle from the newest state packet, and which packet it was.  Write: torques held to
 * the FR3's torque rate and clamped to its limits (a jump the robot would refuse), into the
 * command.  Control: each arm's wish for torque control, its command stamped with the state it
 * answers (release: the torques are in before the stamp), and its link woken. */

int64_t kali_franka_read(FrankaReadArgs *a) {
    for (int64_t k = 0; k < a->n_arms; k++)
        AT(uint64_t, a->seen, k) =
            __atomic_load_n((uint64_t *)(a->arms + AT(int64_t, a->seq_off, k)), __ATOMIC_ACQUIRE);
    for (int64_t i = 0; i < a->n; i++)
        AT(double, a->q, i) = *(double *)(a->arms + AT(int64_t, a->q_off, i));
    return 0;
}

int64_t kali_franka_write(FrankaWriteArgs *a) {
    for (int64_t i = 0; i < a->n; i++) {
        double limit = AT(double, a->torque_limit, i), t = AT(double, a->torque, i);
        AT(uint8_t, a->clamped, i) = fabs(t) > limit;
        double last = AT(double, a->last, i), step = AT(double, a->step, i);
        if (t > last + step) t = last + step;
        if (t < last - step) t = last - step;
        if (t > limit) t = limit; /* last: the limit holds whatever the last torque was */
        if (t < -limit) t = -limit;
        AT(double, a->last, i) = t;
        AT(double, a->current, i) = t;
        *(double *)(a->arms + AT(int64_t, a->tau_off, i)) = t;
    }
    return 0;
}

int64_t kali_franka_control(FrankaControlArgs *a) {
    int halted = __atomic_load_n(a->fault_active, __ATOMIC_ACQUIRE) != 0;
    for (int64_t k = 0; k < a->n_arms; k++) {
        char *arm = a->arms + k * a->row;
        int64_t power = AT(uint8_t, a->power, k);
        int want = !halted && (power == a->on || power == a->enabling);
        *(uint8_t *)(arm + a->want_off) = (uint8_t)want;
        if (!want) {
            double *tau = (double *)(arm + a->tau_off);
            int64_t base = AT(int64_t, a->base, k);
            for (int64_t j = 0; j < AT(int64_t, a->n_joints, k); j++) {
                tau[j] = 0.0;
                AT(double, a->last, base + j) = 0.0;
            }
        }
        __atomic_store_n((uint64_t *)(arm + a->cmd_seq_off), AT(uint64_t, a->seen, k),
                         __ATOMIC_RELEASE);
        if (a->links[k]) sem_post(a->links[k]);
    }
    a->ticks += 1;
    return 1;
}
