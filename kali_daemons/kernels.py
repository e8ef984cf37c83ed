"""The servo path's per-tick arithmetic as compiled kernels (issue 26 item 2), and the numpy
reference each one must equal.

SIO's tick was ~50 small numpy calls (0.3-0.5 µs each before any work) plus Python loops;
these few C loops (``kernels.c``) do the same arithmetic over every joint in one call each:
encoders → angles (``read``), the velocity filter, range and runaway checks, feeding the
slots, the torque sum, torques → DAC codes, the current check, publishing.  The SVs' built-in
servos are here too: the PID and the PD over a set of joints (``servo.vector``) and an SV's
unit, claimed by compare-and-swap of each slot's ``busy`` word and stepped in one call
(``sv.units``); their references are the per-joint Python steps (``servo.builtins``).
The plant's amplifiers and motors and its writes into MuJoCo (``kali_motors``, bound by
``plant.motor.MotorBank.compiled``; its reference is ``plant.motor.drive_reference``) are
here for the plant's cycle, and so are its encoder counters (``kali_encoders``, bound by
``plant.board.EncoderBank.compiled``; its reference is ``EncoderBank.sample``), its I/O
boards (``kali_boards_update``, ``kali_boards_convert``, bound by ``plant.board.boards_kernel``;
their references are ``IoBoardSim.update`` and ``.convert``) and its wrist sensors' gauge
banks (``kali_ft_bank``, bound by ``plant.board.FtBank.compiled``; its reference is
``FtBank.cycle``), and its reading of the DAC boards and of MuJoCo's joints
(``kali_plant_dac``, ``kali_plant_joints``, bound by ``plant.sim.PlantSim``; their references
are its ``_read_dac`` and ``_read_joints``), and its truth records after each cycle
(``kali_plant_truth``, bound by ``PlantSim._truth_views``; its reference is
``PlantSim._write_truth_reference``).
A robot's demand from its FIFO (``kali_fifo_pop``, bound by
``channels.InterpolatingFifo.compiled_pop``; its reference is ``pop_into``) and its
feed-forward as SIO applies it (``kali_feedforward``, bound by
``sio.feedforward.RobotFeedforward.compiled``) is here too; its reference is that class's
``update``; and so is SIO's step of every robot where nothing but its motion is happening
to it: the demand popped, the joints fed (``kali_sio_robots``, bound by
``sio.daemon.ServoIO._bind_kernels``; its reference is ``ServoIO._robot``, which any other
robot still takes).  SIO's whole tick is one call (``kali_sio_tick``) of two passes
(``kali_sio_front``: read, sensors, robots, checks, feed-forward, feed, the feeds posted;
then the sleep until the servos are done; ``kali_sio_back``: the gang's acknowledgements,
torques, DACs, the current check, the boards' registers, publishing, the flight row), bound
by ``ServoIO._bind_tick``; their reference is ``ServoIO._tick_reference``,
which also does every event the passes hand back.  The McGill boards' command registers are
written by ``kali_mcgill_control`` (bound by ``McGillBoards.control_kernel``; its reference
is ``McGillBoards.control`` with ``end_tick``).  An SV's serve (the robots fed whole, the
units, the single slots, each counted done) is ``kali_sv_serve``, bound by
``sv.daemon.ServoWorker._bind_serve``; its reference is ``ServoWorker._serve_reference``.
Every process's account of a cycle in its process-table slot (``kali_cycle_stats``, bound by
``daemon._CycleStats``; its reference is ``_CycleStats.record_reference``) is here, and so is
SIO's row of the flight recorder (``kali_flight_row``, bound by
``flightrec.FlightRecorder.bind``; its reference is ``FlightRecorder.record_reference``), and
so is every clocked process's wait for the wall clock's signal, which first accounts the
cycle before it (``kali_clock_wait``, ``kali_clock_settle``, bound by ``daemon.ClockWait``;
their reference is ``ClockWait.wait_reference``).  An SV's wait for SIO's
feed and what it learns from it are the first stage of its serve (``SV_FEED``; their
references are ``ServoWorker._await_feed`` and ``_learn_feed``).
The flange pose of a robot type's serial chain (``kali_chain_pose``, bound by ``chain_pose``)
is here for a wrist force/torque sensor read each tick; its reference is
``chain.flange_pose``.
The robot-level built-ins (issue 27: computed torque and the Cartesian impedance, one arm a
call: ``kali_computed_torque``, ``kali_impedance``, bound by ``arm_step``) are here too; their
references are ``servo.armbuiltins._ct_step`` and ``_imp_step``; and so is what the SV does
with the torques of any robot-level step (``kali_arm_finish``, bound by ``sv.arm.ArmRunner``;
its reference is ``ArmRunner._finish_reference``).

Why C through ctypes and not numba (measured on this VM, 12 joints): a numba call with 12
array arguments costs 0.67 µs, a ctypes call with one pointer to an argument block laid
out at configure 0.27 µs; and ``import numba`` alone grows a process by ~127 MB RSS
(llvmlite's 179 MB library, all of it locked by SIO's ``mlockall``), against issue 26's
lean daemon set.  The library is ~20 KB and needs only ``cc``.  Those kernels step the
arena's records (slots, the built-ins' private data) in place through C structs that mirror
their dtypes: ``load`` refuses a library whose structs differ (``check_record``).

Build: ``python -m kali_daemons.kernels`` (run by ``scripts/setup.sh``) compiles
``kernels.c`` with ``cc`` (``$CC``) into ``kernels-<hash>.so``, the hash over the source and
the flags, so an edited source is never served by a stale library.  It lives in
``$KALI_KERNEL_DIR`` if set, else in this package's ``__pycache__`` (an editable install, a
clean CI checkout), else, if that is not writable, ``~/.cache/kali``.  A process that finds
no library builds it (~0.2 s) in ``load`` — SIO at configure, never inside a cycle.

Every kernel is bound once (``Kernel``): its argument block holds the arrays' addresses and
strides, so the arrays must never move (arena views and preallocated arrays do not); the
bound kernel keeps them alive.  A call is then ``kernel()``: no allocation.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import os
import subprocess
import tempfile
from collections.abc import Callable
from ctypes import c_double, c_int64, c_void_p
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import layout
from .errors import DaemonError
from .servo.armbuiltins import CT_DTYPE, IMPEDANCE_DTYPE
from .servo.builtins import PD_DTYPE, PID_DTYPE

if TYPE_CHECKING:
    from .chain import Chain
    from .servo.arm import ArmInput

SOURCE = Path(__file__).with_name("kernels.c")
CFLAGS = ("-O2", "-std=c99", "-shared", "-fPIC", "-ffp-contract=off", "-fno-fast-math")
COUNTER_BITS = 12  # the HCTL-2000's counter (figure C.3)
COUNTER_MODULO = 1 << COUNTER_BITS
COUNTER_HALF = COUNTER_MODULO // 2  # wrap threshold of figure C.3

# the code of ``kali_checks``: joint i out of range is i, its runaway n + i
NO_FAULT = -1


class View(ctypes.Structure):
    """A per-joint array as C reads it: element 0 and the stride in bytes."""

    _fields_ = (("p", c_void_p), ("stride", c_int64))


def view(a: np.ndarray) -> View:
    """``a`` (1-D, any stride) as a ``View``; the caller keeps ``a`` alive."""
    assert a.ndim == 1, f"a kernel takes 1-D arrays, not shape {a.shape}"
    return View(a.ctypes.data, a.strides[0])


def _block(name: str, *fields: str | tuple[str, type]) -> type[ctypes.Structure]:
    """A kernel's argument block, as its C struct: a bare name is a ``View``."""
    spec = tuple((f, View) if isinstance(f, str) else f for f in fields)
    return type(name, (ctypes.Structure,), {"_fields_": spec})


