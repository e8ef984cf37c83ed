"""Every compiled kernel's argument block, declared once in ``BLOCKS``: the C structs
(``csrc/kernel_args.h``) and the ctypes classes are both generated from it, as LinuxCNC's
halcompile makes a component's struct and glue from its ``.comp`` declaration.

A block is its C name, its owner (whose library holds its kernels, ``LIBRARIES``), its
kernels each with its Python reference, and its rows in C order: ``(names, C type)`` or
``(names, C type, doc)``, or a bare string, a comment.  A per-joint array is a ``View``.  The
records the kernels step in place (``RECORDS``) are generated from their numpy dtypes.  After
editing, regenerate the checked-in header (``python -m kali_daemons.core.kernel_args``): a
test and ``kernels.open_library`` refuse a mismatch.  The rules in full:
docs/internals/sio-viewer-core.md.

One module on purpose: every kernel's argument block declared once, the one source of the C
header and the ctypes classes.
"""

from __future__ import annotations

import ctypes
import importlib
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, cast

import numpy as np

from . import layout

HEADER = Path(__file__).with_name("csrc") / "kernel_args.h"

Row = tuple[str, str] | tuple[str, str, str] | str


@dataclass(frozen=True)
class Block:
    """One argument block: its C name, owner, the kernels taking it (each with its
    reference) and its rows."""

    name: str
    owner: str
    kernels: dict[str, str]
    rows: tuple[Row, ...]

    def fields(self) -> list[tuple[str, str]]:
        """Its fields in order, each ``(name, C type)``."""
        return [
            (name.strip(), row[1])
            for row in self.rows
            if not isinstance(row, str)
            for name in row[0].split(",")
        ]


def block(name: str, owner: str, kernels: dict[str, str], *rows: Row) -> Block:
    """A ``Block`` (the declarations below read as a table)."""
    return Block(name, owner, kernels, rows)


