"""The built-in robot-level servos, computed_torque and impedance (``arm.py`` for the interface).

**computed_torque** (thesis 2.2.3: τ = H(q) u + h(q, q̇)) linearises the arm with its own
model into n decoupled second-order errors of natural frequency ``wn`` and damping ratio
``zeta``; an integral (``wi``, ``ilimit``) takes up what the model misses.  **impedance** is
a Cartesian spring and damper about the tool point per tool axis with a force set-point
(thesis 3.3.4); with a wrist sensor it also feeds back the spring's imbalance against the
sensed wrench (the joints stick), compensates friction in the direction the joints are
driven, and shares a squeeze of a held object with a ``partner`` arm.

Both hand over bumplessly: the difference between the motors' last torque and the law's
first becomes a ``bias`` decaying with ``handover_s``.  Each slot's ``error`` is q_d − q, as
the joint servos'.  Their steps run compiled (``kernels.arm_step``), equal to ``_ct_step``
and ``_imp_step`` here.  The laws in full: docs/internals/servo-level.md.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core import kernels, layout
from ...core.errors import ConfigError
from ...core.layout import CT_DTYPE, IMPEDANCE_DTYPE
from .algorithm import Param, defaults, resolve_params
from .arm import ArmInput, ArmServoAlgorithm

if TYPE_CHECKING:
    from .registry import Registry

N = layout.MAX_JOINTS  # the per-joint arrays of a record are this long; a robot uses n
AXES = ("x", "y", "z", "rx", "ry", "rz")  # tool axes: the wrench's and a twist's order

HANDOVER = Param(
    "handover_s", 0.05, "s", "time constant of the bumpless hand-over bias", positive=True,
    maximum=3600.0,
)  # fmt: skip
FRICTION = Param("friction", 1.0, "flag", "1: compensate the drive's friction at q̇_d", maximum=1.0)

# ------------------------------------------------------------------------------ shared


def _common_init(d: Any, values: dict[str, float], dt: float) -> None:
    d["dt"] = dt
    d["bias"] = 0.0
    _derive(d, values)


def _derive(d: Any, values: Mapping[str, float]) -> None:
    """The parameters every robot-level built-in has: the hand-over's decay per tick."""
    d["handover_s"] = values["handover_s"]
    d["friction"] = values["friction"]
    d["decay"] = math.exp(-float(d["dt"]) / values["handover_s"])


def _bias_out(d: Any, inp: ArmInput, tau: np.ndarray) -> None:
    """Add the hand-over bias to ``tau`` and let it decay a tick."""
    bias = d["bias"][: inp.n]
    np.add(tau, bias, out=tau)
    np.multiply(bias, float(d["decay"]), out=bias)


def _handover(core: Any) -> Any:
    """A hand-over for the law ``core(d, inp, tau)``: the bias that makes its first torque
    the one the motors had."""

    def handover(d: Any, inp: ArmInput, tau_prev: np.ndarray) -> None:
        first = inp.work[3]
        core(d, inp, first)
        np.subtract(tau_prev, first, out=d["bias"][: inp.n])

    return handover


def _compiled(name: str) -> Callable[[Any, ArmInput, np.ndarray], Callable[[], int]]:
    """``ArmServoAlgorithm.bind`` for built-in ``name``: its step compiled
    (``kernels.arm_step``), since as small numpy calls two arms' steps and the plant fill
    the second CPU (figures: docs/internals/servo-level.md)."""

    def bind(d: Any, inp: ArmInput, tau: np.ndarray) -> Callable[[], int]:
        return kernels.arm_step(name, d, inp, tau)

    return bind


def _model_terms(d: Any, inp: ArmInput, tau: np.ndarray) -> None:
    """Add h(q, q̇) and, if asked for, the friction at q̇_d to ``tau``."""
    np.add(tau, inp.h, out=tau)
    if d["friction"]:
        f = inp.work[2]
        inp.friction(inp.qd_d, f)
        np.add(tau, f, out=tau)


# ------------------------------------------------------------------------------ computed torque

CT_PARAMS: tuple[Param, ...] = (
    Param("wn", 80.0, "rad/s", "natural frequency of every joint's error", positive=True,
          maximum=2000.0),
    Param("zeta", 1.0, "", "damping ratio of every joint's error", maximum=10.0),
    Param("wi", 10.0, "rad/s", "integral action: ω_i ω_n² ∫e (0: none)", maximum=2000.0),
    Param("ilimit", 0.01, "rad·s", "limit of each joint's ∫e", maximum=10.0),
    FRICTION,
    HANDOVER,
)  # fmt: skip


