"""Motions that change while they run (thesis 3.2.3, 3.3.2, 2.7): a motion system
follows a target the TG evaluates every tick, within speed and acceleration limits.

A TRACK request's target is RCCL's position equation, a loop O* = F_0 · … · F_{n-1} of fixed
poses, shared transforms (``tg.frames`` records a program writes whole, at any rate, and the
TG reads without waiting: ``SharedFrames``) and TG functions; TRACK_JOINTS streams joint
targets.  ``follow`` moves the commanded target towards O* each tick: exactly while O* moves
within the limits, at the limits and braking without overshoot beyond them.  A stale,
non-finite or non-rigid target stops the motion on its path; a next set-point that cannot be
had (no solution, a joint too fast) holds the arms and ends it STOPPED, never halting the cell;
near a singularity or the cell's clearances it slows, and holds at the limit until the target
leads away.  ``start`` (the loop must close) runs outside the cycle; ``step`` allocates
no arrays and runs inside it.  The whole law: docs/internals/motion-client-bridge.md.

Long on purpose: a tracking motion's whole law (shared frames, following, braking, the Cartesian
and joint variants) in one place.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core import atomic, layout
from ..core.errors import KinematicsError
from ..core.layout import FrameKind
from ..core.spinlock import pid_alive
from ..robots import RobotType
from ..robots.profile import SINGULAR_MARGINS
from ..runtime.instance import decode
from .cartesian import Arms, decode_config, held_object
from .functions import FunctionSlots, TgFunction
from .profiles import (
    MAX_ANGULAR_SPEED_RAD_S,
    MAX_LINEAR_SPEED_M_S,
    MAX_MOTION_S,
    MAX_POSE_M,
    RIGID_TOLERANCE,
    MotionError,
    angle_axis,
    rigid_pose,
)

if TYPE_CHECKING:
    from ..robots.collision import ClearanceWalk

MAX_LINEAR_ACCEL_M_S2 = 50.0  # above this a tracking limit is a units mistake, not a request
MAX_ANGULAR_ACCEL_RAD_S2 = 200.0
READ_TRIES = 4  # seqlock copies tried per tick before the last whole value is kept
SLACK = 1.0 + 1e-9  # rounding allowance on the limits when a target is followed exactly
SPEED_MARGIN = 1.0 + 1e-9  # on the joint speed limits
# near the cell's clearance (TrackingMotion.keep_clear): the speed towards the nearest body
# shrinks within this margin of it, to this share of the linear limit at it (a look measures
# exact distances further out, robots.collision.NEAR_M, so one that measures none leaves the
# arms a few cm of motion outside this zone, not one tick)
SLOW_ZONE_M = 0.05
MIN_NEAR_SCALE = 0.02
# near a singularity (MoveIt Servo's rule): within SINGULAR_MARGINS[-1] times the type's limit
# (robots.profile) the speed shrinks with the margin left, to MIN_NEAR_SCALE at the limit,
# while the margin shrinks; there the arms hold until the target leads them away


# ---------------------------------------------------------------------------------------------
# Shared transforms


class SharedFrames:
    """The TG's view of ``tg.frames``: a whole copy of one record, without waiting on its
    writer (thesis 3.2.3; a Type 4 record).

    The writer makes ``seq`` odd, writes, makes it even; a copy taken between two equal even
    values of ``seq`` is whole.  After ``READ_TRIES`` torn copies (a writer busy, or stopped
    mid-write) ``read`` says so and the reader keeps its last whole value: the frame then ages
    and, past its lifetime, stops what tracks it."""

    def __init__(self, records: np.ndarray, base_tick_ns: int) -> None:
        self.records = records
        self.tick_s = base_tick_ns * 1e-9
        self._seq = [records["seq"][i : i + 1].ctypes.data for i in range(len(records))]
        self._pose = records["pose"]
        self._joints = records["joints"]
        self._stamp = records["stamp_tick"]
        self._lifetime = records["lifetime_s"]

    def name(self, i: int) -> str:
        """Shared transform ``i``'s name (for messages; allocates)."""
        return decode(self.records["name"][i]) or f"#{i}"

    def why_unusable(self, i: int) -> str:
        """Why shared transform ``i`` cannot start a motion (no live writer, never written),
        or ''.  Outside the cycle."""
        rec = self.records[i]
        pid = int(rec["owner_pid"])
        if pid <= 0 or not pid_alive(pid):
            return f"shared transform #{i} is not held by any running program"
        if int(rec["writes"]) == 0:
            return f"shared transform '{self.name(i)}' has never been written"
        return ""

    def read(self, i: int, pose: np.ndarray | None, joints: np.ndarray | None) -> tuple:
        """Copy record ``i``'s pose into ``pose`` and/or its joints into ``joints`` (n
        wide) whole; returns (whole, stamp tick, lifetime s).  In the cycle."""
        addr = self._seq[i]
        for _ in range(READ_TRIES):
            s0 = atomic.load32(addr)
            if s0 & 1:
                continue
            if pose is not None:
                np.copyto(pose, self._pose[i])
            if joints is not None:
                np.copyto(joints, self._joints[i, : joints.shape[0]])
            stamp = int(self._stamp[i])
            lifetime = float(self._lifetime[i])
            if atomic.load32(addr) == s0:
                return True, stamp, lifetime
        return False, 0, 0.0