BLOCKS: tuple[Block, ...] = (
    block(
        "View",
        "core",
        {},
        ("p", "char *", "element 0"),
        ("stride", "int64_t", "bytes between elements"),
    ),
    block(
        "ReadArgs",
        "sio",
        {"kali_read": "core.kernels:read_reference"},
        ("n", "int64_t"),
        ("encoders", "char *", "the boards' registers"),
        ("enc_off", "View", "int64: joint i's counter at encoders + enc_off[i] (uint16)"),
        ("acc, prev", "View", "int32: accumulated counts, last 12-bit reading"),
        ("offset", "View", "double: calibration offsets, rad"),
        ("rad_per_count, q", "View"),
        ("modulo, half", "int64_t", "4096, 2048 (figure C.3)"),
    ),
    block(
        "VelocityArgs",
        "sio",
        {"kali_velocity": "core.kernels:velocity_reference"},
        ("n", "int64_t"),
        ("q, q_prev, qd", "View"),
        ("gain", "double", "rate * a"),
        ("b", "double", "1 / (1 + a)"),
    ),
    block(
        "ChecksArgs",
        "sio",
        {"kali_checks": "core.kernels:checks_reference"},
        ("n, n_robots", "int64_t"),
        ("bounds", "View", "int64, n_robots + 1: robot k's joints are bounds[k] .. bounds[k+1]"),
        ("q, demand, q_min, q_max", "View"),
        ("range_check", "View", "uint8: nonzero = checked"),
        ("fed", "View", "uint8 (bool)"),
        ("safe", "View", "double: client-written limits"),
        ("safe_ok", "View", "double: the last valid limit of each joint (updated here)"),
        ("pi", "double"),
    ),
    block(
        "FeedArgs",
        "sio",
        {"kali_feed": "core.kernels:feed_reference"},
        ("n", "int64_t"),
        ("demand, q, qd, fed", "View"),
        ("slot_demand, slot_position, slot_velocity", "View"),
        ("slot_busy", "View", "uint32: 0 = fed (an SV may claim it), else not_fed"),
        ("not_fed", "int64_t"),
        ("ctrl_fed, ctrl_done", "uint32_t *", "the servo control record's counts"),
        ("demand_vel, demand_acc, ff, slot_demand_vel, slot_demand_acc, slot_ff", "View"),
        (
            "mark",
            "View",
            "uint32 per slot: the busy value a fed slot gets (0, or ARM_FREE/ARM_HELD)",
        ),
    ),
    block(
        "TorquesArgs",
        "sio",
        {"kali_torques": "core.kernels:torques_reference"},
        ("n", "int64_t"),
        ("slot_torque, fed, servo_torque, ff, torque", "View"),
    ),
    block(
        "DacArgs",
        "sio",
        {"kali_dac": "core.kernels:dac_reference"},
        ("n", "int64_t"),
        ("torque, gkt, current_limit, codes_per_amp", "View"),
        ("current", "View", "double out, A"),
        ("clamped", "View", "uint8 (bool) out"),
        ("dacs", "char *", "the DAC boards' registers"),
        ("dac_off", "View", "int64: joint i's DAC code at dacs + dac_off[i] (uint16)"),
        ("zero, top", "double", "DAC code of 0 V, highest code"),
    ),
    block(
        "CurrentArgs",
        "sio",
        {"kali_current_check": "core.kernels:current_check_reference"},
        ("n", "int64_t"),
        ("torque, fed, clamped", "View"),
        ("over", "View", "int64: consecutive fed ticks clamped"),
        ("current_ticks", "View", "int64: how many halt"),
    ),
    block(
        "MotorArgs",
        "plant",
        {"kali_motors": "plant.motor:drive_reference"},
        ("n", "int64_t"),
        ("volts, qd, enabled, current", "const double *"),
        ("gear, kt_r, vbus_r, i_max, gain, w_scale, g_extra_pos, g_extra_neg", "const double *"),
        ("ctrl, range, friction", "double *", "the bank's: range is n x 2 (low, high)"),
        ("acts, act_adr, dofs", "const int64_t *", "joint i's actuator, activation, dof"),
        ("mj_actrange, mj_ctrl, mj_act, mj_qfrc", "double *", "MuJoCo's arrays (actrange nu x 2)"),
    ),
    block(
        "EncoderArgs",
        "plant",
        {"kali_encoders": "plant.board:EncoderBank.sample"},
        ("n", "int64_t"),
        ("angle, cpr, phase", "const double *", "motor angle, counts per rad, index phase"),
        ("ref, count", "int64_t *", "the bank's: the count's zero, the count"),
        ("rev", "double *", "the bank's: revolution of the last index"),
        ("robot_of, joint_of", "const int64_t *"),
        ("encoders", "char *", "the boards' counter registers (uint16)"),
        ("enc_off", "const int64_t *", "joint i's at encoders + enc_off[i]"),
        ("csr, index", "View", "uint8 per board"),
        ("index_off, modulo", "int64_t", "CSR_INDEX_OFF; 4096"),
        ("two_pi", "double"),
    ),
    block(
        "StatsArgs",
        "clock",
        {"kali_cycle_stats": "runtime.daemon:_CycleStats.record_reference"},
        ("late, late_max, exec, exec_max, heart, ack", "int64_t *"),
        ("acks", "uint64_t *"),
        ("hist", "uint32_t *"),
        ("linear_us, log_bins", "int64_t", "layout.HIST_LINEAR_US, HIST_LOG_BINS"),
        ("tick, release, woke, done", "int64_t"),
    ),
    block(
        "FlightArgs",
        "flightrec",
        {"kali_flight_row": "runtime.flightrec:FlightRecorder.record_reference"},
        ("n, n_robots, rows", "int64_t"),
        ("ring", "char *"),
        ("row_size", "int64_t"),
        (
            "off_tick, off_t, off_lat, off_late, off_wait, off_ran, off_shadow, off_wrench",
            "int64_t",
        ),
        ("off_cols", "const int64_t *", "the float64 columns' offsets in a row"),
        ("cols", "const View *", "their sources, n each"),
        ("n_cols", "int64_t"),
        ("shadow", "View", "float64, n"),
        ("wrench", "const char *", "n_robots x 6 float64"),
        ("wrench_row, wrench_col", "int64_t", "its strides, bytes"),
        ("release", "const int64_t *", "SIO's slot's release_ns"),
        ("count", "uint64_t *", "rows written: the header's, this writer's alone"),
        ("tick, t_read, latency, wait, ran", "int64_t"),
    ),
    block(
        "BoardArgs",
        "plant",
        {
            "kali_boards_update": "plant.board:IoBoardSim.update",
            "kali_boards_convert": "plant.board:IoBoardSim.convert",
            "kali_boards_truth": "plant.sim:PlantSim._write_truth_reference",
        },
        ("n_arms", "int64_t"),
        (
            "csr, estop, power, index, adc_control, adc_analog, adc_digital, clamped, scans",
            "View",
            "registers",
        ),
        ("amps_on, brakes_engaged, watchdog_tripped, truth_estop", "View", "truth"),
        ("state", "int64_t *", "n_arms x B_STATE"),
        ("base, count", "const int64_t *", "arm k's joints: flat base[k] .. base[k] + count[k]"),
        ("enabled", "double *", "per joint: the motor bank's enable (1.0 / 0.0)"),
        ("braked", "uint8_t *", "per joint: the brakes hold"),
        ("q, lo, hi, mid", "const double *", "per joint: angle, the pots' span, 2.5 V"),
        ("now_ns, hold_ns, watchdog_ns, brake_ns, never", "int64_t"),
        ("timeout_on, retrigger, no_disable, enable, index_off", "int64_t", "CSR bits"),
        ("p_amps, p_brakes, p_tripped, p_estop", "int64_t", "POWER bits"),
        ("adc_start, channel_mask, adc_done, value_mask, channels, self_test", "int64_t"),
        ("pot_v_min, pot_v_max, adc_volts, adc_top", "double"),
    ),
    block(
        "PlantIoArgs",
        "plant",
        {
            "kali_plant_dac": "plant.sim:PlantSim._read_dac",
            "kali_plant_joints": "plant.sim:PlantSim._read_joints",
        },
        ("n", "int64_t"),
        ("qpos, qvel, act", "const double *", "MuJoCo's"),
        ("qpos_idx, dofs, act_adr", "const int64_t *", "joint i's entries in them"),
        ("gear, gkt", "const double *"),
        ("q, qd, current, motor_angle, torque", "double *"),
        ("dacs", "char *", "the DAC boards' records"),
        ("dac_off, robot_of", "const int64_t *", "joint i's code at dacs + dac_off[i]"),
        ("clamped", "View", "uint32 per arm"),
        ("volts", "double *"),
        ("top, zero, scale", "double", "4095, the code of 0 V, volts per code"),
    ),
    block(
        "PlantTruthArgs",
        "plant",
        {"kali_plant_truth": "plant.sim:PlantSim._write_truth_reference"},
        ("n", "int64_t", "arms"),
        ("welds", "int64_t", "graspable objects: arm k's weld of the g-th is k * welds + g"),
        ("eq_active", "const uint8_t *", "MuJoCo's: the welds, n x welds"),
        ("graspable", "const int64_t *", "welds: the g-th graspable's index among the objects"),
        ("held", "uint8_t *", "n, bool"),
        ("held_object", "int64_t *", "n: the object arm k holds, -1 none"),
        ("weld", "const double *", "n x 6: the rows _weld_forces copied"),
        ("grasped, holding", "View", "uint8 and int8, per arm record"),
        ("grasp_wrench, ft_wrench, push", "View", "each record's field (6, 6, 3 doubles)"),
        ("ft_true", "const double *", "n x 6"),
        ("xfrc", "const double *", "MuJoCo's xfrc_applied, 6 a body"),
        ("tool_body", "const int64_t *", "n"),
        ("site_xpos", "const double *", "3 a site"),
        ("grasp_site", "const int64_t *", "n: the grasp each arm took hold at"),
        ("objects", "int64_t", "the free objects"),
        ("object_qpos", "const double *", "7 an object: MuJoCo's first qpos"),
        ("sim_time_ns", "int64_t *"),
        ("ticks", "uint64_t *"),
        ("object_pose", "double *", "7 an object: its truth records"),
        ("internal_force", "double *"),
        ("sim_ns, cycles, welds_read", "int64_t"),
    ),
    block(
        "FtArgs",
        "plant",
        {"kali_ft_bank": "plant.board:FtBank.cycle"},
        ("normals", "const double *"),
        ("size, at", "int64_t", "the block's length, the next draw"),
        ("offset", "double *", "six volts: the bank's (FtBank.offset)"),
        ("drift", "double", "a cycle's random-walk step, volts"),
        ("gauges, noise_sd", "const double *", "C^-1 (6 x 6), the wrench's noise per axis"),
        ("wrench", "const double *", "the tool on the sensor, sensor frame"),
        ("codes", "int16_t *"),
        ("control", "const uint16_t *"),
        ("status", "uint16_t *"),
        ("served, seq_mask, request, ready", "int64_t", "ready: FT_READY | FT_PRESENT"),
        ("volts_per_code, rail", "double"),
    ),
    block(
        "FifoPopArgs",
        "fifo",
        {"kali_fifo_pop": "core.channels:InterpolatingFifo.pop_into"},
        ("n", "int64_t", "the set-points' width"),
        ("head", "uint64_t *", "the header's head (this consumer's) and tail"),
        ("tail", "const uint64_t *"),
        ("ring", "const double *", "capacity x n"),
        ("stamps", "const uint64_t *", "each set-point's ratio word"),
        ("capacity", "int64_t"),
        ("bound", "double", "a value not strictly within +-bound is refused"),
        ("cur, start, target", "double *", "the .state block: output, A, B"),
        ("seg_ticks, seg_done, primed, rejected, ratio_num, ratio_den", "uint32_t *"),
        ("underruns, phase_acc", "uint64_t *"),
        ("out", "View"),
        ("num, den", "int64_t", "the ratio of the segment in progress"),
        ("stamp", "uint64_t", "num | den << 32"),
    ),
    block(
        "RobotsArgs",
        "sio",
        {"kali_sio_robots": "sio.cycle:SioCycle._robot"},
        ("n, n_robots", "int64_t"),
        ("bounds", "View", "int64, n_robots + 1: robot k's joints bounds[k] .."),
        ("fed", "View", "uint8 (bool), every joint"),
        ("pots_read, power, power_cmd, calib_cmd, calib_state, guided", "View", "uint8, per robot"),
        ("guard_state", "View", "uint32, per robot"),
        ("amps", "View", "uint8, per robot: the board register with ..."),
        ("amps_bit", "int64_t", "... this bit set while its amplifiers are on"),
        ("on, tripped", "int64_t", "PowerState.ON, GuardState.TRIPPED"),
        ("calib_active", "int64_t", "bit s set: calibration state s is under way"),
        ("pops", "FifoPopArgs **", "robot k's kali_fifo_pop block"),
        ("faulted", "int64_t", "this tick's, set by SIO before each call"),
    ),
    block(
        "FfArgs",
        "sio",
        {"kali_feedforward": "sio.feedforward:RobotFeedforward.update"},
        ("n, rows, row_len", "int64_t", "joints; FF_ROWS; MAX_JOINTS (a row's values)"),
        ("keys", "const uint64_t *", "the record's key[FF_ROWS]"),
        ("tau, qd, qdd", "const double *", "its rows: row r at r * row_len"),
        ("mode", "const uint8_t *", "its words: the mode a client wants"),
        ("state", "uint8_t *", "FfState"),
        ("heartbeat", "const int64_t *", "the dynamics process's last tick"),
        ("stale_ticks", "uint64_t *"),
        ("stale_events", "uint32_t *"),
        ("weight_rec", "double *"),
        ("head", "const uint64_t *", "the FIFO's header: the next set-point to take"),
        ("seg_ticks, seg_done", "const uint32_t *"),
        ("out, vel, acc", "View", "double: the robot's joints of SIO's arrays"),
        ("last", "double *", "3 x n: the last good torque, velocity, acceleration"),
        ("heartbeat_limit, missing_limit, mode_max", "int64_t"),
        ("step", "double", "weight per servo tick"),
        ("tick, arm", "int64_t", "this tick's, from SIO"),
        ("mode_ok, missing, stale", "int64_t", "the state between ticks"),
        ("weight", "double"),
    ),
    block(
        "Copy",
        "core",
        {},
        ("src, dst", "View"),
        ("size", "int64_t", "bytes per element: 4 or 8"),
    ),
    block(
        "CopyArgs",
        "core",
        {"kali_copy": ""},
        ("n, m", "int64_t"),
        ("copies", "Copy *"),
    ),
    block(
        "ChainPoseArgs",
        "chain",
        {"kali_chain_pose": "robots.chain:flange_pose"},
        ("n", "int64_t", "the chain's joints"),
        ("origins", "const double *", "(n + 1) x 16: chain.Chain.origins, C order"),
        ("axes", "const double *", "n x 3: chain.Chain.axes"),
        ("q", "const double *", "n joint angles, rad, contiguous"),
        ("out", "double *", "16: the flange pose, row-major"),
    ),
    block(
        "WrenchArgs",
        "sio",
        {"kali_wrench_tick": "", "kali_wrench_convert": "sio.wrench:convert_reference"},
        ("n", "int64_t", "the chain's joints"),
        ("origins, axes, q", "const double *", "chain.Chain, the arm's angles (contiguous)"),
        ("codes", "const int16_t *", "the board's 6 gauge codes"),
        ("given", "const double *", "6: a wrench the hardware gives, flange; NULL: the codes'"),
        ("given_seq", "const uint64_t *", "the hardware's count of those wrenches"),
        ("cal", "const double *", "6x6 calibration matrix, row-major, N per volt"),
        ("base", "const double *", "4x4 base pose in the world, row-major"),
        ("g", "const double *", "gravity in the world, m/s^2"),
        ("com", "const double *", "the tool's centre of mass, sensor frame"),
        ("rated", "const double *", "the sheet's range per axis"),
        ("limit", "const double *", "FT_STATE.contact_limit: a client may only lower it"),
        ("mass, tip, alpha, volts, limit_config", "double"),
        ("rail", "int64_t", "a code at +-rail is saturated"),
        ("tare_left, tare_ticks", "int64_t", "in/out: samples a tare still sums; of how many"),
        ("raw, grav, sensor, filt, tool, world, bias, sum, rotation", "double *"),
        ("force, limit_used", "double", "out: the contact force and the limit it met, N"),
        "the tick's handshake and bookkeeping (kali_wrench_tick)",
        ("status, control", "uint16_t *", "the board's ft_status, ft_control"),
        ("stale, tare_count", "uint32_t *", "FT_STATE fields"),
        ("samples", "uint64_t *"),
        ("sample_tick", "int64_t *"),
        ("present, tare_cmd, tare_state", "uint8_t *"),
        ("tick, seq, stale_limit", "int64_t", "in: this tick; in/out: the sequence asked for"),
        ("given_seen", "uint64_t", "in/out: the hardware's count at the wrench last taken"),
        ("cycles", "const uint32_t *", "the gauges' hardware's cycles, if it can stall, or NULL"),
        ("cycles_seen", "uint64_t", "in/out: their count at the last tick"),
        (
            "ready, request, seq_mask, averaging, done",
            "int64_t",
            "ftsensor's bits, TareState's values",
        ),
    ),
    block(
        "Field",
        "core",
        {},
        ("name", "const char *", "NULL ends a table; that entry's offset is the struct's size"),
        ("offset, size", "int64_t"),
        ("kind", "char", "numpy's dtype kind: 'f', 'u', 'i'"),
    ),
    block(
        "VectorArgs",
        "servo",
        {
            "kali_pid_vector": "servo.algorithms.builtins:pid_step",
            "kali_pd_vector": "servo.algorithms.builtins:pd_step",
        },
        ("n", "int64_t"),
        ("data", "char *", "the algorithm's records"),
        ("rows", "View", "int64: row k of the step is record rows[k]"),
        ("demand, position, torque, error", "View"),
        ("status", "View", "int32"),
        ("ok", "int64_t", "STATUS_OK"),
    ),
    block(
        "UnitArgs",
        "servo",
        {"kali_serve_unit": "servo.sv.units:serve_unit_reference"},
        ("slots", "SlotRecord *", "the cell's slots"),
        ("pid", "PidRecord *", "the PID's block: a record per slot"),
        ("pd", "PdRecord *", "the PD's block"),
        ("lo, hi", "int64_t", "the robot's slots"),
        ("pid_a, pd_a", "int64_t", "the built-ins' registry indices"),
        ("me", "int64_t", "the SV's busy value: its number + 1"),
        ("sv", "int64_t", "its number"),
        ("ok", "int64_t", "STATUS_OK"),
        ("left", "int64_t *", "out: slots claimed for the per-slot path"),
        ("tick", "int64_t", "in: the tick served"),
        ("exec_ns", "int64_t", "in/out: this unit's last cost per slot, noted as each step's"),
        ("n_left", "int64_t", "out: slots put into left"),
        ("fault", "int64_t", "out: the first slot whose torque was not finite, or -1"),
        ("bad", "double", "out: its torque"),
    ),
    block(
        "ArmFinishArgs",
        "servo",
        {"kali_arm_finish": "servo.sv.arm:ArmRunner._finish_reference"},
        ("n", "int64_t"),
        ("tau", "double *", "n, contiguous: the step's torques"),
        ("q_d, q", "const double *", "the ArmInput's, contiguous"),
        ("enabled", "View", "uint32: the slots' (clients': 0 = no torque)"),
        ("torque, error", "View", "double: the slots'"),
        ("status, sv", "View", "int32"),
        ("ran, exec", "View", "int64"),
        ("arm_status", "int32_t *", "the robot's record"),
        ("arm_exec_ns, arm_ran_tick", "int64_t *"),
        ("tick, sv_index, t0", "int64_t"),
    ),
    block(
        "ArmArgs",
        "servo",
        {
            "kali_impedance": "servo.algorithms.armbuiltins:_imp_step",
            "kali_computed_torque": "servo.algorithms.armbuiltins:_ct_step",
        },
        ("n", "int64_t", "the arm's joints"),
        ("d", "void *", "the robot's record of the algorithm (arena)"),
        ("q_d, qd_d, qdd_d", "const double *", "n each: the demand"),
        ("q, qd, h", "const double *", "n each: the measurement, C(q, qd) qd + g(q)"),
        ("M, J", "const double *", "n x n, 6 x n, row-major"),
        ("pose, pose_d", "const double *", "4x4 row-major: the tool point at q, at q_d"),
        ("wrench", "const double *", "6: this arm's contact wrench, world axes"),
        ("wrenches", "const char *", "robots x 6 doubles, rows wrench_stride bytes apart"),
        ("wrench_stride, robots, has_sensor", "int64_t"),
        ("viscous, gear_w, coulomb_pos, coulomb_neg", "const double *", "n each: DriveFriction's"),
        ("tau", "double *", "n: out"),
    ),
    block(
        "McgillArgs",
        "sio",
        {"kali_mcgill_control": "hardware.mcgill.boards:McGillBoards.control"},
        ("n_arms", "int64_t"),
        ("csr, power_reg", "View", "uint8, per arm: the registers"),
        ("power, enable_ticks", "View", "per robot: uint8 PowerState, int32"),
        ("capture", "View", "uint8, per arm: index capture on (calibration)"),
        ("codes", "char *", "the DAC records' codes: arm k's row at k * codes_row"),
        ("codes_row", "int64_t"),
        ("n_joints", "View", "int64, per arm"),
        ("fault_active", "const uint32_t *", "halted: the fault word, read here"),
        ("base_csr, green_red, no_disable, enable, index_off, amps_on", "int64_t"),
        ("on, enabling, off, hold_ticks, dac_zero, retrigger, retrigger_ticks", "int64_t"),
        ("ticks, bit, prev_bit", "int64_t", "end_tick's state"),
    ),
    block(
        "FrankaReadArgs",
        "franka",
        {"kali_franka_read": "hardware.franka.arms:FrankaDriver.read_reference"},
        ("n, n_arms", "int64_t"),
        ("arms", "char *", "the FR3s' records (hardware.franka.registers)"),
        ("q_off", "View", "int64: joint i's angle at arms + q_off[i] (double)"),
        ("seq_off", "View", "int64, per arm: its state's seq at arms + seq_off[k] (uint64)"),
        ("q", "View", "double out, rad"),
        ("seen", "View", "uint64 out, per arm: the state this tick answers"),
    ),
    block(
        "FrankaWriteArgs",
        "franka",
        {"kali_franka_write": "hardware.franka.arms:FrankaDriver.write_reference"},
        ("n", "int64_t"),
        ("torque, torque_limit", "View", "N·m"),
        ("step", "View", "N·m: the most the torque may change in one tick (the FR3's rate)"),
        ("last", "View", "N·m: the torque sent last tick"),
        ("current", "View", "double out: the torque sent, N·m (the FR3 takes torques)"),
        ("clamped", "View", "uint8 (bool) out: beyond the torque limit"),
        ("arms", "char *"),
        ("tau_off", "View", "int64: joint i's command at arms + tau_off[i] (double)"),
    ),
    block(
        "FrankaControlArgs",
        "franka",
        {"kali_franka_control": "hardware.franka.arms:FrankaArms.control"},
        ("n_arms", "int64_t"),
        ("arms", "char *"),
        ("row", "int64_t", "bytes between two arms' records"),
        ("want_off, cmd_seq_off, tau_off", "int64_t", "fields' offsets in a record"),
        ("power", "View", "per robot: uint8 PowerState"),
        ("n_joints", "View", "int64, per arm"),
        ("seen", "View", "uint64, per arm: the state this tick answers (the read kernel's)"),
        ("last", "View", "double, per joint: the write kernel's, zeroed with the arm's torque"),
        ("base", "View", "int64, per arm: its first joint"),
        ("links", "sem_t **", "per arm: its link's semaphore, posted with the command"),
        ("fault_active", "const uint32_t *"),
        ("on, enabling", "int64_t"),
        ("ticks", "int64_t", "ticks whose commands went out"),
    ),
    block(
        "SioArgs",
        "sio",
        {"kali_sio_tick": "sio.cycle:SioCycle._tick_reference"},
        ("n, n_robots", "int64_t"),
        ("read_fn, dac_fn, control_fn", "KernelFn", "the boards'"),
        ("read_args, dac_args, control_args", "void *"),
        ("capture", "const uint8_t *", "per robot: index capture on"),
        ("velocity", "VelocityArgs *"),
        ("sensors", "WrenchArgs **"),
        ("guard_state", "const uint32_t **", "per sensor: its arm's guard ..."),
        ("guard_n", "const double **", "... and the force that trips it"),
        ("n_sensors, guard_armed", "int64_t"),
        ("robots", "RobotsArgs *"),
        ("checks", "ChecksArgs *"),
        ("ff", "FfArgs **", "per robot"),
        ("feed", "FeedArgs *"),
        ("torques", "TorquesArgs *"),
        ("current", "CurrentArgs *"),
        ("publish", "CopyArgs *"),
        ("flight", "FlightArgs *"),
        ("fault_active", "const uint32_t *"),
        ("fault_count", "const uint64_t *"),
        ("arm_algo, arm_op, shadows", "View", "per robot: int32, uint32, uint32"),
        ("bounds", "View", "int64, n_robots + 1"),
        ("whole", "uint8_t *", "per robot: fed whole last tick"),
        ("mark, ff_out", "View", "per joint: uint32, double"),
        ("arm_none, arm_free, arm_held", "int64_t"),
        ("feeds", "sem_t **"),
        ("n_feeds", "int64_t"),
        ("done_sem", "sem_t *", "the SVs' last post: every servo done"),
        ("ctrl_done", "uint32_t *"),
        ("slice_ns", "int64_t", "how long one wait for it lasts (a period)"),
        ("ctrl_tick", "int64_t *"),
        ("fed_ns", "int64_t *", "when SIO fed its last tick"),
        ("served_max", "int64_t *", "per SV: the longest feed-to-done since it learnt"),
        ("robots_tick, robots_faults", "View", "per robot: int64, uint32"),
        ("sv_fed_tick", "const int64_t *", "the gang (sio/gang.py): per SV"),
        ("signal_tick, ack_tick, vouched_tick", "View", "int64, per process slot"),
        ("gang_sv, gang_slot, gang_lag", "const int64_t *"),
        ("n_gang", "int64_t"),
        ("ack_early", "int64_t *", "SIO's slot's ack_tick, or NULL"),
        ("clock_tick", "const int64_t *"),
        ("lat_last, lat_max", "int64_t *"),
        ("hist", "uint32_t *"),
        ("linear_us, log_bins", "int64_t"),
        "per tick: from SIO, between the passes, to SIO",
        ("tick, post, ok", "int64_t", "ok: the servos were done (_wait_done)"),
        ("stage, faulted, faults_seen, at, result, fed", "int64_t"),
        ("t_read, c_read, t_fed, t_done, t_out, c_out, retrigger_tick", "int64_t"),
    ),
    block(
        "ServeArgs",
        "servo",
        {"kali_sv_serve": "servo.sv.daemon:ServoWorker._serve_reference"},
        ("n, n_arms, n_units", "int64_t"),
        ("slots", "SlotRecord *"),
        ("fed_tick_out", "int64_t *", "ctrl sv_fed_tick[this SV]"),
        ("ctrl_fed", "const uint32_t *"),
        ("ctrl_done", "uint32_t *"),
        ("ctrl_tick", "const int64_t *"),
        ("arm_lo", "const int64_t *", "per robot fed whole, in this SV's order: first slot"),
        ("units", "UnitArgs **", "in this SV's order"),
        ("order", "const int64_t *", "the single slots, in this SV's order"),
        ("done_sem", "sem_t *"),
        ("me, arm_free", "int64_t"),
        ("exec_last, exec_max", "int64_t *"),
        ("servos", "uint64_t *"),
        ("exec_hist", "uint32_t *"),
        ("linear_us, log_bins", "int64_t"),
        "the feed (stage SV_FEED, ServoWorker._await_feed and _learn_feed)",
        ("feed_sem", "sem_t *"),
        ("poll_ns, feed_wait_ns", "int64_t", "poll the feed this long first; wait at most this"),
        ("learn", "int64_t", "a polling SV learns when to wake from each feed"),
        ("fed_ns", "const int64_t *", "ctrl: when SIO fed"),
        ("served_max", "int64_t *", "ctrl: the longest the servos took since it learnt"),
        ("release", "const int64_t *", "procs release_ns[this SV's slot]"),
        ("feed_seen, served", "int64_t *", "the last `history` learnt"),
        ("history, feed_k, margin_ns, share_ns, share_looks, cap_ns", "int64_t"),
        ("sharing", "int64_t", "between calls: the last look found them worth it"),
        (
            "servo_ticks, rest_ticks",
            "int64_t",
            "its period in ticks: sharing, with nothing to share",
        ),
        ("want_ticks", "int64_t", "out: the one it learnt (the SV applies it)"),
        ("poll_after", "int64_t *", "the base loop's: from when after the due tick to poll"),
        "per call: from the SV, between calls, to it",
        ("fed_tick, count", "int64_t"),
        ("stage, at, unit, tick_now, fed, ran, t0", "int64_t"),
        ("wanted", "int64_t", "SV_FEED: the tick signalled (a feed of it or later)"),
    ),
    block(
        "WaitArgs",
        "clock",
        {
            "kali_clock_wait": "runtime.daemon:ClockWait.wait_reference",
            "kali_clock_settle": "runtime.daemon:ClockWait.settle_reference",
        },
        ("stats", "StatsArgs *", "the slot's account of a cycle (daemon._CycleStats)"),
        ("ack_sem", "sem_t *", "lockstep: the clock's acknowledgement post, else NULL"),
        ("sem", "sem_t *", "this slot's: the wall clock posts it"),
        ("release", "const int64_t *", "procs release_ns[slot]: when the clock meant the signal"),
        ("signal_tick", "const int64_t *", "procs signal_tick[slot]"),
        ("after", "const int64_t *", "the daemon's poll_after (an SV learns it)"),
        ("shutdown", "const uint32_t *", "the arena header's"),
        ("next_due", "const int64_t *", "procs next_due[slot]: the clock's next due tick for it"),
        ("base_ns, period_ticks", "int64_t", "the clock's tick and this process's period in ticks"),
        ("poll_ns, idle_ns", "int64_t"),
        ("signalled", "int64_t", "between calls: the last call took a signal"),
        ("cycled", "int64_t", "between calls: its cycle has run, not yet accounted"),
        ("tick, woke, since", "int64_t", "out: the tick signalled, when taken, when meant to wake"),
    ),
    block(
        "WitnessArgs",
        "witness",
        {"kali_witness_start": "", "kali_witness_stop": ""},
        ("cpu, priority", "int64_t", "the CPU witnessed; its thread's SCHED_FIFO priority"),
        ("period_ns, stall_ns", "int64_t", "its wake-ups; one later than stall_ns was lost"),
        ("ring_ns, ring_lost", "int64_t *", "per wake-up: when, and lost after it"),
        ("ring", "int64_t", "the ring's length"),
        "the clock's bottom half (WallClock._below): its thread (0: none) is put back at",
        "guard_priority once it has stood below it for guard_after_ns",
        ("guard_tid, guard_priority, guard_after_ns", "int64_t"),
        ("bottom_since", "int64_t", "the clock's: when it went below, 0 while above"),
        "the thread's, read by the clock while seq is even",
        ("seq, due, lost, wakes", "int64_t", "due: the deadline it sleeps to"),
        "start and stop's",
        ("stop, running, thread", "int64_t"),
    ),
)