N = ("n", c_int64)  # joints: every block's first field
ReadArgs = _block(
    "ReadArgs",
    N,
    ("encoders", c_void_p),
    *("enc_off", "acc", "prev", "offset", "rad_per_count", "q"),
    ("modulo", c_int64),
    ("half", c_int64),
)
VelocityArgs = _block("VelocityArgs", N, "q", "q_prev", "qd", ("gain", c_double), ("b", c_double))
ChecksArgs = _block(
    "ChecksArgs",
    N,
    ("n_robots", c_int64),
    *("bounds", "q", "demand", "q_min", "q_max", "range_check", "fed", "safe", "safe_ok"),
    ("pi", c_double),
)
FeedArgs = _block(
    "FeedArgs",
    N,
    *("demand", "q", "qd", "fed", "slot_demand", "slot_position", "slot_velocity", "slot_busy"),
    ("not_fed", c_int64),
    ("ctrl_fed", c_void_p),
    ("ctrl_done", c_void_p),
    *("demand_vel", "demand_acc", "ff", "slot_demand_vel", "slot_demand_acc", "slot_ff", "mark"),
)
TorquesArgs = _block("TorquesArgs", N, "slot_torque", "fed", "servo_torque", "ff", "torque")
DacArgs = _block(
    "DacArgs",
    N,
    *("torque", "gkt", "current_limit", "codes_per_amp", "current", "clamped"),
    ("dacs", c_void_p),
    "dac_off",
    ("zero", c_double),
    ("top", c_double),
)
CurrentArgs = _block("CurrentArgs", N, "torque", "fed", "clamped", "over", "current_ticks")
Copy = _block("Copy", "src", "dst", ("size", c_int64))
CopyArgs = _block("CopyArgs", N, ("m", c_int64), ("copies", ctypes.POINTER(Copy)))

