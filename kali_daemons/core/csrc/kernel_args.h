/* Generated from kali_daemons/core/kernel_args.py by
 * `python -m kali_daemons.core.kernel_args`: edit the declarations there, not this file.
 * Included by common.h. */

#ifndef KALI_KERNEL_ARGS_H
#define KALI_KERNEL_ARGS_H

#include <semaphore.h>
#include <stddef.h>
#include <stdint.h>
#include <string.h>

typedef int64_t (*KernelFn)(void *); /* a kernel, as another calls it */

/* ---------------------------------------------------- the records, from their dtypes */

/* layout.SERVO_SLOT */
typedef struct {
    uint32_t busy;
    uint32_t op;
    uint32_t op_algo;
    uint32_t op_lock;
    uint32_t ops_done;
    uint32_t algo;
    uint32_t enabled;
    int32_t status;
    double demand;
    double position;
    double velocity;
    double demand_vel;
    double demand_acc;
    double ff;
    double torque;
    double error;
    uint32_t reset;
    int32_t op_status;
    int64_t ran_tick;
    int64_t exec_ns;
    int32_t sv;
    int32_t shadow;
    uint32_t shadow_state;
    uint32_t _pad;
    double shadow_torque;
    uint64_t shadow_n;
    double shadow_sq;
    double shadow_peak;
} SlotRecord;

/* layout.PID_DTYPE */
typedef struct {
    double kp;
    double ki;
    double kv;
    double fe;
    double fv;
    double integration_band;
    double integration_reset;
    double bias_tau;
    double sampling_period;
    double inv_period;
    double ki_t;
    double lpfe1;
    double lpfe2;
    double lpfv1;
    double lpfv2;
    double bias_decay;
    double error;
    double old_position;
    double old_velocity;
    double integral;
    double bias;
    uint32_t primed;
} PidRecord;

/* layout.PD_DTYPE */
typedef struct {
    double kp;
    double kv;
    double fv;
    double bias_tau;
    double sampling_period;
    double inv_period;
    double lpfv1;
    double lpfv2;
    double bias_decay;
    double error;
    double old_position;
    double old_velocity;
    double bias;
    uint32_t primed;
} PdRecord;

/* layout.IMPEDANCE_DTYPE */
typedef struct {
    double k[6];
    double d[6];
    double f[6];
    double integral[6];
    double limit[6];
    double band[6];
    double partner;
    double fi;
    double u[3];
    double kpi;
    double kii;
    double squeeze;
    double gi;
    double kf;
    double kfi;
    double imax;
    double kq;
    double cband;
    double ctau;
    double cdecay;
    double friction;
    double handover_s;
    double dt;
    double decay;
    double bias[8];
    double drive[8];
} ImpRecord;

/* layout.CT_DTYPE */
typedef struct {
    double wn;
    double zeta;
    double friction;
    double handover_s;
    double kp;
    double kd;
    double wi;
    double ilimit;
    double ki;
    double dt;
    double decay;
    double bias[8];
    double integral[8];
} CtRecord;

/* ---------------------------------------------------------------- the blocks */

/* View (core): in other blocks */
typedef struct {
    char *p; /* element 0 */
    int64_t stride; /* bytes between elements */
} View;

/* ReadArgs (sio): kali_read */
typedef struct {
    int64_t n;
    char *encoders; /* the boards' registers */
    View enc_off; /* int64: joint i's counter at encoders + enc_off[i] (uint16) */
    View acc, prev; /* int32: accumulated counts, last 12-bit reading */
    View offset; /* double: calibration offsets, rad */
    View rad_per_count, q;
    int64_t modulo, half; /* 4096, 2048 (figure C.3) */
} ReadArgs;

/* VelocityArgs (sio): kali_velocity */
typedef struct {
    int64_t n;
    View q, q_prev, qd;
    double gain; /* rate * a */
    double b; /* 1 / (1 + a) */
} VelocityArgs;

/* ChecksArgs (sio): kali_checks */
typedef struct {
    int64_t n, n_robots;
    View bounds; /* int64, n_robots + 1: robot k's joints are bounds[k] .. bounds[k+1] */
    View q, demand, q_min, q_max;
    View range_check; /* uint8: nonzero = checked */
    View fed; /* uint8 (bool) */
    View safe; /* double: client-written limits */
    View safe_ok; /* double: the last valid limit of each joint (updated here) */
    double pi;
} ChecksArgs;

/* FeedArgs (sio): kali_feed */
typedef struct {
    int64_t n;
    View demand, q, qd, fed;
    View slot_demand, slot_position, slot_velocity;
    View slot_busy; /* uint32: 0 = fed (an SV may claim it), else not_fed */
    int64_t not_fed;
    uint32_t *ctrl_fed, *ctrl_done; /* the servo control record's counts */
    View demand_vel, demand_acc, ff, slot_demand_vel, slot_demand_acc, slot_ff;
    View mark; /* uint32 per slot: the busy value a fed slot gets (0, or ARM_FREE/ARM_HELD) */
} FeedArgs;

/* TorquesArgs (sio): kali_torques */
typedef struct {
    int64_t n;
    View slot_torque, fed, servo_torque, ff, torque;
} TorquesArgs;

/* DacArgs (sio): kali_dac */
typedef struct {
    int64_t n;
    View torque, gkt, current_limit, codes_per_amp;
    View current; /* double out, A */
    View clamped; /* uint8 (bool) out */
    char *dacs; /* the DAC boards' registers */
    View dac_off; /* int64: joint i's DAC code at dacs + dac_off[i] (uint16) */
    double zero, top; /* DAC code of 0 V, highest code */
} DacArgs;

/* CurrentArgs (sio): kali_current_check */
typedef struct {
    int64_t n;
    View torque, fed, clamped;
    View over; /* int64: consecutive fed ticks clamped */
    View current_ticks; /* int64: how many halt */
} CurrentArgs;

/* MotorArgs (plant): kali_motors */
typedef struct {
    int64_t n;
    const double *volts, *qd, *enabled, *current;
    const double *gear, *kt_r, *vbus_r, *i_max, *gain, *w_scale, *g_extra_pos, *g_extra_neg;
    double *ctrl, *range, *friction; /* the bank's: range is n x 2 (low, high) */
    const int64_t *acts, *act_adr, *dofs; /* joint i's actuator, activation, dof */
    double *mj_actrange, *mj_ctrl, *mj_act, *mj_qfrc; /* MuJoCo's arrays (actrange nu x 2) */
} MotorArgs;

/* EncoderArgs (plant): kali_encoders */
typedef struct {
    int64_t n;
    const double *angle, *cpr, *phase; /* motor angle, counts per rad, index phase */
    int64_t *ref, *count; /* the bank's: the count's zero, the count */
    double *rev; /* the bank's: revolution of the last index */
    const int64_t *robot_of, *joint_of;
    char *encoders; /* the boards' counter registers (uint16) */
    const int64_t *enc_off; /* joint i's at encoders + enc_off[i] */
    View csr, index; /* uint8 per board */
    int64_t index_off, modulo; /* CSR_INDEX_OFF; 4096 */
    double two_pi;
} EncoderArgs;

/* StatsArgs (clock): kali_cycle_stats */
typedef struct {
    int64_t *late, *late_max, *exec, *exec_max, *heart, *ack;
    uint64_t *acks;
    uint32_t *hist;
    int64_t linear_us, log_bins; /* layout.HIST_LINEAR_US, HIST_LOG_BINS */
    int64_t tick, release, woke, done;
} StatsArgs;

/* FlightArgs (flightrec): kali_flight_row */
typedef struct {
    int64_t n, n_robots, rows;
    char *ring;
    int64_t row_size;
    int64_t off_tick, off_t, off_lat, off_late, off_wait, off_ran, off_shadow, off_wrench;
    const int64_t *off_cols; /* the float64 columns' offsets in a row */
    const View *cols; /* their sources, n each */
    int64_t n_cols;
    View shadow; /* float64, n */
    const char *wrench; /* n_robots x 6 float64 */
    int64_t wrench_row, wrench_col; /* its strides, bytes */
    const int64_t *release; /* SIO's slot's release_ns */
    uint64_t *count; /* rows written: the header's, this writer's alone */
    int64_t tick, t_read, latency, wait, ran;
} FlightArgs;

/* BoardArgs (plant): kali_boards_update, kali_boards_convert, kali_boards_truth */
typedef struct {
    int64_t n_arms;
    View csr, estop, power, index, adc_control, adc_analog, adc_digital, clamped, scans; /* registers */
    View amps_on, brakes_engaged, watchdog_tripped, truth_estop; /* truth */
    int64_t *state; /* n_arms x B_STATE */
    const int64_t *base, *count; /* arm k's joints: flat base[k] .. base[k] + count[k] */
    double *enabled; /* per joint: the motor bank's enable (1.0 / 0.0) */
    uint8_t *braked; /* per joint: the brakes hold */
    const double *q, *lo, *hi, *mid; /* per joint: angle, the pots' span, 2.5 V */
    int64_t now_ns, hold_ns, watchdog_ns, brake_ns, never;
    int64_t timeout_on, retrigger, no_disable, enable, index_off; /* CSR bits */
    int64_t p_amps, p_brakes, p_tripped, p_estop; /* POWER bits */
    int64_t adc_start, channel_mask, adc_done, value_mask, channels, self_test;
    double pot_v_min, pot_v_max, adc_volts, adc_top;
} BoardArgs;

/* PlantIoArgs (plant): kali_plant_dac, kali_plant_joints */
typedef struct {
    int64_t n;
    const double *qpos, *qvel, *act; /* MuJoCo's */
    const int64_t *qpos_idx, *dofs, *act_adr; /* joint i's entries in them */
    const double *gear, *gkt;
    double *q, *qd, *current, *motor_angle, *torque;
    char *dacs; /* the DAC boards' records */
    const int64_t *dac_off, *robot_of; /* joint i's code at dacs + dac_off[i] */
    View clamped; /* uint32 per arm */
    double *volts;
    double top, zero, scale; /* 4095, the code of 0 V, volts per code */
} PlantIoArgs;