# the records the kernels step in place: their C struct, kali_fields number and dtype (name
# for messages); their structs are generated from the dtypes
RECORDS: tuple[tuple[str, str, np.dtype], ...] = (
    ("SlotRecord", "layout.SERVO_SLOT", layout.SERVO_SLOT),
    ("PidRecord", "layout.PID_DTYPE", layout.PID_DTYPE),
    ("PdRecord", "layout.PD_DTYPE", layout.PD_DTYPE),
    ("ImpRecord", "layout.IMPEDANCE_DTYPE", layout.IMPEDANCE_DTYPE),
    ("CtRecord", "layout.CT_DTYPE", layout.CT_DTYPE),
)

# --------------------------------------------------------------------------------------------
# C types: their ctypes class and their kind (numpy's letter; 'p' a pointer, 'V' a struct)

_SCALARS: dict[str, tuple[type, str]] = {
    "int64_t": (ctypes.c_int64, "i"),
    "uint64_t": (ctypes.c_uint64, "u"),
    "double": (ctypes.c_double, "f"),
    "char": (ctypes.c_char, "c"),
}
_NUMPY_C = {"f8": "double", "u4": "uint32_t", "i4": "int32_t", "i8": "int64_t", "u8": "uint64_t"}
_FUNCTIONS = ("KernelFn",)  # int64_t (*)(void *): a kernel, as another kernel calls it
_BY_NAME = {b.name: b for b in BLOCKS}


