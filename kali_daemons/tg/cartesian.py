"""Cartesian motion of one motion system: each arm's T6 from the object's path, inverse
kinematics every TG tick, and the whole-path check before anything moves (thesis 2.2.1,
3.3.1; DESIGN 5).

The path is the pose O(τ) of the object's control frame in the world (a
``profiles.CartesianPath``); arm k, based at B_k and holding the object at grasp G_k, has
T6_k(τ) = B_k⁻¹ · O(τ) · G_k, solved near its last set-point in the configuration it starts
in (a straight line cannot change it, 2.2.1).  ``check_some`` walks the path at exactly the
TG's sample times and refuses, naming segment, arm, joint and place, a sample out of reach,
too near a singularity, needing a joint faster than its limit or changing configuration.  A
stop only slows the motion along the same path, so run-time set-points lie between checked
ones; an ``ikine`` failure at run time anyway halts the system (FaultCode.SINGULARITY).
"""

from __future__ import annotations

import math
from bisect import bisect_right
from collections.abc import Sequence
from typing import TYPE_CHECKING, Final

import numpy as np

from ..core import layout
from ..core.errors import KinematicsError
from ..robots import Kinematics, RobotType
from ..robots.cell import inverse
from .profiles import MAX_MOTION_S, CartesianPath, MotionError, rigid_pose

if TYPE_CHECKING:
    from ..robots.collision import ClearanceWalk

GRASP_TOL_M: Final = 0.002  # arms of one motion system must agree on the object's pose to this
GRASP_TOL_RAD: Final = 0.01
SPEED_MARGIN: Final = 1.0 + 1e-9  # rounding allowance on the joint speed limits


def encode_config(config: object | None, kin: Kinematics) -> int:
    """A request's configuration byte (``layout.CONFIG_GIVEN`` | the branch's index in
    ``kin.configs``); None: the arm's own."""
    if config is None:
        return 0
    return layout.CONFIG_GIVEN | kin.configs.index(config)


def decode_config(code: int, kin: Kinematics) -> object | None:
    """The configuration a request's byte names (None: the arm's own); MotionError if bad."""
    if code == 0:
        return None
    index = code - layout.CONFIG_GIVEN
    if not 0 <= index < len(kin.configs):
        raise MotionError(
            f"configuration byte {code:#x} names none of the arm's {len(kin.configs)} "
            f"configurations (layout.CONFIG_GIVEN | 0..{len(kin.configs) - 1})"
        )
    return kin.configs[index]


def rotation_angle(r: np.ndarray) -> float:
    """The angle (rad) of rotation matrix ``r``: how far apart two orientations A, B are
    for r = Aᵀ B."""
    return math.acos(max(-1.0, min(1.0, 0.5 * (float(np.trace(r)) - 1.0))))


def _why(exc: KinematicsError) -> str:
    """An ikine error's message without its "kinematics: ikine: " prefix."""
    return str(exc).removeprefix(f"{exc.subsystem}: ").removeprefix("ikine: ")


def _deg(x: float) -> str:
    return f"{math.degrees(x):.1f}°"


def _xyz(p: np.ndarray) -> str:
    return "(" + ", ".join(f"{float(v):.3f}" for v in p) + ") m"


def held_object(
    names: Sequence[str],
    kins: Sequence[Kinematics],
    bases: Sequence[np.ndarray],
    grasps: list[np.ndarray],
    starts: Sequence[np.ndarray],
    measured: Sequence[np.ndarray] | None = None,
) -> np.ndarray:
    """The object's pose in the world as the arms of one motion system hold it at joints
    ``starts`` (arm 0's view: B_0 · T6 · G_0⁻¹); MotionError if another arm's view differs by
    more than ``GRASP_TOL_M`` / ``GRASP_TOL_RAD``.  ``grasps[k]`` of the other arms is then
    replaced by the grasp each really has, so a motion keeps the arms as they hold the object,
    whatever the (tolerated) disagreement.

    ``measured`` (each arm's measured joints; None while the arms move) is where arms at rest
    really are: the disagreement is judged and the grasps taken from it, not from the
    set-points.  Arms that hold one rigid object are where the object lets them be, and their
    set-points are off that by each arm's servo error; demands that kept the set-points'
    geometry would keep the arms' servos fighting through the object, their integrators
    winding it into a squeeze for as long as the motion lasts.  Taken from where the arms
    are, the other arms' first set-points move by that difference, towards the geometry the
    object holds them in, and arm 0's stays where it is."""
    views = starts if measured is None else measured
    start = bases[0] @ kins[0].fkine(starts[0]) @ inverse(grasps[0])
    held = start if measured is None else bases[0] @ kins[0].fkine(views[0]) @ inverse(grasps[0])
    for k in range(1, len(names)):
        other = bases[k] @ kins[k].fkine(views[k]) @ inverse(grasps[k])
        gap = float(np.linalg.norm(other[:3, 3] - held[:3, 3]))
        turn = rotation_angle(held[:3, :3].T @ other[:3, :3])
        if gap > GRASP_TOL_M or turn > GRASP_TOL_RAD:
            how = "" if measured is None else "as measured at rest, "
            raise MotionError(
                f"robots '{names[0]}' and '{names[k]}' do not hold the object where their "
                f"grasps say: {how}their object poses differ by {gap * 1000:.1f} mm and "
                f"{_deg(turn)} (allowed {GRASP_TOL_M * 1000:g} mm, {_deg(GRASP_TOL_RAD)})"
            )
        grasps[k] = inverse(held) @ bases[k] @ kins[k].fkine(views[k])
    return start


