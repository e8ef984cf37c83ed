"""Small robot-program-like processes the wall-clock tests run through ``control``.

    python -m tests.periodic_programs KIND INSTANCE NAME [options]

Each registers one function with the wall clock (thesis 3.6.2 ``control``) and runs until
released or until the instance stops.
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from kali_daemons.core.arena import Arena
from kali_daemons.core.spinlock import SpinLock
from kali_daemons.wallclock import control

TRACE = np.dtype([("lock", "<u4"), ("n", "<u4"), ("rows", "<i8", (4096, 2))])


def trace_view(arena: Arena) -> tuple[SpinLock, np.ndarray]:
    """The shared trace: (tick, program id) rows appended under a spinlock."""
    off = arena.shmalloc("test.trace", TRACE.itemsize)
    return SpinLock(arena.address_of_field(off, TRACE, "lock"), "trace"), arena.view(off, TRACE)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("kind", choices=["trace", "slow", "hang", "boom"])
    ap.add_argument("instance")
    ap.add_argument("name")
    ap.add_argument("--id", type=int, default=0)
    ap.add_argument("--period", type=int, default=1)
    ap.add_argument("--stage", type=int, default=8)
    ap.add_argument("--serious", action="store_true")
    ap.add_argument("--after", type=int, default=0, help="misbehave from this cycle on")
    ap.add_argument("--sleep-ms", type=float, default=0.0)
    a = ap.parse_args()
    arena = Arena.attach(a.instance)
    lock, trace = trace_view(arena)
    cycles = 0

    def func(tick: int) -> None:
        nonlocal cycles
        cycles += 1
        if a.kind == "trace":
            with lock:
                n = int(trace["n"])
                trace["rows"][n] = (tick, a.id)
                trace["n"] = n + 1
        elif cycles > a.after:
            if a.kind == "boom":
                raise RuntimeError(f"boom at tick {tick}")
            time.sleep(a.sleep_ms / 1000 if a.kind == "slow" else 3600)

    raise SystemExit(
        control(a.instance, func, name=a.name, serious=a.serious, period_ms=a.period, stage=a.stage)
    )


if __name__ == "__main__":
    main()