def kind(ctype: str) -> str:
    """A declared C type's kind, as ``kali_layout`` lists it."""
    if ctype.endswith("*") or ctype in _FUNCTIONS:
        return "p"
    if ctype in _BY_NAME:
        return "V"
    return _SCALARS[ctype][1]


def ctypes_kind(t: type) -> str:
    """A ctypes field type's kind (``kind`` of the C type it stands for)."""
    if issubclass(t, ctypes.c_void_p | ctypes._Pointer):
        return "p"
    if issubclass(t, ctypes.Structure):
        return "V"
    return next(k for c, k in _SCALARS.values() if c is t)


def _structure(b: Block, done: dict[str, type[ctypes.Structure]]) -> type[ctypes.Structure]:
    def ctype_of(ctype: str) -> type:
        if ctype in done:
            return done[ctype]
        target = ctype.removeprefix("const ").removesuffix("*").strip()
        if ctype.count("*") == 1 and target in done and not _BY_NAME[target].kernels:
            return ctypes.POINTER(done[target])  # a table of Views or Copies
        if kind(ctype) == "p":
            return ctypes.c_void_p
        return _SCALARS[ctype][0]

    fields = tuple((name, ctype_of(ctype)) for name, ctype in b.fields())
    doc = f"{b.name}: the argument block of {', '.join(b.kernels) or 'kernels'} ({b.owner})."
    return type(b.name, (ctypes.Structure,), {"_fields_": fields, "__doc__": doc})


