"""The FR3's records: what the link process (``link``) holding an FR3's libfranka connection
and SIO exchange each robot cycle, one record per arm (config order), so that nothing outside
this package knows libfranka.

The link writes a state packet's fields and then ``seq``; SIO answers it in ``tau`` with
``cmd_seq = seq`` and posts the link's semaphore.  ``want``, ``stop``, ``recover`` and the
gripper fields are requests; ``status`` says what the link has done with them.
"""

from __future__ import annotations

import numpy as np

from ...core.layout import HIST_BINS, MAX_JOINTS, MESSAGE_BYTES, WRENCH, Record

KEY_ARMS = "hw.franka.arms"

# status bits, written by the link
LINK_CONNECTED = 1 << 0  # connected: state packets arrive
LINK_CONTROL = 1 << 1  # torque control running: the robot takes Kali's torques (power on)
LINK_ERROR = 1 << 2  # libfranka reported an error (``error``); cleared by recovery
LINK_ESTOP = 1 << 3  # the e-stop is pressed (kalictl estop): control stopped until released

# libfranka's RobotMode, by its value (``mode``)
ROBOT_MODES = (
    "Other",
    "Idle",
    "Move",
    "Guiding",
    "Reflex",
    "UserStopped",
    "AutomaticErrorRecovery",
)

# ``ls_expect``: what reaches the plant before it steps (a command datagram, a TCP request)
LS_UDP, LS_TCP = 1 << 0, 1 << 1

GRIP_IDLE, GRIP_BUSY, GRIP_DONE, GRIP_FAILED = 0, 1, 2, 3  # ``grip_state``

_STATUS_NAMES = (
    (LINK_CONNECTED, "connected"),
    (LINK_CONTROL, "torque control on"),
    (LINK_ERROR, "error"),
    (LINK_ESTOP, "e-stop pressed"),
)


def status_text(bits: int) -> str:
    """The link's status for a message: ``0x3 (connected, torque control on)``."""
    names = [name for bit, name in _STATUS_NAMES if bits & bit] or ["not connected"]
    return f"0x{bits:x} ({', '.join(names)})"


FRANKA_ARM = np.dtype(
    [
        # the link: the newest state packet (libfranka's RobotState)
        ("seq", "<u8"),  # state packets published
        ("state_ns", "<i8"),  # CLOCK_MONOTONIC when it came in
        ("robot_ms", "<u8"),  # the robot's own time stamp (RobotState.time)
        ("q", "<f8", (MAX_JOINTS,)),  # rad
        ("dq", "<f8", (MAX_JOINTS,)),  # rad/s
        ("tau_J", "<f8", (MAX_JOINTS,)),  # N·m, measured link-side torques
        ("wrench", "<f8", (WRENCH,)),  # the wrist wrench at the flange, flange axes (wrench.py)
        ("success_rate", "<f8"),  # control_command_success_rate
        ("mode", "u1"),  # RobotMode
        ("status", "u1"),  # LINK_* bits
        ("grip_state", "u1"),  # the hand: GRIP_*, the last gripper command's outcome
        ("grip_held", "u1"),  # the hand: 1 while its fingers hold something
        ("hand_up", "u1"),  # the hand: 1 while its process takes commands
        ("link_pid", "<i4"),
        ("answered", "<u8"),  # states answered by a command (writeOnce)
        ("late", "<u8"),  # states in control that SIO's command did not answer in time
        ("lost", "<u8"),  # state packets that never came (the robot's time jumped)
        ("sent_ns", "<i8"),  # CLOCK_MONOTONIC when the last command went out
        ("share_max_ns", "<i8"),  # the longest state-in to command-out so far
        ("share_hist", "<u4", (HIST_BINS,)),  # state-in to command-out (layout.lateness_bin)
        ("grip_width", "<f8"),  # the hand: m, the fingers' opening
        ("grip_done", "<u4"),  # the hand: the gripper command ``grip_state`` is the outcome of
        ("error", f"S{MESSAGE_BYTES}"),  # libfranka's error while LINK_ERROR
        # SIO: the command answering state ``cmd_seq``
        ("cmd_seq", "<u8"),
        ("tau", "<f8", (MAX_JOINTS,)),  # N·m, without gravity (the FR3 adds it)
        ("want", "u1"),  # 1: torque control on (the arm is powered), 0: off
        # any process, outside any cycle (``FrankaOps``)
        ("stop", "u1"),  # 1: a halt: stop now; the link clears it on reset, out of control
        ("estop", "u1"),  # 1: the e-stop is pressed
        ("recover", "u1"),  # 1: run libfranka's error recovery (kalictl reset); the link clears
        ("grip_cmd", "<u4"),  # a gripper command's number: bumped with grip_close (FrankaOps)
        ("grip_close", "u1"),  # 1: grasp (close), 0: open
        # lockstep (``kali_daemons.link.turns``): the plant and the link take turns on each
        # state; the 32-bit counts are futex words (a waiter sleeps until one changes)
        ("ls_sent", "<u4"),  # the plant: states sent to this arm
        ("ls_go", "<u4"),  # the plant: the state it sends next (a tick began: choose)
        ("ls_call", "<u4"),  # the plant: the state it sends next (every link ready: call)
        ("ls_ready", "<u4"),  # the link: the number of the state its next call takes
        ("ls_taken", "<u4"),  # the link: the number of the state its last call took
        ("ls_expect", "u1"),  # the link: what it has sent or sends first (LS_UDP, LS_TCP)
        ("ls_off", "u1"),  # the link: out of the turns (libfranka failed): nobody waits
        ("grip_sent", "<u4"),  # the hand: the gripper command it sent last
    ],
    align=True,
)

RECORDS: tuple[Record, ...] = (
    Record(KEY_ARMS, FRANKA_ARM, lambda c, i: len(c.robots), "each arm's link and SIO", "SIO"),
)