def _ct_set(d: Any, values: Mapping[str, float]) -> None:
    v = resolve_params("computed_torque", CT_PARAMS, values, _ct_get(d))
    d["wn"], d["zeta"] = v["wn"], v["zeta"]
    d["kp"], d["kd"] = v["wn"] ** 2, 2.0 * v["zeta"] * v["wn"]
    d["wi"], d["ilimit"], d["ki"] = v["wi"], v["ilimit"], v["wi"] * v["wn"] ** 2
    np.clip(d["integral"], -v["ilimit"], v["ilimit"], out=d["integral"])
    _derive(d, v)


def _ct_get(d: Any) -> dict[str, float]:
    return {p.name: float(d[p.name]) for p in CT_PARAMS}


def _ct_init(d: Any, init: Mapping[str, float], dt: float) -> None:
    v = resolve_params("computed_torque", CT_PARAMS, init, defaults(CT_PARAMS))
    _common_init(d, v, dt)
    d["integral"] = 0.0
    _ct_set(d, v)


def _ct_core(d: Any, inp: ArmInput, tau: np.ndarray) -> None:
    w = inp.work
    e, u = w[0], w[1]
    np.subtract(inp.q_d, inp.q, out=e)
    np.multiply(e, float(d["kp"]), out=u)
    np.subtract(inp.qd_d, inp.qd, out=e)
    np.multiply(e, float(d["kd"]), out=e)
    np.add(u, e, out=u)
    np.add(u, inp.qdd_d, out=u)
    np.multiply(d["integral"][: inp.n], float(d["ki"]), out=e)
    np.add(u, e, out=u)
    np.matmul(inp.M, u, out=tau)
    _model_terms(d, inp, tau)


def _ct_step(d: Any, inp: ArmInput, tau: np.ndarray) -> int:
    _ct_core(d, inp, tau)
    _bias_out(d, inp, tau)
    integral, e = d["integral"][: inp.n], inp.work[0]
    np.subtract(inp.q_d, inp.q, out=e)
    np.multiply(e, float(d["dt"]), out=e)
    np.add(integral, e, out=integral)
    limit = float(d["ilimit"])
    np.clip(integral, -limit, limit, out=integral)
    return 0


COMPUTED_TORQUE = ArmServoAlgorithm(
    name="computed_torque",
    dtype=CT_DTYPE,
    params=tuple(p.name for p in CT_PARAMS),
    init=_ct_init,
    step=_ct_step,
    handover=_handover(_ct_core),
    set_params=_ct_set,
    get_params=_ct_get,
    doc="τ = M(q)(q̈_d + 2ζω_n ė + ω_n² e + ω_iω_n² ∫e) + h(q, q̇): computed torque (2.2.3)",
    bind=_compiled("computed_torque"),
)

# ------------------------------------------------------------------------------ impedance

STIFFNESS_MAX = 1e6  # N/m (N·m/rad): a rigid fixture's; beyond it, a typo
DAMPING_MAX = 1e5
FORCE_MAX = 1e4  # N (N·m): the client refuses a set-point beyond the sensor's rating first
MOMENT_ARM_M = 0.1  # the integral's moment limit is its force limit times this