VectorArgs = _block(
    "VectorArgs",
    N,
    ("data", c_void_p),
    *("rows", "demand", "position", "torque", "error", "status"),
    ("ok", c_int64),
)
UnitArgs = _block(
    "UnitArgs",
    *(("slots", c_void_p), ("pid", c_void_p), ("pd", c_void_p)),
    *((f, c_int64) for f in ("lo", "hi", "pid_a", "pd_a", "me", "sv", "ok")),
    ("left", c_void_p),
    *((f, c_int64) for f in ("tick", "exec_ns", "n_left", "fault")),
    ("bad", c_double),
)
ChainPoseArgs = _block(
    "ChainPoseArgs",
    N,
    *((f, c_void_p) for f in ("origins", "axes", "q", "out")),  # contiguous float64
)
WrenchArgs = _block(
    "WrenchArgs",
    N,
    *(
        (f, c_void_p)
        for f in ("origins", "axes", "q", "codes", "cal", "base", "g", "com", "rated", "limit")
    ),
    *((f, c_double) for f in ("mass", "tip", "alpha", "volts", "limit_config")),
    *((f, c_int64) for f in ("rail", "tare_left", "tare_ticks")),
    *(
        (f, c_void_p)
        for f in ("raw", "grav", "sensor", "filt", "tool", "world", "bias", "sum", "rotation")
    ),
    *((f, c_double) for f in ("force", "limit_used")),
    *(
        (f, c_void_p)
        for f in (
            *("status", "control", "stale", "tare_count", "samples", "sample_tick"),
            *("present", "tare_cmd", "tare_state"),
        )
    ),
    *(
        (f, c_int64)
        for f in ("tick", "seq", "stale_limit", "ready", "request", "seq_mask", "averaging")
    ),
    ("done", c_int64),
)
ArmFinishArgs = _block(
    "ArmFinishArgs",
    N,
    *((f, c_void_p) for f in ("tau", "q_d", "q")),
    *("enabled", "torque", "error", "status", "sv", "ran", "exec"),
    *((f, c_void_p) for f in ("arm_status", "arm_exec_ns", "arm_ran_tick")),
    *((f, c_int64) for f in ("tick", "sv_index", "t0")),
)
ArmArgs = _block(
    "ArmArgs",
    N,
    *((f, c_void_p) for f in ("d", "q_d", "qd_d", "qdd_d", "q", "qd", "h", "M", "J")),
    *((f, c_void_p) for f in ("pose", "pose_d", "wrench", "wrenches")),
    *((f, c_int64) for f in ("wrench_stride", "robots", "has_sensor")),
    *((f, c_void_p) for f in ("viscous", "gear_w", "coulomb_pos", "coulomb_neg", "tau")),
)
MotorArgs = _block(
    "MotorArgs",
    N,
    *((f, c_void_p) for f in ("volts", "qd", "enabled", "current", "gear", "kt_r", "vbus_r")),
    *((f, c_void_p) for f in ("i_max", "gain", "w_scale", "g_extra_pos", "g_extra_neg")),
    *((f, c_void_p) for f in ("ctrl", "range", "friction", "acts", "act_adr", "dofs")),
    *((f, c_void_p) for f in ("mj_actrange", "mj_ctrl", "mj_act", "mj_qfrc")),
)
EncoderArgs = _block(
    "EncoderArgs",
    N,
    *((f, c_void_p) for f in ("angle", "cpr", "phase", "ref", "count", "rev")),
    *((f, c_void_p) for f in ("robot_of", "joint_of", "encoders", "enc_off")),
    *("csr", "index"),
    *((f, c_int64) for f in ("index_off", "modulo")),
    ("two_pi", c_double),
)
BoardArgs = _block(
    "BoardArgs",
    ("n_arms", c_int64),
    *("csr", "estop", "power", "index", "adc_control", "adc_analog", "adc_digital", "clamped"),
    *("amps_on", "brakes_engaged", "watchdog_tripped", "truth_estop"),
    *((f, c_void_p) for f in ("state", "base", "count", "enabled", "braked")),
    *((f, c_void_p) for f in ("q", "lo", "hi", "mid")),
    *((f, c_int64) for f in ("now_ns", "hold_ns", "watchdog_ns", "brake_ns", "never")),
    *((f, c_int64) for f in ("timeout_on", "retrigger", "no_disable", "enable", "index_off")),
    *((f, c_int64) for f in ("p_amps", "p_brakes", "p_tripped", "p_estop")),
    *((f, c_int64) for f in ("adc_start", "channel_mask", "adc_done", "value_mask")),
    *((f, c_int64) for f in ("channels", "self_test")),
    *((f, c_double) for f in ("pot_v_min", "pot_v_max", "adc_volts", "adc_top")),
)
StatsArgs = _block(
    "StatsArgs",
    *((f, c_void_p) for f in ("late", "late_max", "exec", "exec_max", "heart", "ack", "acks")),
    ("hist", c_void_p),
    *((f, c_int64) for f in ("linear_us", "log_bins", "tick", "release", "woke", "done")),
)
FlightArgs = _block(
    "FlightArgs",
    *((f, c_int64) for f in ("n", "n_robots", "rows")),
    ("ring", c_void_p),
    ("row_size", c_int64),
    *((f, c_int64) for f in ("off_tick", "off_t", "off_lat", "off_late", "off_wait", "off_ran")),
    *((f, c_int64) for f in ("off_shadow", "off_wrench")),
    ("off_cols", c_void_p),
    ("cols", ctypes.POINTER(View)),
    ("n_cols", c_int64),
    "shadow",
    ("wrench", c_void_p),
    *((f, c_int64) for f in ("wrench_row", "wrench_col")),
    *((f, c_void_p) for f in ("release", "count")),
    *((f, c_int64) for f in ("tick", "t_read", "latency", "wait", "ran")),
)
PlantIoArgs = _block(
    "PlantIoArgs",
    N,
    *((f, c_void_p) for f in ("qpos", "qvel", "act", "qpos_idx", "dofs", "act_adr")),
    *((f, c_void_p) for f in ("gear", "gkt", "q", "qd", "current", "motor_angle", "torque")),
    *((f, c_void_p) for f in ("dacs", "dac_off", "robot_of")),
    "clamped",
    ("volts", c_void_p),
    *((f, c_double) for f in ("top", "zero", "scale")),
)
FtArgs = _block(
    "FtArgs",
    ("normals", c_void_p),
    *((f, c_int64) for f in ("size", "at")),
    ("offset", c_void_p),
    ("drift", c_double),
    *((f, c_void_p) for f in ("gauges", "noise_sd", "wrench", "codes", "control", "status")),
    *((f, c_int64) for f in ("served", "seq_mask", "request", "ready")),
    *((f, c_double) for f in ("volts_per_code", "rail")),
)
PlantTruthArgs = _block(
    "PlantTruthArgs",
    N,
    *((f, c_void_p) for f in ("eq_active", "held", "weld")),
    *("grasped", "grasp_wrench", "ft_wrench", "push"),
    *((f, c_void_p) for f in ("ft_true", "xfrc", "tool_body", "site_xpos", "grasp_site")),
    *((f, c_void_p) for f in ("object_qpos", "sim_time_ns", "ticks", "object_pose")),
    ("internal_force", c_void_p),
    *((f, c_int64) for f in ("sim_ns", "cycles", "welds_read")),
)
FifoPopArgs = _block(
    "FifoPopArgs",
    N,
    *((f, c_void_p) for f in ("head", "tail", "ring", "stamps")),
    ("capacity", c_int64),
    ("bound", c_double),
    *((f, c_void_p) for f in ("cur", "start", "target", "seg_ticks", "seg_done", "primed")),
    *((f, c_void_p) for f in ("rejected", "ratio_num", "ratio_den", "underruns", "phase_acc")),
    "out",
    *((f, c_int64) for f in ("num", "den")),
    ("stamp", ctypes.c_uint64),
)
RobotsArgs = _block(
    "RobotsArgs",
    N,
    ("n_robots", c_int64),
    *("bounds", "fed", "pots_read", "power", "power_cmd", "calib_cmd", "calib_state", "guided"),
    *("guard_state", "amps"),
    *((f, c_int64) for f in ("amps_bit", "on", "tripped", "calib_active")),
    ("pops", c_void_p),
    ("faulted", c_int64),
)
FfArgs = _block(
    "FfArgs",
    N,
    *((f, c_int64) for f in ("rows", "row_len")),
    *((f, c_void_p) for f in ("keys", "tau", "qd", "qdd", "mode", "state", "heartbeat")),
    *((f, c_void_p) for f in ("stale_ticks", "stale_events", "weight_rec")),
    *((f, c_void_p) for f in ("head", "seg_ticks", "seg_done")),
    *("out", "vel", "acc"),
    ("last", c_void_p),
    *((f, c_int64) for f in ("heartbeat_limit", "missing_limit", "mode_max")),
    ("step", c_double),
    *((f, c_int64) for f in ("tick", "arm", "mode_ok", "missing", "stale")),
    ("weight", c_double),
)
McgillArgs = _block(
    "McgillArgs",
    ("n_arms", c_int64),
    *("csr", "power_reg", "power", "enable_ticks", "capture"),
    ("codes", c_void_p),
    ("codes_row", c_int64),
    "n_joints",
    ("fault_active", c_void_p),
    *((f, c_int64) for f in ("base_csr", "green_red", "no_disable", "enable", "index_off")),
    ("amps_on", c_int64),
    *((f, c_int64) for f in ("on", "enabling", "off", "hold_ticks", "dac_zero", "retrigger")),
    *((f, c_int64) for f in ("retrigger_ticks", "ticks", "bit", "prev_bit")),
)
SioArgs = _block(
    "SioArgs",
    N,
    ("n_robots", c_int64),
    *((f, c_void_p) for f in ("read_fn", "dac_fn", "control_fn")),
    *((f, c_void_p) for f in ("read_args", "dac_args", "control_args")),
    *((f, c_void_p) for f in ("capture", "velocity", "sensors", "guard_state", "guard_n")),
    *((f, c_int64) for f in ("n_sensors", "guard_armed")),
    *((f, c_void_p) for f in ("robots", "checks", "ff", "feed", "torques", "current")),
    *((f, c_void_p) for f in ("publish", "flight", "fault_active", "fault_count")),
    *("arm_algo", "arm_op", "shadows", "bounds"),
    ("whole", c_void_p),
    *("mark", "ff_out"),
    *((f, c_int64) for f in ("arm_none", "arm_free", "arm_held")),
    ("feeds", c_void_p),
    ("n_feeds", c_int64),
    *((f, c_void_p) for f in ("done_sem", "ctrl_done")),
    ("slice_ns", c_int64),
    *((f, c_void_p) for f in ("ctrl_tick", "fed_ns", "served_max")),
    "robots_tick",
    ("sv_fed_tick", c_void_p),
    *("signal_tick", "ack_tick", "vouched_tick"),
    *((f, c_void_p) for f in ("gang_sv", "gang_slot", "gang_lag")),
    ("n_gang", c_int64),
    *((f, c_void_p) for f in ("ack_early", "clock_tick", "lat_last", "lat_max", "hist")),
    *((f, c_int64) for f in ("linear_us", "log_bins", "tick", "post", "ok", "stage")),
    *((f, c_int64) for f in ("faulted", "faults_seen", "at", "result", "fed", "t_read")),
    *((f, c_int64) for f in ("c_read", "t_fed", "t_done", "t_out", "c_out", "retrigger_tick")),
)
# kali_sio_tick's results (the tick's events) and its stages
SIO_FED, SIO_DONE, SIO_CAPTURE, SIO_SENSOR, SIO_ROBOTS, SIO_CHECK, SIO_CURRENT, SIO_WAIT = range(8)
ST_READ, ST_VELOCITY, ST_SENSORS, ST_ROBOTS, ST_CHECKS, ST_FEED, ST_WAIT, ST_BACK, ST_OUT = range(9)
ServeArgs = _block(
    "ServeArgs",
    *((f, c_int64) for f in ("n", "n_arms", "n_units")),
    *((f, c_void_p) for f in ("slots", "fed_tick_out", "ctrl_fed", "ctrl_done", "ctrl_tick")),
    *((f, c_void_p) for f in ("arm_lo", "units", "order", "done_sem")),
    *((f, c_int64) for f in ("me", "arm_free")),
    *((f, c_void_p) for f in ("exec_last", "exec_max", "servos", "exec_hist")),
    *((f, c_int64) for f in ("linear_us", "log_bins")),
    ("feed_sem", c_void_p),
    *((f, c_int64) for f in ("poll_ns", "feed_wait_ns", "learn")),
    *((f, c_void_p) for f in ("fed_ns", "served_max", "release", "feed_seen", "served")),
    *((f, c_int64) for f in ("history", "feed_k", "margin_ns", "share_ns", "share_looks")),
    ("cap_ns", c_int64),
    *((f, c_int64) for f in ("sharing", "servo_ticks", "rest_ticks", "want_ticks")),
    ("poll_after", c_void_p),
    *((f, c_int64) for f in ("fed_tick", "count", "stage", "at")),
    *((f, c_int64) for f in ("unit", "tick_now", "fed", "ran", "t0", "wanted")),
)
# kali_sv_serve's results: what it hands back to the SV's Python
SV_DONE, SV_ARM, SV_FAULT, SV_LEFT, SV_SLOT = range(5)
SV_START = 0  # its stage for a feed taken (the lockstep executive's serve)
SV_FEED = 7  # its stage for a tick signalled: the feed awaited first (an SV's cycle)
WaitArgs = _block(
    "WaitArgs",
    *((f, c_void_p) for f in ("stats", "ack_sem", "sem", "release", "signal_tick", "after")),
    *((f, c_void_p) for f in ("shutdown", "next_due")),
    *((f, c_int64) for f in ("base_ns", "period_ticks", "poll_ns", "idle_ns")),
    *((f, c_int64) for f in ("signalled", "cycled", "tick")),
    *((f, c_int64) for f in ("woke", "since")),
)
# kali_clock_wait's results
WAIT_SIGNAL, WAIT_IDLE, WAIT_INTR, WAIT_SHUTDOWN = range(4)
# kali_wrench_tick's results (sio/wrench.py builds the message)
WRENCH_OK, WRENCH_SATURATED, WRENCH_RATED, WRENCH_CONTACT, WRENCH_SILENT = range(5)

