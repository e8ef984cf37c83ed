"""A request as the TG takes it (DESIGN 7): checked field by field (``check_request``: kind,
robot count and indices, finite numbers in range, segment count, configuration bytes,
calibration) and planned (``plan_joints``, ``plan_path``: a motion longer than
``MAX_MOTION_S`` is refused too), or refused with the reason (``refusal``).  Outside the
cycle's hot part: once per request taken.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..core import layout
from ..core.layout import (
    MotionKind,
)
from ..robots import RobotType
from .cartesian import CartesianMotion, decode_config
from .profiles import (
    MAX_MOTION_S,
    JointMotion,
    MotionError,
    check_guard,
    check_joint_target,
)
from .tracking import (
    check_limits,
    check_loop,
    check_track_time,
)

_KINDS = frozenset(int(k) for k in MotionKind)


def request_robots(req: np.void, n_robots: int) -> list[int]:
    """The robot indices request ``req`` names (``n_robots`` of them, distinct, each in
    0 .. ``n_robots`` - 1 of this cell); MotionError naming the bad count or index."""
    n = int(req["n_robots"])
    if not 1 <= n <= n_robots:
        raise MotionError(f"{n} robots in the request; this cell has 1 to {n_robots}")
    robots = [int(k) for k in req["robots"][:n]]
    for k in robots:
        if not 0 <= k < n_robots:
            raise MotionError(f"robot index {k}; robots are 0..{n_robots - 1}")
    if len(set(robots)) != n:
        raise MotionError(f"robot listed twice: {robots}")
    return robots


def check_request(
    req: np.void,
    names: list[str],
    types: list[RobotType],
    calibrated: np.ndarray | None = None,
    contact_limits: Sequence[float | None] = (),
) -> tuple[MotionKind, list[int]]:
    """(kind, robot indices) of request ``req`` (one ``layout.MOTION_REQUEST``), after
    checking everything that does not need the arms' start; MotionError with the reason.

    ``names`` are the cell's robots and ``types`` their robot types; ``calibrated`` (per robot,
    None: not known yet) is needed by a PATH; ``contact_limits`` (per robot, None without a
    wrist sensor) by a guard.  Checks the kind, the robots (``request_robots``), a guard
    (``check_guard``), for JOINTS the speed scale in (0, 1], each target finite and within the
    joint range and the row's columns past the robot's joint count 0, for PATH the segment
    count, finite speeds, targets and grasps and valid configuration bytes.  Pure: the TG
    calls it on every request it takes, tests call it on random bytes.
    """
    kind = int(req["kind"])
    if kind not in _KINDS:
        allowed = ", ".join(f"{k.value} ({k.name})" for k in MotionKind)
        raise MotionError(f"motion kind {kind} is not one this TG carries out; kinds: {allowed}")
    robots = request_robots(req, len(names))
    if kind in (MotionKind.JOINTS, MotionKind.PATH):
        check_guard(float(req["guard_n"]), robots, names, contact_limits)
    if kind == MotionKind.JOINTS:
        scale = float(req["speed_scale"])
        if not (math.isfinite(scale) and 0.0 < scale <= 1.0):
            raise MotionError(f"speed_scale {scale}, must be in (0, 1]")
        for i, k in enumerate(robots):
            row = req["joints"][i]
            check_joint_target(names[k], row, types[k])
            n = types[k].n_joints
            extra = np.flatnonzero(row[n:])  # NaN is not 0 either
            if extra.size:
                j = n + int(extra[0])
                raise MotionError(
                    f"robot '{names[k]}' ({types[k].name}) has {n} joints, but the request "
                    f"gives joint {j + 1} a target ({float(row[j])} rad)"
                )
    elif kind == MotionKind.PATH:
        n_seg = int(req["n_segments"])
        if not 1 <= n_seg <= layout.MAX_SEGMENTS:
            raise MotionError(f"{n_seg} path targets; 1 to {layout.MAX_SEGMENTS} allowed")
        for field_name in ("speed", "angular_speed", "transition_s"):
            value = float(req[field_name])
            if not math.isfinite(value):
                raise MotionError(f"path {field_name} is {value}, must be finite")
        for i in range(n_seg):
            if int(req["arcs"][i]) not in (0, 1) or not np.isfinite(req["arc_via"][i]).all():
                raise MotionError(f"path arcs[{i}] is not 0/1 with a finite point")
            d = float(req["durations"][i])
            if not (math.isfinite(d) and 0.0 <= d <= MAX_MOTION_S):
                raise MotionError(f"path durations[{i}] is {d} s; 0 (by speed) to {MAX_MOTION_S:g}")
        for i in range(n_seg):
            if not np.isfinite(req["poses"][i]).all():
                raise MotionError(f"path targets[{i}] is not finite")
        _check_arms(req, robots, names, types, calibrated)
    elif kind == MotionKind.TRACK:
        check_limits(req)
        check_loop(req)
        _check_arms(req, robots, names, types, calibrated)
    elif kind == MotionKind.TRACK_JOINTS:
        scale = float(req["speed_scale"])
        if not (math.isfinite(scale) and 0.0 < scale <= 1.0):
            raise MotionError(f"speed_scale {scale}, must be in (0, 1]")
        check_track_time(float(req["track_s"]))
        kind_0, index = (int(v) for v in req["loop"][0])
        if len(robots) != 1 or int(req["n_loop"]) != 1 or kind_0 != layout.FrameKind.SHARED:
            raise MotionError("a joint stream is one robot following one shared record")
        if index >= layout.MAX_FRAMES:
            raise MotionError(f"shared record {index}; 0..{layout.MAX_FRAMES - 1}")
    return MotionKind(kind), robots


def _check_arms(
    req: np.void,
    robots: list[int],
    names: list[str],
    types: list[RobotType],
    calibrated: np.ndarray | None,
) -> None:
    """A Cartesian request's arms (PATH, TRACK): each one's configuration byte valid, its
    grasp finite, and (when known) calibrated; MotionError naming the robot."""
    for i, k in enumerate(robots):
        decode_config(int(req["config"][i]), types[k].kinematics)
        if not np.isfinite(req["grasps"][i]).all():
            raise MotionError(f"grasp of robot '{names[k]}' is not finite")
        if calibrated is not None and not int(calibrated[k]):
            raise MotionError(
                f"robot '{names[k]}' is not calibrated; Cartesian motion needs its true "
                f"joint angles (kalictl calibrate {names[k]})"
            )


def _bounded(what: str, duration: float) -> None:
    """MotionError unless a planned motion ends within ``MAX_MOTION_S``."""
    if not (math.isfinite(duration) and duration <= MAX_MOTION_S):
        raise MotionError(
            f"{what} would last {duration:.3g} s, more than the {MAX_MOTION_S:g} s a request "
            f"may take; nothing moved"
        )


def plan_joints(
    req: np.void, robots: list[int], start: np.ndarray, types: list[RobotType]
) -> JointMotion:
    """The joint motion a checked JOINTS request asks for, from ``start`` (each robot's joints
    one after another, as many as its type has) with the per-joint limits of each robot's type
    (``qd_max``, ``qdd_max``) scaled by its speed scale; MotionError if it cannot be planned or
    would outlast ``MAX_MOTION_S``."""
    scale = float(req["speed_scale"])
    target = np.concatenate([req["joints"][i][: types[k].n_joints] for i, k in enumerate(robots)])
    v_max = np.concatenate([types[k].qd_max for k in robots]) * scale
    a_max = np.concatenate([types[k].qdd_max for k in robots]) * scale
    profile = JointMotion(start, target, v_max, a_max)
    _bounded("joint motion", profile.duration)
    return profile


def plan_path(
    req: np.void,
    robots: list[int],
    names: list[str],
    types: list[RobotType],
    bases: list[np.ndarray],
    start: Sequence[np.ndarray],
    dt: float,
    measured: Sequence[np.ndarray] | None = None,
) -> CartesianMotion:
    """The Cartesian motion a checked PATH request asks for, its arms starting at ``start``
    (one row per robot, its type's joint count long; ``measured``: where they are, when they
    start at rest), sampled every ``dt`` s; MotionError if it cannot be planned or would
    outlast ``MAX_MOTION_S`` (the whole-path check is ``CartesianMotion.check_some``, run
    afterwards)."""
    n = len(robots)
    return CartesianMotion(
        [names[k] for k in robots],
        [types[k] for k in robots],
        [bases[k] for k in robots],
        [req["grasps"][i] for i in range(n)],
        start,
        [decode_config(int(req["config"][i]), types[k].kinematics) for i, k in enumerate(robots)],
        [req["poses"][i] for i in range(int(req["n_segments"]))],
        float(req["speed"]),
        float(req["angular_speed"]),
        float(req["transition_s"]),
        dt,
        [float(d) for d in req["durations"][: int(req["n_segments"])]],
        [
            req["arc_via"][i].copy() if int(req["arcs"][i]) else None
            for i in range(int(req["n_segments"]))
        ],
        measured,
    )


def refusal(exc: Exception) -> str:
    """The status message refusing a request that raised ``exc`` while being checked or
    planned: a MotionError's own words (the client's error names the subsystem: once);
    anything else named, so nothing is hidden."""
    if isinstance(exc, MotionError):
        return str(exc).removeprefix(f"{MotionError.subsystem}: ")
    return f"request refused: it could not be checked ({type(exc).__name__}: {exc})"
