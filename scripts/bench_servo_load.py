"""Benchmark: what loading a servo plugin into a running instance costs the servo tick, in
real time, beside cyclictest (issue 55 item 6, ``kali_daemons/servo/loading.py``).

What runs.  One real-time instance (the default cell), both arms swinging.  ``layout.MAX_LOADS``
plugin files (the example plugin under new names) loaded one by one through
``kali.servo.load``, each in a window of its own from the call to a second after it
returned, each after a quiet window of 1.5 s (the flight recorder's ring holds the last two
seconds of ticks).  Per window, from the flight recorder: SIO's sensor-to-DAC latency p50 /
p99 / max; from the process table, the misses of SIO and of each SV (a tick whose signal
was still unacknowledged when the next was due); per load, the call's wall time (its checks
on this process's CPU, then until every SV has taken it).  cyclictest on every CPU beside
it is the machine's floor.

How to read it.  An SV takes a file after its cycle, in the gap before the next tick (the
client refused anything whose load would not fit half of it): the load windows' figures
should be the quiet window's, with no miss cyclictest does not also see.

    .venv/bin/python scripts/bench_servo_load.py
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from bench_recording import swinging
from benchlib import ct_row, parse_histfile
from harness import DEFAULT_CONFIG, Floor, KaliRun, cell_config, table

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.examples import servo_plugin_example
from kali_daemons.runtime import flightrec

QUIET_S = 1.5  # a window without a load
AFTER_S = 1.0  # a load's window after the call returned (the SVs took it before it did)


def plugin_files(folder: Path) -> list[Path]:
    """``layout.MAX_LOADS`` copies of the example plugin, each registering a name of its own."""
    text = Path(servo_plugin_example.__file__).read_text()
    files = []
    for n in range(layout.MAX_LOADS):
        path = folder / f"loaded_pd{n}.py"
        path.write_text(text.replace('NAME = "bwpd"', f'NAME = "loaded_pd{n}"'))
        files.append(path)
    return files


def window(kali: Kali, load: Path | None) -> dict[str, float]:
    """One window of about a second (the flight recorder's ring holds two), loading ``load``
    at its start: SIO's latency from the ring over the window, the serious processes'
    misses, the load's wall time."""
    inst = kali.inst
    header = inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
    ring = flightrec.attach_ring(inst.arena, header)
    first = int(header["count"])
    procs = inst.procs
    names = [str(n, "ascii").rstrip("\0") for n in procs["name"]]
    watched = [i for i, n in enumerate(names) if n == "sio" or n.startswith("sv.")]
    misses0 = procs["misses"][watched].copy()
    out: dict[str, float] = {"load_ms": float("nan")}
    if load is not None:
        t0 = time.perf_counter()
        kali.servo.load(load)
        out["load_ms"] = (time.perf_counter() - t0) * 1e3
    time.sleep(AFTER_S if load is not None else QUIET_S)
    out["misses"] = float((procs["misses"][watched] - misses0).sum())
    rows = flightrec.read_ring(header, ring)
    n = int(header["count"]) - first
    assert n < len(rows), f"{n} ticks: more than the ring's {len(rows)}"
    rows = rows[rows["tick"] >= 0][-n:]
    lat = rows["latency_ns"] / 1e3
    out["ticks"] = float(n)
    out["p50"], out["p99"], out["max"] = (float(np.percentile(lat, q)) for q in (50, 99, 100))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--config", type=Path, default=DEFAULT_CONFIG)
    args = ap.parse_args()
    name = f"benchload{os.getpid()}"
    cfg = cell_config({}, name, args.config, "default")
    tmp = Path(tempfile.mkdtemp(prefix="bench_servo_load."))
    hist = tmp / "cyclictest.hist"
    results: list[tuple[str, dict[str, float]]] = []
    duration = int(2 * layout.MAX_LOADS * (QUIET_S + 1.0) + 30)
    with KaliRun(cfg, log_dir=tmp, lockstep=False), Floor(
        duration, 1000, hist, spike_us=0, threads=os.cpu_count() or 1
    ) as ct:
        ct.start()
        with Kali(name) as kali, swinging(kali):
            for path in plugin_files(tmp):
                results.append(("quiet", window(kali, None)))
                results.append((f"load {path.name}", window(kali, path)))
            halt = kali.inst.fault_text()
    floor = ct_row("cyclictest", parse_histfile(hist), "all", 1000)
    if halt is not None:
        print(f"halted: {halt}; cyclictest max {floor.max_us:.0f} µs (the floor)")
        return 1
    rows = [
        (what, f"{r['ticks']:.0f}", f"{r['p50']:.0f}", f"{r['p99']:.0f}", f"{r['max']:.0f}",
         f"{r['misses']:.0f}",
         "-" if r["load_ms"] != r["load_ms"] else f"{r['load_ms']:.0f}")
        for what, r in results
    ]  # fmt: skip
    print(table(
        ["window", "ticks", "SIO s2DAC p50 µs", "p99 µs", "max µs", "misses (sio, svs)",
         "load ms"],
        rows,
        title="servo plugins loaded while running, real time, each window after a quiet one",
        caption=f"cyclictest p99 {floor.p99_us:.0f} µs, max {floor.max_us:.0f} µs (the floor)",
    ))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