_KERNELS = {
    "kali_read": ReadArgs,
    "kali_velocity": VelocityArgs,
    "kali_checks": ChecksArgs,
    "kali_feed": FeedArgs,
    "kali_torques": TorquesArgs,
    "kali_dac": DacArgs,
    "kali_current_check": CurrentArgs,
    "kali_copy": CopyArgs,
    "kali_feedforward": FfArgs,
    "kali_fifo_pop": FifoPopArgs,
    "kali_sio_robots": RobotsArgs,
    "kali_sio_tick": SioArgs,
    "kali_mcgill_control": McgillArgs,
    "kali_sv_serve": ServeArgs,
    "kali_motors": MotorArgs,
    "kali_encoders": EncoderArgs,
    "kali_boards_update": BoardArgs,
    "kali_boards_convert": BoardArgs,
    "kali_boards_truth": BoardArgs,
    "kali_ft_bank": FtArgs,
    "kali_flight_row": FlightArgs,
    "kali_cycle_stats": StatsArgs,
    "kali_clock_wait": WaitArgs,
    "kali_clock_settle": WaitArgs,
    "kali_plant_dac": PlantIoArgs,
    "kali_plant_joints": PlantIoArgs,
    "kali_plant_truth": PlantTruthArgs,
    "kali_pid_vector": VectorArgs,
    "kali_pd_vector": VectorArgs,
    "kali_serve_unit": UnitArgs,
    "kali_arm_finish": ArmFinishArgs,
    "kali_chain_pose": ChainPoseArgs,
    "kali_wrench_tick": WrenchArgs,
    "kali_wrench_convert": WrenchArgs,
    "kali_impedance": ArmArgs,
    "kali_computed_torque": ArmArgs,
}


