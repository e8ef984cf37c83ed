"""Motion profiles the trajectory generator samples at its tick (thesis 2.2.1, DESIGN 5).

Each motion is a pure function of its path time τ with no clock of its own: the TG advances τ
by dt every tick and asks ``sample(tau, ...)`` for the set-point.  A stop scales time, never
the geometry: τ advances by σ·dt with σ going smoothly from 1 to 0 (``StopRamp``), so the
motion keeps its path and its velocity stays continuous.  ``JointMotion``: every joint on one
shared smooth time law; ``CartesianPath``: lines and arcs with Paul's transitions at the via
points; ``joint_move``: the quintic move ``kalictl move`` sends.

Construction validates and allocates; ``sample`` writes into caller-owned arrays and
allocates no arrays, so it may run inside the TG cycle.

Long on purpose: every motion law the TG samples (joint moves, Cartesian paths with their blends
and arcs, the stop ramp) with the checks they share.
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from typing import Literal

import numpy as np

from ..core.errors import MotionError
from ..robots import RobotType

PEAK_SPEED_FACTOR = 15.0 / 8.0  # peak of the quintic's velocity, in units of distance/time
MIN_DURATION_S = 0.1


def quintic(s: np.ndarray) -> np.ndarray:
    """The minimum-jerk time law 10 s³ − 15 s⁴ + 6 s⁵ on normalised time ``s`` in [0, 1]."""
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def move_duration(start: np.ndarray, target: np.ndarray, max_speed: np.ndarray) -> float:
    """Seconds for the quintic move so no joint's peak speed exceeds ``max_speed`` (rad/s)."""
    distance = np.abs(np.asarray(target, dtype=np.float64) - np.asarray(start, dtype=np.float64))
    return max(MIN_DURATION_S, float(np.max(PEAK_SPEED_FACTOR * distance / max_speed)))


def joint_move(
    start: np.ndarray,
    target: np.ndarray,
    period_s: float,
    max_speed: np.ndarray | float,
    q_min: np.ndarray,
    q_max: np.ndarray,
    robot: str = "robot",
) -> np.ndarray:
    """Set-points ``(steps, joints)`` at ``period_s`` from ``start`` (exclusive) to ``target``
    (inclusive, the last row exactly), or MotionError naming the joint, value and limit."""
    start = np.asarray(start, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if target.shape != start.shape:
        raise MotionError(
            f"move: robot '{robot}': {target.size} joint values, expected {start.size}"
        )
    speed = np.broadcast_to(np.asarray(max_speed, dtype=np.float64), start.shape)
    for j in range(start.size):
        if not math.isfinite(float(target[j])):
            raise MotionError(f"move: robot '{robot}' joint {j + 1}: target {target[j]} rad")
        if not q_min[j] <= target[j] <= q_max[j]:
            raise MotionError(
                f"move: robot '{robot}' joint {j + 1}: target {math.degrees(target[j]):.2f}° "
                f"is outside its range {math.degrees(q_min[j]):.1f}° .. "
                f"{math.degrees(q_max[j]):.1f}°; nothing moved"
            )
        if not (math.isfinite(float(speed[j])) and speed[j] > 0.0):
            raise MotionError(
                f"move: robot '{robot}' joint {j + 1}: speed {speed[j]} rad/s, must be > 0"
            )
    duration = move_duration(start, target, speed)
    n = max(1, math.ceil(duration / period_s))
    s = np.arange(1, n + 1, dtype=np.float64) / n
    points = start + np.outer(quintic(s), target - start)
    points[-1] = target
    return points


# ---------------------------------------------------------------------------------------------
# Limits and tolerances of the motion classes below

ZERO_MOVE_S = 1e-6  # duration of a joint motion that goes nowhere: done at the next tick
# A joint move shorter than this goes nowhere (done at the next tick): far below any
# encoder's count (the PUMA's finest is 1e-4 rad), and a law planned for it would overflow
# (1e-234 rad made every sample on the way NaN)
MIN_MOVE_RAD = 1e-12
JERK_RAMP_FRACTION = 0.25  # share of each acceleration phase spent ramping the acceleration
MAX_LINEAR_SPEED_M_S = 5.0  # a Cartesian speed above this is a units mistake, not a request
MAX_ANGULAR_SPEED_RAD_S = 10.0
RIGID_TOLERANCE = 1e-6  # max |RᵀR − I| of a pose's rotation
MAX_POSE_M = 10.0  # a pose or grasp further than this from its frame's origin is garbage
MAX_MOTION_S = 3600.0  # a motion lasting longer is a units mistake or garbage: refused
MIN_SEGMENT_LENGTH = 1e-9  # m and rad: below both, a segment goes nowhere
BLEND_ACCEL_FACTOR = {"paul": 1.5, "parabolic": 1.0}  # peak accel of a blend, × |Δv| / τ_b

Blend = Literal["paul", "parabolic"]


# ---------------------------------------------------------------------------------------------
# Validation helpers (construction only)


def _float(what: str, name: str, value: object, unit: str) -> float:
    """``value`` as a finite float, or MotionError naming the argument and the value."""
    try:
        x = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise MotionError(f"{what}: {name} is {value!r}, not a number") from None
    if not math.isfinite(x):
        raise MotionError(f"{what}: {name} is {x} {unit}, not a finite number")
    return x


def _array(what: str, name: str, value: object, shape: tuple[int, ...]) -> np.ndarray:
    """A float64 copy of ``value`` with ``shape`` and only finite entries, or MotionError."""
    try:
        a = np.array(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise MotionError(f"{what}: {name} is not an array of numbers: {value!r}") from None
    if a.shape != shape:
        raise MotionError(f"{what}: {name} has shape {a.shape}, expected {shape}")
    bad = np.flatnonzero(~np.isfinite(a))
    if bad.size:
        index = np.unravel_index(int(bad[0]), shape)
        at = ", ".join(str(int(i)) for i in index)
        raise MotionError(f"{what}: {name}[{at}] is {a[index]}, not a finite number")
    return a


def _positive(what: str, name: str, value: object, n: int, unit: str) -> np.ndarray:
    """A limit vector of ``n`` finite values > 0 (a scalar is used for every joint)."""
    # np.ndim takes any object; numpy's stubs only an array-like
    a = _array(what, name, [value] * n if np.ndim(value) == 0 else value, (n,))  # type: ignore[arg-type]
    for j in range(n):
        if not a[j] > 0.0:
            raise MotionError(f"{what}: {name}[{j}] is {a[j]} {unit}, must be > 0")
    return a


def rigid_pose(what: str, name: str, value: object) -> np.ndarray:
    """A homogeneous transform whose rotation is orthonormal to RIGID_TOLERANCE and whose
    translation is within MAX_POSE_M, returned with the rotation projected exactly onto SO(3)
    so set-points built from it stay rigid; MotionError naming ``name`` otherwise.  Magnitudes
    are checked before any product, so garbage (1e300) is refused without overflowing."""
    t = _array(what, name, value, (4, 4))
    if np.max(np.abs(t[3] - (0.0, 0.0, 0.0, 1.0))) > 1e-9:
        raise MotionError(f"{what}: {name} bottom row is {t[3].tolist()}, expected [0, 0, 0, 1]")
    offset = float(np.max(np.abs(t[:3, 3])))
    if offset > MAX_POSE_M:
        raise MotionError(
            f"{what}: {name} is {offset:.3g} m from its frame's origin along an axis; beyond "
            f"{MAX_POSE_M:g} m no arm of this cell reaches"
        )
    r = t[:3, :3]
    biggest = float(np.max(np.abs(r)))
    if biggest > 2.0:  # far from rigid: say so before RᵀR could overflow
        raise MotionError(
            f"{what}: {name} is not a rigid pose: a rotation entry of {biggest:.3g} (a rotation's "
            f"entries are within ±1)"
        )
    error = float(np.max(np.abs(r.T @ r - np.eye(3))))
    if error > RIGID_TOLERANCE or np.linalg.det(r) <= 0.0:
        raise MotionError(
            f"{what}: {name} is not a rigid pose: max |RᵀR − I| = {error:.3g} "
            f"(limit {RIGID_TOLERANCE:g}), det R = {np.linalg.det(r):.6g}"
        )
    u, _, vt = np.linalg.svd(r)
    t[:3, :3] = u @ vt
    return t


def _skew(a: np.ndarray) -> np.ndarray:
    """The cross-product matrix K with K x = a × x."""
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])


