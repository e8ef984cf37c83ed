"""The built-in servo algorithms: the PID of thesis figure 3.4 (index 0) and a PD (index 1).

Both close the loop on joint angle (rad) and output joint torque (N·m), as every Kali servo
does (3.3.4); the robot driver in SIO does the encoder and DAC conversions.

**PID.**  Each servo interval the position error and the velocity (the position difference
over the interval) pass first-order low-pass filters, cut-offs ``fe`` and ``fv``; the
integral of the filtered error grows only while ``|e| ≤ integration_band`` and is kept as the
torque it contributes, I, limited to ``± integration_reset`` N·m; then
``torque = kp·e + I − kv·v + bias``.  The hand-over ``bias``, decaying with time constant
``bias_tau``, carries what the integral cannot hold at a switch, so switching is bumpless.

**PD.**  ``torque = kp·e − kv·v + bias`` with the raw error, the same velocity filter and
the same decaying hand-over bias.  No integral: a joint under load holds with an offset.

Each robot type's tuned gains are its ``pid_defaults`` and ``pd_defaults``
(``kali_daemons.robots``); the defaults here are for an unknown joint.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

from ...core.errors import ConfigError
from ...core.layout import PD_DTYPE, PID_DTYPE
from . import admittance, armbuiltins
from .algorithm import (
    STATUS_OK,
    Handover,
    Param,
    ServoAlgorithm,
    defaults,
    resolve_params,
)

if TYPE_CHECKING:
    from .registry import Registry

# ------------------------------------------------------------------------------ PID

# Upper bounds: far beyond any tuning of a PUMA 560 joint (puma560.PID_DEFAULTS: kp up to
# 13,000, ki 260,000, kv 330; stable with every gain doubled), so only a typo meets them.
# The filters' cut-offs have none: above the sample rate they pass the signal through.
KP_MAX = 1e6  # N·m/rad: 1 mrad of error asks 1,000 N·m, ~7 times joint 2's peak torque
KI_MAX = 1e8  # N·m/(rad·s)
KV_MAX = 1e5  # N·m·s/rad
RESET_MAX = 1e4  # N·m
BIAS_TAU_MAX = 3600.0  # s

PID_PARAMS: tuple[Param, ...] = (
    Param("kp", 100.0, "N·m/rad", "proportional gain on the filtered error", maximum=KP_MAX),
    Param("ki", 0.0, "N·m/(rad·s)", "integral gain", maximum=KI_MAX),
    Param(
        "kv",
        5.0,
        "N·m·s/rad",
        "velocity (derivative) gain on the filtered velocity",
        maximum=KV_MAX,
    ),
    Param("fe", 50.0, "Hz", "cut-off of the error's low-pass filter", positive=True),
    Param("fv", 25.0, "Hz", "cut-off of the velocity's low-pass filter", positive=True),
    Param(
        "integration_band",
        0.05,
        "rad",
        "the integral accumulates only while |e| <= this",
        maximum=math.pi,
    ),
    Param(
        "integration_reset",
        10.0,
        "N·m",
        "limit of the integral's torque, ± (anti-windup)",
        maximum=RESET_MAX,
    ),
    Param(
        "bias_tau",
        0.5,
        "s",
        "time constant of the decaying hand-over bias",
        maximum=BIAS_TAU_MAX,
    ),
)


def pid_step(data: Any, demand: float, position: float) -> tuple[float, float, int]:
    """One servo interval of the PID of figure 3.4 (thesis 3.4).  Inside the cycle.

    Returns (torque N·m, filtered error rad, status).
    """
    if not data.primed:
        _prime(data, demand, position)

    # The error signal and the velocity are first low-pass filtered:
    # first order, backward difference, y_k = (a·x_k + y_{k-1}) / (1 + a).
    e = data.lpfe2 * (data.lpfe1 * (demand - position) + data.error)
    v_raw = (position - data.old_position) * data.inv_period
    v = data.lpfv2 * (data.lpfv1 * v_raw + data.old_velocity)
    data.error = e
    data.old_position = position
    data.old_velocity = v

    # Integrate only inside the integration band; limit the integral's torque (anti-windup).
    integral = data.integral
    if -data.integration_band <= e <= data.integration_band:
        integral += data.ki_t * e
        reset = data.integration_reset
        if integral > reset:
            integral = reset
        elif integral < -reset:
            integral = -reset
        data.integral = integral

    # Whatever a servo switch left to carry fades away with time constant bias_tau.
    bias = data.bias
    data.bias = bias * data.bias_decay

    torque = data.kp * e + integral - data.kv * v + bias
    return torque, e, STATUS_OK


def pid_handover(data: Any, h: Handover) -> None:
    """Take the joint over bumplessly.  Inside the cycle, just before this tick's ``pid_step``
    with ``h.demand`` and ``h.position``.

    The filters start in their steady state for that sample (error filter at
    ``demand − position``, velocity filter at ``h.velocity``, ``θ_{k-1}`` one interval back at
    that velocity), and the integral is set so that step outputs exactly ``h.torque``.  What
    the integral cannot hold (``ki = 0``, or beyond ``integration_reset``) goes to the bias.
    """
    e = h.demand - h.position
    data.error = e
    data.old_velocity = h.velocity
    data.old_position = h.position - h.velocity * data.sampling_period
    data.primed = 1
    needed = h.torque - data.kp * e + data.kv * h.velocity  # integral + bias in that step
    held = _clamp(needed, data.integration_reset) if data.ki > 0.0 else 0.0
    in_band = -data.integration_band <= e <= data.integration_band
    data.integral = held - (data.ki_t * e if in_band else 0.0)  # the step adds ki·T·e back
    data.bias = needed - held


def pid_init(data: Any, init_data: Mapping[str, float], sample_interval_s: float) -> None:
    """Parameters from ``init_data`` (missing: the defaults), precomputed terms, state reset.

    Outside the cycle; ConfigError for an unknown parameter or a value out of range, in
    which case ``data`` is left unchanged.
    """
    t = _check_interval("pid", sample_interval_s)
    params = resolve_params("pid", PID_PARAMS, init_data, defaults(PID_PARAMS))
    _zero(data)
    data.sampling_period = t
    data.inv_period = 1.0 / t
    _pid_store(data, params)


def pid_set_params(data: Any, values: Mapping[str, float]) -> None:
    """Change some parameters on line, keeping the state.  Outside the cycle.

    Precomputed terms are recomputed.  The output stays continuous: if ``ki`` becomes 0 or
    ``integration_reset`` drops below the integral, the torque the integral no longer holds
    moves to the decaying bias.
    """
    params = resolve_params("pid", PID_PARAMS, values, pid_get_params(data))
    _pid_store(data, params)
    held = _clamp(data.integral, data.integration_reset) if data.ki > 0.0 else 0.0
    data.bias += data.integral - held
    data.integral = held


def pid_get_params(data: Any) -> dict[str, float]:
    """Every PID parameter's current value.  Outside the cycle."""
    return {p.name: float(getattr(data, p.name)) for p in PID_PARAMS}