class Field(ctypes.Structure):
    """One field of a record's C struct, as ``kali_fields`` lists it (``kernels.c``)."""

    _fields_ = (
        ("name", ctypes.c_char_p),  # NULL ends the table; that entry's offset is the size
        ("offset", c_int64),
        ("size", c_int64),
        ("kind", ctypes.c_char),  # numpy's dtype kind
    )


# the records the kernels read and write in place: their number in ``kali_fields`` and the
# dtype the C struct must mirror, field for field
RECORDS: dict[str, tuple[int, np.dtype]] = {
    "layout.SERVO_SLOT": (0, layout.SERVO_SLOT),
    "servo.builtins.PID_DTYPE": (1, PID_DTYPE),
    "servo.builtins.PD_DTYPE": (2, PD_DTYPE),
    "servo.armbuiltins.IMPEDANCE_DTYPE": (3, IMPEDANCE_DTYPE),
    "servo.armbuiltins.CT_DTYPE": (4, CT_DTYPE),
}

# --------------------------------------------------------------------------------------------
# Build and load (outside any cycle)


def _digest() -> str:
    h = hashlib.sha256(SOURCE.read_bytes())
    h.update(" ".join(CFLAGS).encode())
    return h.hexdigest()[:16]


def _writable(d: Path) -> bool:
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(d, os.W_OK)