/* PlantTruthArgs (plant): kali_plant_truth */
typedef struct {
    int64_t n; /* arms */
    int64_t welds; /* graspable objects: arm k's weld of the g-th is k * welds + g */
    const uint8_t *eq_active; /* MuJoCo's: the welds, n x welds */
    const int64_t *graspable; /* welds: the g-th graspable's index among the objects */
    uint8_t *held; /* n, bool */
    int64_t *held_object; /* n: the object arm k holds, -1 none */
    const double *weld; /* n x 6: the rows _weld_forces copied */
    View grasped, holding; /* uint8 and int8, per arm record */
    View grasp_wrench, ft_wrench, push; /* each record's field (6, 6, 3 doubles) */
    const double *ft_true; /* n x 6 */
    const double *xfrc; /* MuJoCo's xfrc_applied, 6 a body */
    const int64_t *tool_body; /* n */
    const double *site_xpos; /* 3 a site */
    const int64_t *grasp_site; /* n: the grasp each arm took hold at */
    int64_t objects; /* the free objects */
    const double *object_qpos; /* 7 an object: MuJoCo's first qpos */
    int64_t *sim_time_ns;
    uint64_t *ticks;
    double *object_pose; /* 7 an object: its truth records */
    double *internal_force;
    int64_t sim_ns, cycles, welds_read;
} PlantTruthArgs;

/* FtArgs (plant): kali_ft_bank */
typedef struct {
    const double *normals;
    int64_t size, at; /* the block's length, the next draw */
    double *offset; /* six volts: the bank's (FtBank.offset) */
    double drift; /* a cycle's random-walk step, volts */
    const double *gauges, *noise_sd; /* C^-1 (6 x 6), the wrench's noise per axis */
    const double *wrench; /* the tool on the sensor, sensor frame */
    int16_t *codes;
    const uint16_t *control;
    uint16_t *status;
    int64_t served, seq_mask, request, ready; /* ready: FT_READY | FT_PRESENT */
    double volts_per_code, rail;
} FtArgs;

/* FifoPopArgs (fifo): kali_fifo_pop */
typedef struct {
    int64_t n; /* the set-points' width */
    uint64_t *head; /* the header's head (this consumer's) and tail */
    const uint64_t *tail;
    const double *ring; /* capacity x n */
    const uint64_t *stamps; /* each set-point's ratio word */
    int64_t capacity;
    double bound; /* a value not strictly within +-bound is refused */
    double *cur, *start, *target; /* the .state block: output, A, B */
    uint32_t *seg_ticks, *seg_done, *primed, *rejected, *ratio_num, *ratio_den;
    uint64_t *underruns, *phase_acc;
    View out;
    int64_t num, den; /* the ratio of the segment in progress */
    uint64_t stamp; /* num | den << 32 */
} FifoPopArgs;

/* RobotsArgs (sio): kali_sio_robots */
typedef struct {
    int64_t n, n_robots;
    View bounds; /* int64, n_robots + 1: robot k's joints bounds[k] .. */
    View fed; /* uint8 (bool), every joint */
    View pots_read, power, power_cmd, calib_cmd, calib_state, guided; /* uint8, per robot */
    View guard_state; /* uint32, per robot */
    View amps; /* uint8, per robot: the board register with ... */
    int64_t amps_bit; /* ... this bit set while its amplifiers are on */
    int64_t on, tripped; /* PowerState.ON, GuardState.TRIPPED */
    int64_t calib_active; /* bit s set: calibration state s is under way */
    FifoPopArgs **pops; /* robot k's kali_fifo_pop block */
    int64_t faulted; /* this tick's, set by SIO before each call */
} RobotsArgs;

/* FfArgs (sio): kali_feedforward */
typedef struct {
    int64_t n, rows, row_len; /* joints; FF_ROWS; MAX_JOINTS (a row's values) */
    const uint64_t *keys; /* the record's key[FF_ROWS] */
    const double *tau, *qd, *qdd; /* its rows: row r at r * row_len */
    const uint8_t *mode; /* its words: the mode a client wants */
    uint8_t *state; /* FfState */
    const int64_t *heartbeat; /* the dynamics process's last tick */
    uint64_t *stale_ticks;
    uint32_t *stale_events;
    double *weight_rec;
    const uint64_t *head; /* the FIFO's header: the next set-point to take */
    const uint32_t *seg_ticks, *seg_done;
    View out, vel, acc; /* double: the robot's joints of SIO's arrays */
    double *last; /* 3 x n: the last good torque, velocity, acceleration */
    int64_t heartbeat_limit, missing_limit, mode_max;
    double step; /* weight per servo tick */
    int64_t tick, arm; /* this tick's, from SIO */
    int64_t mode_ok, missing, stale; /* the state between ticks */
    double weight;
} FfArgs;

/* Copy (core): in other blocks */
typedef struct {
    View src, dst;
    int64_t size; /* bytes per element: 4 or 8 */
} Copy;

/* CopyArgs (core): kali_copy */
typedef struct {
    int64_t n, m;
    Copy *copies;
} CopyArgs;

/* ChainPoseArgs (chain): kali_chain_pose */
typedef struct {
    int64_t n; /* the chain's joints */
    const double *origins; /* (n + 1) x 16: chain.Chain.origins, C order */
    const double *axes; /* n x 3: chain.Chain.axes */
    const double *q; /* n joint angles, rad, contiguous */
    double *out; /* 16: the flange pose, row-major */
} ChainPoseArgs;

/* WrenchArgs (sio): kali_wrench_tick, kali_wrench_convert */
typedef struct {
    int64_t n; /* the chain's joints */
    const double *origins, *axes, *q; /* chain.Chain, the arm's angles (contiguous) */
    const int16_t *codes; /* the board's 6 gauge codes */
    const double *given; /* 6: a wrench the hardware gives, flange; NULL: the codes' */
    const uint64_t *given_seq; /* the hardware's count of those wrenches */
    const double *cal; /* 6x6 calibration matrix, row-major, N per volt */
    const double *base; /* 4x4 base pose in the world, row-major */
    const double *g; /* gravity in the world, m/s^2 */
    const double *com; /* the tool's centre of mass, sensor frame */
    const double *rated; /* the sheet's range per axis */
    const double *limit; /* FT_STATE.contact_limit: a client may only lower it */
    double mass, tip, alpha, volts, limit_config;
    int64_t rail; /* a code at +-rail is saturated */
    int64_t tare_left, tare_ticks; /* in/out: samples a tare still sums; of how many */
    double *raw, *grav, *sensor, *filt, *tool, *world, *bias, *sum, *rotation;
    double force, limit_used; /* out: the contact force and the limit it met, N */
    /* the tick's handshake and bookkeeping (kali_wrench_tick) */
    uint16_t *status, *control; /* the board's ft_status, ft_control */
    uint32_t *stale, *tare_count; /* FT_STATE fields */
    uint64_t *samples;
    int64_t *sample_tick;
    uint8_t *present, *tare_cmd, *tare_state;
    int64_t tick, seq, stale_limit; /* in: this tick; in/out: the sequence asked for */
    uint64_t given_seen; /* in/out: the hardware's count at the wrench last taken */
    const uint32_t *cycles; /* the gauges' hardware's cycles, if it can stall, or NULL */
    uint64_t cycles_seen; /* in/out: their count at the last tick */
    int64_t ready, request, seq_mask, averaging, done; /* ftsensor's bits, TareState's values */
} WrenchArgs;

/* Field (core): in other blocks */
typedef struct {
    const char *name; /* NULL ends a table; that entry's offset is the struct's size */
    int64_t offset, size;
    char kind; /* numpy's dtype kind: 'f', 'u', 'i' */
} Field;

/* VectorArgs (servo): kali_pid_vector, kali_pd_vector */
typedef struct {
    int64_t n;
    char *data; /* the algorithm's records */
    View rows; /* int64: row k of the step is record rows[k] */
    View demand, position, torque, error;
    View status; /* int32 */
    int64_t ok; /* STATUS_OK */
} VectorArgs;

/* UnitArgs (servo): kali_serve_unit */
typedef struct {
    SlotRecord *slots; /* the cell's slots */
    PidRecord *pid; /* the PID's block: a record per slot */
    PdRecord *pd; /* the PD's block */
    int64_t lo, hi; /* the robot's slots */
    int64_t pid_a, pd_a; /* the built-ins' registry indices */
    int64_t me; /* the SV's busy value: its number + 1 */
    int64_t sv; /* its number */
    int64_t ok; /* STATUS_OK */
    int64_t *left; /* out: slots claimed for the per-slot path */
    int64_t tick; /* in: the tick served */
    int64_t exec_ns; /* in/out: this unit's last cost per slot, noted as each step's */
    int64_t n_left; /* out: slots put into left */
    int64_t fault; /* out: the first slot whose torque was not finite, or -1 */
    double bad; /* out: its torque */
} UnitArgs;

/* ArmFinishArgs (servo): kali_arm_finish */
typedef struct {
    int64_t n;
    double *tau; /* n, contiguous: the step's torques */
    const double *q_d, *q; /* the ArmInput's, contiguous */
    View enabled; /* uint32: the slots' (clients': 0 = no torque) */
    View torque, error; /* double: the slots' */
    View status, sv; /* int32 */
    View ran, exec; /* int64 */
    int32_t *arm_status; /* the robot's record */
    int64_t *arm_exec_ns, *arm_ran_tick;
    int64_t tick, sv_index, t0;
} ArmFinishArgs;