class Arms:
    """The arms of one motion system as a Cartesian motion (a path, ``CartesianMotion``, or a
    tracking one, ``tracking.TrackingMotion``) drives them, checked (construction):
    ``kin``, ``qd_max``, ``bases`` (B_k), ``to_base`` (B_k⁻¹), ``grasps`` (G_k, rigid),
    ``starts`` (each arm's joints, its type's count), ``measured`` (where arms starting at
    rest really are, as many; None: moving) and ``configs`` (each arm's own, which a request
    naming another is refused for: ``keeps`` says why, with ``{want}``).  MotionError for
    lists that do not match or a start of the wrong length."""

    def __init__(
        self,
        what: str,
        names: Sequence[str],
        types: Sequence[RobotType],
        bases: Sequence[np.ndarray],
        grasps: Sequence[np.ndarray],
        q_start: np.ndarray | Sequence[np.ndarray],
        configs: Sequence[object | None],
        keeps: str,
        measured: Sequence[np.ndarray] | None = None,
    ) -> None:
        n = len(names)
        if not len(grasps) == len(bases) == len(configs) == len(types) == n:
            raise MotionError(
                f"{what}: {n} arms, but {len(grasps)} grasps, {len(bases)} bases and "
                f"{len(configs)} configurations"
            )
        if len(q_start) != n:
            raise MotionError(f"{what}: {n} arms, but {len(q_start)} start rows")
        if measured is not None and len(measured) != n:
            raise MotionError(f"{what}: {n} arms, but {len(measured)} measured rows")
        self.kin = [t.kinematics for t in types]
        self.qd_max = [tuple(float(v) for v in t.qd_max) for t in types]
        self.bases = [np.asarray(b, dtype=np.float64) for b in bases]
        self.to_base = [inverse(b) for b in self.bases]
        self.grasps = [
            rigid_pose(what, f"grasp of robot '{names[k]}'", g) for k, g in enumerate(grasps)
        ]
        self.starts = [np.array(q, dtype=np.float64).reshape(-1) for q in q_start]
        self.measured = (
            None
            if measured is None
            else [np.array(q, dtype=np.float64).reshape(-1) for q in measured]
        )
        for rows, at in ((self.starts, "starts"), (self.measured or [], "is measured")):
            for k, (q, t) in enumerate(zip(rows, types[: len(rows)], strict=True)):
                if q.shape != (t.n_joints,):
                    raise MotionError(
                        f"{what}: robot '{names[k]}' ({t.name}, {t.n_joints} joints) {at} "
                        f"at {q.size} joint angles"
                    )
        self.configs: list[object] = []
        for k in range(n):
            have = self.kin[k].config_of(self.starts[k])
            want = configs[k]
            if want is not None and want != have:
                raise MotionError(
                    f"robot '{names[k]}' is in configuration '{have}', the request asks for "
                    f"'{want}': {keeps.format(want=want)}"
                )
            self.configs.append(have)