def library_path() -> Path:
    """Where this source's library is (or goes): see the module docstring."""
    name = f"kernels-{_digest()}.so"
    env = os.environ.get("KALI_KERNEL_DIR")
    if env:
        return Path(env) / name
    here = Path(__file__).parent / "__pycache__"
    if _writable(here):
        return here / name
    return Path.home() / ".cache" / "kali" / name


def build(path: Path | None = None) -> Path:
    """Compile ``kernels.c`` into ``path`` (default ``library_path()``); atomic, so a
    process loading it meanwhile sees the old file or the whole new one."""
    path = library_path() if path is None else path
    path.parent.mkdir(parents=True, exist_ok=True)
    cc = os.environ.get("CC", "cc")
    fd, tmp = tempfile.mkstemp(prefix=".kernels-", suffix=".so", dir=path.parent)
    os.close(fd)
    try:
        done = subprocess.run(
            [cc, *CFLAGS, "-o", tmp, str(SOURCE), "-lm"],
            capture_output=True,
            text=True,
            check=False,
        )
        if done.returncode != 0:
            raise DaemonError(
                f"kernels: '{cc}' could not compile {SOURCE} (exit {done.returncode}): "
                f"{done.stderr.strip()[:2000]}"
            )
        os.replace(tmp, path)
    except FileNotFoundError:
        raise DaemonError(
            f"kernels: no C compiler '{cc}' to build {SOURCE} (install gcc, or set CC)"
        ) from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


_lib: ctypes.CDLL | None = None


def load() -> ctypes.CDLL:
    """The kernels' library, built first if this source has none yet (outside any cycle)."""
    global _lib
    if _lib is None:
        path = library_path()
        if not path.exists():
            build(path)
        _lib = open_library(path)
    return _lib


def open_library(path: Path) -> ctypes.CDLL:
    """The library at ``path`` with its kernels typed, once its structs are found to mirror
    the records' dtypes (``check_record``: a DaemonError otherwise).  Outside any cycle."""
    lib = ctypes.CDLL(str(path))
    for name in _KERNELS:
        fn = getattr(lib, name)
        fn.argtypes = (c_void_p,)
        fn.restype = c_int64
    lib.kali_fields.argtypes = (c_int64,)
    lib.kali_fields.restype = ctypes.POINTER(Field)
    for record, (number, dtype) in RECORDS.items():
        check_record(lib, path, record, number, dtype)
    return lib


def struct_fields(lib: ctypes.CDLL, number: int) -> tuple[dict[str, tuple[int, int, str]], int]:
    """Record ``number``'s C struct in ``lib``: {field: (offset, size, kind)} and its size."""
    table = lib.kali_fields(number)
    assert table, f"kernels: kali_fields knows no record {number}"
    fields: dict[str, tuple[int, int, str]] = {}
    k = 0
    while table[k].name is not None:
        f = table[k]
        fields[f.name.decode()] = (f.offset, f.size, f.kind.decode())
        k += 1
    return fields, table[k].offset


def dtype_fields(dtype: np.dtype) -> dict[str, tuple[int, int, str]]:
    """A structured dtype's fields as ``struct_fields`` gives a C struct's."""
    return {
        name: (offset, sub.itemsize, sub.kind)
        for name, (sub, offset, *_) in (dtype.fields or {}).items()
    }


def check_record(lib: ctypes.CDLL, path: Path, record: str, number: int, dtype: np.dtype) -> None:
    """Refuse ``lib`` (a DaemonError naming the record and the first difference) unless
    its struct for ``record`` has ``dtype``'s fields at the same offsets, of the same size
    and kind, and the same size: the kernels step the arena's records in place."""
    c_fields, c_size = struct_fields(lib, number)
    np_fields = dtype_fields(dtype)
    for name in [*np_fields, *(f for f in c_fields if f not in np_fields)]:
        c, n = c_fields.get(name), np_fields.get(name)
        if c != n:
            raise DaemonError(
                f"kernels: {path.name} does not match {record}: field '{name}' is "
                f"(offset, size, kind) {c} in C, {n} in the dtype; kernels.c's struct must "
                f"mirror the dtype (rebuild: python -m kali_daemons.kernels)"
            )
    if c_size != dtype.itemsize:
        raise DaemonError(
            f"kernels: {path.name} does not match {record}: the C struct is {c_size} B, "
            f"the dtype {dtype.itemsize} B"
        )


class Kernel:
    """One kernel bound to its arguments at configure: ``kernel()`` runs it (inside the
    cycle: no allocation) and returns its int64 result.  Array arguments become ``View``s;
    the kernel keeps them, and whatever ``keep`` holds (a copy table), alive."""

    __slots__ = ("_args", "_fn", "_keep", "_ptr")

    def __init__(self, name: str, keep: tuple[object, ...] = (), **fields: object) -> None:
        arrays = tuple(v for v in fields.values() if isinstance(v, np.ndarray))
        for f, value in fields.items():
            if isinstance(value, np.ndarray):
                fields[f] = view(value)
        self._args = _KERNELS[name](**fields)
        self._keep = keep + arrays
        self._fn = getattr(load(), name)
        self._ptr = ctypes.addressof(self._args)

    def __call__(self) -> int:
        return self._fn(self._ptr)

    @property
    def address(self) -> tuple[int, int]:
        """The kernel's C function and its argument block, as addresses, for a kernel that
        calls it (``kali_sio_front`` calls the boards' kernels through them)."""
        return ctypes.cast(self._fn, c_void_p).value or 0, self._ptr

    def sibling(self, name: str) -> Callable[[], int]:
        """Another kernel of the library on this one's argument block (a part of it the
        tests check against its reference)."""
        fn, ptr = getattr(load(), name), self._ptr
        return lambda: fn(ptr)

    @property
    def args(self) -> ctypes.Structure:
        """The argument block: a kernel's scalar inputs and outputs are read and written
        here between calls (``sv.units.Unit``)."""
        return self._args


