"""UR5 kinematics in closed form: T6 from joint angles and back, its 8 branches, singularities.

Standard DH from ``facts`` (a2 and a3 negative, as in UR's table); ``T6`` is DH frame 6, the
flange, in the base frame, with no tool: the ``flange`` link of ``robots/ur5/ur5.urdf`` and the
toolbox's ``fkine``.  The closed form follows Hawkins, "Analytic inverse kinematics for the
Universal Robots UR-5/UR-10 arms" (2013).  Branches are three geometric flags written in the
PUMA's letters (``Branch``; the home pose is 'lun'), and ``singular`` refuses a Cartesian
path within the PUMA's thresholds of the singularities of det J = a2·a3·s3·s5·s.  The
derivation, the branch definitions and the singularities are in
docs/internals/robots-hardware-plant.md.

Plain ``math`` on Python floats like the PUMA's: ``fkine``/``ikine`` with ``out`` given,
``config_of`` and ``singular`` allocate nothing numpy on the success path.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

import numpy as np

from ...core.errors import KinematicsError
from ..closed_form import check_rigid, into_limits
from ..profile import FloatArray
from . import facts

_D1: Final = float(facts.D[0])
_A2: Final = float(facts.A[1])
_A3: Final = float(facts.A[2])
_D4: Final = float(facts.D[3])
_D5: Final = float(facts.D[4])
_D6: Final = float(facts.D[5])
_LO: Final = tuple(float(v) for v in facts.Q_MIN)
_HI: Final = tuple(float(v) for v in facts.Q_MAX)
_N: Final = facts.NJOINTS

REACH_MIN: Final = abs(abs(_A2) - abs(_A3))  # m, shoulder to joint 4's axis in the arm plane
REACH_MAX: Final = abs(_A2) + abs(_A3)  # m

# Tolerances, as the PUMA's: a pose exactly on a boundary may miss it by rounding.
REACH_TOL: Final = 1e-12  # on s² (m²) and on |cos θ3| − 1
WRIST_SINGULAR: Final = 1e-10  # |sin θ5| below this is θ5 = 0 and θ6 is taken from q_ref

# Singularity thresholds for Cartesian paths: the PUMA's (robots/puma560/kinematics.py).
SHOULDER_MIN_M: Final = 0.05
ELBOW_MIN_M: Final = 0.05
WRIST_MIN_DEG: Final = 5.0


def _check_geometry() -> None:
    """The closed form is written for this DH pattern; refuse constants that break it."""
    alpha = np.degrees(facts.ALPHA)
    if (
        any(facts.A[[0, 3, 4, 5]])
        or any(facts.D[[1, 2]])
        or not np.allclose(alpha, [90, 0, 0, 90, -90, 0])
    ):
        raise KinematicsError(
            f"ur5: closed form needs a = (0, a2, a3, 0, 0, 0), d = (d1, 0, 0, d4, d5, d6), "
            f"α = (90, 0, 0, 90, -90, 0)°; got a = {facts.A}, d = {facts.D}, α = {alpha}°"
        )


_check_geometry()


@dataclass(frozen=True, slots=True)
class Branch:
    """One of the UR5's 8 inverse-kinematics solutions, by three geometric flags.

    ``right``: shoulder RIGHT ('r') when s ≥ 0, else LEFT ('l'); ``up``: elbow UP ('u') when
    s·sin θ3 < 0, else DOWN ('d'); ``flip``: wrist FLIP ('f') when sin θ5 > 0, else NOFLIP
    ('n').  docs/internals/robots-hardware-plant.md defines s and why the flags read as named.
    Written as three letters, shoulder, elbow, wrist, like the PUMA's:
    ``str(Branch(False, True, False)) == "lun"`` (the home pose).
    """

    right: bool
    up: bool
    flip: bool

    def __str__(self) -> str:
        return (
            ("r" if self.right else "l") + ("u" if self.up else "d") + ("f" if self.flip else "n")
        )


BRANCHES: Final = tuple(
    Branch(r, u, f) for r in (True, False) for u in (True, False) for f in (False, True)
)
_BY_NAME: Final = {str(b): b for b in BRANCHES}


def parse_branch(text: str) -> Branch:
    """A branch from its three letters, shoulder l/r, elbow u/d, wrist n/f (case ignored)."""
    branch = _BY_NAME.get(text.lower()) if isinstance(text, str) else None
    if branch is None:
        raise KinematicsError(
            f"ur5: configuration {text!r}: expected three letters in the order shoulder (l/r), "
            f"elbow (u/d), wrist (n/f), e.g. 'lun' (the home pose) or 'rdf'"
        )
    return branch


def _joints(q: FloatArray | list[float] | tuple[float, ...]) -> tuple[float, ...]:
    """The six angles as Python floats (no numpy temporaries)."""
    if isinstance(q, np.ndarray):
        return q.item(0), q.item(1), q.item(2), q.item(3), q.item(4), q.item(5)
    if len(q) != _N:
        raise KinematicsError(f"ur5: expected {_N} joint angles, got {len(q)}")
    return tuple(float(v) for v in q)


def _reach(q2: float, q3: float, q234: float) -> float:
    """s: the wrist point's coordinate along x1 (signed distance from the plane of axes 1, 2)."""
    return _A2 * math.cos(q2) + _A3 * math.cos(q2 + q3) + _D5 * math.sin(q234)


