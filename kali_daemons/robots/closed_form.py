"""Pieces every closed-form inverse kinematics needs (the PUMA's, the UR5's): a target pose
checked rigid, and a joint angle brought within its limits.  Plain ``math`` on Python floats,
as the solvers are: they run every TG tick."""

from __future__ import annotations

import math
from typing import Final

from ..core.errors import KinematicsError

TWO_PI: Final = 2.0 * math.pi
LIMIT_TOL: Final = 1e-10  # rad: a joint this far outside a limit is put on it
RIGID_TOL: Final = 1e-6  # |RᵀR − I| entries, and the bottom row


def into_limits(theta: float, lo: float, hi: float, ref: float) -> float:
    """The 2π-equivalent of ``theta`` within ``lo .. hi`` nearest ``ref``, or NaN if none."""
    t = theta + TWO_PI * round((ref - theta) / TWO_PI)
    if t > hi + LIMIT_TOL:
        t -= TWO_PI * math.ceil((t - hi - LIMIT_TOL) / TWO_PI)
    elif t < lo - LIMIT_TOL:
        t += TWO_PI * math.ceil((lo - LIMIT_TOL - t) / TWO_PI)
    if t > hi + LIMIT_TOL or t < lo - LIMIT_TOL:
        return math.nan
    return hi if t > hi else lo if t < lo else t


def check_rigid(rows: list[list[float]], who: str = "ikine") -> None:
    """Refuse a non-finite or non-rigid transform (``rows``: its 4 rows), naming what is wrong;
    messages start with ``who``."""
    flat = [v for row in rows for v in row]
    if not all(map(math.isfinite, flat)):
        bad = [f"T[{k // 4}, {k % 4}] = {v}" for k, v in enumerate(flat) if not math.isfinite(v)]
        raise KinematicsError(f"{who}: T is not finite: {', '.join(bad)}")
    (nx, ox, ax, _), (ny, oy, ay, _), (nz, oz, az, _), bottom = rows
    gram = (
        nx * nx + ny * ny + nz * nz - 1.0,
        ox * ox + oy * oy + oz * oz - 1.0,
        ax * ax + ay * ay + az * az - 1.0,
        nx * ox + ny * oy + nz * oz,
        nx * ax + ny * ay + nz * az,
        ox * ax + oy * ay + oz * az,
    )
    worst = max(map(abs, gram))
    if worst > RIGID_TOL:
        raise KinematicsError(
            f"{who}: the rotation of T is not orthonormal: max |RᵀR − I| = {worst:.3g} "
            f"> {RIGID_TOL:g}"
        )
    det = ax * (ny * oz - nz * oy) + ay * (nz * ox - nx * oz) + az * (nx * oy - ny * ox)
    if det < 0.0:
        raise KinematicsError(f"{who}: the rotation of T is a reflection (det = {det:.6g})")
    if max(abs(bottom[0]), abs(bottom[1]), abs(bottom[2]), abs(bottom[3] - 1.0)) > RIGID_TOL:
        raise KinematicsError(f"{who}: the bottom row of T is {bottom}, not [0, 0, 0, 1]")