/* ArmArgs (servo): kali_impedance, kali_computed_torque */
typedef struct {
    int64_t n; /* the arm's joints */
    void *d; /* the robot's record of the algorithm (arena) */
    const double *q_d, *qd_d, *qdd_d; /* n each: the demand */
    const double *q, *qd, *h; /* n each: the measurement, C(q, qd) qd + g(q) */
    const double *M, *J; /* n x n, 6 x n, row-major */
    const double *pose, *pose_d; /* 4x4 row-major: the tool point at q, at q_d */
    const double *wrench; /* 6: this arm's contact wrench, world axes */
    const char *wrenches; /* robots x 6 doubles, rows wrench_stride bytes apart */
    int64_t wrench_stride, robots, has_sensor;
    const double *viscous, *gear_w, *coulomb_pos, *coulomb_neg; /* n each: DriveFriction's */
    double *tau; /* n: out */
} ArmArgs;

/* McgillArgs (sio): kali_mcgill_control */
typedef struct {
    int64_t n_arms;
    View csr, power_reg; /* uint8, per arm: the registers */
    View power, enable_ticks; /* per robot: uint8 PowerState, int32 */
    View capture; /* uint8, per arm: index capture on (calibration) */
    char *codes; /* the DAC records' codes: arm k's row at k * codes_row */
    int64_t codes_row;
    View n_joints; /* int64, per arm */
    const uint32_t *fault_active; /* halted: the fault word, read here */
    int64_t base_csr, green_red, no_disable, enable, index_off, amps_on;
    int64_t on, enabling, off, hold_ticks, dac_zero, retrigger, retrigger_ticks;
    int64_t ticks, bit, prev_bit; /* end_tick's state */
} McgillArgs;

/* FrankaReadArgs (franka): kali_franka_read */
typedef struct {
    int64_t n, n_arms;
    char *arms; /* the FR3s' records (hardware.franka.registers) */
    View q_off; /* int64: joint i's angle at arms + q_off[i] (double) */
    View seq_off; /* int64, per arm: its state's seq at arms + seq_off[k] (uint64) */
    View q; /* double out, rad */
    View seen; /* uint64 out, per arm: the state this tick answers */
} FrankaReadArgs;

/* FrankaWriteArgs (franka): kali_franka_write */
typedef struct {
    int64_t n;
    View torque, torque_limit; /* N·m */
    View step; /* N·m: the most the torque may change in one tick (the FR3's rate) */
    View last; /* N·m: the torque sent last tick */
    View current; /* double out: the torque sent, N·m (the FR3 takes torques) */
    View clamped; /* uint8 (bool) out: beyond the torque limit */
    char *arms;
    View tau_off; /* int64: joint i's command at arms + tau_off[i] (double) */
} FrankaWriteArgs;

/* FrankaControlArgs (franka): kali_franka_control */
typedef struct {
    int64_t n_arms;
    char *arms;
    int64_t row; /* bytes between two arms' records */
    int64_t want_off, cmd_seq_off, tau_off; /* fields' offsets in a record */
    View power; /* per robot: uint8 PowerState */
    View n_joints; /* int64, per arm */
    View seen; /* uint64, per arm: the state this tick answers (the read kernel's) */
    View last; /* double, per joint: the write kernel's, zeroed with the arm's torque */
    View base; /* int64, per arm: its first joint */
    sem_t **links; /* per arm: its link's semaphore, posted with the command */
    const uint32_t *fault_active;
    int64_t on, enabling;
    int64_t ticks; /* ticks whose commands went out */
} FrankaControlArgs;

/* SioArgs (sio): kali_sio_tick */
typedef struct {
    int64_t n, n_robots;
    KernelFn read_fn, dac_fn, control_fn; /* the boards' */
    void *read_args, *dac_args, *control_args;
    const uint8_t *capture; /* per robot: index capture on */
    VelocityArgs *velocity;
    WrenchArgs **sensors;
    const uint32_t **guard_state; /* per sensor: its arm's guard ... */
    const double **guard_n; /* ... and the force that trips it */
    int64_t n_sensors, guard_armed;
    RobotsArgs *robots;
    ChecksArgs *checks;
    FfArgs **ff; /* per robot */
    FeedArgs *feed;
    TorquesArgs *torques;
    CurrentArgs *current;
    CopyArgs *publish;
    FlightArgs *flight;
    const uint32_t *fault_active;
    const uint64_t *fault_count;
    View arm_algo, arm_op, shadows; /* per robot: int32, uint32, uint32 */
    View bounds; /* int64, n_robots + 1 */
    uint8_t *whole; /* per robot: fed whole last tick */
    View mark, ff_out; /* per joint: uint32, double */
    int64_t arm_none, arm_free, arm_held;
    sem_t **feeds;
    int64_t n_feeds;
    sem_t *done_sem; /* the SVs' last post: every servo done */
    uint32_t *ctrl_done;
    int64_t slice_ns; /* how long one wait for it lasts (a period) */
    int64_t *ctrl_tick;
    int64_t *fed_ns; /* when SIO fed its last tick */
    int64_t *served_max; /* per SV: the longest feed-to-done since it learnt */
    View robots_tick, robots_faults; /* per robot: int64, uint32 */
    const int64_t *sv_fed_tick; /* the gang (sio/gang.py): per SV */
    View signal_tick, ack_tick, vouched_tick; /* int64, per process slot */
    const int64_t *gang_sv, *gang_slot, *gang_lag;
    int64_t n_gang;
    int64_t *ack_early; /* SIO's slot's ack_tick, or NULL */
    const int64_t *clock_tick;
    int64_t *lat_last, *lat_max;
    uint32_t *hist;
    int64_t linear_us, log_bins;
    /* per tick: from SIO, between the passes, to SIO */
    int64_t tick, post, ok; /* ok: the servos were done (_wait_done) */
    int64_t stage, faulted, faults_seen, at, result, fed;
    int64_t t_read, c_read, t_fed, t_done, t_out, c_out, retrigger_tick;
} SioArgs;

/* ServeArgs (servo): kali_sv_serve */
typedef struct {
    int64_t n, n_arms, n_units;
    SlotRecord *slots;
    int64_t *fed_tick_out; /* ctrl sv_fed_tick[this SV] */
    const uint32_t *ctrl_fed;
    uint32_t *ctrl_done;
    const int64_t *ctrl_tick;
    const int64_t *arm_lo; /* per robot fed whole, in this SV's order: first slot */
    UnitArgs **units; /* in this SV's order */
    const int64_t *order; /* the single slots, in this SV's order */
    sem_t *done_sem;
    int64_t me, arm_free;
    int64_t *exec_last, *exec_max;
    uint64_t *servos;
    uint32_t *exec_hist;
    int64_t linear_us, log_bins;
    /* the feed (stage SV_FEED, ServoWorker._await_feed and _learn_feed) */
    sem_t *feed_sem;
    int64_t poll_ns, feed_wait_ns; /* poll the feed this long first; wait at most this */
    int64_t learn; /* a polling SV learns when to wake from each feed */
    const int64_t *fed_ns; /* ctrl: when SIO fed */
    int64_t *served_max; /* ctrl: the longest the servos took since it learnt */
    const int64_t *release; /* procs release_ns[this SV's slot] */
    int64_t *feed_seen, *served; /* the last `history` learnt */
    int64_t history, feed_k, margin_ns, share_ns, share_looks, cap_ns;
    int64_t sharing; /* between calls: the last look found them worth it */
    int64_t servo_ticks, rest_ticks; /* its period in ticks: sharing, with nothing to share */
    int64_t want_ticks; /* out: the one it learnt (the SV applies it) */
    int64_t *poll_after; /* the base loop's: from when after the due tick to poll */
    /* per call: from the SV, between calls, to it */
    int64_t fed_tick, count;
    int64_t stage, at, unit, tick_now, fed, ran, t0;
    int64_t wanted; /* SV_FEED: the tick signalled (a feed of it or later) */
} ServeArgs;

/* WaitArgs (clock): kali_clock_wait, kali_clock_settle */
typedef struct {
    StatsArgs *stats; /* the slot's account of a cycle (daemon._CycleStats) */
    sem_t *ack_sem; /* lockstep: the clock's acknowledgement post, else NULL */
    sem_t *sem; /* this slot's: the wall clock posts it */
    const int64_t *release; /* procs release_ns[slot]: when the clock meant the signal */
    const int64_t *signal_tick; /* procs signal_tick[slot] */
    const int64_t *after; /* the daemon's poll_after (an SV learns it) */
    const uint32_t *shutdown; /* the arena header's */
    const int64_t *next_due; /* procs next_due[slot]: the clock's next due tick for it */
    int64_t base_ns, period_ticks; /* the clock's tick and this process's period in ticks */
    int64_t poll_ns, idle_ns;
    int64_t signalled; /* between calls: the last call took a signal */
    int64_t cycled; /* between calls: its cycle has run, not yet accounted */
    int64_t tick, woke, since; /* out: the tick signalled, when taken, when meant to wake */
} WaitArgs;

/* WitnessArgs (witness): kali_witness_start, kali_witness_stop */
typedef struct {
    int64_t cpu, priority; /* the CPU witnessed; its thread's SCHED_FIFO priority */
    int64_t period_ns, stall_ns; /* its wake-ups; one later than stall_ns was lost */
    int64_t *ring_ns, *ring_lost; /* per wake-up: when, and lost after it */
    int64_t ring; /* the ring's length */
    /* the clock's bottom half (WallClock._below): its thread (0: none) is put back at */
    /* guard_priority once it has stood below it for guard_after_ns */
    int64_t guard_tid, guard_priority, guard_after_ns;
    int64_t bottom_since; /* the clock's: when it went below, 0 while above */
    /* the thread's, read by the clock while seq is even */
    int64_t seq, due, lost, wakes; /* due: the deadline it sleeps to */
    /* start and stop's */
    int64_t stop, running, thread;
} WitnessArgs;