def branch_of(q: FloatArray | list[float] | tuple[float, ...]) -> Branch:
    """The branch of joint angles ``q`` (rad) by ``Branch``'s definitions.  Inside the cycle."""
    _, q2, q3, q4, q5, _ = _joints(q)
    s = _reach(q2, q3, q2 + q3 + q4)
    # BRANCHES is ordered right, up, flip with True first and flip False first
    return BRANCHES[
        (0 if s >= 0.0 else 4)
        + (0 if s * math.sin(q3) < 0.0 else 2)
        + (1 if math.sin(q5) > 0.0 else 0)
    ]


def fkine(
    q: FloatArray | list[float] | tuple[float, ...], out: FloatArray | None = None
) -> FloatArray:
    """T6, the flange, in the base frame for joint angles ``q`` (rad), as a 4×4.

    Written into ``out`` when given (then nothing numpy is allocated: inside the cycle).
    Works in DH frame 1's axes (x1, y1 = z0, z1), where joints 2-4 turn about z1:
    x4 = (c234, s234, 0), y4 = z1, z4 = (s234, −c234, 0); R45 = Rz(θ5)·Rx(−90°) gives
    x5 = c5·x4 + s5·y4, y5 = −z4, z5 = −s5·x4 + c5·y4; R56 = Rz(θ6).
    """
    q1, q2, q3, q4, q5, q6 = _joints(q)
    c1, s1 = math.cos(q1), math.sin(q1)
    q23 = q2 + q3
    q234 = q23 + q4
    c234, s234 = math.cos(q234), math.sin(q234)
    c5, s5 = math.cos(q5), math.sin(q5)
    c6, s6 = math.cos(q6), math.sin(q6)
    # x5, y5, z5 in frame-1 coordinates
    x5x, x5y, x5z = c5 * c234, c5 * s234, s5
    y5x, y5y = -s234, c234  # y5z = 0
    z5x, z5y, z5z = -s5 * c234, -s5 * s234, c5
    # x6 = c6·x5 + s6·y5, y6 = −s6·x5 + c6·y5 (frame 1)
    x6x, x6y, x6z = c6 * x5x + s6 * y5x, c6 * x5y + s6 * y5y, c6 * x5z
    y6x, y6y, y6z = -s6 * x5x + c6 * y5x, -s6 * x5y + c6 * y5y, -s6 * x5z
    # the flange's origin, frame 1, from the shoulder
    px1 = _A2 * math.cos(q2) + _A3 * math.cos(q23) + _D5 * s234 + _D6 * z5x
    py1 = _A2 * math.sin(q2) + _A3 * math.sin(q23) - _D5 * c234 + _D6 * z5y
    pz1 = _D4 + _D6 * z5z
    # frame 1 -> base: (a, b, c) -> (a·c1 + c·s1, a·s1 − c·c1, b)
    if out is None:
        out = np.empty((4, 4))
    out[0, 0] = x6x * c1 + x6z * s1
    out[1, 0] = x6x * s1 - x6z * c1
    out[2, 0] = x6y
    out[0, 1] = y6x * c1 + y6z * s1
    out[1, 1] = y6x * s1 - y6z * c1
    out[2, 1] = y6y
    out[0, 2] = z5x * c1 + z5z * s1
    out[1, 2] = z5x * s1 - z5z * c1
    out[2, 2] = z5y
    out[0, 3] = px1 * c1 + pz1 * s1
    out[1, 3] = px1 * s1 - pz1 * c1
    out[2, 3] = _D1 + py1
    out[3, 0] = out[3, 1] = out[3, 2] = 0.0
    out[3, 3] = 1.0
    return out


