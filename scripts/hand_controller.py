"""A simulated hand controller: a scripted 6-DOF input device, as its own process (issue 28).

    python scripts/hand_controller.py [--seconds S] [--name hand]

It attaches to the instance ($KALI_INSTANCE, as ``kalictl run`` sets it), holds a shared
transform (``--name``, default ``hand``) from the first tick the clock runs it, and writes into
it every 20 ms on the wall clock
(``client.control``: this process is the periodic function, so a lockstep run waits for it),
the offset an operator's hand would give: a slow figure of eight in the tool's x-y plane, a
small nod about its z, starting and ending at rest.  After ``--seconds`` it stops writing and
exits: a motion following it sees the transform go stale and stops the arm
(``scripts/example_teleop.py``).
"""

from __future__ import annotations

import argparse
import math
import os

import numpy as np

from kali_daemons import client
from kali_daemons.client import Kali

PERIOD_MS = 20.0
LIFETIME_S = 0.1  # the stream is stale after this: five missed writes
REACH_M = 0.03  # the figure of eight's half width
NOD_RAD = 0.1
FIGURE_S = 4.0  # one figure of eight


def offset(t: float, seconds: float) -> np.ndarray:
    """The device's offset at time ``t`` of ``seconds``: a figure of eight, faded in and out
    over its first and last second so it starts and ends at rest (4×4)."""
    fade = min(1.0, t, max(0.0, seconds - t)) ** 2
    a = 2.0 * math.pi * t / FIGURE_S
    out = np.eye(4)
    out[0, 3] = fade * REACH_M * math.sin(a)
    out[1, 3] = fade * REACH_M * math.sin(a) * math.cos(a)
    nod = fade * NOD_RAD * math.sin(a)
    out[:2, :2] = ((math.cos(nod), -math.sin(nod)), (math.sin(nod), math.cos(nod)))
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=6.0)
    parser.add_argument("--name", default="hand")
    args = parser.parse_args()
    with Kali() as kali:
        tick_s = kali.inst.config.clock.base_tick_ms / 1000.0
        stream: list = []  # the transform and the tick the device started on, at its first run

        def write(tick: int) -> bool:
            if not stream:  # held from the first tick the clock runs the device: a program
                # that finds the transform finds it streaming, never while the device is
                # still registering (the stream would go stale under its follower)
                stream.extend(
                    (kali.shared_transform(args.name, np.eye(4), lifetime=LIFETIME_S), tick)
                )
            hand, start = stream
            t = (tick - start) * tick_s
            hand.set(offset(t, args.seconds))
            return t < args.seconds  # False: the device stops (released)

        client.control(kali.inst.name, write, name=f"hand.{os.getpid()}", period_ms=PERIOD_MS)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