IMPEDANCE_PARAMS: tuple[Param, ...] = (
    *(Param(f"k{a}", 2000.0, "N/m", f"stiffness along tool {a}", maximum=STIFFNESS_MAX)
      for a in AXES[:3]),
    *(Param(f"k{a}", 150.0, "N·m/rad", f"stiffness about tool {a[1]}", maximum=STIFFNESS_MAX)
      for a in AXES[3:]),
    *(Param(f"d{a}", 300.0, "N·s/m", f"damping along tool {a}", maximum=DAMPING_MAX)
      for a in AXES[:3]),
    *(Param(f"d{a}", 10.0, "N·m·s/rad", f"damping about tool {a[1]}", maximum=DAMPING_MAX)
      for a in AXES[3:]),
    *(Param(f"f{a}", 0.0, "N", f"force set-point along tool {a}", minimum=-FORCE_MAX,
            maximum=FORCE_MAX) for a in AXES[:3]),
    # a squeeze shared with another arm holding the same object (MotionSystem.set_internal_force)
    Param("partner", 0.0, "robot", "the other arm's config index + 1 (0: no squeeze)",
          maximum=layout.MAX_ROBOTS),
    Param("fi", 0.0, "N", "squeeze along the line to the partner", maximum=FORCE_MAX),
    *(Param(f"u{a}", 0.0, "", f"that line's direction, tool {a}", minimum=-1.0, maximum=1.0)
      for a in AXES[:3]),
    Param("kpi", 2.0, "", "proportional gain of the squeeze, from both arms' sensors",
          maximum=50.0),
    Param("kii", 80.0, "1/s", "integral gain of the squeeze, from both arms' sensors",
          maximum=1e4),
    Param("kf", 1.0, "", "force feedback gain on the impedance's imbalance", maximum=50.0),
    Param("kfi", 10.0, "1/s", "its integral gain", maximum=1e4),
    Param("imax", 60.0, "N", "limit of the integral (moments: times 0.1 m)", maximum=FORCE_MAX),
    Param("iband", 2.0, "N", "the integral advances on an axis only while its imbalance is within "
          "this (moments: times 0.1 m)", maximum=FORCE_MAX),
    Param("kq", 1.0, "N·m·s/rad", "joint damping of q̇ − q̇_d", maximum=DAMPING_MAX),
    Param("cband", 0.5, "N", "Coulomb compensation's band: the drive at the tool (N; moments "
          "N·0.1 m) over which it turns", maximum=FORCE_MAX),
    Param("ctau", 0.05, "s", "time constant of the drive the Coulomb compensation follows",
          maximum=10.0),
    FRICTION,
    HANDOVER,
)  # fmt: skip

_ARRAYS = {f"{f}{a}": (f, i) for f in "kd" for i, a in enumerate(AXES)}
_ARRAYS.update({f"f{a}": ("f", i) for i, a in enumerate(AXES[:3])})
_ARRAYS.update({f"u{a}": ("u", i) for i, a in enumerate(AXES[:3])})
_ARRAYS["iband"] = ("band", 0)  # the force axes' band; the moments' is it times MOMENT_ARM_M
_SCALARS = ("partner", "fi", "kpi", "kii", "kf", "kfi", "imax", "kq", "cband", "ctau")


def _imp_get(d: Any) -> dict[str, float]:
    out = {}
    for p in IMPEDANCE_PARAMS:
        field, i = _ARRAYS.get(p.name, (p.name, None))
        out[p.name] = float(d[field] if i is None else d[field][i])
    return out


def _imp_set(d: Any, values: Mapping[str, float]) -> None:
    v = resolve_params("impedance", IMPEDANCE_PARAMS, values, _imp_get(d))
    if v["partner"] != int(v["partner"]):
        raise ConfigError(f"impedance: partner {v['partner']:g} is not a robot index + 1")
    norm = math.sqrt(v["ux"] ** 2 + v["uy"] ** 2 + v["uz"] ** 2)
    if v["partner"] and abs(norm - 1.0) > 1e-3:
        raise ConfigError(
            f"impedance: the line to the partner (ux, uy, uz) has length {norm:.4g}, not 1"
        )
    for name, (field, i) in _ARRAYS.items():
        d[field][i] = v[name]
    for name in _SCALARS:
        d[name] = v[name]
    if not v["partner"]:
        d["gi"] = 0.0  # no squeeze: its integral starts afresh next time
    d["gi"] = min(max(float(d["gi"]), -v["imax"]), v["imax"])
    d["limit"][:3] = v["imax"]
    d["limit"][3:] = v["imax"] * MOMENT_ARM_M
    d["cdecay"] = math.exp(-float(d["dt"]) / v["ctau"]) if v["ctau"] > 0.0 else 0.0
    d["band"][:3] = v["iband"]
    d["band"][3:] = v["iband"] * MOMENT_ARM_M
    np.clip(d["integral"], -d["limit"], d["limit"], out=d["integral"])
    _derive(d, v)


def _imp_init(d: Any, init: Mapping[str, float], dt: float) -> None:
    v = resolve_params("impedance", IMPEDANCE_PARAMS, init, defaults(IMPEDANCE_PARAMS))
    _common_init(d, v, dt)
    d["integral"] = 0.0
    d["gi"] = 0.0
    d["drive"] = 0.0
    _imp_set(d, v)


