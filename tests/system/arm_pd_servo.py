"""A robot-level servo plugin for the loading tests (issue 55 item 6): a joint-space PD on
every joint of the arm at once, plus the feed-forward and a hand-over bias that fades, so
the switch to it is bumpless.  ``tau = kp (q_d - q) + kv (qd_d - qd) + tau_ff + bias``."""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from kali_daemons.servo import ArmInput, ArmServoAlgorithm, Registry

NAME = "arm_pd"
PARAMS = ("kp", "kv")
DTYPE = np.dtype(
    [("kp", "<f8"), ("kv", "<f8"), ("decay", "<f8"), ("bias", "<f8", (8,))], align=True
)


def init(data: Any, init_data: Mapping[str, float], dt: float) -> None:
    data["kp"], data["kv"] = 2000.0, 100.0
    data["decay"] = math.exp(-dt / 0.3)
    data["bias"] = 0.0
    set_params(data, init_data)


def step(data: Any, inp: ArmInput, tau: np.ndarray) -> int:
    n = inp.n
    bias = data["bias"][:n]
    np.subtract(inp.q_d, inp.q, out=tau)
    tau *= data["kp"]
    w = inp.work[0]
    np.subtract(inp.qd_d, inp.qd, out=w)
    w *= data["kv"]
    tau += w
    tau += inp.tau_ff
    tau += bias
    bias *= data["decay"]
    return 0


def handover(data: Any, inp: ArmInput, tau_prev: np.ndarray) -> None:
    n = inp.n
    law = data["kp"] * (inp.q_d - inp.q) + data["kv"] * (inp.qd_d - inp.qd) + inp.tau_ff
    data["bias"][:n] = tau_prev - law


def set_params(data: Any, values: Mapping[str, float]) -> None:
    for key, value in values.items():
        if key not in PARAMS or not 0.0 <= float(value) < 1e5:
            raise ValueError(f"arm_pd: {key} = {value}: parameters {PARAMS}, 0 .. 1e5")
        data[key] = float(value)


def get_params(data: Any) -> dict[str, float]:
    return {p: float(data[p]) for p in PARAMS}


def register(registry: Registry) -> None:
    registry.register(
        ArmServoAlgorithm(NAME, DTYPE, PARAMS, init, step, handover, set_params, get_params)
    )