/* ---------------------------------------------------------------- the layouts */

#define FIELD(T, f, k) {#f, (int64_t)offsetof(T, f), (int64_t)sizeof(((T *)0)->f), k}
#define END(T) {NULL, (int64_t)sizeof(T), 0, 0}

/* a block's field with the kind of its compiled type, as kernel_args.kind names it */
#define IS(x, type) __builtin_types_compatible_p(__typeof__(x), type)
#define KIND(x)                                                                     \
    (IS(x, double) ? 'f' : IS(x, int64_t) ? 'i' : IS(x, uint64_t) ? 'u'             \
     : IS(x, char) ? 'c' : __builtin_classify_type(x) == 5 ? 'p'                     \
     : __builtin_classify_type(x) == 12 ? 'V' : '?')
#define LAYOUT(T, f) {#f, (int64_t)offsetof(T, f), (int64_t)sizeof(((T *)0)->f), \
                      KIND(((T *)0)->f)}

static const Field SlotRecord_FIELDS[] = {
    FIELD(SlotRecord, busy, 'u'),
    FIELD(SlotRecord, op, 'u'),
    FIELD(SlotRecord, op_algo, 'u'),
    FIELD(SlotRecord, op_lock, 'u'),
    FIELD(SlotRecord, ops_done, 'u'),
    FIELD(SlotRecord, algo, 'u'),
    FIELD(SlotRecord, enabled, 'u'),
    FIELD(SlotRecord, status, 'i'),
    FIELD(SlotRecord, demand, 'f'),
    FIELD(SlotRecord, position, 'f'),
    FIELD(SlotRecord, velocity, 'f'),
    FIELD(SlotRecord, demand_vel, 'f'),
    FIELD(SlotRecord, demand_acc, 'f'),
    FIELD(SlotRecord, ff, 'f'),
    FIELD(SlotRecord, torque, 'f'),
    FIELD(SlotRecord, error, 'f'),
    FIELD(SlotRecord, reset, 'u'),
    FIELD(SlotRecord, op_status, 'i'),
    FIELD(SlotRecord, ran_tick, 'i'),
    FIELD(SlotRecord, exec_ns, 'i'),
    FIELD(SlotRecord, sv, 'i'),
    FIELD(SlotRecord, shadow, 'i'),
    FIELD(SlotRecord, shadow_state, 'u'),
    FIELD(SlotRecord, _pad, 'u'),
    FIELD(SlotRecord, shadow_torque, 'f'),
    FIELD(SlotRecord, shadow_n, 'u'),
    FIELD(SlotRecord, shadow_sq, 'f'),
    FIELD(SlotRecord, shadow_peak, 'f'),
    END(SlotRecord),
};

static const Field PidRecord_FIELDS[] = {
    FIELD(PidRecord, kp, 'f'),
    FIELD(PidRecord, ki, 'f'),
    FIELD(PidRecord, kv, 'f'),
    FIELD(PidRecord, fe, 'f'),
    FIELD(PidRecord, fv, 'f'),
    FIELD(PidRecord, integration_band, 'f'),
    FIELD(PidRecord, integration_reset, 'f'),
    FIELD(PidRecord, bias_tau, 'f'),
    FIELD(PidRecord, sampling_period, 'f'),
    FIELD(PidRecord, inv_period, 'f'),
    FIELD(PidRecord, ki_t, 'f'),
    FIELD(PidRecord, lpfe1, 'f'),
    FIELD(PidRecord, lpfe2, 'f'),
    FIELD(PidRecord, lpfv1, 'f'),
    FIELD(PidRecord, lpfv2, 'f'),
    FIELD(PidRecord, bias_decay, 'f'),
    FIELD(PidRecord, error, 'f'),
    FIELD(PidRecord, old_position, 'f'),
    FIELD(PidRecord, old_velocity, 'f'),
    FIELD(PidRecord, integral, 'f'),
    FIELD(PidRecord, bias, 'f'),
    FIELD(PidRecord, primed, 'u'),
    END(PidRecord),
};

static const Field PdRecord_FIELDS[] = {
    FIELD(PdRecord, kp, 'f'),
    FIELD(PdRecord, kv, 'f'),
    FIELD(PdRecord, fv, 'f'),
    FIELD(PdRecord, bias_tau, 'f'),
    FIELD(PdRecord, sampling_period, 'f'),
    FIELD(PdRecord, inv_period, 'f'),
    FIELD(PdRecord, lpfv1, 'f'),
    FIELD(PdRecord, lpfv2, 'f'),
    FIELD(PdRecord, bias_decay, 'f'),
    FIELD(PdRecord, error, 'f'),
    FIELD(PdRecord, old_position, 'f'),
    FIELD(PdRecord, old_velocity, 'f'),
    FIELD(PdRecord, bias, 'f'),
    FIELD(PdRecord, primed, 'u'),
    END(PdRecord),
};

static const Field ImpRecord_FIELDS[] = {
    FIELD(ImpRecord, k, 'V'),
    FIELD(ImpRecord, d, 'V'),
    FIELD(ImpRecord, f, 'V'),
    FIELD(ImpRecord, integral, 'V'),
    FIELD(ImpRecord, limit, 'V'),
    FIELD(ImpRecord, band, 'V'),
    FIELD(ImpRecord, partner, 'f'),
    FIELD(ImpRecord, fi, 'f'),
    FIELD(ImpRecord, u, 'V'),
    FIELD(ImpRecord, kpi, 'f'),
    FIELD(ImpRecord, kii, 'f'),
    FIELD(ImpRecord, squeeze, 'f'),
    FIELD(ImpRecord, gi, 'f'),
    FIELD(ImpRecord, kf, 'f'),
    FIELD(ImpRecord, kfi, 'f'),
    FIELD(ImpRecord, imax, 'f'),
    FIELD(ImpRecord, kq, 'f'),
    FIELD(ImpRecord, cband, 'f'),
    FIELD(ImpRecord, ctau, 'f'),
    FIELD(ImpRecord, cdecay, 'f'),
    FIELD(ImpRecord, friction, 'f'),
    FIELD(ImpRecord, handover_s, 'f'),
    FIELD(ImpRecord, dt, 'f'),
    FIELD(ImpRecord, decay, 'f'),
    FIELD(ImpRecord, bias, 'V'),
    FIELD(ImpRecord, drive, 'V'),
    END(ImpRecord),
};

static const Field CtRecord_FIELDS[] = {
    FIELD(CtRecord, wn, 'f'),
    FIELD(CtRecord, zeta, 'f'),
    FIELD(CtRecord, friction, 'f'),
    FIELD(CtRecord, handover_s, 'f'),
    FIELD(CtRecord, kp, 'f'),
    FIELD(CtRecord, kd, 'f'),
    FIELD(CtRecord, wi, 'f'),
    FIELD(CtRecord, ilimit, 'f'),
    FIELD(CtRecord, ki, 'f'),
    FIELD(CtRecord, dt, 'f'),
    FIELD(CtRecord, decay, 'f'),
    FIELD(CtRecord, bias, 'V'),
    FIELD(CtRecord, integral, 'V'),
    END(CtRecord),
};

static const Field View_LAYOUT[] = {
    LAYOUT(View, p),
    LAYOUT(View, stride),
    END(View),
};

static const Field ReadArgs_LAYOUT[] = {
    LAYOUT(ReadArgs, n),
    LAYOUT(ReadArgs, encoders),
    LAYOUT(ReadArgs, enc_off),
    LAYOUT(ReadArgs, acc),
    LAYOUT(ReadArgs, prev),
    LAYOUT(ReadArgs, offset),
    LAYOUT(ReadArgs, rad_per_count),
    LAYOUT(ReadArgs, q),
    LAYOUT(ReadArgs, modulo),
    LAYOUT(ReadArgs, half),
    END(ReadArgs),
};

static const Field VelocityArgs_LAYOUT[] = {
    LAYOUT(VelocityArgs, n),
    LAYOUT(VelocityArgs, q),
    LAYOUT(VelocityArgs, q_prev),
    LAYOUT(VelocityArgs, qd),
    LAYOUT(VelocityArgs, gain),
    LAYOUT(VelocityArgs, b),
    END(VelocityArgs),
};

static const Field ChecksArgs_LAYOUT[] = {
    LAYOUT(ChecksArgs, n),
    LAYOUT(ChecksArgs, n_robots),
    LAYOUT(ChecksArgs, bounds),
    LAYOUT(ChecksArgs, q),
    LAYOUT(ChecksArgs, demand),
    LAYOUT(ChecksArgs, q_min),
    LAYOUT(ChecksArgs, q_max),
    LAYOUT(ChecksArgs, range_check),
    LAYOUT(ChecksArgs, fed),
    LAYOUT(ChecksArgs, safe),
    LAYOUT(ChecksArgs, safe_ok),
    LAYOUT(ChecksArgs, pi),
    END(ChecksArgs),
};

static const Field FeedArgs_LAYOUT[] = {
    LAYOUT(FeedArgs, n),
    LAYOUT(FeedArgs, demand),
    LAYOUT(FeedArgs, q),
    LAYOUT(FeedArgs, qd),
    LAYOUT(FeedArgs, fed),
    LAYOUT(FeedArgs, slot_demand),
    LAYOUT(FeedArgs, slot_position),
    LAYOUT(FeedArgs, slot_velocity),
    LAYOUT(FeedArgs, slot_busy),
    LAYOUT(FeedArgs, not_fed),
    LAYOUT(FeedArgs, ctrl_fed),
    LAYOUT(FeedArgs, ctrl_done),
    LAYOUT(FeedArgs, demand_vel),
    LAYOUT(FeedArgs, demand_acc),
    LAYOUT(FeedArgs, ff),
    LAYOUT(FeedArgs, slot_demand_vel),
    LAYOUT(FeedArgs, slot_demand_acc),
    LAYOUT(FeedArgs, slot_ff),
    LAYOUT(FeedArgs, mark),
    END(FeedArgs),
};

