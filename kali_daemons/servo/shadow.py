"""Shadow trials: a servo run beside the active one on the same inputs, never applied.

Every tick the SV steps the shadow on exactly the inputs the active servo just had and keeps,
in the slots (``SERVO_SLOT.shadow*``), the ticks compared and the sum of squares and peak of
(shadow − active) as the motors would get them, for ``kalictl servo compare``.  A trial is
started and ended through the slot's or the robot's mailbox (``SlotOp.SHADOW``); starting
hands the running servo's state over, as a select would, and selecting the shadow afterwards
goes on from its own state.  A robot runs joint trials or one robot-level trial, not both
(their figures share the slots); while any runs, SIO feeds the robot whole (``shadows``, a
count kept by atomic add).  A shadow that raises or returns a bad status or a non-finite
torque is never a fault: its trial ends (RAISED, FAILED) and the arm runs on.  More:
docs/internals/servo-level.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core import atomic, layout
from ..core.layout import ShadowState
from .algorithms.algorithm import Handover

if TYPE_CHECKING:
    from .level import ServoLevel

_MINUS_ONE = 0xFFFFFFFF  # fetch_add32 of this subtracts one


def start_joint(level: ServoLevel, i: int, b: int) -> str:
    """Start a trial of joint servo ``b`` on slot ``i`` (the SV, at the slot's run, or a
    client while the clock is stopped): its state handed over from the running servo, its
    figures cleared; '' when done, else why it was refused (nothing changed)."""
    s = level.slot_structs[i]
    registry = level.registry
    k = int(level.map.robot_of[i])
    if b == s.algo:
        return (
            f"SHADOW refused: '{registry[b].name}' is the joint's active servo; a trial runs "
            f"another beside it"
        )
    r = level.robots[k]
    if int(r["arm_shadow_state"]) == ShadowState.RUNNING:
        arm = registry.arms[int(r["arm_shadow"])].name
        return (
            f"SHADOW refused: robot '{level.names[k]}' runs robot-level servo '{arm}' in "
            f"shadow; end that trial first (kalictl servo shadow {level.names[k]} off)"
        )
    registry[b].handover(
        level.structs[i][b], Handover(s.position, s.velocity, s.demand, s.error, s.torque)
    )
    _clear(s, b, s.torque)
    r["arm_shadow_state"] = ShadowState.NONE  # a robot-level trial's figures are gone now
    if s.shadow_state != ShadowState.RUNNING:
        s.shadow_state = ShadowState.RUNNING
        atomic.fetch_add32(level.shadows_addr[k], 1)
    return ""


def end_joint(level: ServoLevel, i: int, state: ShadowState) -> None:
    """End slot ``i``'s trial, if one runs, as ``state``; its figures stay, its torque is NaN
    from now on (the flight recorder's: no trial), or for FAILED the bad one."""
    s = level.slot_structs[i]
    if s.shadow_state == ShadowState.RUNNING:
        if state != ShadowState.FAILED:
            s.shadow_torque = math.nan
        s.shadow_state = state
        atomic.fetch_add32(level.shadows_addr[int(level.map.robot_of[i])], _MINUS_ONE)


def start_arm(level: ServoLevel, k: int, b: int) -> str:
    """Mark robot ``k``'s trial of robot-level servo ``b`` started and clear its joints'
    figures (its state is handed over by the caller, ``sv.arm.ArmRunner``, which has this
    tick's inputs); '' when done, else why it was refused."""
    r = level.robots[k]
    name = level.registry.arms[b].name
    if b == int(r["arm_algo"]):
        return f"SHADOW refused: '{name}' is the robot's active servo; a trial runs another"
    span = level.map.span(k)
    joints = [
        j + 1
        for j, i in enumerate(range(span.start, span.stop))
        if level.slot_structs[i].shadow_state == ShadowState.RUNNING
    ]
    if joints:
        return (
            f"SHADOW refused: joint(s) {', '.join(map(str, joints))} of robot "
            f"'{level.names[k]}' run a joint servo in shadow; end those trials first"
        )
    for i in range(span.start, span.stop):
        s = level.slot_structs[i]
        _clear(s, layout.NO_SHADOW, s.torque)
        s.shadow_state = ShadowState.NONE
    r["arm_shadow"] = b
    if int(r["arm_shadow_state"]) != ShadowState.RUNNING:
        r["arm_shadow_state"] = ShadowState.RUNNING
        atomic.fetch_add32(level.shadows_addr[k], 1)
    return ""


def end_arm(level: ServoLevel, k: int, state: ShadowState) -> None:
    """End robot ``k``'s robot-level trial, if one runs, as ``state``."""
    r = level.robots[k]
    if int(r["arm_shadow_state"]) == ShadowState.RUNNING:
        if state != ShadowState.FAILED:
            level.slots["shadow_torque"][level.map.span(k)] = math.nan
        r["arm_shadow_state"] = state
        atomic.fetch_add32(level.shadows_addr[k], _MINUS_ONE)


def _clear(s: Any, b: int, torque: float) -> None:
    s.shadow = b
    s.shadow_torque = torque
    s.shadow_n = 0
    s.shadow_sq = 0.0
    s.shadow_peak = 0.0


def record(s: Any, torque: float, diff: float) -> None:
    """One compared tick of a joint's trial: the shadow's ``torque`` and (shadow − active)
    ``diff`` as the motor would get them (inside the cycle)."""
    s.shadow_torque = torque
    s.shadow_n += 1
    s.shadow_sq += diff * diff
    mag = -diff if diff < 0.0 else diff
    if mag > s.shadow_peak:
        s.shadow_peak = mag


@dataclass(frozen=True)
class Trial:
    """A joint's figures from its last shadow trial, as ``kalictl servo compare`` prints."""

    robot: str
    joint: int  # 1..n
    level: str  # 'joint' or 'robot': which kind of servo ran in shadow
    active: str  # the servo running the joint now (a robot-level one's name, or the joint's)
    shadow: str
    state: ShadowState
    ticks: int
    rms: float  # N·m, of (shadow − active) over the ticks compared
    peak: float  # N·m
    torque: float  # the shadow's last torque, N·m (NaN once ended; FAILED: the bad one)

    def text(self) -> str:
        """One line of the comparison table."""
        return (
            f"{self.robot:<8} {self.joint:>5}  {self.level:<5}  {self.active:<16} "
            f"{self.shadow:<16} {self.state.name.lower():<9} {self.ticks:>8}  "
            f"{self.rms:>9.4f}  {self.peak:>9.4f}"
        )


HEADER = (
    f"{'robot':<8} {'joint':>5}  {'level':<5}  {'active':<16} {'shadow':<16} {'state':<9} "
    f"{'ticks':>8}  {'rms N·m':>9}  {'peak N·m':>9}"
)


def trials(level: ServoLevel, robot: int | None = None) -> list[Trial]:
    """The figures of every joint (of ``robot``, or all) that has run a trial."""
    joint, arm = level.registry.names(), level.registry.arm_names()
    out: list[Trial] = []
    for k in range(level.n_robots) if robot is None else (robot,):
        slots = level.slots[level.map.span(k)]
        out += robot_trials(level.names[k], level.robots[k], slots, joint, arm)
    return out


def robot_trials(
    robot: str, r: np.void, slots: np.ndarray, joint: list[str], arm: list[str]
) -> list[Trial]:
    """One robot's trials from its ROBOT_STATE ``r`` and its ``slots``, the algorithms
    named by ``joint`` and ``arm`` (registry order): for readers without the registry
    (``kalictl status`` reads the names SIO wrote, ``layout.KEY_SERVO_NAMES``)."""
    out: list[Trial] = []
    arm_active, arm_shadow = int(r["arm_algo"]), int(r["arm_shadow"])
    arm_state = ShadowState(int(r["arm_shadow_state"]))
    for j, s in enumerate(slots):
        active = name_of(arm, arm_active) if arm_active >= 0 else name_of(joint, int(s["algo"]))
        if int(s["shadow"]) >= 0:
            kind, shadow = "joint", name_of(joint, int(s["shadow"]))
            state = ShadowState(int(s["shadow_state"]))
        elif arm_state != ShadowState.NONE:
            kind, shadow, state = "robot", name_of(arm, arm_shadow), arm_state
        else:
            continue
        n = int(s["shadow_n"])
        rms = math.sqrt(float(s["shadow_sq"]) / n) if n else math.nan
        peak, torque = float(s["shadow_peak"]), float(s["shadow_torque"])
        out.append(Trial(robot, j + 1, kind, active, shadow, state, n, rms, peak, torque))
    return out


def name_of(names: list[str], a: int) -> str:
    """Algorithm ``a`` of ``names``, or ``#a`` for an index outside them."""
    return names[a] if 0 <= a < len(names) else f"#{a}"
