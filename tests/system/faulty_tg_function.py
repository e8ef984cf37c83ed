"""A TG function plugin that misbehaves on request, for tests/test_tracking.py: ``faulty``
returns the identity with ``mode`` 0, raises with 1, and takes 50 ms (far beyond its share of
a 10 ms TG tick) with 2."""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from kali_daemons.servo import Param
from kali_daemons.tg.functions import FunctionRegistry, Sensors, TgFunction


def evaluate(data: Any, t: float, sensors: Sensors, out: np.ndarray) -> None:
    if data.mode == 1.0:
        raise RuntimeError("asked to fail")
    if data.mode == 2.0:
        time.sleep(0.05)


def register(registry: FunctionRegistry) -> None:
    registry.register(
        TgFunction(
            "faulty",
            np.dtype([("mode", "<f8")], align=True),
            (Param("mode", 0.0, "", "0 fine, 1 raise, 2 slow", maximum=2.0),),
            evaluate,
        )
    )
