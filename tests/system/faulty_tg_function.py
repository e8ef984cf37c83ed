"""A TG function plugin that misbehaves on request, for tests/test_tracking.py and
tests/system/test_trust_round2.py: ``faulty`` returns the identity with ``mode`` 0, raises
with 1, sleeps ``work_ms`` (50 ms by default: far beyond its share of a 10 ms TG tick) with 2,
burns ``work_ms`` of its thread's CPU time (fixed work, however loaded the CPU) and waves
along z with 3, and never returns with 4."""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from kali_daemons.servo import Param
from kali_daemons.tg.functions import FunctionRegistry, Sensors, TgFunction


def evaluate(data: Any, t: float, sensors: Sensors, out: np.ndarray) -> None:
    if data.mode == 1.0:
        raise RuntimeError("asked to fail")
    if data.mode == 2.0:
        time.sleep(data.work_ms / 1000.0)
    if data.mode == 3.0:
        end = time.thread_time_ns() + int(data.work_ms * 1e6)
        while time.thread_time_ns() < end:
            pass
        out[2, 3] = 0.01 * math.sin(math.pi * t)
    while data.mode == 4.0:
        time.sleep(0.01)


def register(registry: FunctionRegistry) -> None:
    registry.register(
        TgFunction(
            "faulty",
            np.dtype([("mode", "<f8"), ("work_ms", "<f8")], align=True),
            (
                Param("mode", 0.0, "", "0 fine, 1 raise, 2 sleep, 3 burn, 4 hang", maximum=4.0),
                Param("work_ms", 50.0, "ms", "how long mode 2 sleeps or 3 burns", maximum=1000.0),
            ),
            evaluate,
        )
    )
