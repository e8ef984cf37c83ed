"""A servo plugin to copy: a critically damped PD set by its bandwidth (thesis 3.4).

    plugins: [kali_daemons.examples.servo_plugin_example]     # or [my_servo.py]

    kalictl servo select left 2 bwpd
    kalictl servo set left 2 bandwidth_hz=6 inertia=4.4

With ω = 2π·bandwidth_hz and J the joint's inertia (kg·m², armature G²·Jm included), the
gains kp = J·ω² and kv = 2·J·ω put both closed-loop poles at −ω: no overshoot, and one
number to turn.  A load (gravity) leaves an error of load / kp: there is no integral.
What a plugin must do: docs/guide/servos.md, "What a plugin must do".
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from kali_daemons.servo import (
    STATUS_OK,
    Handover,
    Param,
    Registry,
    ServoAlgorithm,
    defaults,
    resolve_params,
)

NAME = "bwpd"
VELOCITY_FILTER_HZ = 25.0  # first-order low-pass on the velocity, as in thesis figure 3.4
BIAS_TAU_S = 0.5  # the hand-over bias fades with this time constant

PARAMS = (
    Param("bandwidth_hz", 5.0, "Hz", "closed-loop bandwidth: both poles at -2π·f", positive=True),
    Param("inertia", 1.0, "kg·m²", "the joint's inertia, armature included", positive=True),
)

DTYPE = np.dtype(
    [
        ("bandwidth_hz", "<f8"),  # parameter
        ("inertia", "<f8"),  # parameter
        ("kp", "<f8"),  # N·m/rad, J·ω²
        ("kv", "<f8"),  # N·m·s/rad, 2·J·ω
        ("period", "<f8"),  # s, the servo interval
        ("lpf_a", "<f8"),  # T·2π·f of the velocity filter
        ("bias_decay", "<f8"),  # exp(-T/τ)
        ("old_position", "<f8"),  # rad
        ("velocity", "<f8"),  # rad/s, filtered
        ("bias", "<f8"),  # N·m, what is left of the hand-over torque
        ("primed", "<u4"),  # 0 until the first step or hand-over
    ],
    align=True,
)


def step(data: Any, demand: float, position: float) -> tuple[float, float, int]:
    """One servo tick: kp·e − kv·v + bias.  Inside the cycle."""
    if not data.primed:  # first step after init: start at rest here
        data.old_position = position
        data.primed = 1
    a = data.lpf_a
    v_raw = (position - data.old_position) / data.period
    v = (a * v_raw + data.velocity) / (1.0 + a)
    data.old_position = position
    data.velocity = v
    bias = data.bias
    data.bias = bias * data.bias_decay
    error = demand - position
    return data.kp * error - data.kv * v + bias, error, STATUS_OK


def handover(data: Any, h: Handover) -> None:
    """Start from the previous servo's torque: the bias makes up the difference."""
    data.old_position = h.position - h.velocity * data.period  # as if we had been running
    data.velocity = h.velocity
    data.primed = 1
    data.bias = h.torque - (data.kp * (h.demand - h.position) - data.kv * h.velocity)


def init(data: Any, init_data: Mapping[str, float], sample_interval_s: float) -> None:
    """Parameters from ``init_data`` (missing: defaults), gains computed, state reset."""
    params = resolve_params(NAME, PARAMS, init_data, defaults(PARAMS))
    data.period = sample_interval_s
    data.lpf_a = sample_interval_s * 2.0 * math.pi * VELOCITY_FILTER_HZ
    data.bias_decay = math.exp(-sample_interval_s / BIAS_TAU_S)
    data.old_position = data.velocity = data.bias = 0.0
    data.primed = 0
    _store(data, params)


def set_params(data: Any, values: Mapping[str, float]) -> None:
    """Change bandwidth or inertia on line; the state (velocity, bias) is kept."""
    _store(data, resolve_params(NAME, PARAMS, values, get_params(data)))


def get_params(data: Any) -> dict[str, float]:
    """The current parameters."""
    return {"bandwidth_hz": data.bandwidth_hz, "inertia": data.inertia}


def _store(data: Any, params: Mapping[str, float]) -> None:
    data.bandwidth_hz = params["bandwidth_hz"]
    data.inertia = params["inertia"]
    w = 2.0 * math.pi * data.bandwidth_hz
    data.kp = data.inertia * w * w
    data.kv = 2.0 * data.inertia * w


def register(registry: Registry) -> None:
    """Called by Kali when it loads the plugins named in the config."""
    registry.register(
        ServoAlgorithm(
            name=NAME,
            dtype=DTYPE,
            params=tuple(p.name for p in PARAMS),
            init=init,
            step=step,
            handover=handover,
            set_params=set_params,
            get_params=get_params,
            doc="critically damped PD: kp = J·ω², kv = 2·J·ω, ω = 2π·bandwidth_hz",
        )
    )