# --------------------------------------------------------------------------------------------
# Inverse kinematics


def _deg(x: float) -> str:
    return f"{math.degrees(x):.2f}°"


def _pose(t6: FloatArray) -> tuple[float, ...]:
    """The top three rows of ``t6`` as 12 floats, refused unless finite and rigid."""
    if not isinstance(t6, np.ndarray) or t6.shape != (4, 4):
        raise KinematicsError(
            f"ur5 ikine: T must be a 4×4 array, got {type(t6).__name__} {getattr(t6, 'shape', '')}"
        )
    rows = t6.tolist()
    check_rigid(rows, "ur5 ikine")
    (nx, ox, ax, px), (ny, oy, ay, py), (nz, oz, az, pz), _ = rows
    return nx, ox, ax, px, ny, oy, ay, py, nz, oz, az, pz


def ikine(
    t6: FloatArray,
    config: Branch | str,
    q_ref: FloatArray | list[float] | tuple[float, ...] | None = None,
    out: FloatArray | None = None,
) -> FloatArray:
    """Joint angles (rad) that put the flange at ``t6`` (4×4, base frame) in branch ``config``.

    Each joint gets the 2π-equivalent within its limits nearest ``q_ref`` (default 0).  At the
    wrist singularity (|sin θ5| < ``WRIST_SINGULAR``) θ5 is 0 or π, θ6 = ``q_ref[5]`` and
    θ4 takes the rest; there FLIP and NOFLIP coincide (``config_of`` says NOFLIP).

    ``KinematicsError`` for a non-finite or non-rigid ``t6``, a wrist point within d4 of joint
    1's axis, joint 4's axis outside the annulus ``REACH_MIN``..``REACH_MAX`` around the
    shoulder in the arm plane, or joints that no 2π-equivalent brings within their limits.

    Inside the cycle when ``config`` is a ``Branch`` and ``out`` (6,) is given: nothing numpy
    is allocated (an error allocates its message; the motion stops then anyway).
    """
    if not isinstance(config, Branch):
        config = parse_branch(config)
    nx, ox, ax, px, ny, oy, ay, py, nz, oz, az, pz = _pose(t6)
    ref = (0.0,) * _N if q_ref is None else _joints(q_ref)

    # θ1 from the wrist point P5 = p − d6·z6: (x, y) = s·x1 + d4·z1.
    wx, wy, wz = px - _D6 * ax, py - _D6 * ay, pz - _D6 * az
    s2_ = wx * wx + wy * wy - _D4 * _D4
    if s2_ < 0.0:
        if s2_ < -REACH_TOL:
            raise KinematicsError(
                f"ur5 ikine: pose out of reach: wrist point ({wx:.4f}, {wy:.4f}, {wz:.4f}) m is "
                f"{math.hypot(wx, wy):.4f} m from joint 1's axis, closer than the shoulder "
                f"offset d4 = {_D4} m"
            )
        s2_ = 0.0
    s = math.sqrt(s2_) if config.right else -math.sqrt(s2_)
    q1 = math.atan2(_D4 * wx + s * wy, s * wx - _D4 * wy)
    c1, s1 = math.cos(q1), math.sin(q1)

    # θ5, θ6 from the flange axes against z1 = (s1, −c1, 0).
    nz1 = nx * s1 - ny * c1
    oz1 = ox * s1 - oy * c1
    c5 = ax * s1 - ay * c1
    sin5 = math.hypot(nz1, oz1)
    if sin5 < WRIST_SINGULAR:
        q5 = math.atan2(0.0, c5)
        s5 = 0.0
        q6 = ref[5]
    else:
        if not config.flip:
            sin5 = -sin5
        q5 = math.atan2(sin5, c5)
        s5 = sin5
        q6 = math.atan2(-oz1 / sin5, nz1 / sin5)
    c5 = math.cos(q5)
    c6, s6 = math.cos(q6), math.sin(q6)

    # θ234 from x4 = c5c6·x6 − c5s6·y6 − s5·z6 = c234·x1 + s234·z0.
    x4x = c5 * c6 * nx - c5 * s6 * ox - s5 * ax
    x4y = c5 * c6 * ny - c5 * s6 * oy - s5 * ay
    x4z = c5 * c6 * nz - c5 * s6 * oz - s5 * az
    q234 = math.atan2(x4z, x4x * c1 + x4y * s1)
    c234, s234 = math.cos(q234), math.sin(q234)

    # The planar two-link arm: joint 4's axis at (u, v) from the shoulder in the arm plane.
    u = wx * c1 + wy * s1 - _D5 * s234
    v = wz - _D1 + _D5 * c234
    dist2 = u * u + v * v
    c3 = (dist2 - _A2 * _A2 - _A3 * _A3) / (2.0 * _A2 * _A3)
    if abs(c3) > 1.0:
        if abs(c3) > 1.0 + REACH_TOL:
            raise KinematicsError(
                f"ur5 ikine: pose out of reach: joint 4's axis is {math.sqrt(dist2):.4f} m from "
                f"the shoulder in the arm plane; the arm reaches {REACH_MIN:.5f} .. "
                f"{REACH_MAX:.5f} m"
            )
        c3 = 1.0 if c3 > 0.0 else -1.0
    sin3 = math.sqrt(max(0.0, 1.0 - c3 * c3))
    if config.up == (s >= 0.0):
        sin3 = -sin3
    q3 = math.atan2(sin3, c3)
    q2 = math.atan2(v, u) - math.atan2(_A3 * sin3, _A2 + _A3 * c3)
    q4 = q234 - q2 - q3

    r1, r2, r3 = (
        into_limits(q1, _LO[0], _HI[0], ref[0]),
        into_limits(q2, _LO[1], _HI[1], ref[1]),
        into_limits(q3, _LO[2], _HI[2], ref[2]),
    )
    r4, r5, r6 = (
        into_limits(q4, _LO[3], _HI[3], ref[3]),
        into_limits(q5, _LO[4], _HI[4], ref[4]),
        into_limits(q6, _LO[5], _HI[5], ref[5]),
    )
    if math.isnan(r1 + r2 + r3 + r4 + r5 + r6):
        raw = (q1, q2, q3, q4, q5, q6)
        q = (r1, r2, r3, r4, r5, r6)
        bad = [
            f"joint {j + 1} = {_deg(raw[j])} is outside its limits {_deg(_LO[j])} .. {_deg(_HI[j])}"
            for j in range(_N)
            if math.isnan(q[j])
        ]
        raise KinematicsError(
            f"ur5 ikine: configuration '{config}' out of joint limits: {'; '.join(bad)} "
            f"(no 2π-equivalent inside)"
        )
    if out is None:
        out = np.empty(_N)
    out[0], out[1], out[2], out[3], out[4], out[5] = r1, r2, r3, r4, r5, r6
    return out


