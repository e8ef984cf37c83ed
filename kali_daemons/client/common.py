"""What the client's modules share: the instance a program attaches to by default, the
errors a motion ends with, where a guarded move touched, a pose from a point and a rotation,
and the checks every call runs on its arguments (a bad one raises ``MotionError`` naming it).
Outside any cycle.
"""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..core import layout
from ..core.errors import KinematicsError, MotionError
from ..robots import Kinematics
from ..runtime.instance import Instance
from ..tg.profiles import check_guard

if TYPE_CHECKING:
    from .motion import Kali

DEFAULT_INSTANCE = "default"
INSTANCE_ENV = "KALI_INSTANCE"  # set by `kalictl -i NAME run PROGRAM`


class MotionFailedError(MotionError):
    """The system halted (or the request was refused, stopped or aborted) while waiting."""


class RequestLostError(MotionFailedError):
    """The request's status record holds a later request: its outcome cannot be told."""


def fault_since(inst: Instance, epoch: int) -> str | None:
    """The fault that halts a request put at fault count ``epoch``: the active one, or one
    raised (and maybe cleared) since; None if there is none."""
    if inst.fault_text() is not None or int(inst.fault["count"]) > epoch:
        return inst.fault_text(last=True) or "the system halted"
    return None


def program_name() -> bytes:
    """This program's name as requests carry it (the script's file name, else the pid)."""
    path = sys.argv[0] if sys.argv else ""
    name = os.path.basename(path)
    if name == "__main__.py":  # python -m PACKAGE
        name = os.path.basename(os.path.dirname(path))
    if name in ("", "-c", "-m"):
        name = f"python pid {os.getpid()}"
    return name.encode()[: layout.PROGRAM_BYTES]


@dataclass(frozen=True)
class Contact:
    """Where a guarded move touched: the robot whose wrist sensor felt the guard's force,
    its tool point then (world, m), the contact force that tripped the guard (N, the
    sample's magnitude) and the contact wrench then (world axes, N and N·m, low-passed
    as ``Robot.read_wrench``: it lags the sample)."""

    robot: str
    position: np.ndarray
    force: float
    wrench: np.ndarray


def pose(xyz: Sequence[float], rotation: np.ndarray | None = None) -> np.ndarray:
    """A 4×4 pose at ``xyz`` (m) with ``rotation`` (3×3, or a 4×4 whose rotation is taken;
    default: the identity)."""
    t = np.eye(4)
    t[:3, 3] = np.asarray(xyz, dtype=np.float64).reshape(3)
    if rotation is not None:
        r = np.asarray(rotation, dtype=np.float64)
        t[:3, :3] = r[:3, :3]
    return t


def _real_array(what: str, value: object, expected: str) -> np.ndarray:
    """``value`` as a float64 array if it holds real numbers (not complex, text, objects or
    bools, which numpy would convert or refuse in its own words); MotionError otherwise."""
    try:
        raw = np.asarray(value)
        if raw.dtype.kind not in "iuf":
            raise TypeError(f"dtype {raw.dtype}")
        return raw.astype(np.float64)
    except (TypeError, ValueError) as exc:
        raise MotionError(f"{what}: {value!r:.60} is not {expected} ({exc})") from None


def _pose_arg(what: str, value: object) -> np.ndarray:
    t = _real_array(what, value, "a 4×4 pose")
    if t.shape != (4, 4):
        raise MotionError(f"{what}: shape {t.shape}, expected a 4×4 pose")
    if not np.isfinite(t).all():
        raise MotionError(f"{what}: not finite")
    return t


def _config_arg(what: str, value: object, kin: Kinematics) -> object | None:
    """A configuration of the arm's type: one of ``kin.configs``, its string, or None."""
    if value is None:
        return None
    if isinstance(value, str):
        try:
            return kin.parse_config(value)
        except KinematicsError as exc:
            raise MotionError(f"{what}: {exc}") from None
    try:
        known = value in kin.configs
    except (TypeError, ValueError):  # an array compares element-wise: no truth value
        known = False
    if not known:
        raise MotionError(
            f"{what}: {value!r:.60} is not one of the arm's configurations "
            f"({', '.join(map(str, kin.configs))}), nor None"
        )
    return value