static const Field TorquesArgs_LAYOUT[] = {
    LAYOUT(TorquesArgs, n),
    LAYOUT(TorquesArgs, slot_torque),
    LAYOUT(TorquesArgs, fed),
    LAYOUT(TorquesArgs, servo_torque),
    LAYOUT(TorquesArgs, ff),
    LAYOUT(TorquesArgs, torque),
    END(TorquesArgs),
};

static const Field DacArgs_LAYOUT[] = {
    LAYOUT(DacArgs, n),
    LAYOUT(DacArgs, torque),
    LAYOUT(DacArgs, gkt),
    LAYOUT(DacArgs, current_limit),
    LAYOUT(DacArgs, codes_per_amp),
    LAYOUT(DacArgs, current),
    LAYOUT(DacArgs, clamped),
    LAYOUT(DacArgs, dacs),
    LAYOUT(DacArgs, dac_off),
    LAYOUT(DacArgs, zero),
    LAYOUT(DacArgs, top),
    END(DacArgs),
};

static const Field CurrentArgs_LAYOUT[] = {
    LAYOUT(CurrentArgs, n),
    LAYOUT(CurrentArgs, torque),
    LAYOUT(CurrentArgs, fed),
    LAYOUT(CurrentArgs, clamped),
    LAYOUT(CurrentArgs, over),
    LAYOUT(CurrentArgs, current_ticks),
    END(CurrentArgs),
};

static const Field MotorArgs_LAYOUT[] = {
    LAYOUT(MotorArgs, n),
    LAYOUT(MotorArgs, volts),
    LAYOUT(MotorArgs, qd),
    LAYOUT(MotorArgs, enabled),
    LAYOUT(MotorArgs, current),
    LAYOUT(MotorArgs, gear),
    LAYOUT(MotorArgs, kt_r),
    LAYOUT(MotorArgs, vbus_r),
    LAYOUT(MotorArgs, i_max),
    LAYOUT(MotorArgs, gain),
    LAYOUT(MotorArgs, w_scale),
    LAYOUT(MotorArgs, g_extra_pos),
    LAYOUT(MotorArgs, g_extra_neg),
    LAYOUT(MotorArgs, ctrl),
    LAYOUT(MotorArgs, range),
    LAYOUT(MotorArgs, friction),
    LAYOUT(MotorArgs, acts),
    LAYOUT(MotorArgs, act_adr),
    LAYOUT(MotorArgs, dofs),
    LAYOUT(MotorArgs, mj_actrange),
    LAYOUT(MotorArgs, mj_ctrl),
    LAYOUT(MotorArgs, mj_act),
    LAYOUT(MotorArgs, mj_qfrc),
    END(MotorArgs),
};

static const Field EncoderArgs_LAYOUT[] = {
    LAYOUT(EncoderArgs, n),
    LAYOUT(EncoderArgs, angle),
    LAYOUT(EncoderArgs, cpr),
    LAYOUT(EncoderArgs, phase),
    LAYOUT(EncoderArgs, ref),
    LAYOUT(EncoderArgs, count),
    LAYOUT(EncoderArgs, rev),
    LAYOUT(EncoderArgs, robot_of),
    LAYOUT(EncoderArgs, joint_of),
    LAYOUT(EncoderArgs, encoders),
    LAYOUT(EncoderArgs, enc_off),
    LAYOUT(EncoderArgs, csr),
    LAYOUT(EncoderArgs, index),
    LAYOUT(EncoderArgs, index_off),
    LAYOUT(EncoderArgs, modulo),
    LAYOUT(EncoderArgs, two_pi),
    END(EncoderArgs),
};

static const Field StatsArgs_LAYOUT[] = {
    LAYOUT(StatsArgs, late),
    LAYOUT(StatsArgs, late_max),
    LAYOUT(StatsArgs, exec),
    LAYOUT(StatsArgs, exec_max),
    LAYOUT(StatsArgs, heart),
    LAYOUT(StatsArgs, ack),
    LAYOUT(StatsArgs, acks),
    LAYOUT(StatsArgs, hist),
    LAYOUT(StatsArgs, linear_us),
    LAYOUT(StatsArgs, log_bins),
    LAYOUT(StatsArgs, tick),
    LAYOUT(StatsArgs, release),
    LAYOUT(StatsArgs, woke),
    LAYOUT(StatsArgs, done),
    END(StatsArgs),
};

static const Field FlightArgs_LAYOUT[] = {
    LAYOUT(FlightArgs, n),
    LAYOUT(FlightArgs, n_robots),
    LAYOUT(FlightArgs, rows),
    LAYOUT(FlightArgs, ring),
    LAYOUT(FlightArgs, row_size),
    LAYOUT(FlightArgs, off_tick),
    LAYOUT(FlightArgs, off_t),
    LAYOUT(FlightArgs, off_lat),
    LAYOUT(FlightArgs, off_late),
    LAYOUT(FlightArgs, off_wait),
    LAYOUT(FlightArgs, off_ran),
    LAYOUT(FlightArgs, off_shadow),
    LAYOUT(FlightArgs, off_wrench),
    LAYOUT(FlightArgs, off_cols),
    LAYOUT(FlightArgs, cols),
    LAYOUT(FlightArgs, n_cols),
    LAYOUT(FlightArgs, shadow),
    LAYOUT(FlightArgs, wrench),
    LAYOUT(FlightArgs, wrench_row),
    LAYOUT(FlightArgs, wrench_col),
    LAYOUT(FlightArgs, release),
    LAYOUT(FlightArgs, count),
    LAYOUT(FlightArgs, tick),
    LAYOUT(FlightArgs, t_read),
    LAYOUT(FlightArgs, latency),
    LAYOUT(FlightArgs, wait),
    LAYOUT(FlightArgs, ran),
    END(FlightArgs),
};

static const Field BoardArgs_LAYOUT[] = {
    LAYOUT(BoardArgs, n_arms),
    LAYOUT(BoardArgs, csr),
    LAYOUT(BoardArgs, estop),
    LAYOUT(BoardArgs, power),
    LAYOUT(BoardArgs, index),
    LAYOUT(BoardArgs, adc_control),
    LAYOUT(BoardArgs, adc_analog),
    LAYOUT(BoardArgs, adc_digital),
    LAYOUT(BoardArgs, clamped),
    LAYOUT(BoardArgs, scans),
    LAYOUT(BoardArgs, amps_on),
    LAYOUT(BoardArgs, brakes_engaged),
    LAYOUT(BoardArgs, watchdog_tripped),
    LAYOUT(BoardArgs, truth_estop),
    LAYOUT(BoardArgs, state),
    LAYOUT(BoardArgs, base),
    LAYOUT(BoardArgs, count),
    LAYOUT(BoardArgs, enabled),
    LAYOUT(BoardArgs, braked),
    LAYOUT(BoardArgs, q),
    LAYOUT(BoardArgs, lo),
    LAYOUT(BoardArgs, hi),
    LAYOUT(BoardArgs, mid),
    LAYOUT(BoardArgs, now_ns),
    LAYOUT(BoardArgs, hold_ns),
    LAYOUT(BoardArgs, watchdog_ns),
    LAYOUT(BoardArgs, brake_ns),
    LAYOUT(BoardArgs, never),
    LAYOUT(BoardArgs, timeout_on),
    LAYOUT(BoardArgs, retrigger),
    LAYOUT(BoardArgs, no_disable),
    LAYOUT(BoardArgs, enable),
    LAYOUT(BoardArgs, index_off),
    LAYOUT(BoardArgs, p_amps),
    LAYOUT(BoardArgs, p_brakes),
    LAYOUT(BoardArgs, p_tripped),
    LAYOUT(BoardArgs, p_estop),
    LAYOUT(BoardArgs, adc_start),
    LAYOUT(BoardArgs, channel_mask),
    LAYOUT(BoardArgs, adc_done),
    LAYOUT(BoardArgs, value_mask),
    LAYOUT(BoardArgs, channels),
    LAYOUT(BoardArgs, self_test),
    LAYOUT(BoardArgs, pot_v_min),
    LAYOUT(BoardArgs, pot_v_max),
    LAYOUT(BoardArgs, adc_volts),
    LAYOUT(BoardArgs, adc_top),
    END(BoardArgs),
};

static const Field PlantIoArgs_LAYOUT[] = {
    LAYOUT(PlantIoArgs, n),
    LAYOUT(PlantIoArgs, qpos),
    LAYOUT(PlantIoArgs, qvel),
    LAYOUT(PlantIoArgs, act),
    LAYOUT(PlantIoArgs, qpos_idx),
    LAYOUT(PlantIoArgs, dofs),
    LAYOUT(PlantIoArgs, act_adr),
    LAYOUT(PlantIoArgs, gear),
    LAYOUT(PlantIoArgs, gkt),
    LAYOUT(PlantIoArgs, q),
    LAYOUT(PlantIoArgs, qd),
    LAYOUT(PlantIoArgs, current),
    LAYOUT(PlantIoArgs, motor_angle),
    LAYOUT(PlantIoArgs, torque),
    LAYOUT(PlantIoArgs, dacs),
    LAYOUT(PlantIoArgs, dac_off),
    LAYOUT(PlantIoArgs, robot_of),
    LAYOUT(PlantIoArgs, clamped),
    LAYOUT(PlantIoArgs, volts),
    LAYOUT(PlantIoArgs, top),
    LAYOUT(PlantIoArgs, zero),
    LAYOUT(PlantIoArgs, scale),
    END(PlantIoArgs),
};

