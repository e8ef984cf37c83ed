"""A servo plugin that misbehaves on request, for the fault-injection matrix (issue 7).

``faulty`` is a PD with a hand-over bias (as ``kali_daemons.examples.servo_plugin_example``) whose
``fail`` parameter makes its step go wrong: 1 raises, 2 returns a NaN torque, 3 takes
``slow_ms`` per step.  Set ``fail`` on the joint's ``faulty`` record first, then select it:
the first step misbehaves, so no PD tuning matters.
"""

from __future__ import annotations

import time
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

NAME = "faulty"
RAISE, NAN, SLOW = 1.0, 2.0, 3.0

PARAMS = (
    Param("kp", 4000.0, "N·m/rad", "position gain"),
    Param("kv", 250.0, "N·m·s/rad", "velocity gain"),
    Param("fail", 0.0, "", "0 works, 1 raises, 2 returns NaN, 3 takes slow_ms per step"),
    Param("slow_ms", 50.0, "ms", "how long a slow step takes"),
)

DTYPE = np.dtype(
    [
        ("kp", "<f8"),
        ("kv", "<f8"),
        ("fail", "<f8"),
        ("slow_ms", "<f8"),
        ("period", "<f8"),
        ("old_position", "<f8"),
        ("bias", "<f8"),
    ],
    align=True,
)


def step(data: Any, demand: float, position: float) -> tuple[float, float, int]:
    """PD plus the fading hand-over bias; or the fault ``fail`` asks for."""
    if data.fail == RAISE:
        raise RuntimeError("injected servo fault")
    if data.fail == SLOW:
        time.sleep(data.slow_ms / 1000.0)
    v = (position - data.old_position) / data.period
    data.old_position = position
    data.bias *= 0.999
    error = demand - position
    torque = data.kp * error - data.kv * v + data.bias
    return (float("nan") if data.fail == NAN else torque), error, STATUS_OK


def handover(data: Any, h: Handover) -> None:
    """Continue from the previous servo's torque."""
    data.old_position = h.position - h.velocity * data.period
    data.bias = h.torque - (data.kp * (h.demand - h.position) - data.kv * h.velocity)


def init(data: Any, init_data: Mapping[str, float], sample_interval_s: float) -> None:
    data.period = sample_interval_s
    data.old_position = data.bias = 0.0
    set_params(data, resolve_params(NAME, PARAMS, init_data, defaults(PARAMS)))


def set_params(data: Any, values: Mapping[str, float]) -> None:
    for k, v in resolve_params(NAME, PARAMS, values, get_params(data)).items():
        setattr(data, k, v)


def get_params(data: Any) -> dict[str, float]:
    return {p.name: float(getattr(data, p.name)) for p in PARAMS}


def register(registry: Registry) -> None:
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
            doc="PD that raises, returns NaN or is slow on request (fault injection)",
        )
    )
