"""Benchmark: what the plant costs per simulated millisecond for 1, 2 and 4 arms.

Two measurements per arm count:

1. **In-process cost**: ``PlantSim.cycle`` (one 1 ms plant period: board logic, motor model,
   MuJoCo substeps, encoders, truth records) timed with the thread's CPU time, amplifiers on
   and every DAC driving, after a warm-up; the best of five runs of ``--cycles``/5 cycles.
   From it the real-time factor the plant could sustain on one core (1 ms / cost) and the
   share of one core it needs at real time.
2. **As a process at real time**: the plant daemon of a real instance (``kalictl start``,
   real-time mode), its scheduler run time (``/proc/<pid>/task/*/schedstat``, ns) in 1 s
   windows over ``--seconds``: everything the process really costs, including its own clock,
   the wake-ups and the Python loop around ``cycle``.  This VM's host takes CPU time from
   running programs in bursts (no steal accounting here, so it shows up as run time): a
   window's share varies by 1.5x from one second to the next.  The table gives the median
   window with the lowest and highest, and the goal is judged on the median.

Goal (the issue): two arms in under 15 % of one core at real time.

    .venv/bin/python scripts/bench_plant.py
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import sys
import time

from benchlib import run_ns
from harness import Goal, KaliRun, cell_config, robots, table

from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.hardware.mcgill import registers
from kali_daemons.hardware.mcgill.registers import CSR_ENABLE, CSR_NO_DISABLE
from kali_daemons.plant.sim import PlantSim
from kali_daemons.runtime.config import KaliConfig
from kali_daemons.tools import launcher

GOAL = Goal("two arms at real time", "median share", "<", 15.0, "% of one core")
REPEATS = 5
PLACEMENTS = [  # base x, y, yaw: facing the centre of the cell
    (-0.6, 0.0, 0.0),
    (0.6, 0.0, 180.0),
    (0.0, -0.6, 90.0),
    (0.0, 0.6, -90.0),
]


def config_for(arms: int, instance: str) -> KaliConfig:
    """The default config with ``arms`` PUMAs at ``PLACEMENTS``."""
    cell = [(f"arm{k}", "puma560", x, y, yaw) for k, (x, y, yaw) in enumerate(PLACEMENTS[:arms])]
    return cell_config({"robots": robots(*cell)}, instance, label=f"{arms} arms")


def power_up(sim: PlantSim) -> None:
    """Enable every arm and drive every joint with a small DAC signal."""
    for board in sim.boards:
        board.regs["csr"] = CSR_NO_DISABLE | CSR_ENABLE
    for _ in range(70):
        sim.cycle()
    for board in sim.boards:
        board.regs["csr"] = CSR_NO_DISABLE
    sim.dac["code"][:, : layout.MAX_JOINTS] = registers.DAC_ZERO + 100  # every channel


def in_process(arms: int, cycles: int) -> tuple[float, float]:
    """(CPU µs per simulated ms, wall µs per simulated ms) of ``PlantSim.cycle``."""
    name = f"benchplant{os.getpid()}"
    arena = Arena.create(name, 4 << 20)
    try:
        sim = PlantSim(config_for(arms, name), arena)
        power_up(sim)
        for _ in range(200):
            sim.cycle()
        best = (math.inf, math.inf)
        for _ in range(REPEATS):  # the best of several: this VM's host adds noise, never saves
            c0, w0 = time.thread_time_ns(), time.perf_counter_ns()
            for _ in range(cycles // REPEATS):
                sim.cycle()
            c1, w1 = time.thread_time_ns(), time.perf_counter_ns()
            best = min(best, (c1 - c0, w1 - w0))
        del sim
    finally:
        arena.close()
        launcher.stop(name)
    n = cycles // REPEATS
    return best[0] / n / 1e3, best[1] / n / 1e3


def as_process(arms: int, seconds: float) -> tuple[list[float], int]:
    """(share of one core in each 1 s window, plant cycles) of a real-time plant daemon."""
    name = f"benchplant{os.getpid()}p"
    shares = []
    with KaliRun(config_for(arms, name)) as run:
        inst = run.inst
        assert inst is not None
        pid = run.pids["plant"]
        truth = inst.arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
        time.sleep(1.0)
        n0 = int(truth["ticks"])
        for _ in range(max(1, round(seconds))):
            r0, w0 = run_ns(pid), time.monotonic_ns()
            time.sleep(1.0)
            r1, w1 = run_ns(pid), time.monotonic_ns()
            shares.append((r1 - r0) / (w1 - w0))
        n1 = int(truth["ticks"])
        del truth
    return shares, n1 - n0


def main(argv: list[str] | None = None) -> int:
    """Run both measurements for each arm count and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--arms", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--cycles", type=int, default=3000, help="in-process cycles (1 ms each)")
    ap.add_argument("--seconds", type=float, default=10.0, help="real-time process window")
    args = ap.parse_args(argv)
    print(
        f"plant benchmark: python {sys.version.split()[0]}, {os.cpu_count()} CPUs, "
        f"substep 0.5 ms (2 MuJoCo steps per 1 ms cycle)"
    )
    body, goals = [], []
    for arms in args.arms:
        cpu_us, wall_us = in_process(arms, args.cycles)
        shares, cycles = as_process(arms, args.seconds)
        share = statistics.median(shares)
        if arms == 2:
            goals.append(GOAL.judge(100.0 * share).line())
        spread = f"{share:.1%} ({min(shares):.1%}-{max(shares):.1%})"
        body.append([
            arms, f"{cpu_us:.0f}", f"{wall_us:.0f}", f"{1000 / cpu_us:.1f}x",
            f"{cpu_us / 1000:.1%}", spread, f"{cycles / len(shares):.0f}",
        ])  # fmt: skip
    cols = ["arms", "cpu µs/sim ms", "wall µs/sim ms", "RT factor", "core share",
            "process median (min-max)", "cycles/s"]  # fmt: skip
    print("\n".join([table(cols, body), *goals]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