static const Field PlantTruthArgs_LAYOUT[] = {
    LAYOUT(PlantTruthArgs, n),
    LAYOUT(PlantTruthArgs, welds),
    LAYOUT(PlantTruthArgs, eq_active),
    LAYOUT(PlantTruthArgs, graspable),
    LAYOUT(PlantTruthArgs, held),
    LAYOUT(PlantTruthArgs, held_object),
    LAYOUT(PlantTruthArgs, weld),
    LAYOUT(PlantTruthArgs, grasped),
    LAYOUT(PlantTruthArgs, holding),
    LAYOUT(PlantTruthArgs, grasp_wrench),
    LAYOUT(PlantTruthArgs, ft_wrench),
    LAYOUT(PlantTruthArgs, push),
    LAYOUT(PlantTruthArgs, ft_true),
    LAYOUT(PlantTruthArgs, xfrc),
    LAYOUT(PlantTruthArgs, tool_body),
    LAYOUT(PlantTruthArgs, site_xpos),
    LAYOUT(PlantTruthArgs, grasp_site),
    LAYOUT(PlantTruthArgs, objects),
    LAYOUT(PlantTruthArgs, object_qpos),
    LAYOUT(PlantTruthArgs, sim_time_ns),
    LAYOUT(PlantTruthArgs, ticks),
    LAYOUT(PlantTruthArgs, object_pose),
    LAYOUT(PlantTruthArgs, internal_force),
    LAYOUT(PlantTruthArgs, sim_ns),
    LAYOUT(PlantTruthArgs, cycles),
    LAYOUT(PlantTruthArgs, welds_read),
    END(PlantTruthArgs),
};

static const Field FtArgs_LAYOUT[] = {
    LAYOUT(FtArgs, normals),
    LAYOUT(FtArgs, size),
    LAYOUT(FtArgs, at),
    LAYOUT(FtArgs, offset),
    LAYOUT(FtArgs, drift),
    LAYOUT(FtArgs, gauges),
    LAYOUT(FtArgs, noise_sd),
    LAYOUT(FtArgs, wrench),
    LAYOUT(FtArgs, codes),
    LAYOUT(FtArgs, control),
    LAYOUT(FtArgs, status),
    LAYOUT(FtArgs, served),
    LAYOUT(FtArgs, seq_mask),
    LAYOUT(FtArgs, request),
    LAYOUT(FtArgs, ready),
    LAYOUT(FtArgs, volts_per_code),
    LAYOUT(FtArgs, rail),
    END(FtArgs),
};

static const Field FifoPopArgs_LAYOUT[] = {
    LAYOUT(FifoPopArgs, n),
    LAYOUT(FifoPopArgs, head),
    LAYOUT(FifoPopArgs, tail),
    LAYOUT(FifoPopArgs, ring),
    LAYOUT(FifoPopArgs, stamps),
    LAYOUT(FifoPopArgs, capacity),
    LAYOUT(FifoPopArgs, bound),
    LAYOUT(FifoPopArgs, cur),
    LAYOUT(FifoPopArgs, start),
    LAYOUT(FifoPopArgs, target),
    LAYOUT(FifoPopArgs, seg_ticks),
    LAYOUT(FifoPopArgs, seg_done),
    LAYOUT(FifoPopArgs, primed),
    LAYOUT(FifoPopArgs, rejected),
    LAYOUT(FifoPopArgs, ratio_num),
    LAYOUT(FifoPopArgs, ratio_den),
    LAYOUT(FifoPopArgs, underruns),
    LAYOUT(FifoPopArgs, phase_acc),
    LAYOUT(FifoPopArgs, out),
    LAYOUT(FifoPopArgs, num),
    LAYOUT(FifoPopArgs, den),
    LAYOUT(FifoPopArgs, stamp),
    END(FifoPopArgs),
};

static const Field RobotsArgs_LAYOUT[] = {
    LAYOUT(RobotsArgs, n),
    LAYOUT(RobotsArgs, n_robots),
    LAYOUT(RobotsArgs, bounds),
    LAYOUT(RobotsArgs, fed),
    LAYOUT(RobotsArgs, pots_read),
    LAYOUT(RobotsArgs, power),
    LAYOUT(RobotsArgs, power_cmd),
    LAYOUT(RobotsArgs, calib_cmd),
    LAYOUT(RobotsArgs, calib_state),
    LAYOUT(RobotsArgs, guided),
    LAYOUT(RobotsArgs, guard_state),
    LAYOUT(RobotsArgs, amps),
    LAYOUT(RobotsArgs, amps_bit),
    LAYOUT(RobotsArgs, on),
    LAYOUT(RobotsArgs, tripped),
    LAYOUT(RobotsArgs, calib_active),
    LAYOUT(RobotsArgs, pops),
    LAYOUT(RobotsArgs, faulted),
    END(RobotsArgs),
};

static const Field FfArgs_LAYOUT[] = {
    LAYOUT(FfArgs, n),
    LAYOUT(FfArgs, rows),
    LAYOUT(FfArgs, row_len),
    LAYOUT(FfArgs, keys),
    LAYOUT(FfArgs, tau),
    LAYOUT(FfArgs, qd),
    LAYOUT(FfArgs, qdd),
    LAYOUT(FfArgs, mode),
    LAYOUT(FfArgs, state),
    LAYOUT(FfArgs, heartbeat),
    LAYOUT(FfArgs, stale_ticks),
    LAYOUT(FfArgs, stale_events),
    LAYOUT(FfArgs, weight_rec),
    LAYOUT(FfArgs, head),
    LAYOUT(FfArgs, seg_ticks),
    LAYOUT(FfArgs, seg_done),
    LAYOUT(FfArgs, out),
    LAYOUT(FfArgs, vel),
    LAYOUT(FfArgs, acc),
    LAYOUT(FfArgs, last),
    LAYOUT(FfArgs, heartbeat_limit),
    LAYOUT(FfArgs, missing_limit),
    LAYOUT(FfArgs, mode_max),
    LAYOUT(FfArgs, step),
    LAYOUT(FfArgs, tick),
    LAYOUT(FfArgs, arm),
    LAYOUT(FfArgs, mode_ok),
    LAYOUT(FfArgs, missing),
    LAYOUT(FfArgs, stale),
    LAYOUT(FfArgs, weight),
    END(FfArgs),
};

static const Field Copy_LAYOUT[] = {
    LAYOUT(Copy, src),
    LAYOUT(Copy, dst),
    LAYOUT(Copy, size),
    END(Copy),
};

static const Field CopyArgs_LAYOUT[] = {
    LAYOUT(CopyArgs, n),
    LAYOUT(CopyArgs, m),
    LAYOUT(CopyArgs, copies),
    END(CopyArgs),
};

static const Field ChainPoseArgs_LAYOUT[] = {
    LAYOUT(ChainPoseArgs, n),
    LAYOUT(ChainPoseArgs, origins),
    LAYOUT(ChainPoseArgs, axes),
    LAYOUT(ChainPoseArgs, q),
    LAYOUT(ChainPoseArgs, out),
    END(ChainPoseArgs),
};

static const Field WrenchArgs_LAYOUT[] = {
    LAYOUT(WrenchArgs, n),
    LAYOUT(WrenchArgs, origins),
    LAYOUT(WrenchArgs, axes),
    LAYOUT(WrenchArgs, q),
    LAYOUT(WrenchArgs, codes),
    LAYOUT(WrenchArgs, given),
    LAYOUT(WrenchArgs, given_seq),
    LAYOUT(WrenchArgs, cal),
    LAYOUT(WrenchArgs, base),
    LAYOUT(WrenchArgs, g),
    LAYOUT(WrenchArgs, com),
    LAYOUT(WrenchArgs, rated),
    LAYOUT(WrenchArgs, limit),
    LAYOUT(WrenchArgs, mass),
    LAYOUT(WrenchArgs, tip),
    LAYOUT(WrenchArgs, alpha),
    LAYOUT(WrenchArgs, volts),
    LAYOUT(WrenchArgs, limit_config),
    LAYOUT(WrenchArgs, rail),
    LAYOUT(WrenchArgs, tare_left),
    LAYOUT(WrenchArgs, tare_ticks),
    LAYOUT(WrenchArgs, raw),
    LAYOUT(WrenchArgs, grav),
    LAYOUT(WrenchArgs, sensor),
    LAYOUT(WrenchArgs, filt),
    LAYOUT(WrenchArgs, tool),
    LAYOUT(WrenchArgs, world),
    LAYOUT(WrenchArgs, bias),
    LAYOUT(WrenchArgs, sum),
    LAYOUT(WrenchArgs, rotation),
    LAYOUT(WrenchArgs, force),
    LAYOUT(WrenchArgs, limit_used),
    LAYOUT(WrenchArgs, status),
    LAYOUT(WrenchArgs, control),
    LAYOUT(WrenchArgs, stale),
    LAYOUT(WrenchArgs, tare_count),
    LAYOUT(WrenchArgs, samples),
    LAYOUT(WrenchArgs, sample_tick),
    LAYOUT(WrenchArgs, present),
    LAYOUT(WrenchArgs, tare_cmd),
    LAYOUT(WrenchArgs, tare_state),
    LAYOUT(WrenchArgs, tick),
    LAYOUT(WrenchArgs, seq),
    LAYOUT(WrenchArgs, stale_limit),
    LAYOUT(WrenchArgs, given_seen),
    LAYOUT(WrenchArgs, cycles),
    LAYOUT(WrenchArgs, cycles_seen),
    LAYOUT(WrenchArgs, ready),
    LAYOUT(WrenchArgs, request),
    LAYOUT(WrenchArgs, seq_mask),
    LAYOUT(WrenchArgs, averaging),
    LAYOUT(WrenchArgs, done),
    END(WrenchArgs),
};