# --------------------------------------------------------------------------------------------
# Singularities


def singular(q: FloatArray | list[float] | tuple[float, ...]) -> str | None:
    """Why ``q`` is too near a singularity for a Cartesian path, else None.  Inside the cycle.

    Shoulder: |s| < ``SHOULDER_MIN_M``; elbow: |a3·sin θ3| < ``ELBOW_MIN_M``; wrist:
    asin|sin θ5| < ``WRIST_MIN_DEG``.
    """
    _, q2, q3, q4, q5, _ = _joints(q)
    s = abs(_reach(q2, q3, q2 + q3 + q4))
    if s < SHOULDER_MIN_M:
        return (
            f"within {s * 100:.1f} cm of the shoulder singularity (wrist point on the plane "
            f"of joints 1 and 2; limit {SHOULDER_MIN_M * 100:g} cm)"
        )
    e = abs(_A3 * math.sin(q3))
    if e < ELBOW_MIN_M:
        return (
            f"within {e * 100:.1f} cm of the elbow singularity (arm stretched or folded, "
            f"joint 3 at {_deg(q3)}; limit {ELBOW_MIN_M * 100:g} cm)"
        )
    w = math.asin(min(1.0, abs(math.sin(q5))))
    if w < math.radians(WRIST_MIN_DEG):
        return (
            f"within {_deg(w)} of the wrist singularity (joint 5 at {_deg(q5)}; limit "
            f"{WRIST_MIN_DEG:g}°)"
        )
    return None


