"""A TG function plugin to copy (thesis 3.2.3: a position equation's transforms may be
"objects and functions"): ``circle``, a point going round a circle in the x-y plane of the
frame before it in the loop.

Name it in the config (this module by name, or your copy's file) and a program can use it in
any tracking loop:

    tg_functions: [kali_daemons.examples.tg_function_example]     # or [my_function.py]

    c = kali.tg_function("circle", radius=0.02, frequency_hz=0.25)
    left.track([left.read_pose(), c])        # the tool circles where it is
    c.set(radius=0.04)                       # on line: the TG keeps the arm within its limits

What a plugin must do (``kali_daemons/tg/functions.py`` has the details):

- declare its private data as an *aligned* numpy structured dtype of numeric scalars, at most
  256 B (``layout.FUNCTION_DATA_BYTES``), with a field per parameter; it lives in the arena;
- ``evaluate(data, t, sensors, out)`` runs in the TG every tick of a motion using it: write
  the transform at time ``t`` (s since the program set it up) into ``out`` (4×4, identity on
  entry); ``sensors.q[k]`` and ``sensors.wrench[k]`` are robot k's measured joints and
  contact wrench.  Floats and ``data.<field>`` only: no allocation, no I/O, no logging, and
  at most 20 % of the TG period (beyond, or raising, it holds the motions using it);
- ``derive(data)`` (optional) recomputes derived terms after parameters change;
- ``register(registry)`` registers it.
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
