"""Benchmark: what the flight recorder adds to SIO's cycle, per servo tick.

What is measured.  ``FlightRecorder.record`` exactly as SIO calls it at the end of its cycle
(``kali_daemons/runtime/flightrec.py``): one row of 4 timing integers and 6 per-joint float arrays
written into the ring in a real arena segment, for 1, 2 and 4 arms (6, 12, 24 joints), timed
over ``--iterations`` calls with the garbage collector off, so the ring wraps many times.  An
empty loop is shown beside it for the interpreter's own share.

How to read it.  ``ns/tick`` is the best of ``--repeats`` runs, the median beside it (the gap
is scheduling noise); at a 1 kHz servo rate 1000 ns is 0.1 % of the period.  Run as root with
``--cpu`` and ``--fifo`` for the figures a SCHED_FIFO SIO sees.

    .venv/bin/python scripts/bench_flightrec.py
    .venv/bin/python scripts/bench_flightrec.py --iterations 500000 --cpu 1 --fifo 50
"""

from __future__ import annotations

import argparse
import dataclasses
import gc
import os
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from harness import DEFAULT_CONFIG, table, time_per_op

from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.robots import puma560
from kali_daemons.runtime.config import KaliConfig, load_config
from kali_daemons.runtime.flightrec import FlightRecorder
from kali_daemons.tools import launcher


@dataclass
class Shim:
    """What FlightRecorder needs of an Instance: the arena, the config, the process table."""

    arena: Arena
    config: KaliConfig
    procs: np.ndarray


def bench(arms: int, iterations: int, repeats: int, cfg: KaliConfig) -> tuple[float, float]:
    """Best and median ns per ``record`` for ``arms`` arms of the config's first robot, each
    with its wrist wrench."""
    cfg = dataclasses.replace(cfg, robots=(cfg.robots[0],) * arms)
    n_joints = cfg.joints.total
    name = f"benchfr{os.getpid()}"
    arena = Arena.create(name, 16 << 20)
    try:
        procs = arena.record(layout.KEY_PROCESSES, layout.PROCESS, layout.MAX_PROCESSES)
        rec = FlightRecorder(Shim(arena, cfg, procs), n_joints, create=True, slot=3)  # type: ignore[arg-type]
        src = [np.random.default_rng(k).random(n_joints) for k in range(len(layout.FLIGHT_FIELDS))]
        rec.bind(*src, wrench=np.random.default_rng(9).random((arms, layout.WRENCH)))

        def loop(n: int, record: Callable[..., None] = rec.record) -> None:
            t0 = time.perf_counter_ns()
            for i in range(n):
                record(i, t0, 150_000, 90_000, 60_000)  # latency, wait, ran (ns)

        best_median = time_per_op(loop, iterations, repeats)
        del rec, procs, loop  # the arena's views, before it closes
        return best_median
    finally:
        arena.close()
        launcher.stop(name)


def empty_loop(iterations: int, repeats: int) -> tuple[float, float]:
    """The interpreter's loop alone."""

    def loop(n: int) -> None:
        for _i in range(n):
            pass

    return time_per_op(loop, iterations, repeats)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--iterations", type=int, default=200_000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--cpu", type=int, default=None, help="bind to this CPU")
    ap.add_argument("--fifo", type=int, default=0, help="SCHED_FIFO priority (root)")
    args = ap.parse_args()
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})
    if args.fifo:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(args.fifo))
    cfg = load_config(DEFAULT_CONFIG)
    gc.disable()
    rows = layout.flight_rows(int(cfg.clock.servo_period_ms * 1e6))
    print(f"flight recorder: {rows} rows ({layout.FLIGHT_SECONDS:g} s at the default period)")
    best, med = empty_loop(args.iterations, args.repeats)
    body = [["empty loop", f"{best:.0f}", f"{med:.0f}", ""]]
    for arms in (1, 2, 4):
        n = puma560.ROBOT.n_joints * arms
        best, med = bench(arms, args.iterations, args.repeats, cfg)
        kib = rows * layout.flight_row(n, arms).itemsize / 1024
        body.append([f"record, {arms} arm(s)", f"{best:.0f}", f"{med:.0f}", f"{kib:.0f}"])
    print(table([("", "left"), "best ns/tick", "median", "ring KiB"], body))


if __name__ == "__main__":
    main()