def write_frame(
    record: np.ndarray, tick: int, pose: np.ndarray | None, joints: np.ndarray | None
) -> None:
    """Write one shared transform record (0-d view) whole: ``seq`` odd, the value and its
    stamp (wall clock ``tick``), ``seq`` even.  Its one writer is the program that claimed it."""
    addr = record["seq"].ctypes.data
    seq = atomic.load32(addr)
    atomic.store32(addr, (seq + 1) | 1)
    if pose is not None:
        record["pose"] = pose
    if joints is not None:
        record["joints"][: joints.shape[0]] = joints
    record["stamp_tick"] = tick
    record["writes"] += 1
    atomic.store32(addr, ((seq + 1) | 1) + 1)


# ---------------------------------------------------------------------------------------------
# Following a target within limits (inside the cycle: floats)


def _norm(x: list[float]) -> float:
    return math.sqrt(sum(v * v for v in x))


def follow(
    e: list[float],
    goal_v: list[float],
    v: list[float],
    v_max: float,
    a_max: float,
    dt: float,
) -> bool:
    """One tick of one group of coordinates (a point's 3 coordinates, a rotation vector, or
    one joint) after a target ``e`` away (target − commanded, after the target moved) that
    moves at ``goal_v``; ``v`` is the commanded velocity, updated in place.  Limits are on
    the group's norm: speed ``v_max``, acceleration ``a_max``.

    True when the target is reachable this tick within the limits: ``v`` becomes e/dt and the
    caller puts the commanded value on the target exactly.  Else ``v`` changes by at most
    a_max·dt towards the target's velocity (at most ``v_max``) plus, along what is left of
    ``e`` once that velocity is taken out of it, the discrete braking speed that arrives on it
    (a_max·dt·(√(¼ + 2d/(a_max·dt²)) − ½) for distance d, never more than d/dt): a jump is
    approached at the limits without overshoot, and a target moving steadily is caught up
    with and then followed exactly; returns False (rate-limited)."""
    n = len(e)
    exact_speed = 0.0
    change = 0.0
    for i in range(n):
        x = e[i] / dt
        exact_speed += x * x
        change += (x - v[i]) ** 2
    if math.sqrt(exact_speed) <= v_max * SLACK and math.sqrt(change) <= a_max * dt * SLACK:
        for i in range(n):
            v[i] = e[i] / dt
        return True
    g = _norm(goal_v)
    g_scale = 1.0 if g <= v_max else v_max / g
    ahead = [goal_v[i] * g_scale for i in range(n)]  # the target's own motion
    rest = [e[i] - ahead[i] * dt for i in range(n)]  # what is left of e beyond it
    d = _norm(rest)
    brake = a_max * dt * (math.sqrt(0.25 + 2.0 * d / (a_max * dt * dt)) - 0.5)
    toward = min(v_max, brake, d / dt) / d if d > 0.0 else 0.0  # never past it in a tick
    want = [ahead[i] + rest[i] * toward for i in range(n)]
    w = _norm(want)
    if w > v_max:
        want = [x * v_max / w for x in want]
    dv = [want[i] - v[i] for i in range(n)]
    m = _norm(dv)
    step = 1.0 if m <= a_max * dt else a_max * dt / m
    for i in range(n):
        v[i] += dv[i] * step
    return False


def brake(v: list[float], a_max: float, dt: float) -> None:
    """One tick of stopping: ``v`` shrinks by a_max·dt (its direction kept) down to 0."""
    m = _norm(v)
    scale = 0.0 if m <= a_max * dt else 1.0 - a_max * dt / m
    for i in range(len(v)):
        v[i] *= scale