def angle_axis(r: np.ndarray) -> tuple[float, np.ndarray]:
    """The equivalent angle (in [0, π]) and unit axis of rotation ``r``: r = Rot(axis, angle).

    Stable at both ends: near 0 the axis is arbitrary (z), near π it comes from the symmetric
    part (R + Rᵀ)/2 = cos θ I + (1 − cos θ) a aᵀ rather than from the vanishing skew part.
    """
    v = np.array([r[2, 1] - r[1, 2], r[0, 2] - r[2, 0], r[1, 0] - r[0, 1]])  # 2 sin θ · a
    angle = math.atan2(float(np.linalg.norm(v)), float(np.trace(r)) - 1.0)
    if angle < 1e-12:
        return 0.0, np.array([0.0, 0.0, 1.0])
    if angle > math.pi - 1e-2:
        c = math.cos(angle)
        m = (0.5 * (r + r.T) - c * np.eye(3)) / (1.0 - c)  # a aᵀ
        i = int(np.argmax(np.diag(m)))
        axis = m[:, i] / math.sqrt(m[i, i])
        if float(axis @ v) < 0.0:
            axis = -axis
    else:
        axis = v
    return angle, axis / np.linalg.norm(axis)


# ---------------------------------------------------------------------------------------------
# Joint mode


