"""PUMA 560 kinematics in closed form: T6 from joint angles and back, configurations, singularities.

The trajectory generator calls these every tick for every arm (thesis 3.3.1: ``write_t6`` /
``read_t6``) with *explicit* configuration flags, and checks for singularities before a
motion starts (thesis 2.2.1: picking "the solution nearest the current joints" is not a safe
rule near a singularity).  So this is plain ``math`` on Python floats, no Pinocchio and no
numpy temporaries: the budget is 10 µs per ``fkine`` and 30 µs per ``ikine``.

Standard DH with the pedestal in d1 (``facts``, ``kali_daemons.robots.puma560``); ``T6`` is
DH frame 6, the flange, in the base frame, with no tool: the ``flange`` frame of
``kali_daemons.robots.model`` and the toolbox's ``fkine``.  The closed form (Paul, Shimano &
Mayer 1981; Paul & Zhang 1986), the geometric meaning of the 'l'/'r', 'u'/'d', 'n'/'f' flags
(robotics-toolbox-python's: the nominal pose QN is "ruf") and the singularities are in
docs/internals/robots-hardware-plant.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final, NamedTuple

import numpy as np
import numpy.typing as npt

from ...core.errors import KinematicsError
from ..closed_form import check_rigid, into_limits
from .facts import ALPHA, NJOINTS, Q_MAX, Q_MIN, A, D

FloatArray = npt.NDArray[np.float64]


# --------------------------------------------------------------------------------------------
# Geometry, as Python floats (faster than numpy scalars in the closed form)

_D1: Final = float(D[0])  # m, shoulder height (with the pedestal)
_A2: Final = float(A[1])  # m, upper arm
_A3: Final = float(A[2])  # m, forearm offset at the elbow
_D3: Final = float(D[2])  # m, shoulder offset, along z1
_D4: Final = float(D[3])  # m, forearm
_L: Final = math.hypot(_A3, _D4)  # m, elbow (joint-3 axis) to wrist centre
_PHI: Final = math.atan2(_A3, _D4)  # rad, angle of the forearm's a3 offset seen from the elbow
REACH_MIN: Final = abs(_A2 - _L)  # m, wrist centre to S in the arm plane: the reachable annulus
REACH_MAX: Final = _A2 + _L  # m
STRETCH_Q3: Final = _PHI - math.pi / 2  # rad, θ3 of the stretched arm (elbow singular)

_LO: Final = tuple(float(v) for v in Q_MIN)
_HI: Final = tuple(float(v) for v in Q_MAX)

# Tolerances.  A pose computed by fkine exactly at a boundary may miss it by rounding; these
# accept it (and are far below anything a motion would notice).
REACH_TOL_M2: Final = 1e-12  # m², on ρ² = x² + y² − d3² and on L² − (elbow term)²
WRIST_SINGULAR_RAD: Final = 1e-10  # |θ5| below this is θ5 = 0 and θ4 is taken from q_ref


def _check_geometry() -> None:
    """The closed form is written for this DH pattern; refuse constants that break it."""
    zero_a = (A[0], A[3], A[4], A[5])
    zero_d = (D[1], D[4], D[5])
    alpha = np.degrees(ALPHA)
    if any(zero_a) or any(zero_d) or not np.allclose(alpha, [90, 0, -90, 90, -90, 0]):
        raise KinematicsError(
            f"puma560: closed form needs a = (0, a2, a3, 0, 0, 0), d = (d1, 0, d3, d4, 0, 0), "
            f"α = (90, 0, -90, 90, -90, 0)°; got a = {A}, d = {D}, α = {alpha}°"
        )


_check_geometry()


# --------------------------------------------------------------------------------------------
# Configurations


@dataclass(frozen=True, slots=True)
class Config:
    """One of the 8 solutions of the PUMA's inverse kinematics, by three geometric flags.

    ``right``: arm RIGHT (toolbox 'r') when ρ ≥ 0, the wrist centre on the side of the
    plane of axes 1 and 2 that x1 = z0 × z1 points to; LEFT ('l') otherwise.
    ``up``: elbow UP ('u') when the elbow is above the line from the shoulder to the wrist
    centre in the arm plane (e < 0 on the right arm, e > 0 on the left); DOWN ('d') otherwise.
    ``flip``: wrist FLIP ('f') when sin θ5 > 0; NOFLIP ('n') when θ5 ≤ 0.
    docs/internals/robots-hardware-plant.md defines ρ and e and shows why these read as stated.

    Written as exactly three letters, arm then elbow then wrist: ``str(Config(True, True,
    False)) == "run"`` and ``Config.from_string("ldf")``.
    """

    right: bool
    up: bool
    flip: bool

    def __str__(self) -> str:
        return (
            ("r" if self.right else "l") + ("u" if self.up else "d") + ("f" if self.flip else "n")
        )

    @classmethod
    def from_string(cls, text: str) -> Config:
        """Parse three letters, arm l/r, elbow u/d, wrist n/f in that order (case ignored)."""
        s = text.lower() if isinstance(text, str) else ""
        if len(s) != 3 or s[0] not in "lr" or s[1] not in "ud" or s[2] not in "nf":
            raise KinematicsError(
                f"configuration {text!r}: expected three letters in the order arm (l/r), "
                f"elbow (u/d), wrist (n/f), e.g. 'run' or 'ldf'"
            )
        return cls(right=s[0] == "r", up=s[1] == "u", flip=s[2] == "f")


CONFIGS: Final = tuple(
    Config(r, u, f) for r in (True, False) for u in (True, False) for f in (False, True)
)


def _floats(q: FloatArray | list[float] | tuple[float, ...]) -> list[float]:
    return q.tolist() if isinstance(q, np.ndarray) else [float(v) for v in q]


def config_of(q: FloatArray | list[float] | tuple[float, ...]) -> Config:
    """The configuration of joint angles ``q`` (rad), by the geometric definitions of ``Config``.

    Computed from ρ, e and sin θ5 directly, not through ``ikine``.  Inside the cycle.
    """
    _, q2, q3, _, q5, _ = _floats(q)
    q23 = q2 + q3
    rho = _A2 * math.cos(q2) + _A3 * math.cos(q23) - _D4 * math.sin(q23)
    e = _D4 * math.cos(q3) + _A3 * math.sin(q3)
    right = rho >= 0.0
    return Config(right=right, up=(e < 0.0) if right else (e > 0.0), flip=math.sin(q5) > 0.0)


# --------------------------------------------------------------------------------------------
# Forward kinematics


def fkine(
    q: FloatArray | list[float] | tuple[float, ...], out: FloatArray | None = None
) -> FloatArray:
    """T6, the flange (DH frame 6), in the base frame for joint angles ``q`` (rad), as a 4×4.

    Written into ``out`` when given (then nothing numpy is allocated: inside the cycle),
    else into a new array.  Equals Pinocchio's ``flange`` frame and the toolbox's ``fkine``.
    """
    q1, q2, q3, q4, q5, q6 = _floats(q)
    c1, s1 = math.cos(q1), math.sin(q1)
    c2, s2 = math.cos(q2), math.sin(q2)
    c23, s23 = math.cos(q2 + q3), math.sin(q2 + q3)
    c4, s4 = math.cos(q4), math.sin(q4)
    c5, s5 = math.cos(q5), math.sin(q5)
    c6, s6 = math.cos(q6), math.sin(q6)
    # R36 = Rz(θ4)·Ry(−θ5)·Rz(θ6), row by row
    c4c5, s4c5 = c4 * c5, s4 * c5
    r00, r01, r02 = c4c5 * c6 - s4 * s6, -c4c5 * s6 - s4 * c6, -c4 * s5
    r10, r11, r12 = s4c5 * c6 + c4 * s6, -s4c5 * s6 + c4 * c6, -s4 * s5
    r20, r21, r22 = s5 * c6, -s5 * s6, c5
    # R03 columns: x3 = (c1·c23, s1·c23, s23), y3 = (−s1, c1, 0), z3 = (−c1·s23, −s1·s23, c23)
    x3x, x3y = c1 * c23, s1 * c23
    z3x, z3y = -c1 * s23, -s1 * s23
    rho = _A2 * c2 + _A3 * c23 - _D4 * s23
    rows = (
        (
            x3x * r00 - s1 * r10 + z3x * r20,
            x3x * r01 - s1 * r11 + z3x * r21,
            x3x * r02 - s1 * r12 + z3x * r22,
            c1 * rho + _D3 * s1,
        ),
        (
            x3y * r00 + c1 * r10 + z3y * r20,
            x3y * r01 + c1 * r11 + z3y * r21,
            x3y * r02 + c1 * r12 + z3y * r22,
            s1 * rho - _D3 * c1,
        ),
        (
            s23 * r00 + c23 * r20,
            s23 * r01 + c23 * r21,
            s23 * r02 + c23 * r22,
            _D1 + _A2 * s2 + _A3 * s23 + _D4 * c23,
        ),
        (0.0, 0.0, 0.0, 1.0),
    )
    if out is None:
        return np.array(rows)
    out[:] = rows
    return out


def wrist_centre(t6: FloatArray) -> FloatArray:
    """The wrist centre (m, base frame) of flange pose ``t6``: its origin, as d5 = d6 = 0.

    With a tool, pass T6 (the pose times the inverse tool transform), not the tool pose.
    """
    return np.array(t6[:3, 3], dtype=float)


# --------------------------------------------------------------------------------------------
# Inverse kinematics


def _deg(x: float) -> str:
    return f"{math.degrees(x):.2f}°"


def ikine(
    t6: FloatArray,
    config: Config | str,
    q_ref: FloatArray | list[float] | tuple[float, ...] | None = None,
    out: FloatArray | None = None,
) -> FloatArray:
    """Joint angles (rad) that put the flange at ``t6`` (4×4, base frame) in ``config``.

    Each joint gets the 2π-equivalent within its limits nearest ``q_ref`` (default 0); this
    only chooses for joint 6 (limits ±266°), the other joints' ranges span less than 360°.
    At the wrist singularity (|θ5| < ``WRIST_SINGULAR_RAD``) θ5 = 0, θ4 = ``q_ref[3]`` (0
    without q_ref) put within joint 4's limits, and θ6 takes the rest of θ4 + θ6; there the
    FLIP and NOFLIP solutions coincide (``config_of`` says NOFLIP).

    Raises ``KinematicsError`` for a non-finite or non-rigid ``t6`` (rotation not orthonormal
    to ``RIGID_TOL``), a wrist centre out of reach (closer to joint 1's axis than d3, or
    outside the annulus ``REACH_MIN``..``REACH_MAX`` around the shoulder in the arm plane),
    or joints that no 2π-equivalent brings within their limits in this configuration.

    Inside the cycle when ``config`` is a ``Config`` and ``out`` (6,) is given: nothing numpy
    is allocated (an error allocates its message, but then the motion stops anyway).
    """
    if not isinstance(config, Config):
        config = Config.from_string(config)
    if not isinstance(t6, np.ndarray) or t6.shape != (4, 4):
        raise KinematicsError(
            f"ikine: T must be a 4×4 array, got {type(t6).__name__} {getattr(t6, 'shape', '')}"
        )
    rows = t6.tolist()
    check_rigid(rows)
    (nx, ox, ax, px), (ny, oy, ay, py), (nz, oz, az, pz), _ = rows
    ref = (0.0,) * NJOINTS if q_ref is None else _floats(q_ref)

    # θ1: the wrist centre at (px, py) is ρ·x1 + d3·z1 with x1 = (c1, s1), z1 = (s1, −c1).
    rho2 = px * px + py * py - _D3 * _D3
    if rho2 < 0.0:
        if rho2 < -REACH_TOL_M2:
            raise KinematicsError(
                f"ikine: pose out of reach: wrist centre ({px:.4f}, {py:.4f}, {pz:.4f}) m is "
                f"{math.hypot(px, py):.4f} m from joint 1's axis, closer than the shoulder "
                f"offset d3 = {_D3} m"
            )
        rho2 = 0.0
    rho = math.sqrt(rho2) if config.right else -math.sqrt(rho2)
    q1 = math.atan2(_D3 * px + rho * py, rho * px - _D3 * py)

    # θ3 from the distance shoulder-wrist in the arm plane: (ρ, h) = Rz(θ2)·(a2 + n, e) with
    # n = a3·c3 − d4·s3 = L·sin(φ − θ3) and e = d4·c3 + a3·s3 = L·cos(φ − θ3).
    h = pz - _D1
    dist2 = rho2 + h * h
    n = (dist2 - _A2 * _A2 - _L * _L) / (2.0 * _A2)
    e2 = _L * _L - n * n
    if e2 < 0.0:
        if e2 < -REACH_TOL_M2:
            raise KinematicsError(
                f"ikine: pose out of reach: wrist centre ({px:.4f}, {py:.4f}, {pz:.4f}) m is "
                f"{math.sqrt(dist2):.4f} m from the shoulder in the arm plane; the arm "
                f"reaches {REACH_MIN:.5f} .. {REACH_MAX:.5f} m"
            )
        e2 = 0.0
    e = -math.sqrt(e2) if config.up == config.right else math.sqrt(e2)
    q3 = _PHI - math.atan2(n, e)
    an = _A2 + n
    q2 = math.atan2(h * an - rho * e, rho * an + h * e)

    # The wrist: M = R03ᵀ·R = Rz(θ4)·Ry(−θ5)·Rz(θ6); only the entries needed.
    c1, s1 = math.cos(q1), math.sin(q1)
    c23, s23 = math.cos(q2 + q3), math.sin(q2 + q3)
    x3x, x3y, x3z = c1 * c23, s1 * c23, s23
    z3x, z3y, z3z = -c1 * s23, -s1 * s23, c23
    m02 = x3x * ax + x3y * ay + x3z * az
    m12 = c1 * ay - s1 * ax
    m22 = z3x * ax + z3y * ay + z3z * az
    q5 = math.atan2(math.hypot(m02, m12), m22)  # |θ5|, in [0, π]
    if q5 < WRIST_SINGULAR_RAD:
        m00 = x3x * nx + x3y * ny + x3z * nz
        m10 = c1 * ny - s1 * nx
        q5 = 0.0
        q4 = min(max(ref[3], _LO[3]), _HI[3])
        q6 = math.atan2(m10, m00) - q4
    else:
        m20 = z3x * nx + z3y * ny + z3z * nz
        m21 = z3x * ox + z3y * oy + z3z * oz
        if config.flip:
            q4, q6 = math.atan2(-m12, -m02), math.atan2(-m21, m20)
        else:
            q5 = -q5
            q4, q6 = math.atan2(m12, m02), math.atan2(m21, -m20)

    raw = (q1, q2, q3, q4, q5, q6)
    q = tuple(into_limits(raw[j], _LO[j], _HI[j], ref[j]) for j in range(NJOINTS))
    if any(map(math.isnan, q)):
        bad = [
            f"joint {j + 1} = {_deg(raw[j])} is outside its limits {_deg(_LO[j])} .. {_deg(_HI[j])}"
            for j in range(NJOINTS)
            if math.isnan(q[j])
        ]
        raise KinematicsError(
            f"ikine: configuration '{config}' out of joint limits: {'; '.join(bad)} "
            f"(no 2π-equivalent inside)"
        )
    if out is None:
        return np.array(q)
    out[:] = q
    return out


# --------------------------------------------------------------------------------------------
# Singularities


class Singularities(NamedTuple):
    """How far joint angles are from the three singularities; each is 0 on its singularity.

    ``shoulder`` (m): |ρ|, the wrist centre's distance from the vertical plane through the
    axes of joints 1 and 2 (0 when it is d3 from joint 1's axis).
    ``elbow`` (m): |e|, the wrist centre's distance from the line of the upper arm (shoulder
    to elbow), 0 with the arm stretched or folded.
    ``wrist`` (rad): the angle between the lines of joint axes 4 and 6, asin |sin θ5|
    (= |θ5| within joint 5's limits).
    |det J| = a2 · shoulder · elbow · sin(wrist).
    """

    shoulder: float
    elbow: float
    wrist: float


def singularities(q: FloatArray | list[float] | tuple[float, ...]) -> Singularities:
    """The distances of joint angles ``q`` (rad) from the singularities.  Inside the cycle."""
    _, q2, q3, _, q5, _ = _floats(q)
    q23 = q2 + q3
    rho = _A2 * math.cos(q2) + _A3 * math.cos(q23) - _D4 * math.sin(q23)
    e = _D4 * math.cos(q3) + _A3 * math.sin(q3)
    return Singularities(abs(rho), abs(e), math.asin(min(1.0, abs(math.sin(q5)))))


# How near a singularity a Cartesian path may come (checked by the trajectory generator
# before a motion starts, thesis 2.2.1).
SHOULDER_MIN_M: Final = 0.05  # closest approach of the wrist centre to the shoulder singularity
ELBOW_MIN_M: Final = 0.05  # ... to the elbow singularity (arm stretched or folded)
WRIST_MIN_DEG: Final = 5.0  # closest |θ5| to the wrist singularity
_WRIST_MIN_RAD: Final = math.radians(WRIST_MIN_DEG)


def singular(q: FloatArray | list[float] | tuple[float, ...]) -> str | None:
    """Why joint angles ``q`` are too near a singularity for a Cartesian path, or None.

    Inside the cycle: nothing allocated unless it answers (then the motion is refused).
    """
    sing = singularities(q)
    if sing.shoulder >= SHOULDER_MIN_M and sing.elbow >= ELBOW_MIN_M:
        if sing.wrist >= _WRIST_MIN_RAD:
            return None
        return (
            f"comes within {math.degrees(sing.wrist):.1f}° of the wrist singularity (joint 5 "
            f"at {math.degrees(float(q[4])):.1f}°; limit {WRIST_MIN_DEG:g}°)"
        )
    wc = "(" + ", ".join(f"{v:.3f}" for v in fkine(q)[:3, 3]) + ") m"
    if sing.shoulder < SHOULDER_MIN_M:
        return (
            f"comes within {sing.shoulder * 100:.1f} cm of the shoulder singularity "
            f"(limit {SHOULDER_MIN_M * 100:g} cm): wrist centre at {wc} in its base frame"
        )
    return (
        f"comes within {sing.elbow * 100:.1f} cm of the elbow singularity (arm "
        f"stretched; limit {ELBOW_MIN_M * 100:g} cm): wrist centre at {wc} in its "
        f"base frame"
    )


def singular_margin(q: FloatArray | list[float] | tuple[float, ...]) -> float:
    """How far ``q`` is from its nearest singularity as a multiple of that one's limit
    (below 1: ``singular`` refuses it).  Inside the cycle."""
    sing = singularities(q)
    return min(
        sing.shoulder / SHOULDER_MIN_M, sing.elbow / ELBOW_MIN_M, sing.wrist / _WRIST_MIN_RAD
    )


class PumaKinematics:
    """The PUMA 560's kinematics as a robot type declares it (``robots.Kinematics``)."""

    configs: Final = CONFIGS
    fkine = staticmethod(fkine)
    config_of = staticmethod(config_of)
    parse_config = staticmethod(Config.from_string)
    singular = staticmethod(singular)
    singular_margin = staticmethod(singular_margin)

    @staticmethod
    def ikine(
        t6: FloatArray,
        config: Config | str,
        q_ref: FloatArray | None = None,
        out: FloatArray | None = None,
        redundancy: float | None = None,
    ) -> FloatArray:
        """``ikine`` (the PUMA is not redundant: ``redundancy`` must be None)."""
        if redundancy is not None:
            raise KinematicsError("ikine: the PUMA 560 has no redundancy parameter")
        return ikine(t6, config, q_ref, out)


KINEMATICS: Final = PumaKinematics()


__all__ = [
    "CONFIGS",
    "KINEMATICS",
    "REACH_MAX",
    "REACH_MIN",
    "STRETCH_Q3",
    "Config",
    "KinematicsError",
    "Singularities",
    "config_of",
    "fkine",
    "ikine",
    "singular",
    "singularities",
    "wrist_centre",
]