def rotvec(r: np.ndarray) -> list[float]:
    """The rotation vector (axis × angle, rad) of rotation matrix ``r`` (3×3); floats, stable
    near 0 and near π (where it falls back on ``profiles.angle_axis``, which allocates)."""
    x = float(r[2, 1] - r[1, 2])
    y = float(r[0, 2] - r[2, 0])
    z = float(r[1, 0] - r[0, 1])
    s = math.sqrt(x * x + y * y + z * z)  # 2 sin θ
    angle = math.atan2(s, float(r[0, 0] + r[1, 1] + r[2, 2]) - 1.0)
    if angle < 1e-12:
        return [0.5 * x, 0.5 * y, 0.5 * z]
    if angle > math.pi - 1e-2:
        angle, axis = angle_axis(np.asarray(r))
        return [float(a) * angle for a in axis]
    k = angle / s
    return [x * k, y * k, z * k]


def rotation(w: list[float], out: np.ndarray) -> None:
    """Rot(w): the rotation by |w| about w (Rodrigues), into ``out`` (3×3)."""
    angle = _norm(w)
    if angle < 1e-15:
        out[...] = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0))
        return
    x, y, z = w[0] / angle, w[1] / angle, w[2] / angle
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    out[0, 0], out[0, 1], out[0, 2] = c + t * x * x, t * x * y - s * z, t * x * z + s * y
    out[1, 0], out[1, 1], out[1, 2] = t * x * y + s * z, c + t * y * y, t * y * z - s * x
    out[2, 0], out[2, 1], out[2, 2] = t * x * z - s * y, t * y * z + s * x, c + t * z * z


def pose_fault(t: np.ndarray) -> str:
    """Why 4×4 ``t`` is not a pose a motion can go to (not finite, beyond MAX_POSE_M, not a
    rigid motion), or ''.  In the cycle: floats, no arrays."""
    if not math.isfinite(float(t.sum())):
        return "is not finite"
    if max(abs(float(t[0, 3])), abs(float(t[1, 3])), abs(float(t[2, 3]))) > MAX_POSE_M:
        return f"is more than {MAX_POSE_M:g} m from its frame's origin"
    worst = 0.0
    for i in range(3):
        for j in range(i, 3):
            dot = float(t[0, i] * t[0, j] + t[1, i] * t[1, j] + t[2, i] * t[2, j])
            worst = max(worst, abs(dot - (1.0 if i == j else 0.0)))
    if worst > RIGID_TOLERANCE:
        return f"is not a rigid motion (|RᵀR − I| = {worst:.3g}, limit {RIGID_TOLERANCE:g})"
    return ""


# ---------------------------------------------------------------------------------------------
# Checking a TRACK request (pure: the TG calls it on every request it takes)


def check_limits(req: np.void | np.ndarray) -> None:
    """MotionError unless a TRACK request's limits are finite, > 0 and plausible, and its
    ``track_s`` finite in [0, MAX_MOTION_S]."""
    for name, top, unit in (
        ("speed", MAX_LINEAR_SPEED_M_S, "m/s"),
        ("angular_speed", MAX_ANGULAR_SPEED_RAD_S, "rad/s"),
        ("accel", MAX_LINEAR_ACCEL_M_S2, "m/s²"),
        ("angular_accel", MAX_ANGULAR_ACCEL_RAD_S2, "rad/s²"),
    ):
        value = float(req[name])
        if not (math.isfinite(value) and 0.0 < value <= top):
            raise MotionError(f"tracking {name} is {value} {unit}; it must be > 0 and ≤ {top:g}")
    check_track_time(float(req["track_s"]))


def check_track_time(track_s: float) -> None:
    """MotionError unless ``track_s`` (0: until stopped) is finite in [0, MAX_MOTION_S]."""
    if not (math.isfinite(track_s) and 0.0 <= track_s <= MAX_MOTION_S):
        raise MotionError(
            f"track_s is {track_s} s; it must be 0 (until stopped) to {MAX_MOTION_S:g} s"
        )


def check_loop(req: np.void) -> None:
    """MotionError unless a TRACK request's loop has 1..MAX_LOOP factors, each a fixed pose
    (index < MAX_SEGMENTS, a rigid pose) or a shared transform (index < MAX_FRAMES)."""
    n = int(req["n_loop"])
    if not 1 <= n <= layout.MAX_LOOP:
        raise MotionError(f"{n} transforms in the loop; 1 to {layout.MAX_LOOP} allowed")
    for i in range(n):
        kind, index = (int(v) for v in req["loop"][i])
        if kind == FrameKind.FIXED:
            if index >= layout.MAX_SEGMENTS:
                raise MotionError(f"loop[{i}]: fixed pose {index}; 0..{layout.MAX_SEGMENTS - 1}")
            rigid_pose("tracking", f"loop[{i}] (fixed)", req["poses"][index])
        elif kind == FrameKind.SHARED:
            if index >= layout.MAX_FRAMES:
                raise MotionError(
                    f"loop[{i}]: shared transform {index}; 0..{layout.MAX_FRAMES - 1}"
                )
        elif kind == FrameKind.FUNCTION:
            if index >= layout.MAX_FUNCTIONS:
                raise MotionError(f"loop[{i}]: tg function {index}; 0..{layout.MAX_FUNCTIONS - 1}")
        else:
            kinds = ", ".join(f"{k.value} ({k.name})" for k in FrameKind)
            raise MotionError(f"loop[{i}] is of kind {kind}; kinds: {kinds}")