static const Field Field_LAYOUT[] = {
    LAYOUT(Field, name),
    LAYOUT(Field, offset),
    LAYOUT(Field, size),
    LAYOUT(Field, kind),
    END(Field),
};

static const Field VectorArgs_LAYOUT[] = {
    LAYOUT(VectorArgs, n),
    LAYOUT(VectorArgs, data),
    LAYOUT(VectorArgs, rows),
    LAYOUT(VectorArgs, demand),
    LAYOUT(VectorArgs, position),
    LAYOUT(VectorArgs, torque),
    LAYOUT(VectorArgs, error),
    LAYOUT(VectorArgs, status),
    LAYOUT(VectorArgs, ok),
    END(VectorArgs),
};

static const Field UnitArgs_LAYOUT[] = {
    LAYOUT(UnitArgs, slots),
    LAYOUT(UnitArgs, pid),
    LAYOUT(UnitArgs, pd),
    LAYOUT(UnitArgs, lo),
    LAYOUT(UnitArgs, hi),
    LAYOUT(UnitArgs, pid_a),
    LAYOUT(UnitArgs, pd_a),
    LAYOUT(UnitArgs, me),
    LAYOUT(UnitArgs, sv),
    LAYOUT(UnitArgs, ok),
    LAYOUT(UnitArgs, left),
    LAYOUT(UnitArgs, tick),
    LAYOUT(UnitArgs, exec_ns),
    LAYOUT(UnitArgs, n_left),
    LAYOUT(UnitArgs, fault),
    LAYOUT(UnitArgs, bad),
    END(UnitArgs),
};

static const Field ArmFinishArgs_LAYOUT[] = {
    LAYOUT(ArmFinishArgs, n),
    LAYOUT(ArmFinishArgs, tau),
    LAYOUT(ArmFinishArgs, q_d),
    LAYOUT(ArmFinishArgs, q),
    LAYOUT(ArmFinishArgs, enabled),
    LAYOUT(ArmFinishArgs, torque),
    LAYOUT(ArmFinishArgs, error),
    LAYOUT(ArmFinishArgs, status),
    LAYOUT(ArmFinishArgs, sv),
    LAYOUT(ArmFinishArgs, ran),
    LAYOUT(ArmFinishArgs, exec),
    LAYOUT(ArmFinishArgs, arm_status),
    LAYOUT(ArmFinishArgs, arm_exec_ns),
    LAYOUT(ArmFinishArgs, arm_ran_tick),
    LAYOUT(ArmFinishArgs, tick),
    LAYOUT(ArmFinishArgs, sv_index),
    LAYOUT(ArmFinishArgs, t0),
    END(ArmFinishArgs),
};

static const Field ArmArgs_LAYOUT[] = {
    LAYOUT(ArmArgs, n),
    LAYOUT(ArmArgs, d),
    LAYOUT(ArmArgs, q_d),
    LAYOUT(ArmArgs, qd_d),
    LAYOUT(ArmArgs, qdd_d),
    LAYOUT(ArmArgs, q),
    LAYOUT(ArmArgs, qd),
    LAYOUT(ArmArgs, h),
    LAYOUT(ArmArgs, M),
    LAYOUT(ArmArgs, J),
    LAYOUT(ArmArgs, pose),
    LAYOUT(ArmArgs, pose_d),
    LAYOUT(ArmArgs, wrench),
    LAYOUT(ArmArgs, wrenches),
    LAYOUT(ArmArgs, wrench_stride),
    LAYOUT(ArmArgs, robots),
    LAYOUT(ArmArgs, has_sensor),
    LAYOUT(ArmArgs, viscous),
    LAYOUT(ArmArgs, gear_w),
    LAYOUT(ArmArgs, coulomb_pos),
    LAYOUT(ArmArgs, coulomb_neg),
    LAYOUT(ArmArgs, tau),
    END(ArmArgs),
};

static const Field McgillArgs_LAYOUT[] = {
    LAYOUT(McgillArgs, n_arms),
    LAYOUT(McgillArgs, csr),
    LAYOUT(McgillArgs, power_reg),
    LAYOUT(McgillArgs, power),
    LAYOUT(McgillArgs, enable_ticks),
    LAYOUT(McgillArgs, capture),
    LAYOUT(McgillArgs, codes),
    LAYOUT(McgillArgs, codes_row),
    LAYOUT(McgillArgs, n_joints),
    LAYOUT(McgillArgs, fault_active),
    LAYOUT(McgillArgs, base_csr),
    LAYOUT(McgillArgs, green_red),
    LAYOUT(McgillArgs, no_disable),
    LAYOUT(McgillArgs, enable),
    LAYOUT(McgillArgs, index_off),
    LAYOUT(McgillArgs, amps_on),
    LAYOUT(McgillArgs, on),
    LAYOUT(McgillArgs, enabling),
    LAYOUT(McgillArgs, off),
    LAYOUT(McgillArgs, hold_ticks),
    LAYOUT(McgillArgs, dac_zero),
    LAYOUT(McgillArgs, retrigger),
    LAYOUT(McgillArgs, retrigger_ticks),
    LAYOUT(McgillArgs, ticks),
    LAYOUT(McgillArgs, bit),
    LAYOUT(McgillArgs, prev_bit),
    END(McgillArgs),
};

static const Field FrankaReadArgs_LAYOUT[] = {
    LAYOUT(FrankaReadArgs, n),
    LAYOUT(FrankaReadArgs, n_arms),
    LAYOUT(FrankaReadArgs, arms),
    LAYOUT(FrankaReadArgs, q_off),
    LAYOUT(FrankaReadArgs, seq_off),
    LAYOUT(FrankaReadArgs, q),
    LAYOUT(FrankaReadArgs, seen),
    END(FrankaReadArgs),
};

static const Field FrankaWriteArgs_LAYOUT[] = {
    LAYOUT(FrankaWriteArgs, n),
    LAYOUT(FrankaWriteArgs, torque),
    LAYOUT(FrankaWriteArgs, torque_limit),
    LAYOUT(FrankaWriteArgs, step),
    LAYOUT(FrankaWriteArgs, last),
    LAYOUT(FrankaWriteArgs, current),
    LAYOUT(FrankaWriteArgs, clamped),
    LAYOUT(FrankaWriteArgs, arms),
    LAYOUT(FrankaWriteArgs, tau_off),
    END(FrankaWriteArgs),
};

static const Field FrankaControlArgs_LAYOUT[] = {
    LAYOUT(FrankaControlArgs, n_arms),
    LAYOUT(FrankaControlArgs, arms),
    LAYOUT(FrankaControlArgs, row),
    LAYOUT(FrankaControlArgs, want_off),
    LAYOUT(FrankaControlArgs, cmd_seq_off),
    LAYOUT(FrankaControlArgs, tau_off),
    LAYOUT(FrankaControlArgs, power),
    LAYOUT(FrankaControlArgs, n_joints),
    LAYOUT(FrankaControlArgs, seen),
    LAYOUT(FrankaControlArgs, last),
    LAYOUT(FrankaControlArgs, base),
    LAYOUT(FrankaControlArgs, links),
    LAYOUT(FrankaControlArgs, fault_active),
    LAYOUT(FrankaControlArgs, on),
    LAYOUT(FrankaControlArgs, enabling),
    LAYOUT(FrankaControlArgs, ticks),
    END(FrankaControlArgs),
};

static const Field SioArgs_LAYOUT[] = {
    LAYOUT(SioArgs, n),
    LAYOUT(SioArgs, n_robots),
    LAYOUT(SioArgs, read_fn),
    LAYOUT(SioArgs, dac_fn),
    LAYOUT(SioArgs, control_fn),
    LAYOUT(SioArgs, read_args),
    LAYOUT(SioArgs, dac_args),
    LAYOUT(SioArgs, control_args),
    LAYOUT(SioArgs, capture),
    LAYOUT(SioArgs, velocity),
    LAYOUT(SioArgs, sensors),
    LAYOUT(SioArgs, guard_state),
    LAYOUT(SioArgs, guard_n),
    LAYOUT(SioArgs, n_sensors),
    LAYOUT(SioArgs, guard_armed),
    LAYOUT(SioArgs, robots),
    LAYOUT(SioArgs, checks),
    LAYOUT(SioArgs, ff),
    LAYOUT(SioArgs, feed),
    LAYOUT(SioArgs, torques),
    LAYOUT(SioArgs, current),
    LAYOUT(SioArgs, publish),
    LAYOUT(SioArgs, flight),
    LAYOUT(SioArgs, fault_active),
    LAYOUT(SioArgs, fault_count),
    LAYOUT(SioArgs, arm_algo),
    LAYOUT(SioArgs, arm_op),
    LAYOUT(SioArgs, shadows),
    LAYOUT(SioArgs, bounds),
    LAYOUT(SioArgs, whole),
    LAYOUT(SioArgs, mark),
    LAYOUT(SioArgs, ff_out),
    LAYOUT(SioArgs, arm_none),
    LAYOUT(SioArgs, arm_free),
    LAYOUT(SioArgs, arm_held),
    LAYOUT(SioArgs, feeds),
    LAYOUT(SioArgs, n_feeds),
    LAYOUT(SioArgs, done_sem),
    LAYOUT(SioArgs, ctrl_done),
    LAYOUT(SioArgs, slice_ns),
    LAYOUT(SioArgs, ctrl_tick),
    LAYOUT(SioArgs, fed_ns),
    LAYOUT(SioArgs, served_max),
    LAYOUT(SioArgs, robots_tick),
    LAYOUT(SioArgs, robots_faults),
    LAYOUT(SioArgs, sv_fed_tick),
    LAYOUT(SioArgs, signal_tick),
    LAYOUT(SioArgs, ack_tick),
    LAYOUT(SioArgs, vouched_tick),
    LAYOUT(SioArgs, gang_sv),
    LAYOUT(SioArgs, gang_slot),
    LAYOUT(SioArgs, gang_lag),
    LAYOUT(SioArgs, n_gang),
    LAYOUT(SioArgs, ack_early),
    LAYOUT(SioArgs, clock_tick),
    LAYOUT(SioArgs, lat_last),
    LAYOUT(SioArgs, lat_max),
    LAYOUT(SioArgs, hist),
    LAYOUT(SioArgs, linear_us),
    LAYOUT(SioArgs, log_bins),
    LAYOUT(SioArgs, tick),
    LAYOUT(SioArgs, post),
    LAYOUT(SioArgs, ok),
    LAYOUT(SioArgs, stage),
    LAYOUT(SioArgs, faulted),
    LAYOUT(SioArgs, faults_seen),
    LAYOUT(SioArgs, at),
    LAYOUT(SioArgs, result),
    LAYOUT(SioArgs, fed),
    LAYOUT(SioArgs, t_read),
    LAYOUT(SioArgs, c_read),
    LAYOUT(SioArgs, t_fed),
    LAYOUT(SioArgs, t_done),
    LAYOUT(SioArgs, t_out),
    LAYOUT(SioArgs, c_out),
    LAYOUT(SioArgs, retrigger_tick),
    END(SioArgs),
};

