"""Admittance and hand guiding: robot-level servos that move the arm where the sensed wrench
pushes it (admittance control, the impedance servo's dual; thesis 3.3.4's end-effector force
sensor).

A geared arm's joints stick, so an arm that should yield is moved by its wrist sensor: a
virtual mass-damper(-spring) per tool axis, pushed by the sensed wrench less a dead band
(``band``, ``bandm``), gives a reference that the computed-torque law of ``armbuiltins``
tracks.  **admittance** bases the reference on the demand: the arm follows the TG's motions
and yields to a steady push by F / k per tool axis.  **guiding** has no spring and bases it
where the arm was taken over: the arm goes where it is pushed and stays; its algorithm
``guides`` (SIO's demand follows the arm, the TG moves it not).  Both hand over bumplessly,
as the other robot-level built-ins.  The laws: docs/internals/servo-level.md.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from ...core import layout
from ...core.errors import ConfigError
from .algorithm import Param, defaults, resolve_params
from .arm import ArmInput, ArmServoAlgorithm
from .armbuiltins import AXES, CT_PARAMS, STIFFNESS_MAX, N, to_tool

W = layout.WRENCH
_HALVES = (slice(0, 3), slice(3, 6))

ADMITTANCE_PARAMS: tuple[Param, ...] = (
    Param("mass", 3.0, "kg", "virtual mass along every tool axis", positive=True, maximum=1e3),
    Param("inertia", 0.05, "kg·m²", "virtual inertia about every tool axis", positive=True,
          maximum=1e2),
    *(Param(f"d{a}", 100.0, "N·s/m", f"virtual damping along tool {a}", positive=True,
            maximum=1e5) for a in AXES[:3]),
    *(Param(f"d{a}", 3.0, "N·m·s/rad", f"virtual damping about tool {a[1]}", positive=True,
            maximum=1e4) for a in AXES[3:]),
    Param("band", 2.0, "N", "dead band of the force (noise, offset drift)", maximum=100.0),
    Param("bandm", 0.2, "N·m", "dead band of the moment", maximum=10.0),
    Param("vmax", 0.25, "m/s", "the reference's speed limit", positive=True, maximum=2.0),
    Param("wmax", 0.8, "rad/s", "the reference's turning-rate limit", positive=True,
          maximum=5.0),
    Param("lam", 0.02, "m", "damping of the least squares near a singularity", positive=True,
          maximum=1.0),
    *CT_PARAMS,  # the computed-torque law tracking the reference: wn, zeta, wi, ilimit, ...
)  # fmt: skip
STIFFNESS_PARAMS: tuple[Param, ...] = (
    *(Param(f"k{a}", 2000.0, "N/m", f"stiffness along tool {a} (0: yields freely)",
            maximum=STIFFNESS_MAX) for a in AXES[:3]),
    *(Param(f"k{a}", 150.0, "N·m/rad", f"stiffness about tool {a[1]} (0: yields freely)",
            maximum=STIFFNESS_MAX) for a in AXES[3:]),
)  # fmt: skip

ADMITTANCE_DTYPE = np.dtype(
    [
        ("k", "<f8", (W,)),  # tool axes: N/m, then N·m/rad (guiding: 0)
        ("d", "<f8", (W,)),  # virtual damping, tool axes
        ("inv_m", "<f8", (W,)),  # 1 / virtual mass (inertia), tool axes
        ("v", "<f8", (W,)),  # the reference's twist relative to its base, tool axes
        ("mass", "<f8"),
        ("inertia", "<f8"),
        ("vmax", "<f8"),
        ("wmax", "<f8"),
        ("band", "<f8"),  # dead band of the force's size, N
        ("bandm", "<f8"),  # of the moment's, N·m
        ("lam2", "<f8"),  # lam², m²
        ("wn", "<f8"),
        ("zeta", "<f8"),
        ("wi", "<f8"),
        ("ilimit", "<f8"),
        ("kp", "<f8"),  # ω_n²
        ("kd", "<f8"),  # 2 ζ ω_n
        ("ki", "<f8"),  # ω_i ω_n²
        ("guides", "<f8"),  # 1: guiding (base = anchor, no spring), 0: admittance
        ("friction", "<f8"),
        ("handover_s", "<f8"),
        ("dt", "<f8"),
        ("decay", "<f8"),
        ("anchor", "<f8", (N,)),  # guiding: the joints where it took the arm over, rad
        ("offset", "<f8", (N,)),  # δ: the reference less its base, rad
        ("integral", "<f8", (N,)),  # ∫(q_r − q) per joint, rad·s
        ("bias", "<f8", (N,)),
    ],
    align=True,
)
_ARRAYS = {f"{f}{a}": (f, i) for f in "kd" for i, a in enumerate(AXES)}
_SCALARS = ("mass", "inertia", "vmax", "wmax", "band", "bandm", "wn", "zeta", "wi", "ilimit")

# scratch of the SV's one thread: J Jᵀ + λ² I; the reference's twist and acceleration (world
# axes), the two right-hand sides of one solve
_A = np.zeros((W, W))
_RHS = np.zeros((W, 2))
_TWIST, _ACC = _RHS[:, 0], _RHS[:, 1]


def _specs(guides: bool) -> tuple[Param, ...]:
    return ADMITTANCE_PARAMS if guides else (*STIFFNESS_PARAMS, *ADMITTANCE_PARAMS)


def _getter(guides: bool) -> Any:
    specs = _specs(guides)

    def get(d: Any) -> dict[str, float]:
        out = {}
        for p in specs:
            if p.name in _ARRAYS:
                field, i = _ARRAYS[p.name]
                out[p.name] = float(d[field][i])
            elif p.name == "lam":
                out[p.name] = math.sqrt(float(d["lam2"]))
            else:
                out[p.name] = float(d[p.name])
        return out

    return get


def _setter(guides: bool) -> Any:
    name, specs, get = ("guiding" if guides else "admittance"), _specs(guides), _getter(guides)

    def set_params(d: Any, values: Mapping[str, float]) -> None:
        v = resolve_params(name, specs, values, get(d))
        for key, (field, i) in _ARRAYS.items():
            if key in v:
                d[field][i] = v[key]
        if guides:
            d["k"] = 0.0
        for key in _SCALARS:
            d[key] = v[key]
        d["inv_m"][:3] = 1.0 / v["mass"]
        d["inv_m"][3:] = 1.0 / v["inertia"]
        d["lam2"] = v["lam"] ** 2
        d["kp"], d["kd"] = v["wn"] ** 2, 2.0 * v["zeta"] * v["wn"]
        d["ki"] = v["wi"] * v["wn"] ** 2
        np.clip(d["integral"], -v["ilimit"], v["ilimit"], out=d["integral"])
        d["guides"] = float(guides)
        d["handover_s"], d["friction"] = v["handover_s"], v["friction"]
        d["decay"] = math.exp(-float(d["dt"]) / v["handover_s"])

    return set_params


def _initer(guides: bool) -> Any:
    set_params = _setter(guides)

    def init(d: Any, values: Mapping[str, float], dt: float) -> None:
        if dt <= 0.0:
            raise ConfigError(f"admittance: servo period {dt:g} s must be > 0")
        d["dt"] = dt
        for field in ("v", "anchor", "offset", "integral", "bias"):
            d[field] = 0.0
        set_params(d, {**defaults(_specs(guides)), **values})

    return init


def _solve(inp: ArmInput, d: Any, rate: np.ndarray, acc: np.ndarray) -> None:
    """J⁺ of ``_TWIST`` into ``rate`` and of ``_ACC`` into ``acc`` (joint space) by damped
    least squares, Jᵀ (J Jᵀ + λ² I)⁻¹, both in one solve (its result the one allocation)."""
    np.matmul(inp.J, inp.J.T, out=_A)
    _A.flat[:: W + 1] += float(d["lam2"])
    y = np.linalg.solve(_A, _RHS)
    np.matmul(y[:, 0], inp.J, out=rate)
    np.matmul(y[:, 1], inp.J, out=acc)


def _to_world(v: np.ndarray, rot: np.ndarray, out: np.ndarray) -> None:
    """A tool-axes twist or wrench ``v`` into world axes ``out``: R on each half."""
    for half in _HALVES:
        np.matmul(rot, v[half], out=out[half])


def _core(d: Any, inp: ArmInput, tau: np.ndarray) -> None:
    """The law's torque at this tick's state; leaves q_r − q in ``inp.work[0]``, the
    offset's rate J⁺ R v in ``inp.work[2]`` and v̇ (tool axes) in ``inp.work6[0]`` for
    ``_step`` to integrate."""
    n, w, w6 = inp.n, inp.work, inp.work6
    acc, force, spring, t = w6[0], w6[1], w6[2], w6[3]
    rot = inp.pose[:3, :3]
    offset = d["offset"][:n]
    guiding = bool(d["guides"])
    # the sensed push, tool axes, its force and its moment each shortened by the dead band
    # (along itself: the direction stays; continuous through the band)
    np.copyto(force, inp.wrench)
    to_tool(force, rot, t)
    for half, band in zip(_HALVES, (float(d["band"]), float(d["bandm"])), strict=True):
        size = math.sqrt(float(np.dot(force[half], force[half])))
        np.multiply(
            force[half], max(size - band, 0.0) / size if size > 0.0 else 0.0, out=force[half]
        )
    # m v̇ = F − d v − k x
    np.multiply(d["d"], d["v"], out=acc)
    np.subtract(force, acc, out=acc)
    if not guiding:
        np.matmul(inp.J, offset, out=spring)
        to_tool(spring, rot, t)
        np.multiply(spring, d["k"], out=spring)
        np.subtract(acc, spring, out=acc)
    np.multiply(acc, d["inv_m"], out=acc)
    # the reference in joint space: e = q_r − q, q̇_r, and u (q̈_r first)
    e, qd_r, rate, u = w[0], w[1], w[2], w[3]
    _to_world(d["v"], rot, _TWIST)
    _to_world(acc, rot, _ACC)
    _solve(inp, d, rate, u)  # δ̇ = J⁺ R v, and J⁺ R v̇
    if guiding:
        np.add(d["anchor"][:n], offset, out=e)
        np.copyto(qd_r, rate)
    else:
        np.add(inp.q_d, offset, out=e)
        np.add(rate, inp.qd_d, out=qd_r)
        np.add(u, inp.qdd_d, out=u)
    np.subtract(e, inp.q, out=e)
    if d["friction"]:
        inp.friction(qd_r, tau)  # the drive's friction at q̇_r, the torque's first term
    else:
        tau.fill(0.0)
    # u = q̈_r + kd (q̇_r − q̇) + kp (q_r − q) + ki ∫(q_r − q);  τ += M u + h
    np.subtract(qd_r, inp.qd, out=qd_r)
    np.multiply(qd_r, float(d["kd"]), out=qd_r)
    np.add(u, qd_r, out=u)
    np.multiply(e, float(d["kp"]), out=qd_r)
    np.add(u, qd_r, out=u)
    np.multiply(d["integral"][:n], float(d["ki"]), out=qd_r)
    np.add(u, qd_r, out=u)
    np.matmul(inp.M, u, out=qd_r)
    np.add(tau, qd_r, out=tau)
    np.add(tau, inp.h, out=tau)


def _step(d: Any, inp: ArmInput, tau: np.ndarray) -> int:
    n, dt = inp.n, float(d["dt"])
    _core(d, inp, tau)
    bias = d["bias"][:n]
    np.add(tau, bias, out=tau)
    np.multiply(bias, float(d["decay"]), out=bias)
    # integrate: ∫(q_r − q), the offset at this tick's v, then v (capped)
    integral, offset, e = d["integral"][:n], d["offset"][:n], inp.work[0]
    np.multiply(e, dt, out=e)
    np.add(integral, e, out=integral)
    limit = float(d["ilimit"])
    np.clip(integral, -limit, limit, out=integral)
    rate = inp.work[2]
    np.multiply(rate, dt, out=rate)
    np.add(offset, rate, out=offset)
    v, acc = d["v"], inp.work6[0]
    np.multiply(acc, dt, out=acc)
    np.add(v, acc, out=v)
    for half, cap in zip(_HALVES, (float(d["vmax"]), float(d["wmax"])), strict=True):
        speed = math.sqrt(float(np.dot(v[half], v[half])))
        if speed > cap:
            np.multiply(v[half], cap / speed, out=v[half])
    return 0


def _handover(d: Any, inp: ArmInput, tau_prev: np.ndarray) -> None:
    """Take the arm over where it is, at rest: the reference starts at the measured joints
    (guiding: anchored there; admittance: offset from the demand by q − q_d) with no twist
    and no integral, and the motors' last torque less the law's first is the bias."""
    n = inp.n
    d["v"] = 0.0
    d["integral"] = 0.0
    if d["guides"]:
        d["anchor"][:n] = inp.q
        d["offset"] = 0.0
    else:
        np.subtract(inp.q, inp.q_d, out=d["offset"][:n])
    first = np.zeros(n)  # once per switch, not every tick
    _core(d, inp, first)
    np.subtract(tau_prev, first, out=d["bias"][:n])


def _algorithm(guides: bool) -> ArmServoAlgorithm:
    name = "guiding" if guides else "admittance"
    doc = (
        "hand guiding: the arm goes where its wrist sensor is pushed and stays (demand follows)"
        if guides
        else "admittance: a virtual mass-damper-spring per tool axis, pushed by the wrist sensor"
    )
    return ArmServoAlgorithm(
        name=name,
        dtype=ADMITTANCE_DTYPE,
        params=tuple(p.name for p in _specs(guides)),
        init=_initer(guides),
        step=_step,
        handover=_handover,
        set_params=_setter(guides),
        get_params=_getter(guides),
        doc=doc,
        guides=guides,
        senses=True,
    )


ADMITTANCE = _algorithm(guides=False)
GUIDING = _algorithm(guides=True)