# ---------------------------------------------------------------------------------------------
# The motions


class Tracking(ABC):
    """What both tracking motions share: the stop, the time, the count of limited ticks.

    ``why`` is set (once) when the motion must stop on its path; ``held`` when it ended at
    its last set-point; ``done`` when it is at rest after a stop and may end."""

    duration: float  # s: its ``track_s``, or inf (until stopped)
    q_ref: list[np.ndarray]  # each arm's last set-point (one per arm of its type's joints)

    def __init__(self, dt: float, track_s: float) -> None:
        self.dt = float(dt)
        self.duration = track_s if track_s > 0.0 else math.inf
        self.t = 0.0  # s since it started
        self.limited = 0  # ticks the target moved faster than the limits allowed
        self.why = ""  # why it stops ('' while it follows)
        self.stopping = False
        self.held = False  # ended at its last set-point: no next one could be had
        self.aborted = False  # held because a TG function failed (ABORTED, not STOPPED)
        self.done = False  # at rest after stopping: the TG ends it
        # the cell's clearances (``keep_clear``): None, not kept
        self.clearance: ClearanceWalk | None = None

    def keep_clear(self, walk: ClearanceWalk) -> None:
        """Keep the arms out of the cell's clearance with ``walk`` (outside the cycle, at
        the start, at ``q_ref``): a set-point nearer than the clearance is not taken (the arms
        hold, the motion runs on), and an arm starting within it may only move away
        (``ClearanceWalk.refused``); a Cartesian one also slows near it
        (``TrackingMotion._approach``)."""
        self.clearance = walk

    def _clear(self, rows: Sequence[np.ndarray], here: Sequence[np.ndarray]) -> bool:
        """Whether the next set-points ``rows`` may be taken, the arms being at ``here``: not
        nearer than the clearance, or, where the arms already are within it, not nearer than
        they are."""
        walk = self.clearance
        if walk is None:
            return True
        if walk.refused(rows) is None:
            return True
        walk.hit(here)  # where the arms stay
        return False

    def stop(self, why: str) -> None:
        """Stop on the path from the next tick (the first reason given is kept)."""
        if not self.stopping:
            self.stopping = True
            self.why = why

    def _tick(self) -> None:
        self.t += self.dt
        if self.t >= self.duration:
            self.stop("")  # its time is up: DONE once at rest

    @abstractmethod
    def start(self, now_tick: int) -> None:
        """Check it can start now (outside the cycle); MotionError with the reason."""

    @abstractmethod
    def step(self, now_tick: int) -> list[np.ndarray] | None:
        """This tick's set-point of each arm, or None when it ends held (in the cycle)."""