class CartesianMotion:
    """One Cartesian request of one motion system: planned, checked, then sampled per tick.

    ``names`` are the arms' names (messages), ``types`` their robot types, ``bases`` their B_k and
    ``grasps`` their G_k, ``q_start`` where each arm starts (one row per arm, as many angles as its
    type has joints: a list, or a 2-D array when the arms have the same count), ``measured``
    where arms starting at rest really are (their grasps are taken from it: ``held_object``;
    None: from ``q_start``), ``configs`` the configuration each must keep (None: the one it
    starts in), ``targets`` the object's poses in the world, ``dt`` the TG period (s).  Raises
    ``MotionError`` when the request cannot even be planned: a start of the wrong length, arms
    that do not agree on where the object is, a configuration other than the arm's, a bad path.
    """

    def __init__(
        self,
        names: Sequence[str],
        types: Sequence[RobotType],
        bases: Sequence[np.ndarray],
        grasps: Sequence[np.ndarray],
        q_start: np.ndarray | Sequence[np.ndarray],
        configs: Sequence[object | None],
        targets: Sequence[np.ndarray],
        speed: float,
        angular_speed: float,
        transition_s: float,
        dt: float,
        durations: Sequence[float] | None = None,
        arcs: Sequence[Sequence[float] | np.ndarray | None] | None = None,
        measured: Sequence[np.ndarray] | None = None,
    ) -> None:
        self.names = list(names)
        n = len(self.names)
        self.n = n
        self.dt = float(dt)
        arms = Arms(
            "cartesian motion", names, types, bases, grasps, q_start, configs,
            "a straight line cannot change configuration (move_joints into '{want}' first)",
            measured,
        )  # fmt: skip
        self._kin, self._qd_max, self.configs = arms.kin, arms.qd_max, arms.configs
        self._bases, self._to_base, self._grasps = arms.bases, arms.to_base, arms.grasps
        starts = arms.starts
        self.request_grasp = np.array(grasps[0], dtype=np.float64)  # the first arm's, as given
        # scratch, so sampling allocates nothing
        self._obj = np.empty((4, 4))
        self._tmp = np.empty((4, 4))
        self._t6 = np.empty((4, 4))
        self._q = [np.empty(t.n_joints) for t in types]  # per arm: the check's solution
        start = held_object(self.names, self._kin, self._bases, self._grasps, starts, arms.measured)
        self.path = CartesianPath(
            start,
            list(targets),
            speed,
            angular_speed,
            transition_s,
            durations=durations,
            arcs=arcs,
        )
        for i in range(1, len(self.path.poses)):  # each target first: the plainest refusal
            np.copyto(self._obj, self.path.poses[i])
            for k in range(n):
                try:
                    self._kin[k].ikine(self._t6_of(k), self.configs[k])
                except KinematicsError as exc:
                    raise MotionError(
                        f"path refused: targets[{i - 1}] at {_xyz(self._obj[:3, 3])}: robot "
                        f"'{self.names[k]}': {_why(exc)}"
                    ) from None
        self.duration = float(self.path.duration)
        if not self.duration <= MAX_MOTION_S:  # also NaN, inf: a speed of 1e-300 m/s
            raise MotionError(
                f"path refused: it would last {self.duration:.3g} s, more than the "
                f"{MAX_MOTION_S:g} s a motion may take (speed {self.path.speed:g} m/s, "
                f"angular_speed {self.path.angular_speed:g} rad/s)"
            )
        self.n_samples = max(1, math.ceil(self.duration / self.dt - 1e-9))
        # each arm's last set-point (its own width): ikine's q_ref at run time
        self.q_ref = [q.copy() for q in starts]
        # the check's own walk
        self.checked = 0  # samples checked so far (1..n_samples)
        # the TG's walk of the cell's clearances along the samples (None: not checked here,
        # as in a client's own check before it queues the request)
        self.clearance: ClearanceWalk | None = None
        self._check_q = [q.copy() for q in starts]

    # ------------------------------------------------------------------ frames

    def _t6_of(self, k: int) -> np.ndarray:
        """T6 of arm ``k`` for the object pose in ``_obj`` (into scratch; no allocation)."""
        np.matmul(self._to_base[k], self._obj, out=self._tmp)
        np.matmul(self._tmp, self._grasps[k], out=self._t6)
        return self._t6

    # ------------------------------------------------------------------ the check

    def segment_label(self, tau: float) -> str:
        """Which segment path time ``tau`` is in, for messages ("segment 2 of 4")."""
        n_seg = len(self.path.segment_times)
        s = min(max(bisect_right(self.path.via_times.tolist(), tau), 1), n_seg)
        return f"segment {s} of {n_seg}"

    def check_some(self, samples: int) -> bool:
        """Check up to ``samples`` more path samples; True once the whole path is checked.

        Raises ``MotionError`` with the reason at the first sample that fails.
        """
        end = min(self.n_samples, self.checked + samples)
        while self.checked < end:
            self.checked += 1
            tau = min(self.checked * self.dt, self.duration)
            self.path.sample(tau, self._obj)
            for k in range(self.n):
                self._check_sample(k, tau, self._check_q[k])
            if self.clearance is not None:
                near = self.clearance.refused(self._check_q)
                if near is not None:
                    raise MotionError(
                        f"path refused: {self.segment_label(tau)}, {tau:.2f} s into the motion, "
                        f"object at {_xyz(self._obj[:3, 3])}: "
                        f"{near.within(self.clearance.cell.clearance)}"
                    )
        return self.checked >= self.n_samples

    @property
    def progress(self) -> float:
        """How much of the path is checked (0 .. 1)."""
        return self.checked / self.n_samples

    def check_all(self) -> None:
        """The whole check at once (the client's, before it queues the request)."""
        self.check_some(self.n_samples)

    def _refuse(self, k: int, tau: float, what: str) -> MotionError:
        where = _xyz(self._obj[:3, 3])
        return MotionError(
            f"path refused: {self.segment_label(tau)}, {tau:.2f} s into the motion, object at "
            f"{where}: robot '{self.names[k]}' {what}"
        )

    def _check_sample(self, k: int, tau: float, prev: np.ndarray) -> None:
        """Check arm ``k``'s solution for the object pose in ``_obj`` against ``prev``, its
        solution a TG period before (updated); MotionError naming what fails."""
        t6 = self._t6_of(k)
        try:
            q = self._kin[k].ikine(t6, self.configs[k], q_ref=prev, out=self._q[k])
        except KinematicsError as exc:
            raise self._refuse(k, tau, _why(exc)) from None
        near = self._kin[k].singular(q)
        if near is not None:
            raise self._refuse(k, tau, near)
        qd_max = self._qd_max[k]
        for j in range(len(qd_max)):
            speed = abs(float(q[j]) - float(prev[j])) / self.dt
            if speed > qd_max[j] * SPEED_MARGIN:
                raise self._refuse(
                    k,
                    tau,
                    f"needs joint {j + 1} at {math.degrees(speed):.1f}°/s, above its limit "
                    f"{math.degrees(qd_max[j]):.0f}°/s (slow the path down)",
                )
        have = self._kin[k].config_of(q)
        if have != self.configs[k]:
            raise self._refuse(
                k, tau, f"would change configuration from '{self.configs[k]}' to '{have}'"
            )
        prev[:] = q

    def end_q(self) -> list[np.ndarray]:
        """Each arm's joints at the path's end (a copy): where a motion blended after this
        one starts.  Known once the whole path is checked (the check walks to the end)."""
        assert self.checked >= self.n_samples, "end_q before the check reached the end"
        return [q.copy() for q in self._check_q]

    def check_poses(self, poses: Sequence[np.ndarray], q_start: Sequence[np.ndarray]) -> None:
        """Check the object poses ``poses`` one TG period apart as the path's own samples are
        checked (reach, singularities, joint speeds, configuration), the arms starting at
        ``q_start``; MotionError naming the first that fails.  Outside the cycle (a blend's
        window, before the blend is taken)."""
        prev = [np.array(q, dtype=np.float64) for q in q_start]
        for i, pose in enumerate(poses):
            np.copyto(self._obj, pose)
            for k in range(self.n):
                self._check_sample(k, (i + 1) * self.dt, prev[k])

    def solve(self, obj: np.ndarray) -> list[np.ndarray]:
        """Every arm's joints holding the object at ``obj``, each near its last set-point
        (``q_ref``, overwritten and returned).  ``KinematicsError`` if an arm has none.
        Inside the cycle: nothing allocated unless it fails."""
        np.copyto(self._obj, obj)
        rows = self.q_ref
        for k in range(self.n):
            self._kin[k].ikine(self._t6_of(k), self.configs[k], q_ref=rows[k], out=rows[k])
        return rows

    # ------------------------------------------------------------------ run time

    def sample(self, tau: float) -> list[np.ndarray]:
        """Every arm's joint set-point at path time ``tau``, each solved near its last one;
        returns ``q_ref``, one array per arm of its type's joint count (overwritten next
        time).  ``KinematicsError`` if an arm has no solution.  Inside the cycle: nothing
        allocated unless it fails."""
        self.path.sample(tau, self._obj)
        rows = self.q_ref
        for k in range(self.n):
            self._kin[k].ikine(self._t6_of(k), self.configs[k], q_ref=rows[k], out=rows[k])
        return rows