def structures() -> dict[str, type[ctypes.Structure]]:
    """Every block's ctypes class, by name, generated from ``BLOCKS``."""
    done: dict[str, type[ctypes.Structure]] = {}
    for b in BLOCKS:
        done[b.name] = _structure(b, done)
    return done


STRUCTS = structures()
View = STRUCTS["View"]
Copy = STRUCTS["Copy"]
Field = STRUCTS["Field"]
KERNELS: dict[str, type[ctypes.Structure]] = {k: STRUCTS[b.name] for b in BLOCKS for k in b.kernels}

# the libraries (csrc/<name>.c) and the owners whose kernels each holds: the simulator's are
# its own, so that no controller process loads them; the core's are in both
LIBRARIES: dict[str, tuple[str, ...]] = {
    "controller": (
        "core", "chain", "sio", "franka", "servo", "fifo", "clock", "witness", "flightrec",
    ),
    "simulator": ("core", "plant"),
}


def library_blocks(library: str) -> list[type[ctypes.Structure]]:
    """The ctypes classes of the blocks ``library``'s kernels take."""
    return [STRUCTS[b.name] for b in BLOCKS if b.owner in LIBRARIES[library]]


def library_kernels(library: str) -> list[str]:
    """The kernels ``library`` holds."""
    return [k for b in BLOCKS if b.owner in LIBRARIES[library] for k in b.kernels]


