"""Every record that lives in the shared-memory arena, declared once (thesis 3.6.1).

Each record is a numpy structured dtype; processes view it in place and never pickle or copy
it inside a cycle.  Like a LinuxCNC ``.comp`` header, each field says who writes it: a field
has exactly one writer, so most records need no lock (Type 4, thesis 3.2.1).

References inside the arena are byte offsets from its base, never addresses; ``NULL_INDEX``
is the named null of the directory's linked list.

``RECORDS`` at the end lists every record (key, dtype, count, writer, readers).  ``kalictl
start`` allocates them all (``blocks``) before any process starts and seals the arena, so a
daemon only attaches; ``LAYOUT_VERSION`` is a digest of every dtype here.

One module on purpose, however long: every record in shared memory in one place (DESIGN 2), so
``LAYOUT_VERSION`` covers them all and each says who writes it.
"""

from __future__ import annotations

import enum
import hashlib
import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

MAGIC = int.from_bytes(b"KALIAREN", "little")
# LAYOUT_VERSION, a digest of every dtype here, is computed at the end of the module

ALIGN = 64  # every block starts on a cache line, so every 4/8-byte word in it is aligned
MAX_BLOCKS = 256  # directory descriptors (blocks plus free fragments)
MAX_PROCESSES = 32  # process table slots: daemons plus user programs' periodic functions
KEY_BYTES = 32
NAME_BYTES = 24
MESSAGE_BYTES = 240
NULL_INDEX = -1

# Well-known arena keys.
KEY_CLOCK = "clock"
KEY_PROCESSES = "processes"
KEY_FAULT = "fault"
KEY_CONFIG = "config"
KEY_CONFIG_DIR = "config.dir"  # where relative plugin paths are found
# the instance's copies of the user files it loaded (robot type files, plugins), taken once
# at ``kalictl start`` (``kali_daemons.tools.snapshot``): every later load reads them
KEY_CONFIG_FILES = "config.files"
KEY_CELL = "cell"  # CELL: the arms as started, for the paths that must not load user code
KEY_MISSES = "clock.misses"

# --------------------------------------------------------------------------------------------
# Arena header and directory (writer: kalictl start; the directory under the header's lock)

HEADER = np.dtype(
    [
        ("magic", "<u8"),  # MAGIC
        ("layout_version", "<u4"),  # LAYOUT_VERSION
        ("header_bytes", "<u4"),  # size of header + directory; the heap starts here
        ("arena_bytes", "<u8"),  # total size of the segment
        ("dir_lock", "<u4"),  # spinlock word: holder pid, 0 when free
        ("head", "<i4"),  # first block descriptor in address order, NULL_INDEX if none
        ("instance", f"S{NAME_BYTES}"),  # instance name
        ("owner_pid", "<i4"),  # pid of the kalictl that created the arena
        ("shutdown", "<u4"),  # 1 once kalictl stop has asked every process to leave
        ("created_ns", "<i8"),  # CLOCK_REALTIME at creation, for kalictl status
        ("lockstep", "<u4"),  # 1 when the instance runs in lockstep mode
        # Directory generation, a sequence count: odd while a dir_lock holder changes the
        # directory, so a reader walks it without the lock and retries if it changed
        ("dir_gen", "<u4"),
        # 1 once kalictl start has laid out every record of RECORDS: no block can be added
        ("sealed", "<u4"),
        ("_pad", "<u4"),
    ],
    align=True,
)

DESCRIPTOR = np.dtype(
    [
        ("key", f"S{KEY_BYTES}"),  # block name; empty for a free fragment
        ("offset", "<u8"),  # byte offset of the block from the arena base
        ("size", "<u8"),  # bytes, a multiple of ALIGN
        ("requested", "<u8"),  # bytes asked for by shmalloc
        ("live", "u1"),  # 1 when this descriptor describes a block or fragment
        ("used", "u1"),  # 1 allocated, 0 free
        ("_pad", "u1", (2,)),
        ("prev", "<i4"),  # neighbour descriptors in address order, NULL_INDEX at the ends
        ("next", "<i4"),
    ],
    align=True,
)