def singular_margin(q: FloatArray | list[float] | tuple[float, ...]) -> float:
    """How far ``q`` is from its nearest singularity as a multiple of that one's limit
    (below 1: ``singular`` refuses it).  Inside the cycle."""
    _, q2, q3, q4, q5, _ = _joints(q)
    return min(
        abs(_reach(q2, q3, q2 + q3 + q4)) / SHOULDER_MIN_M,
        abs(_A3 * math.sin(q3)) / ELBOW_MIN_M,
        math.asin(min(1.0, abs(math.sin(q5)))) / math.radians(WRIST_MIN_DEG),
    )


class UR5Kinematics:
    """The UR5's ``Kinematics`` (kali_daemons.robots.profile): the functions of this module."""

    configs: tuple[object, ...] = BRANCHES

    def fkine(self, q: FloatArray, out: FloatArray | None = None) -> FloatArray:
        """The flange pose (4×4) in the base frame; see ``fkine``."""
        return fkine(q, out)

    def ikine(
        self,
        t6: FloatArray,
        config: object,
        q_ref: FloatArray | None = None,
        out: FloatArray | None = None,
        redundancy: float | None = None,
    ) -> FloatArray:
        """See ``ikine``; the UR5 has no redundancy, so ``redundancy`` must be None."""
        if redundancy is not None:
            raise KinematicsError(f"ur5 ikine: the UR5 is not redundant (redundancy={redundancy})")
        if not isinstance(config, Branch | str):
            raise KinematicsError(f"ur5 ikine: {config!r} is not a UR5 configuration")
        return ikine(t6, config, q_ref, out)

    def config_of(self, q: FloatArray) -> object:
        """The branch ``q`` is in; see ``branch_of``."""
        return branch_of(q)

    def parse_config(self, text: str) -> object:
        """A branch from its three letters; see ``parse_branch``."""
        return parse_branch(text)

    def singular(self, q: FloatArray) -> str | None:
        """See ``singular``."""
        return singular(q)

    def singular_margin(self, q: FloatArray) -> float:
        """See ``singular_margin``."""
        return singular_margin(q)


KINEMATICS: Final = UR5Kinematics()
