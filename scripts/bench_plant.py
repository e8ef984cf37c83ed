"""Benchmark: what the plant costs per simulated millisecond for 1, 2 and 4 arms.

Two measurements per arm count:

1. **In-process cost**: ``PlantSim.cycle`` (one 1 ms plant period: board logic, motor model,
   MuJoCo substeps, encoders, truth records) timed with the thread's CPU time, amplifiers on
   and every DAC driving, after a warm-up; the best of five runs of ``--cycles``/5 cycles.
   From it the real-time factor the plant could sustain on one core (1 ms / cost) and the
   share of one core it needs at real time.
2. **As a process at real time**: the plant daemon of a real instance (``kalictl start``,
   real-time mode), CPU time read from ``/proc/<pid>/stat`` over ``--seconds``: everything the
   process really costs, including its own clock and the Python loop around ``cycle``.

Goal (the issue): two arms in under 15 % of one core at real time.

    .venv/bin/python scripts/bench_plant.py
"""

from __future__ import annotations

import argparse
import math
import os
import re
import sys
import time
from pathlib import Path

from kali_daemons import launcher, layout
from kali_daemons.arena import Arena
from kali_daemons.config import KaliConfig, parse_config
from kali_daemons.instance import Instance
from kali_daemons.layout import CSR_ENABLE, CSR_NO_DISABLE
from kali_daemons.plant.sim import PlantSim

REPO = Path(__file__).resolve().parent.parent
GOAL_SHARE = 0.15
REPEATS = 5
PLACEMENTS = [  # base x, y, yaw: facing the centre of the cell
    (-0.6, 0.0, 0.0),
    (0.6, 0.0, 180.0),
    (0.0, -0.6, 90.0),
    (0.0, 0.6, -90.0),
]


def config_for(arms: int, instance: str) -> KaliConfig:
    """The default config with ``arms`` robots."""
    text = (REPO / "config" / "default.yaml").read_text()
    text = re.sub(r"(?m)^instance: .*$", f"instance: {instance}", text)
    robots = "\n".join(
        f"  - {{name: arm{k}, model: puma560, base_xyz: [{x}, {y}, 0.0], base_yaw_deg: {yaw}}}"
        for k, (x, y, yaw) in enumerate(PLACEMENTS[:arms])
    )
    text = re.sub(r"(?ms)^robots:\n(  - .*?\n)+", f"robots:\n{robots}\n", text)
    return parse_config(text, f"<bench {arms} arms>")


def power_up(sim: PlantSim) -> None:
    """Enable every arm and drive every joint with a small DAC signal."""
    for board in sim.boards:
        board.regs["csr"] = CSR_NO_DISABLE | CSR_ENABLE
    for _ in range(70):
        sim.cycle()
    for k, board in enumerate(sim.boards):
        board.regs["csr"] = CSR_NO_DISABLE
        sim.dac[k]["code"][:6] = layout.DAC_ZERO + 100


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


def _cpu_ticks(pid: int) -> int:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return int(fields[11]) + int(fields[12])  # utime + stime


def as_process(arms: int, seconds: float) -> tuple[float, int]:
    """(share of one core, plant cycles) of the plant daemon of a real-time instance."""
    name = f"benchplant{os.getpid()}p"
    cfg = config_for(arms, name)
    launcher.start(cfg, lockstep=False, instance=name)
    try:
        with Instance.attach(name) as inst:
            pid = int(inst.procs[inst.slot_of("plant")]["pid"])
            truth = inst.arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
            time.sleep(1.0)
            t0, n0, w0 = _cpu_ticks(pid), int(truth["ticks"]), time.monotonic()
            time.sleep(seconds)
            t1, n1, w1 = _cpu_ticks(pid), int(truth["ticks"]), time.monotonic()
            del truth
    finally:
        launcher.stop(name)
    hz = os.sysconf("SC_CLK_TCK")
    return (t1 - t0) / hz / (w1 - w0), n1 - n0


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
    head = (
        f"{'arms':>4} {'cpu µs/sim ms':>14} {'wall µs/sim ms':>15} {'RT factor':>10} "
        f"{'core share':>11} {'process share':>14} {'cycles/s':>9}  goal"
    )
    print(head)
    print("-" * len(head))
    for arms in args.arms:
        cpu_us, wall_us = in_process(arms, args.cycles)
        share, cycles = as_process(arms, args.seconds)
        goal = ""
        if arms == 2:
            goal = "PASS" if share < GOAL_SHARE else "FAIL"
            goal += f" (< {GOAL_SHARE:.0%} of a core)"
        print(
            f"{arms:>4} {cpu_us:>14.0f} {wall_us:>15.0f} {1000 / cpu_us:>9.1f}x "
            f"{cpu_us / 1000:>10.1%} {share:>13.1%} {cycles / args.seconds:>9.0f}  {goal}"
        )
    return 0


if __name__ == "__main__":
    sys.exit(main())