def library_of(kernel: str) -> str:
    """The library holding ``kernel`` (the controller's, for a core kernel)."""
    owner = next(b.owner for b in BLOCKS if kernel in b.kernels)
    return next(lib for lib, owners in LIBRARIES.items() if owner in owners)


# --------------------------------------------------------------------------------------------
# The header


def _c_row(names: str, ctype: str) -> str:
    stars = ctype.count("*")
    base = ctype.removesuffix("*" * stars).strip()
    return f"{base} " + ", ".join("*" * stars + n.strip() for n in names.split(","))


def _c_block(b: Block) -> list[str]:
    lines = [f"/* {b.name} ({b.owner}): {', '.join(b.kernels) or 'in other blocks'} */"]
    lines.append("typedef struct {")
    for row in b.rows:
        if isinstance(row, str):
            lines.append(f"    /* {row} */")
            continue
        decl = f"    {_c_row(row[0], row[1])};"
        lines.append(f"{decl} /* {row[2]} */" if len(row) == 3 else decl)
    lines.append(f"}} {b.name};")
    return lines


def _c_record(name: str, source: str, dtype: np.dtype) -> list[str]:
    lines = [f"/* {source} */", "typedef struct {"]
    for field, (sub, *_) in (dtype.fields or {}).items():
        base, shape = (sub.base, sub.shape) if sub.subdtype else (sub, ())
        c = _NUMPY_C[base.str[1:]]
        lines.append(f"    {c} {field}{''.join(f'[{d}]' for d in shape)};")
    lines.append(f"}} {name};")
    return lines