class SmoothTrapezoid:
    """A normalised rest-to-rest time law s(t): 0 → 1 with |ṡ| ≤ v_max and |s̈| ≤ a_max.

    A trapezoidal velocity (accelerate, cruise, decelerate) whose acceleration phases ramp the
    acceleration linearly (constant jerk) over ``JERK_RAMP_FRACTION`` of the phase at each end,
    so s, ṡ and s̈ are continuous (a "double S" with a fixed ramp share).  Short moves lose the
    cruise.  Against the quintic law with the same limits it is never slower: ~4 % faster when
    acceleration-bound and up to 1.875× faster when speed-bound.
    """

    def __init__(self, v_max: float, a_max: float) -> None:
        r = JERK_RAMP_FRACTION
        # an acceleration phase of Ta reaches the speed a_max (1 − r) Ta over speed·Ta/2
        accel_time = v_max / (a_max * (1.0 - r))
        if v_max * accel_time <= 1.0:
            self._shape(accel_time, v_max, a_max)
        else:  # no room to cruise: accelerate half the way, then decelerate
            self._shape(1.0 / math.sqrt(a_max * (1.0 - r)), math.sqrt(a_max * (1.0 - r)), a_max)

    @classmethod
    def lasting(cls, duration_s: float) -> SmoothTrapezoid:
        """The law without cruise that takes ``duration_s`` (e.g. for a move to nowhere)."""
        law = cls.__new__(cls)
        accel_time = 0.5 * duration_s
        law._shape(accel_time, 1.0 / accel_time, 1.0 / ((1.0 - JERK_RAMP_FRACTION) * accel_time**2))
        return law

    def _shape(self, accel_time: float, peak_speed: float, peak_accel: float) -> None:
        """Set the phases from the acceleration time, cruise speed and peak acceleration."""
        self.accel_time = accel_time
        self.peak_speed = peak_speed
        self.peak_accel = peak_accel
        self.cruise_time = max(0.0, (1.0 - peak_speed * accel_time) / peak_speed)
        self.duration = 2.0 * accel_time + self.cruise_time
        self.ramp_time = JERK_RAMP_FRACTION * accel_time
        self.jerk = peak_accel / self.ramp_time
        self._half_distance = 0.5 * peak_speed * accel_time  # covered while accelerating

    def _accelerating(self, t: float) -> tuple[float, float, float]:
        """(s, ṡ, s̈) at ``t`` in [0, accel_time] (inside the cycle)."""
        tj, a, j = self.ramp_time, self.peak_accel, self.jerk
        if t < tj:
            return j * t * t * t / 6.0, 0.5 * j * t * t, j * t
        u = self.accel_time - t
        if u < tj:  # mirror image of the first ramp about the end of the phase
            s = self._half_distance - self.peak_speed * u + j * u * u * u / 6.0
            return s, self.peak_speed - 0.5 * j * u * u, j * u
        d = t - tj
        v1 = 0.5 * a * tj
        return a * tj * tj / 6.0 + d * (v1 + 0.5 * a * d), v1 + a * d, a

    def at(self, t: float) -> tuple[float, float, float]:
        """(s, ṡ, s̈) at time ``t``, clamped to rest outside [0, duration] (inside the cycle)."""
        if t <= 0.0:
            return 0.0, 0.0, 0.0
        if t >= self.duration:
            return 1.0, 0.0, 0.0
        if t < self.accel_time:
            return self._accelerating(t)
        cruise_end = self.accel_time + self.cruise_time
        if t <= cruise_end:
            return (
                self._half_distance + self.peak_speed * (t - self.accel_time),
                self.peak_speed,
                0.0,
            )
        s, sd, sdd = self._accelerating(self.duration - t)
        return 1.0 - s, sd, -sdd


class JointMotion:
    """A smooth joint-mode motion from ``start`` to ``target`` (thesis 2.2.1, "joint mode").

    Every joint follows q_j(τ) = start_j + (target_j − start_j)·s(τ) with one shared
    ``SmoothTrapezoid`` s, so all joints start and arrive together and their normalised progress is
    equal at every τ; s's limits are the tightest of v_max_j / |Δq_j| and a_max_j / |Δq_j|, so no
    joint exceeds its speed or acceleration limit.  A move that goes nowhere (every joint less than
    ``MIN_MOVE_RAD``) lasts ``ZERO_MOVE_S``.  Any number of joints (a motion system may have several
    arms); ``start`` sets it.  ``peak_speed``, ``peak_accel`` and ``peak_jerk`` are each joint's
    maxima over the motion.
    """

    def __init__(
        self, start: np.ndarray, target: np.ndarray, v_max: np.ndarray, a_max: np.ndarray
    ) -> None:
        what = "joint motion"
        start_arr = np.asarray(start)
        if start_arr.ndim != 1 or start_arr.size == 0:
            raise MotionError(f"{what}: start has shape {start_arr.shape}, expected (n,)")
        n = start_arr.size
        self.start = _array(what, "start", start, (n,))
        self.target = _array(what, "target", target, (n,))
        self.v_max = _positive(what, "v_max", v_max, n, "rad/s")
        self.a_max = _positive(what, "a_max", a_max, n, "rad/s²")
        self._delta = self.target - self.start
        distance = np.abs(self._delta)
        planned = distance > MIN_MOVE_RAD  # the joints whose limits set the law
        if planned.any():
            v_norm = float(np.min(self.v_max[planned] / distance[planned]))
            a_norm = float(np.min(self.a_max[planned] / distance[planned]))
            self.law = SmoothTrapezoid(v_norm, a_norm)
        else:
            self.law = SmoothTrapezoid.lasting(ZERO_MOVE_S)  # nowhere to go: only the clock
        self.duration = self.law.duration
        # per joint; a joint that stays put has none
        self.peak_speed = distance * self.law.peak_speed  # ≤ v_max
        self.peak_accel = distance * self.law.peak_accel  # ≤ a_max
        self.peak_jerk = distance * self.law.jerk

    def sample(
        self,
        tau: float,
        q_out: np.ndarray,
        qd_out: np.ndarray | None = None,
        qdd_out: np.ndarray | None = None,
    ) -> None:
        """Write position (and velocity, acceleration) at path time ``tau`` into the given
        float64 arrays; the exact target and rest from ``duration`` on (inside the cycle)."""
        if tau >= self.duration:
            np.copyto(q_out, self.target)
            if qd_out is not None:
                qd_out.fill(0.0)
            if qdd_out is not None:
                qdd_out.fill(0.0)
            return
        s, sd, sdd = self.law.at(tau)
        np.multiply(self._delta, s, out=q_out)
        np.add(q_out, self.start, out=q_out)
        if qd_out is not None:
            np.multiply(self._delta, sd, out=qd_out)
        if qdd_out is not None:
            np.multiply(self._delta, sdd, out=qdd_out)