def _pid_store(data: Any, params: Mapping[str, float]) -> None:
    """Write the parameters and recompute the terms figure 3.4 precomputes."""
    t = data.sampling_period
    for name, value in params.items():
        setattr(data, name, value)
    data.ki_t = data.ki * t
    data.lpfe1 = t * 2.0 * math.pi * data.fe
    data.lpfe2 = 1.0 / (1.0 + data.lpfe1)
    data.lpfv1 = t * 2.0 * math.pi * data.fv
    data.lpfv2 = 1.0 / (1.0 + data.lpfv1)
    data.bias_decay = _decay(t, data.bias_tau)


PID = ServoAlgorithm(
    name="pid",
    dtype=PID_DTYPE,
    params=tuple(p.name for p in PID_PARAMS),
    init=pid_init,
    step=pid_step,
    handover=pid_handover,
    set_params=pid_set_params,
    get_params=pid_get_params,
    doc="PID of thesis figure 3.4: low-pass filtered error and velocity, integral within a "
    "band, limited to ±integration_reset N·m; decaying hand-over bias",
)

# ------------------------------------------------------------------------------ PD

PD_PARAMS: tuple[Param, ...] = (
    Param("kp", 100.0, "N·m/rad", "proportional gain on the error", maximum=KP_MAX),
    Param("kv", 5.0, "N·m·s/rad", "velocity gain on the filtered velocity", maximum=KV_MAX),
    Param("fv", 25.0, "Hz", "cut-off of the velocity's low-pass filter", positive=True),
    Param(
        "bias_tau",
        0.5,
        "s",
        "time constant of the decaying hand-over bias",
        maximum=BIAS_TAU_MAX,
    ),
)