def copies(pairs: list[tuple[np.ndarray, np.ndarray]]) -> Kernel:
    """One kernel copying each flat ``src`` into its ``dst`` (same length and item size)."""
    n = len(pairs[0][0])
    table = (Copy * len(pairs))()
    for c, (src, dst) in enumerate(pairs):
        assert len(src) == n == len(dst) and src.itemsize == dst.itemsize in (4, 8), (src, dst)
        table[c] = Copy(view(src), view(dst), src.itemsize)
    arrays = tuple(a for pair in pairs for a in pair)
    ptr = ctypes.cast(table, ctypes.POINTER(Copy))
    return Kernel("kali_copy", (table, *arrays), n=n, m=len(pairs), copies=ptr)


def chain_pose(chain: Chain, q: np.ndarray, out: np.ndarray) -> Kernel:
    """``kali_chain_pose`` bound to ``chain``: each call puts the flange pose at the angles
    now in ``q`` (``chain.n`` float64, contiguous) into ``out`` (4×4 float64, C order);
    ``chain.flange_pose`` is its reference.  The kernel keeps all three alive."""
    n = chain.n
    for what, a, shape in (
        ("origins", chain.origins, (n + 1, 4, 4)),
        ("axes", chain.axes, (n, 3)),
        ("q", q, (n,)),
        ("out", out, (4, 4)),
    ):
        assert a.shape == shape and a.dtype == np.float64 and a.flags.c_contiguous, (
            f"kernels: chain pose {what} must be float64 {shape}, C order, not {a.dtype} {a.shape}"
        )
    return Kernel(
        "kali_chain_pose",
        (chain, q, out),
        n=n,
        origins=chain.origins.ctypes.data,
        axes=chain.axes.ctypes.data,
        q=q.ctypes.data,
        out=out.ctypes.data,
    )


# each robot-level built-in's kernel and the dtype of the record it steps
ARM_KERNELS: dict[str, tuple[str, np.dtype]] = {
    "impedance": ("kali_impedance", IMPEDANCE_DTYPE),
    "computed_torque": ("kali_computed_torque", CT_DTYPE),
}


def arm_step(algorithm: str, record: Any, inp: ArmInput, tau: np.ndarray) -> Kernel:
    """Robot-level built-in ``algorithm``'s kernel (``ARM_KERNELS``) bound to one robot's
    record of it (0-d, the arena's), its ``ArmInput`` and its torque out (``inp.n``
    float64): each call is one step of the algorithm's Python ``step``
    (``servo.armbuiltins``) on what the SV put in ``inp``, returning its status.  The drive's
    friction comes from ``inp.friction`` (``DriveFriction.coefficients``; none without a
    model).  Outside the cycle."""
    name, dtype = ARM_KERNELS[algorithm]
    n = inp.n
    arrays: dict[str, np.ndarray] = {
        "q_d": inp.q_d, "qd_d": inp.qd_d, "qdd_d": inp.qdd_d, "q": inp.q, "qd": inp.qd,
        "h": inp.h, "M": inp.M, "J": inp.J, "pose": inp.pose, "pose_d": inp.pose_d,
        "wrench": inp.wrench, "tau": tau,
    }  # fmt: skip
    coefficients = getattr(inp.friction, "coefficients", None)
    friction = coefficients() if coefficients is not None else (np.zeros(n),) * 4
    for field, a in zip(("viscous", "gear_w", "coulomb_pos", "coulomb_neg"), friction, strict=True):
        arrays[field] = np.ascontiguousarray(a, dtype=np.float64)
    for field, a in arrays.items():
        assert a.dtype == np.float64 and a.flags.c_contiguous, (
            f"kernels: {algorithm} {field} must be contiguous float64, not {a.dtype} {a.shape}"
        )
    assert n <= layout.MAX_JOINTS, f"kernels: {algorithm} steps at most {layout.MAX_JOINTS} joints"
    wrenches = inp.wrenches
    assert record.dtype == dtype and record.shape == (), record.dtype
    assert wrenches.dtype == np.float64 and wrenches.shape[1:] == (layout.WRENCH,)
    assert wrenches.strides[1] == 8, "kernels: a wrench's six values are contiguous"
    return Kernel(
        name,
        (record, wrenches, *arrays.values()),
        n=n,
        d=record.ctypes.data,
        wrenches=wrenches.ctypes.data,
        wrench_stride=wrenches.strides[0],
        robots=len(wrenches),
        has_sensor=int(inp.has_sensor),
        **{field: a.ctypes.data for field, a in arrays.items()},
    )


def channel_offsets(arms: np.ndarray, robot_of: np.ndarray, joint_of: np.ndarray) -> np.ndarray:
    """Byte offsets from ``arms.ctypes.data`` (a per-arm register array, ``(arms, channels)``)
    of each flat joint's channel: arm ``robot_of[i]``, channel ``joint_of[i]``."""
    start = arms.ctypes.data
    return np.array(
        [arms[k, j : j + 1].ctypes.data - start for k, j in zip(robot_of, joint_of, strict=True)],
        dtype=np.int64,
    )


# --------------------------------------------------------------------------------------------
# The numpy references: what each kernel computes, as SIO and the driver did before them
# (tests/test_sio_kernels.py holds the kernels to these, bit for bit).