# ---------------------------------------------------------------------------------------------
# Cartesian mode


class CartesianPath:
    """Straight-line segments through ``targets`` with transitions at the via points.

    Segment k (1-based in messages) runs from pose k−1 to pose k (pose 0 is ``start``).  Its
    position moves along the line at a constant velocity and its orientation turns about one
    fixed axis: R(s) = R_{k−1} · Rot(a, s·θ), with (a, θ) the angle-axis of R_{k−1}ᵀ R_k.  The
    segment lasts T_k = max(L_k / speed, θ_k / angular_speed), so neither speed is exceeded
    and the limiting one is met exactly during cruise, or the time given for it (thesis 2.2.1:
    "the time for the movement"): ``durations[k]`` > 0, refused if that would be faster than
    ``MAX_LINEAR_SPEED_M_S`` / ``MAX_ANGULAR_SPEED_RAD_S``.

    Transitions (thesis 2.2.1, [Paul81]; R. P. Paul, "Manipulator Cartesian path control",
    IEEE Trans. SMC-9(11), 1979): the piecewise-constant-velocity path passes via point k at
    the nominal time t_k; over the window t_k ± τ_b/2 (τ_b = ``transition_s``) the velocity
    goes from the incoming segment's v_in to the outgoing one's v_out as
    v = v_in + (v_out − v_in)·w(λ), λ = (t − t_k + τ_b/2)/τ_b, and the pose is

        p(t) = p_k − v_in·H_in + v_out·H_out
        R(t) = R_k · Rot(a_in, −θ̇_in·H_in) · Rot(a_out, θ̇_out·H_out)

    with H_out = τ_b·W(λ), H_in = τ_b·(½ − λ + W(λ)), W = ∫w: the incoming segment's remaining
    motion to the via point shrinks to zero while the outgoing one's grows from zero, which are
    Paul's two drive contributions.  ``blend="paul"`` uses w = 3λ² − 2λ³ (his quartic
    transition polynomial; acceleration also continuous, zero at the window ends) and
    ``blend="parabolic"`` w = λ (constant acceleration, the quadratic blend).  Both leave the
    window on the lines exactly, so outside the windows set-points lie on the segments.

    The linear acceleration in the window at via k is (v_out − v_in)·w'(λ)/τ_b, peak
    ``blend_accel[k]`` = c·|v_out − v_in|/τ_b with c = 1.5 (paul) or 1 (parabolic).  The
    angular acceleration is at most ``blend_angular_accel[k]`` = c·|ω_out − ω_in|/τ_b +
    (c/2 + ¼)·|ω_in|·|ω_out| (the second term from turning about two axes at once).  Speeds
    in the window are convex combinations, so never above ``speed`` / ``angular_speed``.

    A segment may be a circular arc instead (``arcs[k]``: a point it passes through, the
    circle being the one through its two ends and that point; thesis 3.1 speaks of straight
    lines, RCCL-style controllers have added arcs since): its position goes round at constant
    speed, its orientation turns as a line's.  Paths with an arc are sampled by the general
    form of Paul's transition: over the window at via k the incoming segment runs on with its
    speed falling as 1 − w(λ) and the outgoing one starts with its speed rising as w(λ), each
    on its own curve, and the pose is their sum about via k (p_in + p_out − p_k,
    R_in · R_kᵀ · R_out); for lines that is exactly the formula above (the fast path, kept for
    paths of lines only).

    The path starts and ends at rest: pose 0 and the last pose are treated as via points with
    a resting segment before / after, so it accelerates over the first τ_b and decelerates over
    the last; each segment must therefore last at least τ_b (its two half-windows may not
    overlap).  ``duration`` = Σ T_k + τ_b.  Poses are stored with rotations projected exactly
    onto SO(3) (``poses``); the last one is returned bit for bit from ``duration`` on.
    """

    def __init__(
        self,
        start: np.ndarray,
        targets: Sequence[np.ndarray] | np.ndarray,
        speed: float,
        angular_speed: float,
        transition_s: float,
        blend: Blend = "paul",
        durations: Sequence[float] | None = None,
        arcs: Sequence[Sequence[float] | np.ndarray | None] | None = None,
    ) -> None:
        what = "cartesian path"
        self.speed = _float(what, "speed", speed, "m/s")
        if not 0.0 < self.speed <= MAX_LINEAR_SPEED_M_S:
            raise MotionError(
                f"{what}: speed {self.speed} m/s must be > 0 and ≤ {MAX_LINEAR_SPEED_M_S} m/s"
            )
        self.angular_speed = _float(what, "angular_speed", angular_speed, "rad/s")
        if not 0.0 < self.angular_speed <= MAX_ANGULAR_SPEED_RAD_S:
            raise MotionError(
                f"{what}: angular_speed {self.angular_speed} rad/s must be > 0 and "
                f"≤ {MAX_ANGULAR_SPEED_RAD_S} rad/s"
            )
        self.transition_s = _float(what, "transition_s", transition_s, "s")
        if self.transition_s < 0.0:
            raise MotionError(f"{what}: transition_s {self.transition_s} s must be ≥ 0")
        if blend not in BLEND_ACCEL_FACTOR:
            raise MotionError(
                f"{what}: blend {blend!r}, expected one of {list(BLEND_ACCEL_FACTOR)}"
            )
        self.blend = blend
        if isinstance(targets, np.ndarray) and targets.ndim == 2:
            raise MotionError(f"{what}: targets is one {targets.shape} array; pass a list of poses")
        try:
            targets = list(targets)
        except TypeError:
            raise MotionError(f"{what}: targets is {targets!r}, not a list of poses") from None
        if not targets:
            raise MotionError(f"{what}: targets is empty; give at least one pose")
        poses = [rigid_pose(what, "start", start)]
        poses += [rigid_pose(what, f"targets[{i}]", t) for i, t in enumerate(targets)]
        self.poses = np.array(poses)
        given = [0.0] * len(targets) if durations is None else list(durations)
        if len(given) != len(targets):
            raise MotionError(f"{what}: {len(given)} durations for {len(targets)} targets")
        self.durations = [_float(what, f"durations[{i}]", d, "s") for i, d in enumerate(given)]
        for i, d in enumerate(self.durations):
            if not 0.0 <= d <= MAX_MOTION_S:
                raise MotionError(
                    f"{what}: durations[{i}] is {d} s; 0 (by the speeds) to {MAX_MOTION_S:g} s"
                )
        vias = [None] * len(targets) if arcs is None else list(arcs)
        if len(vias) != len(targets):
            raise MotionError(f"{what}: {len(vias)} arcs for {len(targets)} targets")
        self.arcs = [
            None if v is None else _array(what, f"arcs[{i}]", v, (3,)) for i, v in enumerate(vias)
        ]
        self._circles: list[tuple[np.ndarray, float, np.ndarray, np.ndarray, float] | None] = []
        self._plan_segments()
        self._precompute_pieces()
        self._generic = any(a is not None for a in self.arcs)
        if self._generic:
            self._prepare_generic()
        self._end = self.poses[-1].copy()
        self._coef = np.zeros(11)
        self._coef[0] = 1.0
        self._vcoef = np.zeros(4)
        self._paul = blend == "paul"

    def _plan_segments(self) -> None:
        """Each segment's time, velocity, turn rate and axis, or MotionError if one is shorter
        than the transition (construction)."""
        what = "cartesian path"
        n = len(self.poses) - 1
        tb = self.transition_s
        self.segment_times = np.empty(n)
        velocities = np.zeros((n + 2, 3))  # rows 0 and n+1: the resting "segments" at the ends
        rates = np.zeros(n + 2)
        axes = np.zeros((n + 2, 3))
        axes[:, 2] = 1.0
        for k in range(n):
            p0, p1 = self.poses[k, :3, 3], self.poses[k + 1, :3, 3]
            length = float(np.linalg.norm(p1 - p0))
            angle, axis = angle_axis(self.poses[k, :3, :3].T @ self.poses[k + 1, :3, :3])
            label = f"segment {k + 1} ({'start' if k == 0 else f'targets[{k - 1}]'} → targets[{k}])"
            arc = self.arcs[k]
            circle = None if arc is None else _circle(what, label, p0, arc, p1)
            self._circles.append(circle)
            if circle is not None:
                length = circle[1] * circle[4]  # r · sweep
            if length < MIN_SEGMENT_LENGTH and angle < MIN_SEGMENT_LENGTH:
                raise MotionError(f"{what}: {label} has zero length: targets[{k}] repeats it")
            t_k = max(length / self.speed, angle / self.angular_speed)
            given = self.durations[k]
            if given > 0.0:  # the time for the movement: its speeds follow
                t_k = given
                if length / t_k > MAX_LINEAR_SPEED_M_S or angle / t_k > MAX_ANGULAR_SPEED_RAD_S:
                    raise MotionError(
                        f"{what}: {label} in {t_k:g} s would go {length / t_k:.3g} m/s and "
                        f"{angle / t_k:.3g} rad/s; at most {MAX_LINEAR_SPEED_M_S:g} m/s and "
                        f"{MAX_ANGULAR_SPEED_RAD_S:g} rad/s"
                    )
            if t_k < tb:
                raise MotionError(
                    f"{what}: {label} lasts {t_k:.4g} s ({length:.4g} m at {self.speed:g} m/s, "
                    f"{angle:.4g} rad at {self.angular_speed:g} rad/s), shorter than "
                    f"transition_s {tb:g} s; shorten the transition, slow down or drop the "
                    f"via point"
                )
            self.segment_times[k] = t_k
            velocities[k + 1] = (p1 - p0) / t_k
            rates[k + 1] = angle / t_k
            axes[k + 1] = axis
        self._velocities, self._turn_rates, self._axes = velocities, rates, axes

    def _precompute_pieces(self) -> None:
        """Per piece, the constant terms whose weighted sums are the pose and the velocity, so
        ``sample`` is one (11,) · (4, 11, 4) and one (6, 4) · (4,) product (construction).

        Expanding Rot(a, x) = I + sin x K + (1 − cos x) K² in R_k · Rot(a_in, α) · Rot(a_out, β)
        gives nine constant matrices R_k·{I, K1, K1²}·{I, K2, K2²} weighted by products of
        sin α, 1 − cos α, sin β, 1 − cos β; the position adds p_k − v_in·H_in + v_out·H_out.
        The angular velocity R_k(α̇ a_in + β̇ Rot(a_in, α) a_out) expands the same way.
        """
        n = len(self.poses) - 1
        tb = self.transition_s
        velocities, rates, axes = self._velocities, self._turn_rates, self._axes
        # piece k (k = 0..n) covers [t_k − τb/2, t_{k+1} − τb/2): via k's window, then the
        # cruise of segment k+1; the last piece is the final window only.
        self._starts = [0.0, *np.cumsum(self.segment_times).tolist()]
        self.via_times = np.array(self._starts) + 0.5 * tb
        self.duration = self._starts[-1] + tb
        c = BLEND_ACCEL_FACTOR[self.blend]
        self.blend_accel = np.empty(n + 1)
        self.blend_angular_accel = np.empty(n + 1)
        self._terms: list[np.ndarray] = []  # (4, 11, 4): T = coef @ terms
        self._velocity_terms: list[np.ndarray] = []  # (6, 4): v = velocity_terms @ vcoef
        self._rates: list[tuple[float, float]] = []
        for k in range(n + 1):
            r_k, p_k = self.poses[k, :3, :3], self.poses[k, :3, 3]
            v_in, v_out = velocities[k], velocities[k + 1]
            w_in, w_out = rates[k], rates[k + 1]
            k1, k2 = _skew(axes[k]), _skew(axes[k + 1])
            k11, k22 = k1 @ k1, k2 @ k2
            rotations = (np.eye(3), k1, k11, k2, k22, k1 @ k2, k1 @ k22, k11 @ k2, k11 @ k22)
            terms = np.zeros((4, 11, 4))
            for i, m in enumerate(rotations):
                terms[:3, i, :3] = r_k @ m
            terms[:3, 0, 3] = p_k
            terms[3, 0, 3] = 1.0
            terms[:3, 9, 3] = v_in
            terms[:3, 10, 3] = v_out
            self._terms.append(terms)
            vterms = np.zeros((6, 4))
            vterms[:3, 0], vterms[3:, 0] = v_in, w_in * (r_k @ axes[k])
            vterms[:3, 1], vterms[3:, 1] = v_out, w_out * (r_k @ axes[k + 1])
            vterms[3:, 2] = w_out * (r_k @ k1 @ axes[k + 1])
            vterms[3:, 3] = w_out * (r_k @ k11 @ axes[k + 1])
            self._velocity_terms.append(vterms)
            self._rates.append((float(w_in), float(w_out)))
            d_omega = float(np.linalg.norm(w_out * axes[k + 1] - w_in * axes[k]))
            if tb > 0.0:
                self.blend_accel[k] = c * float(np.linalg.norm(v_out - v_in)) / tb
                self.blend_angular_accel[k] = c * d_omega / tb + (0.5 * c + 0.25) * w_in * w_out
            else:
                self.blend_accel[k] = self.blend_angular_accel[k] = math.inf

    def _prepare_generic(self) -> None:
        """Scratch and per-segment terms of the general sampler (a path with an arc):
        R_k·K and R_k·K² of each segment's turn, so a segment's rotation is three products
        (construction)."""
        n = len(self.poses) - 1
        self._turns = []
        for k in range(n):
            angle, axis = angle_axis(self.poses[k, :3, :3].T @ self.poses[k + 1, :3, :3])
            kk = _skew(axis)
            r = self.poses[k, :3, :3]
            self._turns.append((r.copy(), r @ kk, r @ kk @ kk, float(angle)))
        self._in, self._out = np.eye(4), np.eye(4)
        self._r3 = np.empty((3, 3))
        self._r3b = np.empty((3, 3))
        self._probe = (np.eye(4), np.eye(4))  # the finite-difference velocity's two samples

    def _segment_pose(self, j: int, u: float, out: np.ndarray) -> None:
        """Segment ``j`` (0-based, pose j → j+1) at local time ``u`` in [0, T_j], into
        ``out`` (4×4): on its line or arc, turned ``u/T_j`` of its way (in the cycle)."""
        s = u / float(self.segment_times[j])
        r, rk, rkk, angle = self._turns[j]
        x = angle * s
        np.multiply(rk, math.sin(x), out=self._r3)
        np.add(self._r3, r, out=self._r3)
        np.multiply(rkk, 1.0 - math.cos(x), out=self._r3b)
        np.add(self._r3, self._r3b, out=out[:3, :3])
        circle = self._circles[j]
        if circle is None:
            p0, p1 = self.poses[j, :3, 3], self.poses[j + 1, :3, 3]
            for i in range(3):
                out[i, 3] = p0[i] + (p1[i] - p0[i]) * s
        else:
            centre, radius, e1, e2, sweep = circle
            phi = sweep * s
            c, sn = radius * math.cos(phi), radius * math.sin(phi)
            for i in range(3):
                out[i, 3] = centre[i] + c * e1[i] + sn * e2[i]

    def _sample_generic(self, tau: float, t_out: np.ndarray) -> None:
        """The pose at path time ``tau`` of a path with an arc (see the class docstring):
        a segment alone in its cruise, the sum of two about the via point in a window."""
        if tau >= self.duration:
            np.copyto(t_out, self._end)
            return
        tau = max(tau, 0.0)
        k = bisect_right(self._starts, tau) - 1
        u = tau - self._starts[k]
        tb = self.transition_s
        n = len(self.poses) - 1
        if u >= tb:  # cruising on segment k
            self._segment_pose(k, u - 0.5 * tb, t_out)
            return
        lam = u / tb
        big_w = lam * lam * lam * (1.0 - 0.5 * lam) if self._paul else 0.5 * lam * lam
        via = self.poses[k]
        if k == 0:
            np.copyto(self._in, via)  # at rest before the start
        else:
            t_in = float(self.segment_times[k - 1]) - 0.5 * tb + tb * (lam - big_w)
            self._segment_pose(k - 1, t_in, self._in)
        if k == n:
            np.copyto(self._out, via)  # at rest after the end
        else:
            self._segment_pose(k, tb * big_w, self._out)
        np.matmul(self._in[:3, :3], via[:3, :3].T, out=self._r3)
        np.matmul(self._r3, self._out[:3, :3], out=self._r3b)
        t_out[:3, :3] = self._r3b
        for i in range(3):
            t_out[i, 3] = self._in[i, 3] + self._out[i, 3] - via[i, 3]
        t_out[3] = (0.0, 0.0, 0.0, 1.0)

    def blend_window(self, k: int) -> tuple[float, float]:
        """Path-time interval of the transition at pose ``k`` (0 = start, n = last target)."""
        t = float(self.via_times[k])
        return t - 0.5 * self.transition_s, t + 0.5 * self.transition_s

    def sample(self, tau: float, t_out: np.ndarray, v_out: np.ndarray | None = None) -> None:
        """Write the pose at path time ``tau`` into ``t_out`` (4, 4) and, if given, the nominal
        velocity dT/dτ into ``v_out`` (a twist: linear m/s, then angular rad/s, both in the
        base frame); the start pose before 0, the last pose at rest from ``duration`` on
        (inside the cycle: float64 outputs, no arrays allocated; with an arc the velocity
        comes from a central difference, which allocates).  A path with an arc is sampled by
        ``_sample_generic``."""
        if self._generic:
            self._sample_generic(tau, t_out)
            if v_out is not None:
                self._difference(tau, v_out)
            return
        if tau >= self.duration:
            np.copyto(t_out, self._end)
            if v_out is not None:
                v_out.fill(0.0)
            return
        if tau < 0.0:
            tau = 0.0
        k = bisect_right(self._starts, tau) - 1
        u = tau - self._starts[k]
        tb = self.transition_s
        if u < tb:  # in the transition window centred on via k
            lam = u / tb
            if self._paul:
                w = lam * lam * (3.0 - 2.0 * lam)
                big_w = lam * lam * lam * (1.0 - 0.5 * lam)
            else:
                w = lam
                big_w = 0.5 * lam * lam
            h_out = tb * big_w
            h_in = tb * (0.5 - lam + big_w)
        else:  # cruising on the segment after via k
            w = 1.0
            h_out = u - 0.5 * tb
            h_in = 0.0
        w_in, w_out = self._rates[k]
        alpha = -w_in * h_in
        beta = w_out * h_out
        s1, c1 = math.sin(alpha), 1.0 - math.cos(alpha)
        s2, c2 = math.sin(beta), 1.0 - math.cos(beta)
        c = self._coef
        c[1] = s1
        c[2] = c1
        c[3] = s2
        c[4] = c2
        c[5] = s1 * s2
        c[6] = s1 * c2
        c[7] = c1 * s2
        c[8] = c1 * c2
        c[9] = -h_in
        c[10] = h_out
        np.matmul(c, self._terms[k], out=t_out)
        if v_out is not None:
            cv = self._vcoef
            cv[0] = 1.0 - w
            cv[1] = w
            cv[2] = w * s1
            cv[3] = w * c1
            np.matmul(self._velocity_terms[k], cv, out=v_out)

    def _difference(self, tau: float, v_out: np.ndarray) -> None:
        """dT/dτ at ``tau`` by central difference (a path with an arc): linear, then ω from
        Ṙ Rᵀ, base frame."""
        h = 1e-6
        a, b = self._probe
        self._sample_generic(tau - h, a)
        self._sample_generic(tau + h, b)
        v_out[:3] = (b[:3, 3] - a[:3, 3]) / (2 * h)
        w = (b[:3, :3] - a[:3, :3]) / (2 * h) @ (0.5 * (a[:3, :3] + b[:3, :3])).T
        v_out[3:] = (
            0.5 * (w[2, 1] - w[1, 2]),
            0.5 * (w[0, 2] - w[2, 0]),
            0.5 * (w[1, 0] - w[0, 1]),
        )