static const Field ServeArgs_LAYOUT[] = {
    LAYOUT(ServeArgs, n),
    LAYOUT(ServeArgs, n_arms),
    LAYOUT(ServeArgs, n_units),
    LAYOUT(ServeArgs, slots),
    LAYOUT(ServeArgs, fed_tick_out),
    LAYOUT(ServeArgs, ctrl_fed),
    LAYOUT(ServeArgs, ctrl_done),
    LAYOUT(ServeArgs, ctrl_tick),
    LAYOUT(ServeArgs, arm_lo),
    LAYOUT(ServeArgs, units),
    LAYOUT(ServeArgs, order),
    LAYOUT(ServeArgs, done_sem),
    LAYOUT(ServeArgs, me),
    LAYOUT(ServeArgs, arm_free),
    LAYOUT(ServeArgs, exec_last),
    LAYOUT(ServeArgs, exec_max),
    LAYOUT(ServeArgs, servos),
    LAYOUT(ServeArgs, exec_hist),
    LAYOUT(ServeArgs, linear_us),
    LAYOUT(ServeArgs, log_bins),
    LAYOUT(ServeArgs, feed_sem),
    LAYOUT(ServeArgs, poll_ns),
    LAYOUT(ServeArgs, feed_wait_ns),
    LAYOUT(ServeArgs, learn),
    LAYOUT(ServeArgs, fed_ns),
    LAYOUT(ServeArgs, served_max),
    LAYOUT(ServeArgs, release),
    LAYOUT(ServeArgs, feed_seen),
    LAYOUT(ServeArgs, served),
    LAYOUT(ServeArgs, history),
    LAYOUT(ServeArgs, feed_k),
    LAYOUT(ServeArgs, margin_ns),
    LAYOUT(ServeArgs, share_ns),
    LAYOUT(ServeArgs, share_looks),
    LAYOUT(ServeArgs, cap_ns),
    LAYOUT(ServeArgs, sharing),
    LAYOUT(ServeArgs, servo_ticks),
    LAYOUT(ServeArgs, rest_ticks),
    LAYOUT(ServeArgs, want_ticks),
    LAYOUT(ServeArgs, poll_after),
    LAYOUT(ServeArgs, fed_tick),
    LAYOUT(ServeArgs, count),
    LAYOUT(ServeArgs, stage),
    LAYOUT(ServeArgs, at),
    LAYOUT(ServeArgs, unit),
    LAYOUT(ServeArgs, tick_now),
    LAYOUT(ServeArgs, fed),
    LAYOUT(ServeArgs, ran),
    LAYOUT(ServeArgs, t0),
    LAYOUT(ServeArgs, wanted),
    END(ServeArgs),
};

static const Field WaitArgs_LAYOUT[] = {
    LAYOUT(WaitArgs, stats),
    LAYOUT(WaitArgs, ack_sem),
    LAYOUT(WaitArgs, sem),
    LAYOUT(WaitArgs, release),
    LAYOUT(WaitArgs, signal_tick),
    LAYOUT(WaitArgs, after),
    LAYOUT(WaitArgs, shutdown),
    LAYOUT(WaitArgs, next_due),
    LAYOUT(WaitArgs, base_ns),
    LAYOUT(WaitArgs, period_ticks),
    LAYOUT(WaitArgs, poll_ns),
    LAYOUT(WaitArgs, idle_ns),
    LAYOUT(WaitArgs, signalled),
    LAYOUT(WaitArgs, cycled),
    LAYOUT(WaitArgs, tick),
    LAYOUT(WaitArgs, woke),
    LAYOUT(WaitArgs, since),
    END(WaitArgs),
};

static const Field WitnessArgs_LAYOUT[] = {
    LAYOUT(WitnessArgs, cpu),
    LAYOUT(WitnessArgs, priority),
    LAYOUT(WitnessArgs, period_ns),
    LAYOUT(WitnessArgs, stall_ns),
    LAYOUT(WitnessArgs, ring_ns),
    LAYOUT(WitnessArgs, ring_lost),
    LAYOUT(WitnessArgs, ring),
    LAYOUT(WitnessArgs, guard_tid),
    LAYOUT(WitnessArgs, guard_priority),
    LAYOUT(WitnessArgs, guard_after_ns),
    LAYOUT(WitnessArgs, bottom_since),
    LAYOUT(WitnessArgs, seq),
    LAYOUT(WitnessArgs, due),
    LAYOUT(WitnessArgs, lost),
    LAYOUT(WitnessArgs, wakes),
    LAYOUT(WitnessArgs, stop),
    LAYOUT(WitnessArgs, running),
    LAYOUT(WitnessArgs, thread),
    END(WitnessArgs),
};

/* Record k's fields (RECORDS' order); NULL for another. */
const Field *kali_fields(int64_t record) {
    switch (record) {
    case 0: return SlotRecord_FIELDS;
    case 1: return PidRecord_FIELDS;
    case 2: return PdRecord_FIELDS;
    case 3: return ImpRecord_FIELDS;
    case 4: return CtRecord_FIELDS;
    default: return NULL;
    }
}

/* The fields of the block named `name`; NULL for another. */
const Field *kali_layout(const char *name) {
    if (!strcmp(name, "View")) return View_LAYOUT;
    if (!strcmp(name, "ReadArgs")) return ReadArgs_LAYOUT;
    if (!strcmp(name, "VelocityArgs")) return VelocityArgs_LAYOUT;
    if (!strcmp(name, "ChecksArgs")) return ChecksArgs_LAYOUT;
    if (!strcmp(name, "FeedArgs")) return FeedArgs_LAYOUT;
    if (!strcmp(name, "TorquesArgs")) return TorquesArgs_LAYOUT;
    if (!strcmp(name, "DacArgs")) return DacArgs_LAYOUT;
    if (!strcmp(name, "CurrentArgs")) return CurrentArgs_LAYOUT;
    if (!strcmp(name, "MotorArgs")) return MotorArgs_LAYOUT;
    if (!strcmp(name, "EncoderArgs")) return EncoderArgs_LAYOUT;
    if (!strcmp(name, "StatsArgs")) return StatsArgs_LAYOUT;
    if (!strcmp(name, "FlightArgs")) return FlightArgs_LAYOUT;
    if (!strcmp(name, "BoardArgs")) return BoardArgs_LAYOUT;
    if (!strcmp(name, "PlantIoArgs")) return PlantIoArgs_LAYOUT;
    if (!strcmp(name, "PlantTruthArgs")) return PlantTruthArgs_LAYOUT;
    if (!strcmp(name, "FtArgs")) return FtArgs_LAYOUT;
    if (!strcmp(name, "FifoPopArgs")) return FifoPopArgs_LAYOUT;
    if (!strcmp(name, "RobotsArgs")) return RobotsArgs_LAYOUT;
    if (!strcmp(name, "FfArgs")) return FfArgs_LAYOUT;
    if (!strcmp(name, "Copy")) return Copy_LAYOUT;
    if (!strcmp(name, "CopyArgs")) return CopyArgs_LAYOUT;
    if (!strcmp(name, "ChainPoseArgs")) return ChainPoseArgs_LAYOUT;
    if (!strcmp(name, "WrenchArgs")) return WrenchArgs_LAYOUT;
    if (!strcmp(name, "Field")) return Field_LAYOUT;
    if (!strcmp(name, "VectorArgs")) return VectorArgs_LAYOUT;
    if (!strcmp(name, "UnitArgs")) return UnitArgs_LAYOUT;
    if (!strcmp(name, "ArmFinishArgs")) return ArmFinishArgs_LAYOUT;
    if (!strcmp(name, "ArmArgs")) return ArmArgs_LAYOUT;
    if (!strcmp(name, "McgillArgs")) return McgillArgs_LAYOUT;
    if (!strcmp(name, "FrankaReadArgs")) return FrankaReadArgs_LAYOUT;
    if (!strcmp(name, "FrankaWriteArgs")) return FrankaWriteArgs_LAYOUT;
    if (!strcmp(name, "FrankaControlArgs")) return FrankaControlArgs_LAYOUT;
    if (!strcmp(name, "SioArgs")) return SioArgs_LAYOUT;
    if (!strcmp(name, "ServeArgs")) return ServeArgs_LAYOUT;
    if (!strcmp(name, "WaitArgs")) return WaitArgs_LAYOUT;
    if (!strcmp(name, "WitnessArgs")) return WitnessArgs_LAYOUT;
    return NULL;
}

#endif