def pd_step(data: Any, demand: float, position: float) -> tuple[float, float, int]:
    """One servo interval of the PD: ``kp·e − kv·v + bias``.  Inside the cycle."""
    if not data.primed:
        _prime(data, demand, position)
    e = demand - position
    v_raw = (position - data.old_position) * data.inv_period
    v = data.lpfv2 * (data.lpfv1 * v_raw + data.old_velocity)
    data.error = e
    data.old_position = position
    data.old_velocity = v
    bias = data.bias
    data.bias = bias * data.bias_decay
    return data.kp * e - data.kv * v + bias, e, STATUS_OK


def pd_handover(data: Any, h: Handover) -> None:
    """Take the joint over bumplessly: the bias makes this tick's ``pd_step`` (with
    ``h.demand``, ``h.position``) output ``h.torque``, then fades with ``bias_tau``.
    Inside the cycle."""
    e = h.demand - h.position
    data.error = e
    data.old_velocity = h.velocity
    data.old_position = h.position - h.velocity * data.sampling_period
    data.primed = 1
    data.bias = h.torque - data.kp * e + data.kv * h.velocity


def pd_init(data: Any, init_data: Mapping[str, float], sample_interval_s: float) -> None:
    """Parameters from ``init_data`` (missing: the defaults), state reset.  Outside the
    cycle; ConfigError leaves ``data`` unchanged."""
    t = _check_interval("pd", sample_interval_s)
    params = resolve_params("pd", PD_PARAMS, init_data, defaults(PD_PARAMS))
    _zero(data)
    data.sampling_period = t
    data.inv_period = 1.0 / t
    _pd_store(data, params)


def pd_set_params(data: Any, values: Mapping[str, float]) -> None:
    """Change some parameters on line, keeping the state.  Outside the cycle."""
    _pd_store(data, resolve_params("pd", PD_PARAMS, values, pd_get_params(data)))


def pd_get_params(data: Any) -> dict[str, float]:
    """Every PD parameter's current value.  Outside the cycle."""
    return {p.name: float(getattr(data, p.name)) for p in PD_PARAMS}


def _pd_store(data: Any, params: Mapping[str, float]) -> None:
    t = data.sampling_period
    for name, value in params.items():
        setattr(data, name, value)
    data.lpfv1 = t * 2.0 * math.pi * data.fv
    data.lpfv2 = 1.0 / (1.0 + data.lpfv1)
    data.bias_decay = _decay(t, data.bias_tau)


PD = ServoAlgorithm(
    name="pd",
    dtype=PD_DTYPE,
    params=tuple(p.name for p in PD_PARAMS),
    init=pd_init,
    step=pd_step,
    handover=pd_handover,
    set_params=pd_set_params,
    get_params=pd_get_params,
    doc="PD on the raw error and the filtered velocity, with a decaying hand-over bias",
)

# ------------------------------------------------------------------------------ shared


def _prime(data: Any, demand: float, position: float) -> None:
    """First step after init: no previous sample, so start at rest here (no velocity kick)."""
    data.error = demand - position
    data.old_position = position
    data.old_velocity = 0.0
    data.primed = 1


def _clamp(x: float, limit: float) -> float:
    return limit if x > limit else -limit if x < -limit else x


def _decay(t: float, tau: float) -> float:
    """Per-step factor of a bias decaying with time constant ``tau`` (0: gone after one step)."""
    return math.exp(-t / tau) if tau > 0.0 else 0.0


def _zero(data: Any) -> None:
    ctypes.memset(ctypes.addressof(data), 0, ctypes.sizeof(data))


def _check_interval(algo: str, sample_interval_s: float) -> float:
    t = float(sample_interval_s)
    if not (math.isfinite(t) and t > 0.0):
        raise ConfigError(f"servo {algo}: sample interval {sample_interval_s!r} s must be > 0")
    return t


def register(registry: Registry) -> None:
    """The built-ins, in their fixed order: pid = 0, pd = 1; then the robot-level ones
    (``armbuiltins``: computed_torque = 0, impedance = 1; ``admittance``: admittance = 2,
    guiding = 3)."""
    registry.register(PID)
    registry.register(PD)
    armbuiltins.register(registry)
    registry.register(admittance.ADMITTANCE)
    registry.register(admittance.GUIDING)