class TrackingMotion(Tracking):
    """A TRACK request of one motion system: its control frame O follows the loop's product.

    ``names``, ``types``, ``bases``, ``grasps``, ``configs``, ``q_start`` and ``measured`` as
    for ``cartesian.CartesianMotion``; ``loop`` the factors as (FrameKind, index or 4×4 pose);
    ``frames`` the shared records; limits in m/s, rad/s, m/s², rad/s²."""

    def __init__(
        self,
        names: Sequence[str],
        types: Sequence[RobotType],
        bases: Sequence[np.ndarray],
        grasps: Sequence[np.ndarray],
        q_start: Sequence[np.ndarray],
        configs: Sequence[object | None],
        loop: Sequence[tuple[FrameKind, int | np.ndarray]],
        frames: SharedFrames,
        limits: tuple[float, ...],  # v_max, w_max, a_max, alpha_max
        dt: float,
        track_s: float = 0.0,
        functions: FunctionSlots | None = None,
        measured: Sequence[np.ndarray] | None = None,
    ) -> None:
        super().__init__(dt, track_s)
        self.names = list(names)
        self.n = len(self.names)
        arms = Arms(
            "tracking", names, types, bases, grasps, q_start, configs,
            "tracking cannot change configuration", measured,
        )  # fmt: skip
        self._kin, self._qd_max, self.configs = arms.kin, arms.qd_max, arms.configs
        self._bases, self._to_base, self._grasps = arms.bases, arms.to_base, arms.grasps
        starts = arms.starts
        self.frames = frames
        self.v_max, self.w_max, self.a_max, self.alpha_max = (float(x) for x in limits)
        # the loop: a value per factor (fixed ones copied, shared ones read each tick)
        self._values: list[np.ndarray] = []
        self._shared: list[tuple[int, np.ndarray, str]] = []  # (record, value, name)
        self.functions = functions
        self._unbound: list[tuple[int, np.ndarray]] = []  # TG functions: (slot, value)
        self._functions: list[tuple[int, np.ndarray, TgFunction, Any]] = []  # bound at start
        for kind, what in loop:
            if kind == FrameKind.FIXED:
                self._values.append(np.array(what, dtype=np.float64))
            elif kind == FrameKind.FUNCTION:
                value = np.eye(4)
                self._values.append(value)
                self._unbound.append((int(what), value))
            else:
                index = int(what)
                value = np.eye(4)
                self._values.append(value)
                self._shared.append((index, value, frames.name(index)))
        self._seen = [False] * len(self._shared)  # read whole at least once
        self._a = np.empty((4, 4))
        self._b = np.empty((4, 4))
        self._goal = np.empty((4, 4))  # O*: the loop's product this tick
        self._goal_last = np.empty((4, 4))
        self._r = np.empty((3, 3))
        self._rot = np.empty((3, 3))
        self._t6 = np.empty((4, 4))
        self._tmp = np.empty((4, 4))
        self.cmd = held_object(
            self.names, self._kin, self._bases, self._grasps, starts, arms.measured
        )
        self._v = [0.0, 0.0, 0.0]  # commanded linear velocity, world, m/s
        self._w = [0.0, 0.0, 0.0]  # commanded angular velocity, world, rad/s
        self.q_ref = [q.copy() for q in starts]  # each arm's last set-point
        self._q = [q.copy() for q in starts]  # scratch: the next one
        self._cmd_last = self.cmd.copy()  # the commanded pose of the last set-point
        # the singular margin of the last set-point (the least of its arms'), of the one
        # before it, and of the next one (``_singular_next``, kept as the last's once taken)
        self._margin_ref = self._margin_of(self.q_ref)
        self._margin_last = self._margin_next = math.inf

    def _margin_of(self, qs: list[np.ndarray]) -> float:
        """The least singular margin of the arms at joint angles ``qs``.  In the cycle."""
        margin = math.inf
        for k in range(self.n):
            margin = min(margin, self._kin[k].singular_margin(qs[k]))
        return margin

    def _singular_slow(self) -> bool:
        """Within ``SINGULAR_MARGINS[-1]`` of a singularity at the last set-point (the least
        margin of its arms) and no further from it than the tick before, cap the linear and
        angular speeds at the share the margin leaves (as ``_approach`` caps, at once).  True
        if it capped them.  In the cycle: floats only."""
        margin = self._margin_ref
        closer, self._margin_last = margin <= self._margin_last, margin
        top = SINGULAR_MARGINS[-1]
        if margin >= top or not closer:
            return False
        share = max(MIN_NEAR_SCALE, (margin - 1.0) / (top - 1.0))
        capped = False
        for vec, limit in ((self._v, self.v_max), (self._w, self.w_max)):
            speed, allowed = _norm(vec), limit * share
            if speed > allowed:
                for i in range(3):
                    vec[i] *= allowed / speed
                capped = True
        return capped

    def _approach(self) -> bool:
        """Within ``SLOW_ZONE_M`` of the clearance (by the walk's bound of the margin), cap
        the commanded velocity's component towards the nearest body (the last look's nearest
        pair, looked at afresh if it measured none) at the linear limit's share the margin
        leaves (down to ``MIN_NEAR_SCALE`` at the clearance); moving away, or along it, is
        not slowed.  True if it capped it.  In the cycle: floats only."""
        walk = self.clearance
        if walk is None or walk.slack >= SLOW_ZONE_M:
            return False
        if walk.nearest is None:  # the bound came into the zone: which body is nearest?
            walk.hit(self.q_ref, SLOW_ZONE_M)  # (a look: exact within NEAR_M > the zone)
        near = walk.nearest
        if near is None or walk.slack >= SLOW_ZONE_M:
            return False
        v = self._v
        allowed = self.v_max * max(MIN_NEAR_SCALE, walk.slack / SLOW_ZONE_M)
        a, b = near.point_a, near.point_b
        n = [float(a[i]) - float(b[i]) for i in range(3)]  # from the body towards the arm
        size = _norm(n)
        if size < 1e-9:  # touching: the guard (``_clear``) holds the arms
            return False
        toward = -sum(v[i] * n[i] for i in range(3)) / size
        if toward <= allowed:
            return False
        for i in range(3):
            v[i] += (toward - allowed) * n[i] / size
        return True

    # ------------------------------------------------------------------ the loop

    def start(self, now_tick: int) -> None:
        """Check that the loop closes: every shared transform held by a live program and
        written, the target whole and rigid, every arm able to reach it; MotionError naming
        the factor or the arm.  Outside the cycle (when the request starts)."""
        for index, _, _ in self._shared:
            why = self.frames.why_unusable(index)
            if why:
                raise MotionError(f"the loop does not close: {why}")
        for index, value in self._unbound:
            if self.functions is None:
                raise MotionError("the loop does not close: this TG has no functions")
            try:
                fn, data = self.functions.bind(index)
            except ValueError as exc:
                raise MotionError(f"the loop does not close: {exc}") from None
            self._functions.append((index, value, fn, data))
        why = self._evaluate(now_tick)
        if why:
            raise MotionError(f"the loop does not close: {why}")
        np.copyto(self._goal_last, self._goal)
        for k in range(self.n):
            try:
                self._solve(k, self._goal)
            except KinematicsError as exc:
                where = ", ".join(f"{float(v):.3f}" for v in self._goal[:3, 3])
                raise MotionError(
                    f"the loop does not close: its target at ({where}) m is out of robot "
                    f"'{self.names[k]}''s reach: {str(exc).removeprefix('kinematics: ')}"
                ) from None

    def _evaluate(self, now_tick: int) -> str:
        """The loop's product this tick into ``_goal``; why it cannot be followed, or ''."""
        frames = self.frames
        for n, (index, value, name) in enumerate(self._shared):
            whole, stamp, lifetime = frames.read(index, value, None)
            if not whole:
                if not self._seen[n]:  # no whole value yet to stand for it
                    return f"shared transform '{name}' is being written (no whole value yet)"
                continue  # its last whole value stands (and ages)
            self._seen[n] = True
            age = (now_tick - stamp) * frames.tick_s
            if lifetime > 0.0 and age > lifetime:
                return (
                    f"shared transform '{name}' was not written for {age:.3f} s (its "
                    f"lifetime is {lifetime:g} s)"
                )
            bad = pose_fault(value)
            if bad:
                return f"shared transform '{name}' {bad}"
        slots = self.functions
        for index, value, fn, data in self._functions:
            why = slots.evaluate(index, fn, data, now_tick, value)  # type: ignore[union-attr]
            if why:
                self.aborted = True
                return why
            bad = pose_fault(value)
            if bad:  # stops on its path, as a shared transform's would
                name = slots.name(index)  # type: ignore[union-attr]
                return f"tg function '{name}' gave a transform that {bad}"
        values = self._values
        if len(values) == 1:
            np.copyto(self._goal, values[0])
        else:
            acc, spare = self._a, self._b
            np.matmul(values[0], values[1], out=acc)
            for f in values[2:]:
                np.matmul(acc, f, out=spare)
                acc, spare = spare, acc
            np.copyto(self._goal, acc)
        bad = pose_fault(self._goal)
        return f"the loop's product {bad}" if bad else ""

    # ------------------------------------------------------------------ each tick

    def step(self, now_tick: int) -> list[np.ndarray] | None:
        """This tick's set-point of every arm (``q_ref``, overwritten next time), or None
        when none can be had (``held``, ``why`` says why).  In the cycle."""
        self._tick()
        dt = self.dt
        cmd = self.cmd
        if not self.stopping:
            why = self._evaluate(now_tick)
            if self.aborted:  # a TG function failed: its motion system holds (by name)
                self.held = True
                self.why = f"{why}; held at its last set-point"
                return None
            if why:
                self.stop(why)
        if self.stopping:
            brake(self._v, self.a_max, dt)
            brake(self._w, self.alpha_max, dt)
            self._move(exact_p=False, exact_r=False)
            self.done = _norm(self._v) == 0.0 and _norm(self._w) == 0.0
        else:
            goal, last = self._goal, self._goal_last
            e = [float(goal[i, 3] - cmd[i, 3]) for i in range(3)]
            gv = [float(goal[i, 3] - last[i, 3]) / dt for i in range(3)]
            exact_p = follow(e, gv, self._v, self.v_max, self.a_max, dt)
            if self._approach():
                exact_p = False
            np.matmul(goal[:3, :3], cmd[:3, :3].T, out=self._r)
            er = rotvec(self._r)
            np.matmul(goal[:3, :3], last[:3, :3].T, out=self._r)
            gw = [x / dt for x in rotvec(self._r)]
            exact_r = follow(er, gw, self._w, self.w_max, self.alpha_max, dt)
            if self._singular_slow():
                exact_p = exact_r = False
            if not (exact_p and exact_r):
                self.limited += 1
            self._move(exact_p, exact_r)
            np.copyto(last, goal)
        for k in range(self.n):
            why = self._next(k)
            if why:
                self.held = True
                self.why = f"robot '{self.names[k]}' {why}; held at its last set-point"
                return None
        # at the clearance or a singularity's limit: the arms hold
        if not self._clear(self._q, self.q_ref) or self._singular_next():
            np.copyto(cmd, self._cmd_last)
            self._v[:] = (0.0, 0.0, 0.0)
            self._w[:] = (0.0, 0.0, 0.0)
            self.limited += 1
            self.done = self.stopping
            return self.q_ref
        np.copyto(self._cmd_last, cmd)
        for k in range(self.n):
            np.copyto(self.q_ref[k], self._q[k])
        self._margin_ref = self._margin_next
        return self.q_ref

    def _move(self, exact_p: bool, exact_r: bool) -> None:
        """The commanded pose one tick on: onto the target where exact, else by v·dt, w·dt."""
        cmd, goal, dt = self.cmd, self._goal, self.dt
        if exact_p:
            np.copyto(cmd[:3, 3], goal[:3, 3])
        else:
            for i in range(3):
                cmd[i, 3] += self._v[i] * dt
        if exact_r:
            np.copyto(cmd[:3, :3], goal[:3, :3])
        else:
            rotation([x * dt for x in self._w], self._rot)
            np.matmul(self._rot, cmd[:3, :3], out=self._r)
            np.copyto(cmd[:3, :3], self._r)

    def _solve(self, k: int, obj: np.ndarray) -> np.ndarray:
        """Arm ``k``'s joints for object pose ``obj`` near its last set-point, into scratch."""
        np.matmul(self._to_base[k], obj, out=self._tmp)
        np.matmul(self._tmp, self._grasps[k], out=self._t6)
        return self._kin[k].ikine(self._t6, self.configs[k], q_ref=self.q_ref[k], out=self._q[k])

    def _next(self, k: int) -> str:
        """Solve arm ``k``'s next set-point into scratch; why it cannot move there, or ''."""
        try:
            q = self._solve(k, self.cmd)
        except KinematicsError as exc:
            return f"has no joint solution: {str(exc).removeprefix('kinematics: ')}"
        prev, limits = self.q_ref[k], self._qd_max[k]
        for j in range(len(limits)):
            speed = abs(float(q[j]) - float(prev[j])) / self.dt
            if speed > limits[j] * SPEED_MARGIN:
                return (
                    f"would need joint {j + 1} at {math.degrees(speed):.1f}°/s, above its "
                    f"limit {math.degrees(limits[j]):.0f}°/s"
                )
        return ""

    def _singular_next(self) -> bool:
        """Whether the next set-point comes within an arm type's singularity limit, and no
        further out than the last (one leaving a limit it started inside is let go); its
        margin kept for when it is taken.  In the cycle."""
        self._margin_next = self._margin_of(self._q)
        return self._margin_next < 1.0 and self._margin_next <= self._margin_ref