def _circle(
    what: str, label: str, p0: np.ndarray, via: np.ndarray, p1: np.ndarray
) -> tuple[np.ndarray, float, np.ndarray, np.ndarray, float]:
    """The arc from ``p0`` through ``via`` to ``p1``: (centre, radius, e1, e2, sweep), the
    point at angle φ being centre + r(cos φ e1 + sin φ e2), φ from 0 to sweep; MotionError
    naming the segment if the three points are (nearly) on one line or repeat."""
    a, b = via - p0, p1 - p0
    w = np.cross(a, b)
    ww = float(w @ w)
    scale = float(np.linalg.norm(a) * np.linalg.norm(b))
    if scale < MIN_SEGMENT_LENGTH**2 or math.sqrt(ww) < 1e-6 * scale:
        raise MotionError(
            f"{what}: {label} is an arc through {np.round(via, 4).tolist()}, but that point is "
            f"on the line between its ends (or repeats one): no circle passes through them"
        )
    centre = p0 + np.cross(float(a @ a) * b - float(b @ b) * a, w) / (2.0 * ww)
    radius = float(np.linalg.norm(p0 - centre))
    e1 = (p0 - centre) / radius
    e2 = np.cross(w / math.sqrt(ww), e1)  # the way round that meets via before p1

    def angle(p: np.ndarray) -> float:
        d = p - centre
        return math.atan2(float(d @ e2), float(d @ e1)) % (2.0 * math.pi)

    sweep = angle(p1)
    if angle(via) > sweep:  # via lies the other way round
        e2, sweep = -e2, 2.0 * math.pi - sweep
    return centre, radius, e1, e2, sweep