def header_bytes() -> int:
    """Bytes taken by the header and directory, rounded up to ALIGN."""
    raw = HEADER.itemsize + MAX_BLOCKS * DESCRIPTOR.itemsize
    return -(-raw // ALIGN) * ALIGN


# --------------------------------------------------------------------------------------------
# Wall clock (thesis 3.6.2).  Writer: the wall clock, except the command fields.


class RunMode(enum.IntEnum):
    """What the wall clock is doing; commands ask for a change, the clock applies it."""

    STOPPED = 0
    RUNNING = 1
    STEPPING = 2  # lockstep: run until ``step_target`` then stop


CLOCK = np.dtype(
    [
        ("pid", "<i4"),  # wall clock process
        ("ready", "<u4"),  # 1 once the clock loop runs
        ("mode", "<u4"),  # RunMode, written by the clock
        ("lockstep", "<u4"),  # 1: no sleeping, every tick waits for every due ack
        ("tick", "<i8"),  # ticks since start_kali_clock at tick 0
        ("base_tick_ns", "<i8"),  # length of one tick
        ("t0_ns", "<i8"),  # CLOCK_MONOTONIC of tick 0 of the current run
        ("time_offset_ms", "<f8"),  # running time = time_offset_ms + tick * base tick
        ("serious_miss_tolerance_ms", "<u4"),  # how long a serious process may stay unacknowledged
        ("lockstep_timeout_ms", "<u4"),  # lockstep: longest wait for one acknowledgement
        ("busy_wait_ns", "<i8"),  # spin this long before each tick instead of sleeping
        ("step_target", "<i8"),  # lockstep STEPPING: stop when tick reaches this
        ("registry_gen", "<u4"),  # bumped on register/release; the clock reads the table
        ("rates_gen", "<u4"),  # bumped on a rate change; the clock re-reads its slots' periods
        ("table_lock", "<u4"),  # spinlock word guarding process-table slot claims
        ("overruns", "<u8"),  # times the clock itself woke more than one tick late
        ("skipped_ticks", "<u8"),  # ticks jumped over after overruns (no catch-up burst)
        # Commands, written by kalictl or a client, then the command semaphore is posted.
        ("cmd_seq", "<u8"),  # incremented by the writer of a command
        ("cmd_done", "<u8"),  # last cmd_seq the clock has applied
        ("cmd", "<u4"),  # ClockCommand
        ("paced", "<u4"),  # 1: the hardware's state packets pace the tick (real time)
        ("cmd_arg", "<f8"),  # argument: ticks for STEP, ms for SET
        ("cmd_lock", "<u4"),  # spinlock word serialising command writers
        ("cmd_status", "<i4"),  # 0 applied, -1 refused (reason in cmd_message)
        ("cmd_message", f"S{MESSAGE_BYTES}"),
    ],
    align=True,
)


class ClockCommand(enum.IntEnum):
    """Commands to the wall clock (start/stop/set_kali_clock of thesis 3.6.2, plus step)."""

    NONE = 0
    START = 1
    STOP = 2
    SET_TIME = 3
    STEP = 4


# --------------------------------------------------------------------------------------------
# Process table.  One slot per Kali process or registered periodic function.


class ProcState(enum.IntEnum):
    """Lifecycle state of a slot (after ros2_control's managed nodes)."""

    FREE = 0
    SPAWNED = 1  # reserved by kalictl start, process not yet configured
    INACTIVE = 2  # configured, not yet cycling
    ACTIVE = 3  # cycling: ready
    FINALIZED = 4  # shut down cleanly
    ERROR = 5  # failed; see the fault record
    DIED = 6  # died; the wall clock left this non-serious process out (DESIGN 7: degrade)


# Wake-up lateness histogram: 1 µs bins below 1 ms, then eight bins per octave to ~256 ms.
HIST_LINEAR_US = 1000
HIST_LOG_BINS = 64
HIST_BINS = HIST_LINEAR_US + HIST_LOG_BINS


def lateness_bin(ns: int) -> int:
    """Histogram bin for a lateness of ``ns`` nanoseconds (negative counts as 0)."""
    us = ns // 1000
    if us < HIST_LINEAR_US:
        return us if us > 0 else 0
    return HIST_LINEAR_US + min(int(math.log2(us / HIST_LINEAR_US) * 8), HIST_LOG_BINS - 1)


def bin_upper_us(b: int) -> float:
    """Upper edge in µs of histogram bin ``b`` (percentiles are reported at upper edges)."""
    if b < HIST_LINEAR_US:
        return float(b + 1)
    return HIST_LINEAR_US * 2.0 ** ((b - HIST_LINEAR_US + 1) / 8)


PROCESS = np.dtype(
    [
        # Identity, written by the owner on registration (name/pid first by kalictl start).
        ("name", f"S{NAME_BYTES}"),
        ("state", "<u4"),  # ProcState, owner
        ("pid", "<i4"),  # owner
        ("cpu", "<i4"),  # CPU the owner is bound to, -1 if none
        ("priority", "<i4"),  # SCHED_FIFO priority, 0 for SCHED_OTHER
        ("periodic", "<u4"),  # 1 when the wall clock signals this slot
        ("serious", "<u4"),  # 1: a missed deadline halts the system (thesis 3.6.2)
        ("stage", "<u4"),  # lockstep order within a tick, lower first
        ("period_ticks", "<u4"),  # owner or set_control_rate
        # Clock side, written only by the wall clock.
        ("signal_tick", "<i8"),  # last tick signalled
        ("release_ns", "<i8"),  # CLOCK_MONOTONIC at which that tick was due
        ("next_due", "<i8"),  # next tick at which the slot is due
        ("signals", "<u8"),
        ("misses", "<u8"),  # due ticks at which the previous signal was unacknowledged
        ("consecutive_misses", "<u4"),
        ("max_consecutive_misses", "<u4"),
        # Process side, written only by the owner.
        ("ack_tick", "<i8"),  # last tick whose cycle finished
        ("acks", "<u8"),
        ("exec_last_ns", "<i8"),  # wake to acknowledgement
        ("exec_max_ns", "<i8"),
        ("late_last_ns", "<i8"),  # due time to wake-up
        ("late_max_ns", "<i8"),
        ("heartbeat_ns", "<i8"),  # CLOCK_MONOTONIC, refreshed every cycle and every idle wait
        # SIO side, an SV's slot only: the last tick SIO acknowledged for it before it had
        # taken that tick's feed (sio/gang.py); the clock looks whether it is alive
        ("vouched_tick", "<i8"),
        ("hist", "<u4", (HIST_BINS,)),  # wake-up lateness histogram, see lateness_bin
    ],
    align=True,
)


# Missed-deadline log: the last MISS_LOG_LEN misses, written only by the wall clock, so a miss
# can be matched in time against the machine's own stalls (scripts/bench_wallclock.py).
MISS_LOG_LEN = 512

MISS = np.dtype(
    [
        ("tick", "<i8"),  # tick at which the clock found the previous signal unacknowledged
        ("signal_ns", "<i8"),  # CLOCK_MONOTONIC due time of that unacknowledged signal
        ("due_ns", "<i8"),  # CLOCK_MONOTONIC due time of the tick that found it
        ("slot", "<i4"),  # process-table slot
        ("consecutive", "<u4"),  # consecutive misses of the slot so far
    ],
    align=True,
)

MISS_LOG = np.dtype(
    [("count", "<u8"), ("entries", MISS, (MISS_LOG_LEN,))],  # entry = count % MISS_LOG_LEN
    align=True,
)


# --------------------------------------------------------------------------------------------
# Fault record (DESIGN section 7).  Lock-free, so no process, stopped or dead, can keep a halt
# from being recorded: the first writer wins by one compare-and-swap of ``active`` from 0 to
# its pid, then writes the rest alone; readers check ``seq`` before and after a copy.


class FaultCode(enum.IntEnum):
    """Why the system halted."""

    NONE = 0
    DEADLINE = 1  # a serious process missed its deadline beyond the tolerance
    LOCKSTEP_TIMEOUT = 2  # reserved: a lockstep tick not acknowledged in time is a DEADLINE
    DAEMON_ERROR = 3  # a daemon's cycle raised
    PROCESS_DIED = 4
    ESTOP = 5
    RANGE = 6
    RUNAWAY = 7
    CURRENT = 8
    SINGULARITY = 9
    OPERATOR = 10  # halted on request
    SERVO = 11  # a servo algorithm raised, returned a bad status or a non-finite torque
    POWER = 12  # a robot's amplifiers went off while it was servoing
    FORCE = 13  # a wrist force/torque sensor saturated, beyond its range or the contact limit
    HARDWARE = 14  # the hardware reported an error (a robot's controller, its connection)


FAULT = np.dtype(
    [
        # ``active`` and ``seq`` are one 64-bit state word, swapped whole (Instance.raise_fault).
        # The fault word: 0 while no fault is active, else the pid of the process whose fault
        # it is (set with ``seq`` by one compare-and-swap; kalictl reset sets it back to 0)
        ("active", "<u4"),
        ("seq", "<u4"),  # the record's sequence count: odd while the winner writes the rest
        ("code", "<u4"),  # FaultCode
        ("pid", "<i4"),  # process that raised it
        ("tick", "<i8"),
        ("time_ns", "<i8"),  # CLOCK_REALTIME
        ("count", "<u8"),  # faults raised since start, atomic add (later ones are counted too)
        ("process", f"S{NAME_BYTES}"),
        ("message", f"S{MESSAGE_BYTES}"),
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# Dashboard (DESIGN 8, thesis 3.3.7): where the viewer's live rerun dashboard goes, for
# ``kalictl view``.  ``record`` is written by kalictl start before the viewer starts; every
# other field by the viewer.

KEY_DASHBOARD = "viewer.dashboard"
URL_BYTES = 256  # URLs and paths, UTF-8, NUL-padded

DASHBOARD = np.dtype(
    [
        ("record", f"S{URL_BYTES}"),  # kalictl start: the .rrd file to record to ('' = none)
        ("ready", "<u4"),  # viewer: 1 once its sinks are set up
        ("live", "<u4"),  # viewer: 1 when it streams to a live rerun viewer at live_url
        ("web_pid", "<i4"),  # viewer: pid of its web viewer server (rerun --serve-web), 0: none
        ("_pad", "<u4"),
        ("frames", "<u8"),  # viewer: dashboard frames logged
        ("errors", "<u8"),  # viewer: frames that failed (the dashboard never halts the system)
        ("live_url", f"S{URL_BYTES}"),  # viewer: the live viewer's gRPC address, '' if none
        ("web_url", f"S{URL_BYTES}"),  # viewer: what a browser opens, '' if not served
        ("message", f"S{MESSAGE_BYTES}"),  # viewer: what it could not do (a port taken, ...)
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# Channels (thesis 3.2.1, 2.2.2).  See channels.py for the protocols.

QUEUE_HEADER = np.dtype(
    [
        ("lock", "<u4"),  # producers' spinlock (multi-producer)
        ("capacity", "<u4"),
        ("entry_bytes", "<u4"),  # payload bytes per entry
        # entries the consumer dropped: a seq that does not match the entry's place, or a
        # head/tail no producer wrote (a writer outside the protocol); consumer
        ("discarded", "<u4"),
        ("head", "<u8"),  # next entry to read; written by the consumer
        ("tail", "<u8"),  # next entry to write; written by producers under the lock
        # seq of the next entry, always tail + 1: an entry's seq is its place + 1, so the
        # consumer tells a stale or forged entry from a real one; producers under the lock
        ("next_seq", "<u8"),
        ("rejected", "<u8"),  # puts refused because the queue was full
    ],
    align=True,
)


def queue_entry(payload: np.dtype) -> np.dtype:
    """One Type 1 queue entry: a sequence number and the payload record."""
    return np.dtype([("seq", "<u8"), ("payload", payload)], align=True)


FIFO_HEADER = np.dtype(
    [
        ("capacity", "<u4"),  # set-points the ring holds
        ("width", "<u4"),  # values per set-point (joints)
        # r = ratio_num / ratio_den = servo rate / TG rate of the segment in progress;
        # creator, then the consumer when it takes a set-point stamped with another ratio.
        ("ratio_num", "<u4"),
        ("ratio_den", "<u4"),
        ("head", "<u8"),  # next set-point to take; consumer
        ("tail", "<u8"),  # next set-point to write; producer
        # Interpolation state, consumer only.
        ("phase_acc", "<u8"),  # integer accumulator deciding ticks per segment
        ("seg_ticks", "<u4"),  # servo ticks in the current segment
        ("seg_done", "<u4"),  # ticks of it already output
        ("primed", "<u4"),  # 1 once the first set-point has been taken
        ("rejected", "<u4"),  # set-points (or ratio stamps) the consumer refused as garbage
        ("underruns", "<u8"),  # servo ticks with no set-point to move to (holds B)
        ("overflows", "<u8"),  # pushes refused because the ring was full
        # The ratio the next set-point pushed is stamped with (num | den << 32, one atomic
        # word); producer (set_ratio), creator.  Each set-point carries its own stamp in the
        # ``.ratios`` block, so a change never touches set-points already in the ring.
        ("push_ratio", "<u8"),
        # The consumer's resets (``reset``: a start, power on, calibration, a guard's trip, a
        # hand guiding): a sequence lock, odd while one is written, then ``hold_index``
        # (the tail then: the first set-point pushed after it) and the ``.hold`` block (the
        # position it holds, that set-point's predecessor for the dynamics process).
        ("resets", "<u8"),
        ("hold_index", "<u8"),
    ],
    align=True,
)

FLAG = np.dtype([("word", "<u4")])  # Type 3 test-and-set flag: 0 clear, else the setter's pid


# --------------------------------------------------------------------------------------------
# The simulated plant's truth and the operator's pushes (DESIGN 6): never read by the
# controller.  The hardware's own registers are its kind's records (``hardware/<kind>``),
# laid out with these through ``Cell.hardware``.
KEY_TRUTHS = "truths"  # plant-only truth, ARM_TRUTH per robot (never read by the controller)
KEY_JOINT_TRUTHS = "truths.joints"  # plant-only truth, JOINT_TRUTH per joint of the cell
KEY_WORLD_TRUTH = "truth.world"
KEY_OBJECT_TRUTHS = "truths.objects"  # plant-only truth, OBJECT_TRUTH per free object
KEY_PUSHES = "plant.pushes"  # PUSH per robot: external pushes the operator asks the plant for

# The joints one arm's records hold: every hardware kind carries at most these per arm
# (``hardware.registry`` checks it).  Per-arm records size their joint arrays by it; per-joint
# records (JOINT_STATE, JOINT_TRUTH) hold the cell's joints flat instead, arm k's joint j at
# joints.JointMap.base[k] + j.
MAX_JOINTS = 8
WRENCH = 6  # a wrench's values: force x, y, z (N), then torque x, y, z (N·m); one gauge each

ARM_TRUTH = np.dtype(
    [
        ("grasp_wrench", "<f8", (WRENCH,)),  # weld force (N) and torque (N·m) on the object, world
        # what an ideal wrist sensor reads: the wrench the tool exerts on it, sensor frame
        ("ft_wrench", "<f8", (WRENCH,)),
        ("push", "<f8", (3,)),  # the external push on the tool now (N, world), kalictl push
        ("amps_on", "u1"),
        ("brakes_engaged", "u1"),
        ("grasped", "u1"),
        ("watchdog_tripped", "u1"),
        ("estop", "u1"),
        ("held", "i1"),  # the free object it holds: its index in OBJECT_TRUTH, -1 none
        ("_pad", "u1", (2,)),
    ],
    align=True,
)

JOINT_TRUTH = np.dtype(  # one per joint of the cell, flat (joints.JointMap)
    [
        ("q", "<f8"),  # joint angle, rad
        ("qd", "<f8"),  # joint velocity, rad/s
        ("current", "<f8"),  # motor current, A
        ("torque", "<f8"),  # motor torque at the joint (G·Kt·i), N·m
        ("motor_angle", "<f8"),  # rad, G·q (what the encoder sees)
    ],
    align=True,
)

WORLD_TRUTH = np.dtype(
    [
        ("sim_time_ns", "<i8"),  # simulated time since the plant started
        ("ticks", "<u8"),  # plant cycles
        ("internal_force", "<f8"),  # N, along the line between the grasps: + squeeze, − tension
    ],
    align=True,
)

OBJECT_TRUTH = np.dtype(  # per free object of the scene (robots.scene), in the scene's order
    [
        ("pose", "<f8", (7,)),  # position (m) and quaternion (w, x, y, z), world
    ],
    align=True,
)

# A camera's image ring (DESIGN 6): its process renders into the buffer after the latest and
# then names it latest, each buffer's seq odd while it is written, so a reader copies the
# latest frame and checks its seq unchanged: never torn (``camera.ring``).  A real camera's
# driver process fills the same records.
KEY_CAMERAS = "cameras"  # CAMERA per camera of the scene, the scene's order
KEY_CAMERA_FRAMES = "cameras.frames"  # every camera's CAMERA_BUFFERS buffers (camera_bytes)
CAMERA_BUFFERS = 3

CAMERA = np.dtype(
    [
        ("width", "<u4"),  # pixels
        ("height", "<u4"),
        ("K", "<f8", (3, 3)),  # intrinsics: pixel = K @ p / p[2], p in the camera's frame
        ("pose", "<f8", (4, 4)),  # the camera in the world: x right, y down, z along the view
        ("offset", "<i8"),  # its first buffer's byte in KEY_CAMERA_FRAMES
        ("latest", "<i4"),  # the buffer last finished, -1 before the first
        ("up", "u1"),  # 1 once its process renders (or its driver delivers)
        ("_pad", "u1", (3,)),
        ("frames", "<u8"),  # frames finished
        ("seq", "<u8", (CAMERA_BUFFERS,)),  # per buffer: bumped before and after a write
        ("tick", "<i8", (CAMERA_BUFFERS,)),  # the clock's tick of the state each buffer shows
        ("sim_time_ns", "<i8", (CAMERA_BUFFERS,)),  # the plant's time of it (-1: real)
        ("stamp_ns", "<i8", (CAMERA_BUFFERS,)),  # CLOCK_MONOTONIC when it was taken
        ("frame_ns", "<i8"),  # what the last frame cost its process (CPU time)
        ("frame_max_ns", "<i8"),  # the most a frame has cost
    ],
    align=True,
)


def camera_bytes(pixels: int) -> int:
    """One buffer of a camera of ``pixels`` pixels: depth (float32, m) then colour (RGB, one
    byte each) padded to whole 8-byte words, so every buffer's depth is aligned."""
    return 4 * pixels + (3 * pixels + 7) // 8 * 8


PUSH = np.dtype(  # kalictl push: an external force on a robot's tool, for tests and demos
    [
        ("force", "<f8", (3,)),  # operator: N, world frame, applied at the tool's sensor origin
        ("duration_ns", "<i8"),  # operator: how long, in the plant's simulated time
        ("seq", "<u4"),  # operator: written last, incremented per push; the plant starts it
        ("_pad", "<u4"),
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# Servo level (DESIGN 4, thesis 3.3.3 - 3.5, figure 3.3): SIO's robot records, the servo
# slots SIO feeds and the SVs claim, and the tick's bookkeeping between them.

MAX_SV = 8  # servo workers (thesis 3.3.4: one to eight)
SERVO_STAGING_BYTES = 1024  # largest private servo data a put/get mailbox carries
KEY_ROBOTS = "robots"  # ROBOT_STATE per robot, config order
KEY_JOINTS = "robots.joints"  # JOINT_STATE per joint of the cell, flat (joints.JointMap)
KEY_SLOTS = "servo.slots"  # SERVO_SLOT per joint, flat: robot k joint j is slot base[k] + j
KEY_STAGING = "servo.staging"  # SERVO_STAGING_BYTES per slot: the put/get mailbox data
KEY_SERVO_CTRL = "servo.ctrl"
# the servo algorithms' names, registry order: the joint servos, then the robot-level ones
# (SIO, at first start), for readers that do not load the plugins (kalictl status, top)
KEY_SERVO_NAMES = "servo.names"
SERVO_NAME = np.dtype([("name", "S31"), ("robot_level", "u1")])  # 1: a robot-level servo
# private data of one algorithm for every joint of the cell: a block of one record per joint
# (slot order), so an SV runs a built-in over many joints in one call (servo.vector)
KEY_SERVO_DATA = "servo.data.{algo}"
# robot-level servos (thesis 3.3.4's Cartesian servo mode): one algorithm's private
# data for every robot, a record per robot (config order), and each robot's put/get mailbox
KEY_ARM_DATA = "servo.arm.{arm}"
KEY_ARM_STAGING = "servo.arm_staging"  # SERVO_STAGING_BYTES per robot
# servo plugins loaded while running (``servo/loading.py``): the arena is laid out before any
# process starts, so it holds spare algorithms (``servo.data.{algo}`` after the configured
# ones, ``servo.arm.{arm}`` after theirs, each a LOADED_RECORD per joint or robot, viewed as
# the plugin's dtype once loaded) and a table of the files loaded, each offered by a client
# and taken by every process that runs or reads servos
SERVO_LOADABLE = 4  # joint servos loadable while running, per instance
ARM_LOADABLE = 2  # robot-level servos
MAX_LOADS = 4  # plugin files
LOADED_RECORD = np.dtype(f"V{SERVO_STAGING_BYTES}")  # a spare's record: any private data
KEY_SERVO_LOADS = "servo.loads"


class LoadState(enum.IntEnum):
    """A loaded plugin file's entry, as its client moves it on."""

    FREE = 0
    OFFERED = 1  # written whole: the SVs take it (import, register) and say so
    READY = 2  # every SV has it: clients may select it
    FAILED = 3  # an SV could not take it (``reason``): never selectable


SERVO_LOAD = np.dtype(
    [
        ("state", "<u4"),  # LoadState, written last by the loading client
        ("joint_first", "<u4"),  # registry index of its first joint servo
        ("n_joint", "<u4"),  # joint servos it registers, indices joint_first..
        ("arm_first", "<u4"),  # robot-level index of its first robot-level servo
        ("n_arm", "<u4"),
        ("_pad", "<u4"),
        ("taken", "<u4", (MAX_SV,)),  # SV k: 1 = registered, 2 = could not (``reason``)
        ("path", "S256"),  # its compiled copy in the instance's directory
        ("origin", "S128"),  # the file the user named
        ("names", "S160"),  # what it registers, comma-separated, registry order
        ("reason", "S256"),  # FAILED: which SV and why
    ],
    align=True,
)
SERVO_LOADS = np.dtype(
    [
        ("generation", "<u4"),  # entries offered so far (an entry's number + 1)
        ("lock", "<u4"),  # clients: spinlock serialising loads
        ("entries", SERVO_LOAD, (MAX_LOADS,)),
    ],
    align=True,
)
KEY_FIFO = "fifo.{robot}"  # TG → SIO set-points (Type 2), the robot's joint angles each


class PowerState(enum.IntEnum):
    """Amplifier power of one robot, as SIO drives the board's power switch (C.5.1)."""

    OFF = 0
    ENABLING = 1  # enable bit held high for the relay, then brakes releasing
    ON = 2


class PowerCmd(enum.IntEnum):
    """Requests to SIO in ``ROBOT_STATE.power_cmd`` (kalictl enable/disable); SIO clears.
    A halt voids a pending one (``cmd_faults``)."""

    NONE = 0
    ENABLE = 1
    DISABLE = 2


class CalibState(enum.IntEnum):
    """Progress of a robot's calibration (thesis 3.5.1), in the order SIO goes through it."""

    IDLE = 0
    SEARCH = 1  # index capture on, every joint servoed slowly toward its nearest index pulse
    SETTLE = 2  # every index found, capture off: the joints come to rest on their pulses
    POTS = 3  # reading the potentiometers at the index pulses
    DONE = 4
    FAILED = 5


class SlotOp(enum.IntEnum):
    """Mailbox operations on a servo slot, carried out by the SV at the slot's next run."""

    NONE = 0
    PUT = 1  # copy the staging bytes into the private data of algorithm ``op_algo``
    GET = 2  # copy the private data of ``op_algo`` into the staging bytes
    SELECT = 3  # make ``op_algo`` the joint's servo, handing over its state (bumpless)
    PARAMS = 4  # set parameters of ``op_algo`` from float64 staging values (NaN = unchanged)
    # run ``op_algo`` in shadow beside the active servo (SHADOW_OFF: stop the one running):
    # stepped on the same inputs each tick, its torque compared, never applied
    SHADOW = 5


SHADOW_OFF = 0xFFFFFFFF  # ``op_algo`` of a SHADOW operation that ends the running trial
NO_SHADOW = -1  # ``SERVO_SLOT.shadow`` and ``ROBOT_STATE.arm_shadow`` before any trial


class ShadowState(enum.IntEnum):
    """A shadow trial, as the SV runs it: its algorithm and figures stay
    readable after it ends, until the next trial on the joint or robot starts."""

    NONE = 0  # no trial has run
    RUNNING = 1  # stepped every tick beside the active servo, compared, never applied
    STOPPED = 2  # ended by a client (kalictl servo shadow ... off)
    SELECTED = 3  # it became the active servo, going on from its own state
    RAISED = 4  # its step raised: the trial ended, the arm ran on
    FAILED = 5  # its step returned a nonzero status or a non-finite torque (shadow_torque)


class SlotReset(enum.IntEnum):
    """What SIO asks the SV to do to a slot's servo state before its next step."""

    NONE = 0
    REST = 1  # take the joint over at rest with no torque (power on)
    SHIFT = 2  # positions moved by a constant (calibration): hand over from the running state


SLOT_NOT_FED = 0xFFFFFFFF  # ``busy`` of a slot SIO did not feed this tick
# A robot fed whole (it runs a robot-level servo, or has a robot-level mailbox operation):
# its first slot's ``busy`` is ARM_FREE, claimed by test-and-set like 0, the others ARM_HELD;
# the SV that claims the first runs the robot's servos (all its joints) as one unit.
ARM_FREE = 0xFFFFFFFE
ARM_HELD = 0xFFFFFFFD
ARM_NONE = -1  # ``ROBOT_STATE.arm_algo`` of a robot that runs its joint servos
OP_REFUSED = -1  # ``op_status`` of a mailbox operation the SV refused (see the staging bytes)

ROBOT_STATE = np.dtype(
    [
        ("first_joint", "<u4"),  # SIO: the flat index of its joint 1 in JOINT_STATE and slots
        ("n_joints", "<u4"),  # SIO: its robot type's joint count
        ("power", "u1"),  # SIO: PowerState
        ("power_cmd", "u1"),  # clients: PowerCmd; SIO clears it when taken
        ("calibrated", "u1"),  # SIO: 1 once calibrated against the index pulses
        ("pots_read", "u1"),  # SIO: 1 once the offsets are set roughly from the pots
        ("calib_cmd", "u1"),  # clients: 1 = calibrate; SIO clears it when taken
        ("calib_state", "u1"),  # SIO: CalibState
        ("calib_found", "u1"),  # SIO: bit j = joint j's index pulse found
        # SV: 1 while a robot-level servo guides the arm by hand (ArmServoAlgorithm.guides):
        # SIO's demand follows the measured arm, the TG refuses to move it
        ("guided", "u1"),
        ("enable_ticks", "<i4"),  # SIO: ticks into the enable sequence
        # clients: the fault count (low 32 bits) seen when power_cmd / calib_cmd was written;
        # SIO takes a command only while it matches and no fault is active: a halt voids it
        ("cmd_faults", "<u4"),
        # SIO: the fault count (low 32 bits) its last tick had seen: while the fault record's
        # is another, ``power`` may still say a halted robot is ON (SIO has not run since)
        ("faults_seen", "<u4"),
        ("tick", "<i8"),  # SIO: last servo tick
        # the robot-level servo: the active one, or ARM_NONE for joint servos,
        # and its mailbox, as a slot's (SlotOp; the SV carries it out, op_algo -1 = joints)
        ("arm_algo", "<i4"),  # SV
        ("arm_op", "<u4"),  # clients, written last; the SV clears it when done
        ("arm_op_algo", "<i4"),  # clients
        ("arm_op_lock", "<u4"),  # clients: spinlock serialising mailbox users
        ("arm_ops_done", "<u4"),  # SV
        ("arm_op_status", "<i4"),  # SV: 0 or OP_REFUSED (the reason in the robot's staging)
        ("arm_status", "<i4"),  # SV: what the robot-level servo's step returned last
        # SV: the robot-level servo of the robot's last shadow trial (NO_SHADOW: none) and
        # its ShadowState; its torques and figures go to the slots' shadow fields
        ("arm_shadow", "<i4"),
        ("arm_shadow_state", "<u4"),
        # SV (atomic add): shadow trials running on the robot, joint and robot-level; SIO
        # feeds a robot with any whole, for one SV (servo/sv/arm.py)
        ("shadows", "<u4"),
        ("arm_exec_ns", "<i8"),  # SV: duration of its last step, model update included
        ("arm_ran_tick", "<i8"),  # SV: last tick it ran
        ("message", f"S{MESSAGE_BYTES}"),  # SIO: last calibration or power message
    ],
    align=True,
)

JOINT_STATE = np.dtype(  # one per joint of the cell, flat (joints.JointMap)
    [
        ("q", "<f8"),  # SIO: measured joint angle, rad
        ("qd", "<f8"),  # SIO: joint velocity from the encoder, rad/s
        ("demand", "<f8"),  # SIO: this tick's interpolated set-point, rad
        ("servo_torque", "<f8"),  # SIO: what the servo asked for, N·m
        ("ff_torque", "<f8"),  # SIO: feed-forward added this tick, N·m
        ("torque", "<f8"),  # SIO: torque sent (after the current clamp), N·m
        ("current", "<f8"),  # SIO: motor current commanded, A
        ("offset", "<f8"),  # SIO: calibration offset of the driver, rad
        ("safe", "<f8"),  # clients: tracking-error tolerance, rad
        ("calib_shift", "<f8"),  # SIO: how far calibration moved the angle, rad
        ("acc", "<i4"),  # SIO: 32-bit accumulated encoder counts
        ("prev", "<i4"),  # SIO: last 12-bit counter reading
        ("over_ticks", "<i4"),  # SIO: consecutive ticks beyond the current limit
        ("range_check", "u1"),  # clients: 1 = joint range checked
        ("_pad", "u1", (3,)),
    ],
    align=True,
)

KEY_FT = "robots.ft"  # FT_STATE per robot, config order: its wrist sensor in Newtons


class TareState(enum.IntEnum):
    """A robot's tare, as SIO goes through it (``FT_STATE.tare_state``)."""

    IDLE = 0
    AVERAGING = 1  # summing the next samples
    DONE = 2
    FAILED = 3  # no sensor, or it did not answer, or the arm moved


FT_STATE = np.dtype(  # one per robot: its wrist force/torque sensor (ftsensor.py), SIO
    [
        ("present", "u1"),  # SIO: 1 once the sensor answered
        ("tare_cmd", "u1"),  # clients: 1 = tare; SIO clears it when taken
        ("tare_state", "u1"),  # SIO: TareState
        ("_pad", "u1", (5,)),
        ("tare_count", "<u4"),  # SIO: tares done
        ("stale", "<u4"),  # SIO: ticks since the last fresh sample
        ("samples", "<u8"),  # SIO: fresh samples read
        ("sample_tick", "<i8"),  # SIO: tick of the last fresh sample
        # SIO: the calibrated reading less the tare bias: the wrench the tool exerts on the
        # sensor (its weight included), sensor frame, N and N·m, unfiltered
        ("sensor", "<f8", (WRENCH,)),
        # SIO: the contact wrench, what the environment applies to the tool (tool gravity
        # removed), low-pass filtered, about the tool point: tool axes, then world axes
        ("tool", "<f8", (WRENCH,)),
        ("world", "<f8", (WRENCH,)),
        ("bias", "<f8", (WRENCH,)),  # SIO: the tare's bias, sensor frame (kept across SIO restarts)
        ("rotation", "<f8", (3, 3)),  # SIO: the sensor frame in the world at the sample
        ("contact_limit", "<f8"),  # clients: contact force beyond this halts, N (0: config's)
        # a guarded move: the TG arms this arm's guard for a request, SIO
        # trips it when the contact force reaches guard_n and holds the arm where it is then
        ("guard_state", "<u4"),  # GuardState; TG: IDLE→ARMED, back by CAS; SIO: ARMED→TRIPPED
        ("guard_seq", "<u8"),  # TG: the guarded request
        ("guard_n", "<f8"),  # TG: the contact force that trips it (N, unfiltered magnitude)
        ("guard_tick", "<i8"),  # SIO: the tick it tripped
        ("guard_force", "<f8"),  # SIO: the contact force that tripped it, N
        ("guard_q", "<f8", (MAX_JOINTS,)),  # SIO: the measured joints then, where it holds
        ("guard_wrench", "<f8", (WRENCH,)),  # SIO: the contact wrench then, world axes
    ],
    align=True,
)


class GuardState(enum.IntEnum):
    """A robot's guard, between the TG and SIO (``FT_STATE.guard_state``)."""

    IDLE = 0
    ARMED = 1  # the TG's guarded motion runs: SIO watches the contact force
    TRIPPED = 2  # SIO saw it reach guard_n: it holds the arm until the TG sets IDLE


SERVO_SLOT = np.dtype(
    [
        ("busy", "<u4"),  # SIO clears to 0 when fed; an SV claims by test-and-set (3.3.5)
        ("op", "<u4"),  # clients: SlotOp, written last; the SV clears it when done
        ("op_algo", "<u4"),  # clients: algorithm the op is about
        ("op_lock", "<u4"),  # clients: spinlock serialising mailbox users
        ("ops_done", "<u4"),  # SV: mailbox operations carried out
        ("algo", "<u4"),  # SV: the joint's active algorithm (registry index)
        ("enabled", "<u4"),  # clients: 1 = servo runs; 0 = it outputs no torque
        ("status", "<i4"),  # SV: status the step returned
        ("demand", "<f8"),  # SIO: position demand, rad
        ("position", "<f8"),  # SIO: measured position, rad
        ("velocity", "<f8"),  # SIO: measured velocity, rad/s (for hand-over)
        # SIO: the demand's velocity and acceleration (the dynamics process's rows,
        # interpolated as the demand), rad/s and rad/s², and this tick's feed-forward, N·m
        ("demand_vel", "<f8"),
        ("demand_acc", "<f8"),
        ("ff", "<f8"),
        ("torque", "<f8"),  # SV: torque demand, N·m (held while the servo is not run)
        ("error", "<f8"),  # SV: the servo's tracking error, rad
        ("reset", "<u4"),  # SIO: SlotReset; the SV clears it
        # SV: 0 = the last mailbox op was carried out, OP_REFUSED = refused, the reason as
        # UTF-8 text in the slot's staging bytes; written before ops_done is incremented
        ("op_status", "<i4"),
        ("ran_tick", "<i8"),  # SV: last tick the servo ran
        ("exec_ns", "<i8"),  # SV: duration of the last step
        ("sv", "<i4"),  # SV: which worker ran it last
        # a shadow trial, SV: joint servo ``shadow`` (NO_SHADOW: none yet)
        # stepped after the active one on the same inputs, its torque never applied; its
        # ShadowState, its torque, and of (shadow − active) as the motor would get them (a
        # joint servo's plus the feed-forward) the ticks compared, the sum of squares and the
        # largest magnitude.  A robot-level trial writes its joints' torques and figures here.
        ("shadow", "<i4"),
        ("shadow_state", "<u4"),
        ("_pad", "<u4"),
        ("shadow_torque", "<f8"),
        ("shadow_n", "<u8"),
        ("shadow_sq", "<f8"),
        ("shadow_peak", "<f8"),
    ],
    align=True,
)

SERVO_CTRL = np.dtype(
    [
        ("tick", "<i8"),  # SIO: the tick being served
        ("fed", "<u4"),  # SIO: slots fed this tick
        ("done", "<u4"),  # SVs: slots finished this tick (atomic add)
        ("waiting", "<u4"),  # SIO: 1 while it sleeps on the done semaphore
        ("sv_count", "<u4"),  # SIO: servo workers to wake
        ("ready", "<u4"),  # SIO: 1 once every slot's private data exists and is initialised
        ("_pad", "<u4"),
        ("latency_last_ns", "<i8"),  # SIO: encoder read to DAC write, last tick
        ("latency_max_ns", "<i8"),
        ("latency_hist", "<u4", (HIST_BINS,)),  # SIO: sensor-to-DAC latency histogram
        ("sv_exec_last_ns", "<i8", (MAX_SV,)),  # SV k: time from feed to its last servo done
        ("sv_exec_max_ns", "<i8", (MAX_SV,)),
        ("sv_servos", "<u8", (MAX_SV,)),  # SV k: servos it has run
        ("sv_exec_hist", "<u4", (MAX_SV, HIST_BINS)),  # SV k: feed-to-done time histogram
        ("sv_fed_tick", "<i8", (MAX_SV,)),  # SV k: the tick whose feed it took last (-1: none)
        ("fed_ns", "<i8"),  # SIO: CLOCK_MONOTONIC when it fed its last tick (polling SVs learn)
        # SIO: the longest feed to every servo done since SV k last learnt it (servo/sv/daemon.py)
        ("sv_served_max_ns", "<i8", (MAX_SV,)),
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# The built-in servos' private data (writer: the SV running the servo; servo/builtins.py and
# servo/armbuiltins.py): one record per slot (PID, PD) or per robot (computed torque,
# impedance), stepped in place by the compiled kernels (core/kernel_args.py's RECORDS)

PID_DTYPE = np.dtype(
    [
        # parameters (set_params / get_params)
        ("kp", "<f8"),  # N·m/rad
        ("ki", "<f8"),  # N·m/(rad·s)
        ("kv", "<f8"),  # N·m·s/rad
        ("fe", "<f8"),  # Hz, error filter cut-off
        ("fv", "<f8"),  # Hz, velocity filter cut-off
        ("integration_band", "<f8"),  # rad
        ("integration_reset", "<f8"),  # N·m
        ("bias_tau", "<f8"),  # s
        # precomputed from the parameters and the sample interval (figure 3.4's lpf terms)
        ("sampling_period", "<f8"),  # s, T
        ("inv_period", "<f8"),  # 1/s, 1/T
        ("ki_t", "<f8"),  # N·m/rad, ki·T
        ("lpfe1", "<f8"),  # T·2π·fe
        ("lpfe2", "<f8"),  # 1/(1 + lpfe1)
        ("lpfv1", "<f8"),  # T·2π·fv
        ("lpfv2", "<f8"),  # 1/(1 + lpfv1)
        ("bias_decay", "<f8"),  # exp(-T/bias_tau), per step
        # state
        ("error", "<f8"),  # rad, the filtered error e_{k-1}
        ("old_position", "<f8"),  # rad, θ_{k-1}
        ("old_velocity", "<f8"),  # rad/s, the filtered velocity v_{k-1}
        ("integral", "<f8"),  # N·m, ki·∫e so far, within ±integration_reset
        ("bias", "<f8"),  # N·m, hand-over torque still to fade out
        ("primed", "<u4"),  # 0 after init: the first step takes its position as θ_{k-1}
    ],
    align=True,
)

PD_DTYPE = np.dtype(
    [
        # parameters
        ("kp", "<f8"),  # N·m/rad
        ("kv", "<f8"),  # N·m·s/rad
        ("fv", "<f8"),  # Hz
        ("bias_tau", "<f8"),  # s
        # precomputed
        ("sampling_period", "<f8"),  # s, T
        ("inv_period", "<f8"),  # 1/s
        ("lpfv1", "<f8"),  # T·2π·fv
        ("lpfv2", "<f8"),  # 1/(1 + lpfv1)
        ("bias_decay", "<f8"),  # exp(-T/bias_tau)
        # state
        ("error", "<f8"),  # rad, last error (raw)
        ("old_position", "<f8"),  # rad
        ("old_velocity", "<f8"),  # rad/s, filtered
        ("bias", "<f8"),  # N·m, hand-over torque still to fade out
        ("primed", "<u4"),  # 0 after init
    ],
    align=True,
)

# a robot-level servo's per-joint arrays are MAX_JOINTS long; a robot uses its n
CT_DTYPE = np.dtype(
    [
        ("wn", "<f8"),
        ("zeta", "<f8"),
        ("friction", "<f8"),
        ("handover_s", "<f8"),
        ("kp", "<f8"),  # ω_n², 1/s²
        ("kd", "<f8"),  # 2 ζ ω_n, 1/s
        ("wi", "<f8"),
        ("ilimit", "<f8"),
        ("ki", "<f8"),  # ω_i ω_n², 1/s³
        ("dt", "<f8"),
        ("decay", "<f8"),
        ("bias", "<f8", (MAX_JOINTS,)),
        ("integral", "<f8", (MAX_JOINTS,)),  # ∫e per joint, rad·s
    ],
    align=True,
)

IMPEDANCE_DTYPE = np.dtype(
    [
        ("k", "<f8", (WRENCH,)),  # tool axes: N/m, then N·m/rad
        ("d", "<f8", (WRENCH,)),
        ("f", "<f8", (WRENCH,)),  # force set-point, tool axes (moments 0)
        ("integral", "<f8", (WRENCH,)),  # the force feedback's integral, tool axes
        ("limit", "<f8", (WRENCH,)),  # its limit per axis
        ("band", "<f8", (WRENCH,)),  # it advances only while the imbalance is within
        ("partner", "<f8"),  # the other arm's index + 1, 0: no squeeze
        ("fi", "<f8"),  # the squeeze, N
        ("u", "<f8", (3,)),  # the line towards the partner, tool axes, unit
        ("kpi", "<f8"),
        ("kii", "<f8"),
        ("squeeze", "<f8"),  # the squeeze both sensors measure, N (this tick's)
        ("gi", "<f8"),  # its integral, N
        ("kf", "<f8"),
        ("kfi", "<f8"),
        ("imax", "<f8"),
        ("kq", "<f8"),
        ("cband", "<f8"),
        ("ctau", "<f8"),
        ("cdecay", "<f8"),  # exp(-dt / ctau): the drive's low-pass per tick
        ("friction", "<f8"),
        ("handover_s", "<f8"),
        ("dt", "<f8"),
        ("decay", "<f8"),
        ("bias", "<f8", (MAX_JOINTS,)),
        ("drive", "<f8", (MAX_JOINTS,)),  # the drive Coulomb compensation follows, low-passed, N·m
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# Feed-forward dynamics (DESIGN 1, thesis 3.3.6, 2.2.3): the dynamics process computes, for
# each set-point in a robot's TG → SIO FIFO, the joint torque that the demanded motion needs
# (gravity, or the full inverse dynamics); SIO interpolates them exactly as it interpolates
# the set-points and adds them to the servo torques.  Rows are keyed by the set-point's
# absolute FIFO index, so feed-forward and demand stay aligned whatever the dynamics
# process's own timing.

KEY_FEEDFORWARD = "dyn.ff"  # FEEDFORWARD per robot, config order
KEY_LOADS = "robots.loads"  # LOAD per robot, config order
FF_ROWS = 512  # rows per robot: every set-point a full FIFO holds, and the two being used
FF_NO_KEY = 0xFFFFFFFFFFFFFFFF  # ``key`` of a row not (or being) written
# A row's key is 1 + the FIFO index of its set-point: the set-point SIO holds before any was
# pushed has index -1.  Row of key k: k % FF_ROWS.


class FfMode(enum.IntEnum):
    """What feed-forward a robot gets (``kalictl ff on|off|gravity ROBOT``)."""

    OFF = 0
    GRAVITY = 1  # g(q) at the demanded position
    FULL = 2  # inverse dynamics of the demanded trajectory: M q̈ + C q̇ + g + friction


class FfState(enum.IntEnum):
    """What SIO does with a robot's feed-forward, tick by tick."""

    OFF = 0  # not asked for (or fading out after being switched off)
    ON = 1  # applied
    STALE = 2  # asked for, but the dynamics process is silent or behind: dropped


FEEDFORWARD = np.dtype(
    [
        ("mode", "u1"),  # clients: FfMode wanted
        ("state", "u1"),  # SIO: FfState
        ("computed_mode", "u1"),  # dynamics: FfMode its rows were computed in
        ("_pad", "u1", (5,)),
        ("heartbeat_tick", "<i8"),  # dynamics: wall-clock tick of its last cycle
        ("rows_written", "<u8"),  # dynamics: rows computed since start
        ("stale_ticks", "<u8"),  # SIO: servo ticks the feed-forward was dropped as stale
        ("stale_events", "<u4"),  # SIO: times it went stale
        ("_pad2", "<u4"),
        ("weight", "<f8"),  # SIO: 0..1, ramps so switching on or off gives no torque step
        ("key", "<u8", (FF_ROWS,)),  # dynamics: whose row it is, FF_NO_KEY while written
        # dynamics: the demanded position the row is for, rad (the robot's n_joints used)
        ("q", "<f8", (FF_ROWS, MAX_JOINTS)),
        ("tau", "<f8", (FF_ROWS, MAX_JOINTS)),  # dynamics: feed-forward torque there, N·m
        ("qd", "<f8", (FF_ROWS, MAX_JOINTS)),  # dynamics: the demand's velocity there, rad/s
        ("qdd", "<f8", (FF_ROWS, MAX_JOINTS)),  # dynamics: its acceleration, rad/s²
    ],
    align=True,
)

# What an arm holds beyond its configured tool (libfranka's setLoad; robots.payload): the
# program moving the arm writes it whole (a seqlock: ``seq`` odd while it writes), the
# dynamics process's feed-forward and the robot-level servos' model carry it.
LOAD = np.dtype(
    [
        ("seq", "<u4"),  # writer: odd while it writes the rest, even when whole
        ("held", "<i4"),  # the scene object it is: its index in the scene's objects + 1 (0: none)
        ("mass", "<f8"),  # kg
        ("com", "<f8", (3,)),  # its centre of mass, flange frame, m
        ("inertia", "<f8", (3, 3)),  # about the centre of mass, flange axes, kg·m²
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# Trajectory generator (DESIGN 5, thesis 3.3.1, 3.3.2): the Type 1 queue of motion requests
# from user programs, the status of each request, and the TG's view of each robot.

MAX_ROBOTS = 4  # arms in one cell (config.MAX_ROBOTS)
MAX_SEGMENTS = 16  # straight-line segments in one Cartesian path request
# The cell as ``kalictl start`` found it (writer: kalictl start; readers: every tool), so the
# safety path (estop, status, stop, reset, enable/disable) needs nothing but the arena: no
# config file, no import of a robot type's or a plugin's code.
ROBOT_NAME_BYTES = 16  # config: [a-z][a-z0-9_]{0,15}
TYPE_NAME_BYTES = 32  # a robot type's name, for messages (cut if longer)
CELL_ROBOT = np.dtype(
    [
        ("name", f"S{ROBOT_NAME_BYTES}"),
        ("model", f"S{TYPE_NAME_BYTES}"),  # its robot type's name
        ("hardware", f"S{TYPE_NAME_BYTES}"),  # its hardware kind's name (hardware.registry)
        ("hardware_version", "<u4"),  # that kind's records' digest (dtypes_digest)
        ("n_joints", "<u4"),
        ("first_joint", "<u4"),  # flat index of its joint 1 (joints.JointMap)
        ("rad_per_count", "<f8", (MAX_JOINTS,)),  # an encoder count at the joint, rad
        ("max_current", "<f8", (MAX_JOINTS,)),  # the motors' current limits, A
    ],
    align=True,
)
CELL = np.dtype(
    [
        ("n_robots", "<u4"),
        ("n_svs", "<u4"),  # servo workers sv.0 .. sv.<n_svs - 1>
        ("robots", CELL_ROBOT, (MAX_ROBOTS,)),
    ],
    align=True,
)

MOTION_QUEUE_CAPACITY = 64  # requests waiting for the TG
MOTION_QUEUE_SHARE = 16  # of them, unread entries one program (client_pid) may hold
# Stops and aborts have a lane of their own the TG empties first every tick (``tg.stops``):
# they never wait behind other requests.
STOP_QUEUE_CAPACITY = 32
STOP_QUEUE_SHARE = 4
STATUS_RING = 512  # request status records (tg.records: the TG gives each request one)
STATUS_SHARE = 64  # unread outcomes one program keeps: beyond, its oldest gives way (LOST)
LIVE_SHARE = 64  # requests one program may have queued or running in the TG: more refused
KEY_MOTION_QUEUE = "tg.requests"
KEY_STOP_QUEUE = "tg.stops"
KEY_MOTION_STATUS = "tg.status"
KEY_TG_ROBOTS = "tg.robots"
KEY_TG_STATE = "tg.state"
KEY_TG_LEASES = "tg.leases"
KEY_TG_FRAMES = "tg.frames"
KEY_TG_FUNCTIONS = "tg.functions"
PROGRAM_BYTES = 24  # a client's program name in its requests and leases

# A request's ``flags``.
REQUEST_FORCE = 1 << 0  # take the arms over from the program that owns them (kalictl --force)
REQUEST_UNWATCHED = 1 << 1  # nobody reads the outcome: its status record is free once it ends
# start only once the motion before it on its arms has ended at rest; without it, a JOINTS or
# PATH request queued behind one of the same kind on the same arms continues it without a stop
# (thesis 3.1: the transition between one request's last segment and the next one's first)
REQUEST_STOP_BETWEEN = 1 << 2


class MotionKind(enum.IntEnum):
    """What a motion request asks of the TG."""

    JOINTS = 1  # a smooth joint move of every robot in ``robots`` to ``joints``
    PATH = 2  # straight lines of the control frame through ``poses``, blended
    STOP = 3  # decelerate the motions of ``robots`` to rest on their paths
    ABORT = 4  # drop the motions of ``robots`` at once (the arms hold where the set-point is)
    # follow the control frame's target, the product of the transforms ``loop`` names
    # (fixed ones in ``poses``, shared ones in ``tg.frames``), evaluated every TG tick,
    # within the speed and acceleration limits, until stopped (or ``track_s`` has passed)
    TRACK = 5
    # follow the joint targets a program streams into the shared record ``loop[0]`` (one
    # robot), within ``speed_scale`` of its joint speed and acceleration limits, until stopped
    TRACK_JOINTS = 6


class RequestState(enum.IntEnum):
    """A request's life, written by the TG into its status record; printed by name (a
    program's ``print(handle.state)`` says DONE, not 3)."""

    def __str__(self) -> str:
        return self.name

    FREE = 0
    QUEUED = 1  # accepted by the TG, waiting for its robots to finish earlier motions
    RUNNING = 2
    DONE = 3  # arrived
    REFUSED = 4  # nothing moved: the message says why
    STOPPED = 5  # stopped on request, at rest on the path
    ABORTED = 6
    HALTED = 7  # the system halted: the message is the fault
    LOST = 8  # client only, never written: the status record now holds a later request
    CONTACT = 9  # a guarded motion touched: held where its guard tripped (contact_* say where)


TERMINAL_STATES = (
    RequestState.DONE,
    RequestState.REFUSED,
    RequestState.STOPPED,
    RequestState.ABORTED,
    RequestState.HALTED,
    RequestState.LOST,
    RequestState.CONTACT,
)

# A PATH request's configuration per robot: CONFIG_GIVEN set means the low bits are the
# index, in its robot type's ``kinematics.configs``, of the inverse-kinematics branch the arm
# must be in; 0 means "the one it is in".
CONFIG_GIVEN = 1 << 7

# Position equations (thesis 3.2.3, RCCL): a TRACK request's target is the product of up to
# MAX_LOOP transforms, each fixed (one of the request's ``poses``) or shared (a record of
# ``tg.frames`` that programs write while the motion runs).
MAX_LOOP = 8
MAX_FRAMES = 16  # shared transforms in one cell
FRAME_NAME_BYTES = 32


class FrameKind(enum.IntEnum):
    """What a factor of a TRACK request's loop is (``MOTION_REQUEST.loop[i, 0]``)."""

    FIXED = 1  # ``poses[index]`` of the request
    SHARED = 2  # ``tg.frames[index]``, read every TG tick
    FUNCTION = 3  # ``tg.functions[index]``, evaluated by the TG every tick


# A shared transform (thesis 3.2.3 "objects and functions", Type 4 record): one program
# writes it, whole or not at all (a seqlock: ``seq`` odd while it writes, even when whole),
# whenever it likes; the TG reads it every tick without waiting.  A motion tracking it stops
# on its path once it is older than ``lifetime_s`` (libfranka's and MoveIt Servo's
# stale-command rule), or holds a value that is not finite or not a rigid motion.
SHARED_FRAME = np.dtype(
    [
        ("seq", "<u4"),  # writer: odd while it writes the rest, even when whole
        ("owner_pid", "<i4"),  # the program writing it (0: free); claimed by compare-and-swap
        ("name", f"S{FRAME_NAME_BYTES}"),  # the owner's name for it
        ("stamp_tick", "<i8"),  # wall clock tick of the last write (simulated in lockstep)
        ("lifetime_s", "<f8"),  # older than this it is stale (0: never)
        ("writes", "<u8"),  # writes since claimed (0: nothing to read yet)
        ("pose", "<f8", (4, 4)),  # the transform (a pose stream's target), world or parent
        ("joints", "<f8", (MAX_JOINTS,)),  # a joint stream's targets, rad
    ],
    align=True,
)

# A TG function in use (thesis 3.2.3 "functions"; ``tg.functions``): a transform the TG
# computes every tick by a registered function (``tg.functions``: built-ins and the config's
# ``tg_functions`` plugins) from the time, the sensors and its private data, here.  A program
# claims a slot, sets its parameters (``seq`` odd while it writes them, the TG skips the slot
# then) and names it in a TRACK loop.
MAX_FUNCTIONS = 16
FUNCTION_DATA_BYTES = 256
TG_FUNCTION = np.dtype(
    [
        ("seq", "<u4"),  # the program: odd while it changes the parameters
        ("owner_pid", "<i4"),  # the program using it (0: free); claimed by compare-and-swap
        ("name", f"S{FRAME_NAME_BYTES}"),  # the program's name for it
        ("algo", "<u2"),  # 1 + the function's index in the TG's registry (0: none)
        ("status", "u1"),  # TG: FunctionStatus
        ("_pad", "u1"),
        ("function", f"S{FRAME_NAME_BYTES}"),  # TG: its registry name, once a motion used it
        ("evaluations", "<u4"),  # TG: times evaluated
        # TG: evaluations longer than its budget (functions.FUNCTION_SHARE of the TG period);
        # in real time the first holds its motions (TOO_LONG), in lockstep none does
        ("over_budget", "<u4"),
        ("start_tick", "<i8"),  # its time t counts from this wall clock tick
        ("last_ns", "<i8"),  # TG: how long its last evaluation took
        ("worst_ns", "<i8"),  # TG: its longest evaluation
        ("data", "u1", (FUNCTION_DATA_BYTES,)),  # its private data (its own dtype)
    ],
    align=True,
)


class FunctionStatus(enum.IntEnum):
    """What became of a TG function (``TG_FUNCTION.status``), written by the TG."""

    IDLE = 0
    RUNNING = 1
    RAISED = 2  # it raised: every motion using it was held
    TOO_LONG = 3  # an evaluation outlasted its budget (real time): every motion using it was held


MOTION_REQUEST = np.dtype(
    [
        ("kind", "u1"),  # MotionKind
        ("n_robots", "u1"),  # robots in the motion system
        ("n_segments", "u1"),  # PATH: poses used
        ("flags", "u1"),  # REQUEST_* bits
        ("robots", "u1", (MAX_ROBOTS,)),  # robot indices (config order)
        ("config", "u1", (MAX_ROBOTS,)),  # PATH: CONFIG_* bits per robot; 0 = the arm's own
        ("client_pid", "<i4"),  # the program asking: it owns the arms (lease) and the outcome
        # FAULT ``count`` when the client put it: a fault raised since halts the request, one
        # cleared before it does not (the TG judges it by the state it finds)
        ("fault_epoch", "<u8"),
        ("client_name", f"S{PROGRAM_BYTES}"),  # the program's name, for refusals and leases
        ("joints", "<f8", (MAX_ROBOTS, MAX_JOINTS)),  # JOINTS: targets, rad (n_joints used)
        ("speed_scale", "<f8"),  # JOINTS: fraction (0, 1] of the joint speed/accel limits
        ("poses", "<f8", (MAX_SEGMENTS, 4, 4)),  # PATH: control-frame targets, world frame
        ("grasps", "<f8", (MAX_ROBOTS, 4, 4)),  # PATH: each arm's flange in the control frame
        ("speed", "<f8"),  # PATH: m/s
        ("angular_speed", "<f8"),  # PATH: rad/s
        ("transition_s", "<f8"),  # PATH: blend time at each via point
        ("durations", "<f8", (MAX_SEGMENTS,)),  # PATH: each segment's time, s (0: by speed)
        ("arcs", "u1", (MAX_SEGMENTS,)),  # PATH: 1 = segment i is an arc through arc_via[i]
        ("arc_via", "<f8", (MAX_SEGMENTS, 3)),  # PATH: a point each arc passes, world, m
        ("guard_n", "<f8"),  # JOINTS, PATH: stop at this contact force on any arm, N (0: none)
        ("n_loop", "u1"),  # TRACK: factors in ``loop``; TRACK_JOINTS: 1
        ("loop", "u1", (MAX_LOOP, 2)),  # TRACK: factor i is (FrameKind, index)
        ("accel", "<f8"),  # TRACK: m/s², the control frame's linear acceleration limit
        ("angular_accel", "<f8"),  # TRACK: rad/s²
        ("track_s", "<f8"),  # TRACK, TRACK_JOINTS: ends (at rest) after this long; 0: stop()
        # motions started together (``Kali.together``): ``group_size`` requests of one
        # program share ``group`` (its pid << 32 | a count; 0: none) and start on one TG tick
        ("group", "<u8"),
        ("group_size", "u1"),
    ],
    align=True,
)

# A request of the stop lane (``tg.stops``): a stop or an abort of some robots, which the TG
# carries out before any request of ``tg.requests`` (MOTION_REQUEST's fields of the same name).
STOP_REQUEST = np.dtype(
    [
        ("kind", "u1"),  # MotionKind.STOP or ABORT
        ("n_robots", "u1"),
        ("flags", "u1"),  # REQUEST_* bits (FORCE)
        ("robots", "u1", (MAX_ROBOTS,)),
        ("client_pid", "<i4"),
        ("client_name", f"S{PROGRAM_BYTES}"),
        ("fault_epoch", "<u8"),
        # its robots' requests put in ``tg.requests`` before this seq are cancelled too (they
        # would otherwise start after the stop that jumped them)
        ("before_seq", "<u8"),
    ],
    align=True,
)

REQUEST_STATUS = np.dtype(
    [
        ("seq", "<u8"),  # the request this record is about (0: none yet)
        ("state", "u1"),  # RequestState
        # the owning client, once it has seen the final state (or dropped its handle): the TG
        # may give the record to another request (tg/records.py says when before that)
        ("read", "u1"),
        ("contact_robot", "u1"),  # TG, CONTACT: the robot whose guard tripped (config index)
        ("_pad", "u1"),
        ("client_pid", "<i4"),  # TG: the request's client_pid
        ("duration_s", "<f8"),  # planned duration once running
        ("progress", "<f8"),  # path time / duration, 0..1
        ("message", f"S{MESSAGE_BYTES}"),  # why refused, stopped or halted
        ("contact_xyz", "<f8", (3,)),  # TG, CONTACT: that robot's tool point then, world, m
        ("contact_force", "<f8"),  # TG, CONTACT: the contact force that tripped it, N
        ("contact_wrench", "<f8", (WRENCH,)),  # TG, CONTACT: its contact wrench then, world
        # TG, TRACK*: ticks its target moved faster than the limits allow (rate-limited)
        ("limited", "<u8"),
    ],
    align=True,
)

TG_ROBOT = np.dtype(
    [
        ("busy_seq", "<u8"),  # TG: the request moving this robot (0: idle)
        ("setpoint", "<f8", (MAX_JOINTS,)),  # TG: the last joint set-point pushed, rad
        ("t6", "<f8", (4, 4)),  # TG: T6 of that set-point, base frame
        ("tick", "<i8"),  # TG: last TG tick
        ("stop_seq", "<u8"),  # TG: the last stop-lane request carried out on this robot
    ],
    align=True,
)

TG_STATE = np.dtype(
    [
        ("taken_seq", "<u8"),  # TG: the last request taken from the queue
        # TG: ticks the next request waited in the queue for its status record (unread by a
        # live client): admission is bounded, the queue pushes back on producers
        ("record_waits", "<u8"),
        # TG: its longest tick since start, wall time from its start to its end, and what
        # went into it: taking requests, starting waiting ones (planning paths), the motions
        # (their checks and set-points), its CPU time, and the requests it took then; a
        # serious miss of the TG (DEADLINE) can then be put down to its own work or not
        ("longest_tick", "<i8"),
        ("longest_ns", "<i8"),
        ("longest_take_ns", "<i8"),
        ("longest_start_ns", "<i8"),
        ("longest_motions_ns", "<i8"),
        ("longest_cpu_ns", "<i8"),
        ("longest_requests", "<u4"),
        ("longest_motions", "<u4"),
        # TG: where it is now (TgPhase), since when (CLOCK_MONOTONIC ns) and about which
        # request: a reader at a halt sees a tick that never ended, which ``longest_*`` cannot
        ("phase", "<u4"),
        ("phase_seq", "<u4"),  # the request (low 32 bits of its seq) being worked on
        ("phase_ns", "<i8"),
        # TG: the request taken from the queue that waits for a status record because every
        # record holds a request queued or running (0: none), and since which tick
        ("blocked_seq", "<u8"),
        ("blocked_tick", "<i8"),
        ("evicted", "<u8"),  # TG: unread outcomes that gave way (their handles read LOST)
        ("stops_taken", "<u8"),  # TG: stop-lane requests carried out
        ("stops_refused", "<u8"),  # TG: stop-lane requests refused (an arm owned by another)
        # TG: 1 + the ``tg.functions`` slot whose function it is evaluating now (0: none), so
        # a halt for a TG that does not acknowledge names the function it is stuck in
        ("phase_function", "<i4"),
    ],
    align=True,
)


class TgPhase(enum.IntEnum):
    """What the TG is doing (``TG_STATE.phase``)."""

    IDLE = 0  # between ticks
    REQUESTS = 1  # taking requests from the queue
    STARTING = 2  # starting waiting ones (planning a path)
    CHECKING = 3  # checking a path before it moves
    ADVANCING = 4  # a motion's next set-point
    ENDING = 5  # a motion's end


# A motion system's arms belong to one program at a time (like ros2_control's claimed command
# interfaces): the TG gives an arm to the first live program that requests it and refuses the
# others, naming the owner, until the owner's pid is dead or a request with REQUEST_FORCE
# takes it over.  Writer: the TG.  Readers: clients, kalictl.
LEASE = np.dtype(
    [
        ("pid", "<i4"),  # the owning program (0: none)
        ("_pad", "<i4"),
        ("tick", "<i8"),  # TG tick it was claimed
        ("name", f"S{PROGRAM_BYTES}"),  # the owner's program name
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# Flight recorder (DESIGN 7, 8): the last FLIGHT_SECONDS of every servo tick — demands,
# positions, torques, currents and SIO's timing — in a ring SIO writes inside its cycle, so a
# halt can be examined after the fact.  The wall clock dumps the ring to a file in the
# instance's log directory once per fault, after it has stopped (``flightrec.py``).

KEY_FLIGHT = "flight"  # FLIGHT header
KEY_FLIGHT_RING = "flight.ring"  # flight_row(n_joints, n_robots) × FLIGHT header ``rows``
FLIGHT_SECONDS = 2.0  # servo time the ring holds
FLIGHT_PATH_BYTES = 256
FLIGHT_FIELDS = (
    "q", "qd", "demand", "demand_qd", "servo_torque", "ff_torque", "torque", "current",
    "shadow_torque",
)  # fmt: skip


def flight_rows(servo_period_ns: int) -> int:
    """Rows of the ring: FLIGHT_SECONDS of servo ticks (4000 at 0.5 ms, 2000 at 1 ms)."""
    return max(2, -(-int(FLIGHT_SECONDS * 1e9) // servo_period_ns))


def flight_row(n_joints: int, n_robots: int) -> np.dtype:
    """One servo tick in the ring: SIO's flat per-joint arrays (joints.JointMap order) and
    each robot's wrist wrench (zeros for an arm without a sensor)."""
    n = (n_joints,)
    return np.dtype(
        [
            ("tick", "<i8"),  # wall-clock tick of the servo cycle
            ("t_ns", "<i8"),  # CLOCK_MONOTONIC when SIO read the encoders
            ("latency_ns", "<i8"),  # encoder read to DAC write (SERVO_CTRL latency)
            ("late_ns", "<i8"),  # SIO's wake-up lateness: encoder read − the tick's due time
            ("wait_ns", "<i8"),  # of latency_ns, SIO asleep for the servos: feeds to done
            ("ran_ns", "<i8"),  # SIO's CPU time from the read to the write (rt.thread_time_ns)
            ("q", "<f8", n),  # measured joint angles, rad
            ("qd", "<f8", n),  # their velocity from the encoders, rad/s
            ("demand", "<f8", n),  # interpolated set-points, rad
            ("demand_qd", "<f8", n),  # the set-points' velocity, rad/s
            ("servo_torque", "<f8", n),  # what the servos asked for, N·m
            ("ff_torque", "<f8", n),  # feed-forward added, N·m
            ("torque", "<f8", n),  # torque sent (after the current clamp), N·m
            ("current", "<f8", n),  # motor current commanded, A
            # a shadow trial's torque, never applied (SERVO_SLOT.shadow_torque; NaN: none ran),
            # N·m; single precision (its figures are the SV's, in double): a 2 kHz ring of 13
            # joints then still fits the default 4 MiB arena
            ("shadow_torque", "<f4", n),
            # the contact wrench at the tool point, tool axes (FT_STATE.tool), N and N·m
            ("wrench", "<f8", (n_robots, WRENCH)),
        ],
        align=True,
    )


FLIGHT = np.dtype(
    [
        ("rows", "<u4"),  # SIO: ring capacity
        ("n_joints", "<u4"),  # SIO: values per field per row
        ("servo_period_ns", "<i8"),  # SIO
        ("count", "<u8"),  # SIO: rows written since start; row i is at i % rows
        ("dumps", "<u4"),  # wall clock: dump files written
        ("n_robots", "<u4"),  # SIO: wrenches per row
        ("dumped_fault_ns", "<i8"),  # wall clock: FAULT time_ns of the fault last dumped
        ("dump_tick", "<i8"),  # wall clock: fault tick of the last dump
        ("dump_path", f"S{FLIGHT_PATH_BYTES}"),  # wall clock: the last dump file
        ("dump_message", f"S{MESSAGE_BYTES}"),  # wall clock: what the last dump did, or why not
    ],
    align=True,
)


# --------------------------------------------------------------------------------------------
# The layout itself (after iceoryx): every record of the arena in one
# declarative list, allocated by ``kalictl start`` before any process starts (then the arena is
# sealed: a daemon attaches to what is here and cannot add a block), and the layout's version
# as a digest of every dtype, so a changed record can never keep an old version number.

HARDWARE_KEYS = "hw."  # every hardware kind's records are keyed hw.<kind>.<record>
FIFO_CAPACITY = 256  # TG set-points a TG → SIO FIFO holds (2.56 s at 10 ms)


@dataclass(frozen=True)
class Cell:
    """What the arena's layout depends on: the arms, the servo algorithms and the config."""

    robots: tuple[str, ...]  # robot names, config order
    joints: tuple[int, ...]  # each robot's joint count
    flight_rows: int  # servo ticks the flight recorder holds (``flight_rows``)
    algorithms: tuple[np.dtype, ...]  # each servo algorithm's private data, registry order
    config_bytes: int  # the config text's UTF-8 bytes
    config_dir_bytes: int  # its directory's
    arms: tuple[np.dtype, ...] = ()  # each robot-level servo's private data, registry order
    config_files_bytes: int = 0  # the path of the instance's copies of its user files
    hardware: tuple[Record, ...] = ()  # the records of the cell's hardware kinds (HARDWARE_KEYS)
    objects: int = 0  # the scene's free objects (robots.scene)
    cameras: tuple[int, ...] = ()  # each scene camera's pixels, the scene's order

    @property
    def n_joints(self) -> int:
        """Joints of the cell (every per-joint record has this many)."""
        return sum(self.joints)


# A record's dtype and count: fixed, or computed from the cell and the record's index (the
# robot for a ``{robot}`` key, the algorithm for an ``{algo}`` key, else None).
Sized = Callable[[Cell, Any], int]
Typed = Callable[[Cell, Any], np.dtype]


@dataclass(frozen=True)
class Record:
    """One entry of the layout: ``count`` records of ``dtype`` (None: one, viewed 0-d) at
    ``key``; ``writer`` and ``readers`` say who touches it (a field may name its own writer)."""

    key: str
    dtype: np.dtype | Typed
    count: int | Sized | None
    writer: str
    readers: str


def _u1(n: Sized) -> tuple[Typed, Sized]:
    return (lambda c, i: np.dtype("u1")), n


RECORDS: tuple[Record, ...] = (
    Record(KEY_CLOCK, CLOCK, None, "wallclock (commands: kalictl, clients)", "all"),
    Record(KEY_PROCESSES, PROCESS, MAX_PROCESSES, "each slot's owner; the wallclock", "all"),
    Record(KEY_FAULT, FAULT, None, "whoever halts (one CAS wins)", "all"),
    Record(KEY_MISSES, MISS_LOG, None, "wallclock", "kalictl status, benchmarks"),
    Record(KEY_DASHBOARD, DASHBOARD, None, "viewer (record: kalictl start)", "kalictl view"),
    Record(KEY_CONFIG, *_u1(lambda c, i: c.config_bytes + 1), "kalictl start", "all"),
    Record(KEY_CONFIG_DIR, *_u1(lambda c, i: c.config_dir_bytes + 1), "kalictl start", "all"),
    Record(KEY_CONFIG_FILES, *_u1(lambda c, i: c.config_files_bytes + 1), "kalictl start", "all"),
    Record(KEY_CELL, CELL, None, "kalictl start", "kalictl, introspection"),
    # the simulated plant's truth
    Record(KEY_TRUTHS, ARM_TRUTH, lambda c, i: len(c.robots), "plant", "tests, viewer"),
    Record(KEY_JOINT_TRUTHS, JOINT_TRUTH, lambda c, i: c.n_joints, "plant", "tests"),
    Record(KEY_WORLD_TRUTH, WORLD_TRUTH, None, "plant", "viewer, tests"),
    Record(KEY_OBJECT_TRUTHS, OBJECT_TRUTH, lambda c, i: c.objects, "plant", "viewer, tests"),
    Record(KEY_CAMERAS, CAMERA, lambda c, i: len(c.cameras), "camera", "clients, viewer"),
    Record(
        KEY_CAMERA_FRAMES,
        *_u1(lambda c, i: sum(CAMERA_BUFFERS * camera_bytes(n) for n in c.cameras)),
        "camera",
        "clients, viewer",
    ),
    Record(KEY_PUSHES, PUSH, lambda c, i: len(c.robots), "kalictl push", "the plant"),
    # the servo level
    Record(KEY_ROBOTS, ROBOT_STATE, lambda c, i: len(c.robots), "SIO (commands: clients)", "all"),
    Record(KEY_JOINTS, JOINT_STATE, lambda c, i: c.n_joints, "SIO (limits: clients)", "all"),
    Record(KEY_FT, FT_STATE, lambda c, i: len(c.robots), "SIO (tare, limit: clients)", "all"),
    Record(KEY_SLOTS, SERVO_SLOT, lambda c, i: c.n_joints, "SIO, SVs, clients", "SIO, SVs"),
    Record(KEY_SERVO_CTRL, SERVO_CTRL, None, "SIO, SVs", "all"),
    Record(
        KEY_SERVO_NAMES,
        SERVO_NAME,
        lambda c, i: len(c.algorithms) + len(c.arms),
        "SIO",
        "kalictl status, top",
    ),
    Record(
        KEY_STAGING,
        *_u1(lambda c, i: c.n_joints * SERVO_STAGING_BYTES),
        "clients, SVs",
        "SVs, clients",
    ),
    Record(
        KEY_SERVO_DATA,
        lambda c, a: c.algorithms[a],
        lambda c, a: c.n_joints,
        "SVs (put: mailbox)",
        "SVs",
    ),
    Record(KEY_SERVO_LOADS, SERVO_LOADS, None, "loading clients; SVs (taken)", "all"),
    Record(
        KEY_ARM_STAGING,
        *_u1(lambda c, i: len(c.robots) * SERVO_STAGING_BYTES),
        "clients, SVs",
        "SVs, clients",
    ),
    Record(
        KEY_ARM_DATA,
        lambda c, a: c.arms[a],
        lambda c, a: len(c.robots),
        "SVs (put: mailbox)",
        "SVs",
    ),
    Record(KEY_FEEDFORWARD, FEEDFORWARD, lambda c, i: len(c.robots), "dynamics, SIO", "SIO"),
    Record(KEY_LOADS, LOAD, lambda c, i: len(c.robots), "the arm's program", "dynamics, SVs"),
    Record(KEY_FLIGHT, FLIGHT, None, "SIO, the wallclock (dumps)", "kalictl flight"),
    Record(
        KEY_FLIGHT_RING,
        lambda c, i: flight_row(c.n_joints, len(c.robots)),
        lambda c, i: c.flight_rows,
        "SIO",
        "the wallclock",
    ),
    # TG → SIO set-points, one FIFO per robot (channels.InterpolatingFifo)
    Record(KEY_FIFO, FIFO_HEADER, None, "TG (push), SIO (take)", "TG, SIO, dynamics"),
    Record(
        KEY_FIFO + ".ring",
        np.dtype("<f8"),
        lambda c, k: FIFO_CAPACITY * c.joints[k],
        "TG",
        "SIO, dynamics",
    ),
    Record(KEY_FIFO + ".ratios", np.dtype("<u8"), FIFO_CAPACITY, "TG", "SIO, dynamics"),
    # each set-point's 1 if its motion stops there (its last), for the dynamics process
    Record(KEY_FIFO + ".rests", np.dtype("u1"), FIFO_CAPACITY, "TG", "dynamics"),
    Record(KEY_FIFO + ".state", np.dtype("<f8"), lambda c, k: 3 * c.joints[k], "SIO", "SIO"),
    Record(KEY_FIFO + ".hold", np.dtype("<f8"), lambda c, k: c.joints[k], "SIO", "dynamics"),
    # motion requests (channels.RequestQueue) and the TG's records
    Record(KEY_MOTION_QUEUE, QUEUE_HEADER, None, "clients (tail), TG (head)", "clients, TG"),
    Record(
        KEY_MOTION_QUEUE + ".slots",
        queue_entry(MOTION_REQUEST),
        MOTION_QUEUE_CAPACITY,
        "clients",
        "TG",
    ),
    Record(KEY_STOP_QUEUE, QUEUE_HEADER, None, "clients (tail), TG (head)", "clients, TG"),
    Record(
        KEY_STOP_QUEUE + ".slots",
        queue_entry(STOP_REQUEST),
        STOP_QUEUE_CAPACITY,
        "clients",
        "TG",
    ),
    Record(KEY_MOTION_STATUS, REQUEST_STATUS, STATUS_RING, "TG (read: clients)", "clients"),
    Record(KEY_TG_ROBOTS, TG_ROBOT, lambda c, i: len(c.robots), "TG", "clients, viewer"),
    Record(KEY_TG_STATE, TG_STATE, None, "TG", "kalictl status"),
    Record(KEY_TG_LEASES, LEASE, lambda c, i: len(c.robots), "TG", "clients, kalictl"),
    Record(KEY_TG_FRAMES, SHARED_FRAME, MAX_FRAMES, "clients (each its own)", "TG"),
    Record(KEY_TG_FUNCTIONS, TG_FUNCTION, MAX_FUNCTIONS, "clients (params), TG (state)", "TG"),
)


@dataclass(frozen=True)
class Block:
    """One record of the layout for one cell: its key, dtype and count, and the entry."""

    key: str
    dtype: np.dtype
    count: int | None
    record: Record

    @property
    def nbytes(self) -> int:
        """Bytes asked of the arena (before rounding up to ALIGN)."""
        return self.dtype.itemsize * (1 if self.count is None else self.count)


def blocks(cell: Cell) -> list[Block]:
    """Every block of ``cell``'s arena, in ``RECORDS`` order then its hardware's: a
    ``{robot}`` key once per robot, an ``{algo}`` key once per servo algorithm; a record
    counted zero (a scene without free objects) has none (``Arena.record`` views it empty)."""
    out: list[Block] = []
    for rec in (*RECORDS, *cell.hardware):
        at: list[tuple[str, int | None]]  # each block's key and index
        if "{robot}" in rec.key:
            at = [(rec.key.format(robot=name), k) for k, name in enumerate(cell.robots)]
        elif "{algo}" in rec.key:
            at = [(rec.key.format(algo=a), a) for a in range(len(cell.algorithms))]
        elif "{arm}" in rec.key:
            at = [(rec.key.format(arm=a), a) for a in range(len(cell.arms))]
        else:
            at = [(rec.key, None)]
        for key, index in at:
            dtype = rec.dtype if isinstance(rec.dtype, np.dtype) else rec.dtype(cell, index)
            count = rec.count(cell, index) if callable(rec.count) else rec.count
            if count != 0:
                out.append(Block(key, dtype, count, rec))
    return out


def _key_pattern(template: str) -> str:
    return (
        re.escape(template)
        .replace(r"\{robot\}", r"[^.]+")
        .replace(r"\{algo\}", r"\d+")
        .replace(r"\{arm\}", r"\d+")
    )


_LAYOUT_KEYS = re.compile("|".join(f"(?:{_key_pattern(r.key)})" for r in RECORDS))


def is_layout_key(key: str) -> bool:
    """Whether ``key`` names a record of ``RECORDS`` (for some robot, slot or algorithm) or of
    a hardware kind (``HARDWARE_KEYS``): once the arena is sealed no such block may be
    created; a program's own blocks may."""
    return key.startswith(HARDWARE_KEYS) or _LAYOUT_KEYS.fullmatch(key) is not None


def dtypes_digest(shapes: Sequence[tuple[str, Any]]) -> int:
    """32 bits of a BLAKE2b digest of named dtypes' shapes (names, types, shapes and offsets
    of every field): a record's version, which no change to it can keep."""
    text = repr(
        [(name, d.descr if isinstance(d, np.dtype) and d.names else d) for name, d in shapes]
    )
    return int.from_bytes(hashlib.blake2b(text.encode(), digest_size=4).digest(), "little")


def _digest() -> int:
    """The layout's version: ``dtypes_digest`` of every dtype this module declares (by the
    dtype's ``descr``) and the constants that size the arena's header."""
    shapes: list[tuple[str, Any]] = [
        (name, value if value.names else value.str)
        for name, value in sorted(globals().items())
        if isinstance(value, np.dtype)
    ]
    shapes.append(("flight_row", flight_row(1, 1)))
    shapes.append(("queue_entry", queue_entry(MOTION_REQUEST)))
    shapes.append(("sizes", (ALIGN, MAX_BLOCKS, MAX_PROCESSES)))
    return dtypes_digest(shapes)


LAYOUT_VERSION = _digest()