def read_reference(
    raw: np.ndarray, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray, rpc: np.ndarray,
    q: np.ndarray,
) -> None:  # fmt: skip
    """``kali_read``: counter readings ``raw`` (int32, flat) accumulated with wrap (figure
    C.3) into ``acc``, ``prev``; angles into ``q``."""
    r = np.bitwise_and(raw, COUNTER_MODULO - 1).astype(np.int32)
    d = np.subtract(r, prev)
    np.add(d, COUNTER_HALF, out=d)
    np.bitwise_and(d, COUNTER_MODULO - 1, out=d)
    np.subtract(d, COUNTER_HALF, out=d)
    np.add(acc, d, out=acc)
    np.copyto(prev, r)
    np.multiply(acc, rpc, out=q)
    np.add(q, offset, out=q)


def velocity_reference(
    q: np.ndarray, q_prev: np.ndarray, qd: np.ndarray, gain: float, b: float
) -> None:
    """``kali_velocity``: backward difference through the first-order low-pass."""
    raw = np.subtract(q, q_prev)
    np.multiply(raw, gain, out=raw)
    np.add(qd, raw, out=qd)
    np.multiply(qd, b, out=qd)
    np.copyto(q_prev, q)


def checks_reference(
    bounds: np.ndarray, q: np.ndarray, demand: np.ndarray, q_min: np.ndarray,
    q_max: np.ndarray, range_check: np.ndarray, fed: np.ndarray, safe: np.ndarray,
    safe_ok: np.ndarray,
) -> int:  # fmt: skip
    """``kali_checks``: NO_FAULT, i (joint i beyond its range) or n + i (its runaway)."""
    n = len(q)
    beyond = (q < q_min) | (q > q_max)
    beyond &= range_check.astype(bool) & fed
    safe_in = (safe > 0.0) & (safe <= math.pi)
    np.copyto(safe_ok, safe, where=safe_in)
    over = (np.abs(demand - q) > safe_ok) & fed
    for k in range(len(bounds) - 1):
        span = slice(int(bounds[k]), int(bounds[k + 1]))
        if beyond[span].any():
            return span.start + int(np.argmax(beyond[span]))
        if over[span].any():
            return n + span.start + int(np.argmax(over[span]))
    return NO_FAULT


def feed_reference(
    demand: np.ndarray, q: np.ndarray, qd: np.ndarray, fed: np.ndarray, slots: np.ndarray,
    not_fed: int, ctrl: np.ndarray, demand_vel: np.ndarray, demand_acc: np.ndarray,
    ff: np.ndarray, mark: np.ndarray,
) -> int:  # fmt: skip
    """``kali_feed``: the slots' demand (and its velocity and acceleration), position,
    velocity and feed-forward, the count fed and done = 0 in ``ctrl``, then busy = the
    slot's mark where fed; the count."""
    for field, src in (
        ("demand", demand), ("position", q), ("velocity", qd), ("demand_vel", demand_vel),
        ("demand_acc", demand_acc), ("ff", ff),
    ):  # fmt: skip
        np.copyto(slots[field], src)
    count = int(np.count_nonzero(fed))
    ctrl["fed"] = count
    ctrl["done"] = 0
    busy = np.full(len(q), not_fed, dtype=np.uint32)
    np.copyto(busy, mark, where=fed)
    np.copyto(slots["busy"], busy)
    return count


def torques_reference(
    slot_torque: np.ndarray, fed: np.ndarray, servo_torque: np.ndarray, ff: np.ndarray,
    torque: np.ndarray,
) -> None:  # fmt: skip
    """``kali_torques``: servo and feed-forward torques of the fed joints, and their sum."""
    f = fed.astype(np.float64)
    np.multiply(slot_torque, f, out=servo_torque)
    np.multiply(ff, f, out=ff)
    np.add(servo_torque, ff, out=torque)


def dac_reference(
    torque: np.ndarray, gkt: np.ndarray, limit: np.ndarray, codes_per_amp: np.ndarray,
    current: np.ndarray, clamped: np.ndarray, zero: float, top: float,
) -> np.ndarray:  # fmt: skip
    """``kali_dac``: motor currents (clamped at the limit) and the DAC codes (uint16)."""
    np.divide(torque, gkt, out=current)
    np.greater(np.abs(current), limit, out=clamped)
    np.minimum(current, limit, out=current)
    np.maximum(current, -limit, out=current)
    codes = current * codes_per_amp
    np.add(codes, zero, out=codes)
    np.rint(codes, out=codes)
    np.maximum(codes, 0, out=codes)
    np.minimum(codes, top, out=codes)
    return codes.astype(np.uint16)


def current_check_reference(
    torque: np.ndarray, fed: np.ndarray, clamped: np.ndarray, over: np.ndarray,
    current_ticks: np.ndarray,
) -> int:  # fmt: skip
    """``kali_current_check``: -1, or the first joint clamped for its ``current_ticks``."""
    np.multiply(torque, fed.astype(np.float64), out=torque)
    np.multiply(over, clamped, out=over)
    np.add(over, clamped, out=over)
    np.multiply(over, fed, out=over)
    hit = over >= current_ticks
    return int(np.argmax(hit)) if hit.any() else -1


def warm() -> Path:
    """Build the library if needed and load it; its path (``python -m kali_daemons.kernels``)."""
    load()
    return library_path()


if __name__ == "__main__":
    print(f"kali kernels: {warm()}")