class JointTracking(Tracking):
    """A TRACK_JOINTS request: one arm's joints follow the targets a program streams into
    shared record ``index``, each joint within ``scale`` of its type's speed and acceleration
    limits (every joint followed exactly while all can be)."""

    def __init__(
        self,
        name: str,
        rtype: RobotType,
        q_start: np.ndarray,
        index: int,
        frames: SharedFrames,
        scale: float,
        dt: float,
        track_s: float = 0.0,
    ) -> None:
        super().__init__(dt, track_s)
        self.names = [name]
        self.type = rtype
        self.frames = frames
        self.index = index
        self.frame_name = frames.name(index)
        n = rtype.n_joints
        self.v_max = [float(v) * scale for v in rtype.qd_max]
        self.a_max = [float(a) * scale for a in rtype.qdd_max]
        self.q = np.array(q_start, dtype=np.float64).reshape(n)
        self.q_ref = [self.q]
        self._target = np.empty(n)
        self._last = np.empty(n)
        self._seen = False  # targets read whole at least once
        self._q_last = [self.q.copy()]  # the last set-point, while the next is had
        self._v = [[0.0] for _ in range(n)]
        self._e = [[0.0] for _ in range(n)]
        self._g = [[0.0] for _ in range(n)]

    def start(self, now_tick: int) -> None:
        """MotionError unless the stream is held by a live program, written, and its target
        finite and within the arm's joint ranges."""
        why = self.frames.why_unusable(self.index) or self._read(now_tick)
        if why:
            raise MotionError(f"the joint stream cannot start: {why}")
        np.copyto(self._last, self._target)

    def _read(self, now_tick: int) -> str:
        """The stream's targets into ``_target``; why they cannot be followed, or ''."""
        whole, stamp, lifetime = self.frames.read(self.index, None, self._target)
        if not whole:  # the last whole targets stand (and age); at the start there are none
            return "" if self._seen else f"joint stream '{self.frame_name}' is being written"
        self._seen = True
        age = (now_tick - stamp) * self.frames.tick_s
        if lifetime > 0.0 and age > lifetime:
            return (
                f"joint stream '{self.frame_name}' was not written for {age:.3f} s (its "
                f"lifetime is {lifetime:g} s)"
            )
        t = self.type
        for j in range(t.n_joints):
            x = float(self._target[j])
            if not (math.isfinite(x) and t.q_min[j] <= x <= t.q_max[j]):
                return (
                    f"joint stream '{self.frame_name}': joint {j + 1} target {x:.4g} rad is "
                    f"outside its range {float(t.q_min[j]):.3f} .. {float(t.q_max[j]):.3f} rad"
                )
        return ""

    def step(self, now_tick: int) -> list[np.ndarray] | None:
        """This tick's set-point (``q_ref[0]``); never None (no kinematics to fail)."""
        self._tick()
        dt, q = self.dt, self.q
        if not self.stopping:
            why = self._read(now_tick)
            if why:
                self.stop(why)
        n = q.shape[0]
        np.copyto(self._q_last[0], q)
        if self.stopping:
            for j in range(n):
                brake(self._v[j], self.a_max[j], dt)
                q[j] += self._v[j][0] * dt
            self.done = all(v[0] == 0.0 for v in self._v)
            self._keep_clear()
            return self.q_ref
        all_exact = True
        for j in range(n):
            self._e[j][0] = float(self._target[j] - q[j])
            self._g[j][0] = float(self._target[j] - self._last[j]) / dt
        exact = [
            follow(self._e[j], self._g[j], self._v[j], self.v_max[j], self.a_max[j], dt)
            for j in range(n)
        ]
        for j in range(n):
            if exact[j]:
                q[j] = self._target[j]
            else:
                all_exact = False
                q[j] += self._v[j][0] * dt
        if not all_exact:
            self.limited += 1
        np.copyto(self._last, self._target)
        self._keep_clear()
        return self.q_ref

    def _keep_clear(self) -> None:
        """At the clearance: the arm holds where it was (at rest), the stream runs on."""
        if not self._clear(self.q_ref, self._q_last):
            np.copyto(self.q, self._q_last[0])
            for v in self._v:
                v[0] = 0.0
            self.limited += 1
            self.done = self.stopping