def rotation_error(r_d: np.ndarray, r: np.ndarray, out: np.ndarray, scratch: np.ndarray) -> None:
    """log(R_d Rᵀ) as a rotation vector (world axes) into ``out`` (3,); ``scratch`` (3, 3)."""
    np.matmul(r_d, r.T, out=scratch)
    e = scratch
    out[0] = 0.5 * (e[2, 1] - e[1, 2])
    out[1] = 0.5 * (e[0, 2] - e[2, 0])
    out[2] = 0.5 * (e[1, 0] - e[0, 1])
    c = max(-1.0, min(1.0, 0.5 * (e[0, 0] + e[1, 1] + e[2, 2] - 1.0)))
    angle = math.acos(c)
    s = math.sin(angle)
    if s > 1e-9:
        np.multiply(out, angle / s, out=out)


_ROT_SCRATCH = np.zeros((3, 3))  # rotation_error's, in the SV's one thread
_HALVES = (slice(0, 3), slice(3, 6))


def to_tool(v: np.ndarray, rot: np.ndarray, scratch: np.ndarray) -> None:
    """A world wrench or twist ``v`` (``layout.WRENCH`` values) into tool axes, in place:
    Rᵀ on each half."""
    for half in _HALVES:
        np.matmul(v[half], rot, out=scratch[half])  # Rᵀ v as a row vector: v R
    np.copyto(v, scratch)


def _imp_core(d: Any, inp: ArmInput, tau: np.ndarray, fresh: bool = False) -> None:
    """The law, with the imbalance k e + f + w (tool axes) left in ``inp.work6[3]``."""
    w, w6 = inp.work, inp.work6
    e, edot, f, imbalance = w6[0], w6[1], w6[2], w6[3]
    rot = inp.pose[:3, :3]
    np.subtract(inp.pose_d[:3, 3], inp.pose[:3, 3], out=e[:3])
    rotation_error(inp.pose_d[:3, :3], rot, e[3:], _ROT_SCRATCH)
    dq = w[0]
    np.subtract(inp.qd_d, inp.qd, out=dq)
    np.matmul(inp.J, dq, out=edot)
    to_tool(e, rot, f)
    to_tool(edot, rot, f)
    np.multiply(e, d["k"], out=f)  # the spring and the set-point: what the arm should exert
    np.add(f, d["f"], out=f)
    if _squeezing(d, inp):  # a squeeze (docs/internals/servo-level.md)
        u, line = d["u"], e[:3]  # e is free until the force feedback
        np.matmul(rot, u, out=line)  # the line towards the partner, world axes
        other = inp.wrenches[int(d["partner"]) - 1]
        squeeze = 0.5 * (float(np.dot(other[:3], line)) - float(np.dot(inp.wrench[:3], line)))
        d["squeeze"] = squeeze
        fi = float(d["fi"])
        push = fi + float(d["gi"]) + float(d["kpi"]) * (fi - squeeze)
        np.multiply(u, push, out=line)
        np.add(f[:3], line, out=f[:3])
    if inp.has_sensor:  # what it does exert is -w: feed the difference back (stiction)
        np.copyto(imbalance, inp.wrench)
        to_tool(imbalance, rot, e)
        np.add(imbalance, f, out=imbalance)
        np.multiply(imbalance, float(d["kf"]), out=e)
        np.add(f, e, out=f)
        np.add(f, d["integral"], out=f)
    else:
        imbalance.fill(0.0)
    drive = w[2]  # what moves each joint but the damping: Jᵀ (R F + w)
    for half in _HALVES:
        np.matmul(rot, f[half], out=e[half])
    if inp.has_sensor:
        np.add(e, inp.wrench, out=e)
    np.matmul(e, inp.J, out=drive)
    if not fresh:  # low-passed: s + (previous - s) * cdecay
        lag = w[1]
        np.subtract(d["drive"][: inp.n], drive, out=lag)
        np.multiply(lag, float(d["cdecay"]), out=lag)
        np.add(drive, lag, out=drive)
    np.multiply(edot, d["d"], out=e)
    np.add(f, e, out=f)
    for half in _HALVES:
        np.matmul(rot, f[half], out=e[half])
    np.matmul(e, inp.J, out=tau)  # Jᵀ F
    np.matmul(inp.M, inp.qdd_d, out=w[1])
    np.add(tau, w[1], out=tau)
    np.multiply(dq, float(d["kq"]), out=dq)
    np.add(tau, dq, out=tau)
    np.add(tau, inp.h, out=tau)
    if d["friction"]:
        _friction_toward(inp, drive, float(d["cband"]), w[1])
        np.add(tau, w[1], out=tau)


