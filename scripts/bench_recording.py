"""Benchmark: what recording a run to MCAP costs, in real time, beside cyclictest.

What is measured.  One real-time instance (the default cell unless ``--config``), both arms
swinging, for two windows of ``--seconds`` each in one invocation: without a recording, then
with ``kali.record`` on.  Per window: SIO's sensor-to-DAC latency (its read-to-write time,
the flight recorder's ``latency_ns``) p50 / p99 / max and SIO's own CPU time per tick, the
servo ticks the recording holds against those SIO served, the ticks it lost, its size per
minute and the recorder's CPU share of one core.  cyclictest runs beside both windows on
every CPU as the machine's floor (its p99 wake-up lateness).

How to read it.  ``+µs`` is the recording window's p50 less the other's: what recording adds
to SIO's tick (nothing is copied twice in SIO's cycle: the recorder drains the ring SIO
writes anyway); ``lost`` must be 0; the recorder's share is of one CPU.

    .venv/bin/python scripts/bench_recording.py --seconds 60
    .venv/bin/python scripts/bench_recording.py --cell four --seconds 600   # 4 arms, 10 min
"""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import tempfile
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
from benchlib import ct_row, parse_histfile
from harness import CELLS, DEFAULT_CONFIG, Floor, KaliRun, cell_config, table

from kali_daemons.client import Kali
from kali_daemons.client.common import MotionFailedError
from kali_daemons.core import layout
from kali_daemons.recording import recorder
from kali_daemons.runtime import flightrec


def swing(kali: Kali, stop: threading.Event) -> None:
    """Every arm back and forth until ``stop``, or a halt (``main`` reports it)."""
    arms = [kali.robot(n) for n in kali.names]
    homes = [a.read_joints() for a in arms]
    sign = 1.0
    while not stop.is_set():
        try:
            with kali.together():
                handles = [
                    a.move_joints(q + sign * 0.15, speed=0.5, wait=False)
                    for a, q in zip(arms, homes, strict=True)
                ]
            for h in handles:
                h.wait(timeout=30)
        except MotionFailedError:
            return  # halted: main reports it
        sign = -sign


@contextlib.contextmanager
def swinging(kali: Kali) -> Iterator[None]:
    """Every arm readied, then swinging (``swing``) in a thread of its own for the block, two
    seconds under way before it starts; stopped on the way out."""
    stop = threading.Event()
    kali.ready()
    mover = threading.Thread(target=swing, args=(kali, stop), daemon=True)
    mover.start()
    try:
        time.sleep(2.0)
        yield
    finally:
        stop.set()
        mover.join(timeout=60)


def window(kali: Kali, seconds: float, path: Path | None) -> dict[str, float]:
    """One window: SIO's latency and CPU per tick from the ring, and the recording's figures."""
    inst = kali.inst
    header = inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
    ring = flightrec.attach_ring(inst.arena, header)
    first = int(header["count"])
    out: dict[str, float] = {}
    t0 = time.monotonic()
    if path is None:
        time.sleep(seconds)
    else:
        with kali.record(path) as status:
            pid = recorder.running(inst)
            stat = Path(f"/proc/{pid}/stat")
            c0 = sum(int(v) for v in stat.read_text().split()[13:15])
            time.sleep(seconds)
            c1 = sum(int(v) for v in stat.read_text().split()[13:15])
        wall = time.monotonic() - t0
        out["cpu_pct"] = 100.0 * (c1 - c0) / os.sysconf("SC_CLK_TCK") / wall
        out["ticks"], out["lost"] = float(status["ticks"]), float(status["gaps"])
        out["mb_min"] = float(status["bytes"]) / 1e6 / wall * 60.0
    rows = flightrec.read_ring(header, ring)
    rows = rows[rows["tick"] >= 0][-(int(header["count"]) - first) :]
    lat = rows["latency_ns"] / 1e3
    out["served"] = float(int(header["count"]) - first)
    out["p50"], out["p99"], out["max"] = (float(np.percentile(lat, q)) for q in (50, 99, 100))
    out["ran"] = float(np.median(rows["ran_ns"])) / 1e3
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    ap.add_argument(
        "--cell", choices=sorted(CELLS), default="pumas",
        help="the arms, on the config's clock and processes (four: 2 PUMAs, a UR5, a Panda)",
    )  # fmt: skip
    ap.add_argument("--seconds", type=float, default=30.0, help="each window")
    args = ap.parse_args()
    name = f"benchrec{os.getpid()}"
    cfg = cell_config(CELLS[args.cell], name, args.config, args.cell)
    tmp = Path(tempfile.mkdtemp(prefix="bench_recording."))
    hist = tmp / "cyclictest.hist"
    with KaliRun(cfg, log_dir=tmp, lockstep=False), Floor(
        int(2 * args.seconds + 30), 1000, hist, spike_us=0, threads=os.cpu_count() or 1
    ) as ct:
        ct.start()
        with Kali(name) as kali, swinging(kali):
            plain = window(kali, args.seconds, None)
            halt = kali.inst.fault_text()
            if halt is None:
                recorded = window(kali, args.seconds, tmp / "run.mcap")
                halt = kali.inst.fault_text()
    floor = ct_row("cyclictest", parse_histfile(hist), "all", 1000)
    if halt is not None:  # no figures of a window the cell did not run to its end
        print(f"halted: {halt}; cyclictest max {floor.max_us:.0f} µs (the floor)")
        return 1
    rows = [
        ("without recording", f"{plain['p50']:.0f}", f"{plain['p99']:.0f}", f"{plain['max']:.0f}",
         f"{plain['ran']:.0f}", f"{plain['served']:.0f}", "-", "-", "-", "-"),
        ("recording", f"{recorded['p50']:.0f}", f"{recorded['p99']:.0f}",
         f"{recorded['max']:.0f}", f"{recorded['ran']:.0f}", f"{recorded['served']:.0f}",
         f"{recorded['ticks']:.0f}", f"{recorded['lost']:.0f}", f"{recorded['mb_min']:.1f}",
         f"{recorded['cpu_pct']:.1f}"),
    ]  # fmt: skip
    print(table(
        ["window", "SIO p50 µs", "p99 µs", "max µs", "SIO CPU µs", "ticks served",
         "ticks recorded", "lost", "MB/min", "recorder % core"],
        rows,
        title=f"recording to MCAP, {len(cfg.robots)} arms, {args.seconds:g} s windows, real time",
        caption=(f"+µs (SIO p50, recording - without): {recorded['p50'] - plain['p50']:+.1f}; "
                 f"cyclictest p99 {floor.p99_us:.0f} µs (the floor), SIO p99 / floor: "
                 f"{recorded['p99'] / max(floor.p99_us, 1):.2f}"),
    ))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