# ---------------------------------------------------------------------------------------------
# Stopping by time scaling


def stop_profile(t_since_stop: float, stop_time_s: float) -> float:
    """The path-rate σ at ``t_since_stop`` after a stop request: 1 → 0 over ``stop_time_s`` as
    1 − quintic(t/T), so σ̇ and σ̈ are zero at both ends (no acceleration step), then 0.

    The TG advances τ by σ·dt; the path is unchanged and every set-point velocity is σ × the
    nominal one, the acceleration σ²·(nominal) + σ̇·(nominal velocity), |σ̇| ≤ 15/(8T).
    """
    if t_since_stop <= 0.0:
        return 1.0
    if t_since_stop >= stop_time_s:
        return 0.0
    s = t_since_stop / stop_time_s
    return 1.0 - s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def stop_time_for(speed: float, decel: float) -> float:
    """The shortest ``stop_time_s`` whose time scaling adds at most ``decel`` to a motion
    moving at ``speed`` (σ̇ peaks at 15/(8T)); any consistent units (m or rad)."""
    return PEAK_SPEED_FACTOR * speed / decel


class StopRamp:
    """A stop requested at path time ``tau_at_stop``: σ(t) and the exact τ(t) = τ₀ + ∫σ.

    The motion is at rest ``stop_time_s`` after the request, at ``tau_at_rest`` = τ₀ + T/2
    (∫₀ᵀ σ = T/2), or earlier at ``duration`` if the motion ends first (``time_to_rest``).
    ``tau(t)`` is exact whatever the tick, so a TG whose period changes on line loses nothing.
    Summing σ·dt instead works too, but with σ taken at the start of each tick it ends dt/2 of
    path time further on (still on the path, still smooth); σ at the middle of the tick,
    σ(t + dt/2), is exact to O(dt³).
    """

    def __init__(self, tau_at_stop: float, stop_time_s: float) -> None:
        what = "stop ramp"
        self.tau_at_stop = _float(what, "tau_at_stop", tau_at_stop, "s")
        self.stop_time_s = _float(what, "stop_time_s", stop_time_s, "s")
        if not self.stop_time_s > 0.0:
            raise MotionError(f"{what}: stop_time_s {self.stop_time_s} s must be > 0")
        self.tau_at_rest = self.tau_at_stop + 0.5 * self.stop_time_s

    def sigma(self, t_since_stop: float) -> float:
        """The path rate σ (inside the cycle)."""
        return stop_profile(t_since_stop, self.stop_time_s)

    def tau(self, t_since_stop: float) -> float:
        """The path time ``t_since_stop`` after the request (inside the cycle)."""
        if t_since_stop <= 0.0:
            return self.tau_at_stop + t_since_stop
        if t_since_stop >= self.stop_time_s:
            return self.tau_at_rest
        s = t_since_stop / self.stop_time_s
        # ∫ quintic = 5/2 s⁴ − 3 s⁵ + s⁶
        return self.tau_at_stop + t_since_stop - self.stop_time_s * s**4 * (2.5 + s * (-3.0 + s))

    def time_to_rest(self, duration: float) -> float:
        """Seconds after the request until a motion of ``duration`` is at rest (outside the
        cycle): ``stop_time_s``, or less if τ reaches ``duration`` first."""
        if self.tau_at_rest <= duration:
            return self.stop_time_s
        if self.tau_at_stop >= duration:
            return 0.0
        lo, hi = 0.0, self.stop_time_s  # τ(t) is increasing: bisect τ(t) = duration
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if self.tau(mid) < duration else (lo, mid)
        return hi