def _timeout_arg(what: str, value: object) -> float | None:
    """A timeout in seconds: None (no limit) or a number >= 0; MotionError otherwise."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, int | float) or not value >= 0:
        raise MotionError(f"{what}: timeout {value!r:.60}, must be None or seconds >= 0")
    return float(value)


def _flag_arg(what: str, name: str, value: object) -> bool:
    """A yes/no argument (``wait``, ``close``): a bool or 0/1; MotionError otherwise."""
    if isinstance(value, bool | np.bool_) or (
        isinstance(value, int | np.integer) and int(value) in (0, 1)
    ):
        return bool(value)
    raise MotionError(f"{what}: {name} {value!r:.60} is not True or False")


def _list_arg(what: str, name: str, value: object) -> list:
    """A sequence argument (poses, names, configurations) as a list; MotionError if it is
    none (a number, None, a mapping: iterating a mapping would take its keys)."""
    if isinstance(value, Mapping | str | bytes) or value is None:
        raise MotionError(f"{what}: {name} {value!r:.60} is not a list")
    try:
        return list(value)  # type: ignore[call-overload]
    except TypeError:
        raise MotionError(f"{what}: {name} {value!r:.60} is not a list") from None


def _speed_arg(what: str, name: str, value: object) -> float:
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise MotionError(f"{what}: {name} {value!r:.60} is not a finite number")
    return float(value)


FT_FRAMES = ("world", "tool", "sensor")  # Robot.read_wrench's frames (layout.FT_STATE fields)


def _arcs_arg(what: str, arcs: object, n: int) -> list[np.ndarray | None]:
    """``arcs`` (None, or one per segment: a point [x, y, z] the arc passes, or None for a
    line) checked; MotionError naming the bad one."""
    if arcs is None:
        return [None] * n
    items = _list_arg(what, "arcs", arcs)
    if len(items) != n:
        raise MotionError(f"{what}: {len(items)} arcs for {n} segments")
    out: list[np.ndarray | None] = []
    for i, v in enumerate(items):
        if v is None:
            out.append(None)
            continue
        point = _real_array(f"{what}: arcs[{i}]", v, "a point [x, y, z]")
        if point.shape != (3,):
            raise MotionError(f"{what}: arcs[{i}] has shape {point.shape}, not a point (3,)")
        out.append(point)
    return out


def _durations_arg(what: str, durations: object, n: int) -> list[float]:
    """``durations`` (None, or one per segment: s > 0, or None for "by the speeds") as
    floats, 0 meaning by the speeds; MotionError naming the bad one."""
    if durations is None:
        return [0.0] * n
    items = _list_arg(what, "durations", durations)
    if len(items) != n:
        raise MotionError(f"{what}: {len(items)} durations for {n} segments")
    out = []
    for i, d in enumerate(items):
        if d is None:
            out.append(0.0)
            continue
        if (
            isinstance(d, bool)
            or not isinstance(d, int | float)
            or not (math.isfinite(d) and d > 0.0)
        ):
            raise MotionError(f"{what}: durations[{i}] is {d!r:.40}; a time in s > 0, or None")
        out.append(float(d))
    return out


def _guard_arg(what: str, guard: object, kali: Kali, robots: list[int]) -> float:
    """A guarded move's contact force (N; None: unguarded, 0.0), checked as the TG will
    (``check_guard``): every arm with a wrist sensor, the force below its contact limit."""
    if guard is None:
        return 0.0
    if isinstance(guard, bool) or not isinstance(guard, int | float):
        raise MotionError(f"{what}: guard {guard!r:.60}, must be a force in N")
    cfg = kali.inst.config
    limits = [None if r.ft.sheet is None else r.ft.contact_limit_n for r in cfg.robots]
    try:
        check_guard(float(guard), robots, kali.names, limits)
    except MotionError as exc:
        raise MotionError(f"{what}: {str(exc).removeprefix('motion: ')}") from None
    return float(guard)


def _name_arg(name: str, value: object) -> str:
    """A body's name for ``Kali.distance``; MotionError for anything but a string."""
    if not isinstance(value, str):
        raise MotionError(f"distance: {name} {value!r:.60} is not a body's name")
    return value