def plan_tracking(
    req: np.void,
    robots: list[int],
    names: list[str],
    types: list[RobotType],
    bases: list[np.ndarray],
    start: Sequence[np.ndarray],
    frames: SharedFrames,
    dt: float,
    now_tick: int,
    functions: FunctionSlots | None = None,
    measured: Sequence[np.ndarray] | None = None,
) -> Tracking:
    """The tracking motion a checked TRACK or TRACK_JOINTS request asks for, from ``start``
    (``measured``: where the arms are, when they start at rest), its loop checked to close now;
    MotionError with the reason."""
    if int(req["kind"]) == layout.MotionKind.TRACK_JOINTS:
        k = robots[0]
        motion: Tracking = JointTracking(
            names[k], types[k], start[0], int(req["loop"][0][1]), frames,
            float(req["speed_scale"]), dt, float(req["track_s"]),
        )  # fmt: skip
    else:
        loop: list[tuple[FrameKind, int | np.ndarray]] = []
        for i in range(int(req["n_loop"])):
            kind, index = (int(v) for v in req["loop"][i])
            if kind == FrameKind.FIXED:
                fixed = rigid_pose("tracking", f"loop[{i}]", req["poses"][index])
                loop.append((FrameKind.FIXED, fixed))
            else:
                loop.append((FrameKind(kind), index))
        motion = TrackingMotion(
            [names[k] for k in robots],
            [types[k] for k in robots],
            [bases[k] for k in robots],
            [req["grasps"][i] for i in range(len(robots))],
            start,
            [
                decode_config(int(req["config"][i]), types[k].kinematics)
                for i, k in enumerate(robots)
            ],
            loop,
            frames,
            tuple(float(req[f]) for f in ("speed", "angular_speed", "accel", "angular_accel")),
            dt,
            float(req["track_s"]),
            functions,
            measured,
        )
    motion.start(now_tick)
    return motion