def _c_table(table: str, struct: str, fields: list[str]) -> list[str]:
    lines = [f"static const Field {table}[] = {{"]
    lines += [f"    {field}," for field in fields]
    lines += [f"    END({struct}),", "};"]
    return lines


def header() -> str:
    """``kernel_args.h``: every block's and record's C struct, and their layout tables."""
    out = [
        "/* Generated from kali_daemons/core/kernel_args.py by",
        " * `python -m kali_daemons.core.kernel_args`: edit the declarations there, not this file.",
        " * Included by common.h. */",
        "",
        "#ifndef KALI_KERNEL_ARGS_H",
        "#define KALI_KERNEL_ARGS_H",
        "",
        "#include <semaphore.h>",
        "#include <stddef.h>",
        "#include <stdint.h>",
        "#include <string.h>",
        "",
        "typedef int64_t (*KernelFn)(void *); /* a kernel, as another calls it */",
        "",
        "/* ---------------------------------------------------- the records, from their dtypes */",
    ]
    for name, source, dtype in RECORDS:
        out += ["", *_c_record(name, source, dtype)]
    out += ["", "/* ---------------------------------------------------------------- the blocks */"]
    for b in BLOCKS:
        out += ["", *_c_block(b)]
    out += [
        "",
        "/* ---------------------------------------------------------------- the layouts */",
        "",
        "#define FIELD(T, f, k) {#f, (int64_t)offsetof(T, f), (int64_t)sizeof(((T *)0)->f), k}",
        "#define END(T) {NULL, (int64_t)sizeof(T), 0, 0}",
        "",
        "/* a block's field with the kind of its compiled type, as kernel_args.kind names it */",
        "#define IS(x, type) __builtin_types_compatible_p(__typeof__(x), type)",
        "#define KIND(x)                                                                     \\",
        "    (IS(x, double) ? 'f' : IS(x, int64_t) ? 'i' : IS(x, uint64_t) ? 'u'             \\",
        "     : IS(x, char) ? 'c' : __builtin_classify_type(x) == 5 ? 'p'                     \\",
        "     : __builtin_classify_type(x) == 12 ? 'V' : '?')",
        "#define LAYOUT(T, f) {#f, (int64_t)offsetof(T, f), (int64_t)sizeof(((T *)0)->f), \\",
        "                      KIND(((T *)0)->f)}",
    ]
    for name, _, dtype in RECORDS:
        fields = [
            f"FIELD({name}, {f}, '{'V' if sub.subdtype else sub.kind}')"
            for f, (sub, *_) in (dtype.fields or {}).items()
        ]
        out += ["", *_c_table(f"{name}_FIELDS", name, fields)]
    for b in BLOCKS:
        fields = [f"LAYOUT({b.name}, {f})" for f, _ in b.fields()]
        out += ["", *_c_table(f"{b.name}_LAYOUT", b.name, fields)]
    out += ["", "/* Record k's fields (RECORDS' order); NULL for another. */"]
    out += ["const Field *kali_fields(int64_t record) {", "    switch (record) {"]
    out += [f"    case {k}: return {name}_FIELDS;" for k, (name, *_) in enumerate(RECORDS)]
    out += ["    default: return NULL;", "    }", "}", ""]
    out += ["/* The fields of the block named `name`; NULL for another. */"]
    out += ["const Field *kali_layout(const char *name) {"]
    out += [f'    if (!strcmp(name, "{b.name}")) return {b.name}_LAYOUT;' for b in BLOCKS]
    out += ["    return NULL;", "}", "", "#endif", ""]
    return "\n".join(out)