def _friction_toward(inp: ArmInput, drive: np.ndarray, band: float, out: np.ndarray) -> None:
    """The drive's friction (``DriveFriction``) into ``out``: viscous at q̇_d, Coulomb at the
    sign of q̇_d (the drive's own smoothing) plus ``drive`` over ``band`` N at the tool."""
    coefficients = getattr(inp.friction, "coefficients", None)
    if coefficients is None:
        out.fill(0.0)
        return
    viscous, gear_w, pos, neg = coefficients()
    jac = inp.J
    for j in range(inp.n):
        v = float(inp.qd_d[j])
        lin = math.sqrt(
            float(jac[0, j]) * float(jac[0, j])
            + float(jac[1, j]) * float(jac[1, j])
            + float(jac[2, j]) * float(jac[2, j])
        )
        ang = math.sqrt(
            float(jac[3, j]) * float(jac[3, j])
            + float(jac[4, j]) * float(jac[4, j])
            + float(jac[5, j]) * float(jac[5, j])
        )
        lever = lin + ang * MOMENT_ARM_M
        x = v * float(gear_w[j])
        width = band * lever
        if width > 0.0:
            x += float(drive[j]) / width
        th = math.tanh(x)
        fr = v * float(viscous[j])
        fr += (th if th > 0.0 else 0.0) * float(pos[j])
        fr -= (th if th < 0.0 else 0.0) * float(neg[j])
        out[j] = fr


def _squeezing(d: Any, inp: ArmInput) -> bool:
    """True when this arm shares a squeeze with a partner whose wrench it can read (the
    client checks the partner; a record put by hand is not trusted to have)."""
    partner = int(d["partner"])
    return partner > 0 and inp.has_sensor and partner <= len(inp.wrenches)


def _imp_handover(d: Any, inp: ArmInput, tau_prev: np.ndarray) -> None:
    """The hand-over bias, and the drive's low-pass started at this tick's drive."""
    first = inp.work[3]
    _imp_core(d, inp, first, fresh=True)
    np.subtract(tau_prev, first, out=d["bias"][: inp.n])
    np.copyto(d["drive"][: inp.n], inp.work[2])


def _imp_step(d: Any, inp: ArmInput, tau: np.ndarray) -> int:
    _imp_core(d, inp, tau)
    np.copyto(d["drive"][: inp.n], inp.work[2])
    _bias_out(d, inp, tau)
    integral = d["integral"]
    imbalance = inp.work6[3]
    damping = inp.work6[2]  # the damper's force: the arm moving against its demand
    np.multiply(inp.work6[1], d["d"], out=damping)
    outside = (np.abs(imbalance) > d["band"]) | (np.abs(damping) > d["band"])
    np.copyto(imbalance, 0.0, where=outside)
    np.multiply(imbalance, float(d["kfi"]) * float(d["dt"]), out=imbalance)
    np.add(integral, imbalance, out=integral)
    np.clip(integral, -d["limit"], d["limit"], out=integral)
    if _squeezing(d, inp):  # both arms integrate the same squeeze error
        gi = float(d["gi"]) + float(d["kii"]) * float(d["dt"]) * (
            float(d["fi"]) - float(d["squeeze"])
        )
        imax = float(d["imax"])
        d["gi"] = min(max(gi, -imax), imax)
    return 0


IMPEDANCE = ArmServoAlgorithm(
    name="impedance",
    dtype=IMPEDANCE_DTYPE,
    params=tuple(p.name for p in IMPEDANCE_PARAMS),
    init=_imp_init,
    step=_imp_step,
    handover=_imp_handover,
    set_params=_imp_set,
    get_params=_imp_get,
    doc="Cartesian impedance about the tool point: stiffness, damping, force per tool axis",
    bind=_compiled("impedance"),
)


def register(registry: Registry) -> None:
    """This module's robot-level built-ins, in their fixed order: computed_torque = 0,
    impedance = 1 (``admittance.py``'s follow them)."""
    registry.register(COMPUTED_TORQUE)
    registry.register(IMPEDANCE)