def check_joint_target(robot: str, q: np.ndarray, rtype: RobotType) -> None:
    """MotionError unless ``q`` (float64, one per joint of the robot's type; entries past its
    ``n_joints``, such as a request record's unused columns, are not looked at) is finite and
    within the joint range of the type; the one check the client makes before queueing and
    the TG makes again on taking it."""
    if len(q) < rtype.n_joints:
        raise MotionError(
            f"robot '{robot}' ({rtype.name}) has {rtype.n_joints} joints; "
            f"{len(q)} target values given"
        )
    for j in range(rtype.n_joints):
        v = float(q[j])
        if not math.isfinite(v):
            raise MotionError(f"robot '{robot}' joint {j + 1}: target {v} rad, must be finite")
        lo, hi = float(rtype.q_min[j]), float(rtype.q_max[j])
        if not lo <= v <= hi:
            deg = math.degrees(v)
            shown = f"{deg:.2f}" if abs(deg) < 1e6 else f"{deg:.3g}"  # garbage stays one line
            raise MotionError(
                f"robot '{robot}' joint {j + 1}: target {shown}° outside its "
                f"range {math.degrees(lo):.1f}° .. {math.degrees(hi):.1f}°; nothing moved"
            )


def check_guard(guard: float, robots: list[int], names: list[str], limits: Sequence) -> None:
    """MotionError unless ``guard`` (N; 0: none) can guard a motion of ``robots``: finite,
    not negative, every arm with a wrist sensor (``limits[k]``: its contact limit, None
    without a sensor) and below its contact limit, which would halt first."""
    if not (math.isfinite(guard) and guard >= 0.0):
        raise MotionError(f"guard {guard} N, must be a finite force >= 0 (0: none)")
    if guard == 0.0:
        return
    for k in robots:
        limit = limits[k] if k < len(limits) else None
        if limit is None:
            raise MotionError(
                f"robot '{names[k]}' has no wrist force/torque sensor: a guarded move needs one"
            )
        if guard >= limit:
            raise MotionError(
                f"guard {guard:g} N on robot '{names[k]}' is not below its contact limit "
                f"{limit:g} N, which halts first"
            )