def reference(kernel: str) -> Callable[..., Any] | None:
    """``kernel``'s Python reference, imported; None if it has none."""
    path = next(b.kernels[kernel] for b in BLOCKS if kernel in b.kernels)
    if not path:
        return None
    module, _, qualname = path.partition(":")
    found: Any = importlib.import_module(f"kali_daemons.{module}")
    for part in qualname.split("."):
        found = getattr(found, part)
    return cast("Callable[..., Any]", found)


def table() -> str:
    """Every kernel: its library, owner, block and reference (``python -m
    kali_daemons.core.kernel_args --list``)."""
    rows = [("kernel", "library", "owner", "block", "reference")]
    for b in BLOCKS:
        for kernel, ref in b.kernels.items():
            rows.append((kernel, library_of(kernel), b.owner, b.name, ref or "-"))
    widths = [max(len(r[c]) for r in rows) for c in range(5)]
    return "\n".join(
        "  ".join(f"{v:<{w}}" for v, w in zip(r, widths, strict=True)).rstrip() for r in rows
    )


if __name__ == "__main__":
    if sys.argv[1:] == ["--list"]:
        print(table())
        sys.exit(0)
    if sys.argv[1:] == ["--check"]:
        sys.exit(0 if HEADER.read_text() == header() else f"{HEADER} is stale: regenerate it")
    HEADER.write_text(header())
    print(f"kali kernels: wrote {HEADER}")
