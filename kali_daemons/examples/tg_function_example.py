"""A TG function plugin to copy (thesis 3.2.3: a position equation's transforms may be
"objects and functions"): ``circle``, a point going round a circle in the x-y plane of the
frame before it in the loop.

    tg_functions: [kali_daemons.examples.tg_function_example]     # or [my_function.py]

    c = kali.tg_function("circle", radius=0.02, frequency_hz=0.25)
    left.track([left.read_pose(), c])        # the tool circles where it is
    c.set(radius=0.04)                       # on line: the TG keeps the arm within its limits

What a TG function must do: docs/guide/programs.md, "What a TG function must do".
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from kali_daemons.servo import Param
from kali_daemons.tg.functions import FunctionRegistry, Sensors, TgFunction

DTYPE = np.dtype(
    [("radius", "<f8"), ("frequency_hz", "<f8"), ("omega", "<f8")],  # omega: derived
    align=True,
)
PARAMS = (
    Param("radius", 0.02, "m", "of the circle", maximum=0.5),
    Param("frequency_hz", 0.25, "Hz", "turns per second", maximum=5.0),
)


def evaluate(data: Any, t: float, sensors: Sensors, out: np.ndarray) -> None:
    """The point on the circle at time t: it starts on the frame before it (t = 0: no jump)
    and goes round the centre one radius along −x of that frame."""
    a = data.omega * t
    out[0, 3] = data.radius * (math.cos(a) - 1.0)
    out[1, 3] = data.radius * math.sin(a)


def derive(data: Any) -> None:
    data.omega = 2.0 * math.pi * data.frequency_hz


def register(registry: FunctionRegistry) -> None:
    registry.register(TgFunction("circle", DTYPE, PARAMS, evaluate, derive, doc=__doc__ or ""))
