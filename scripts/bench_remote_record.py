"""Benchmark: a remote program's recording, made on the controller's machine and fetched
through the bridge when its ``with kali.record(path):`` block ends (issue 55 item 5: fetched,
not streamed; this measures what that choice costs), in real time, beside cyclictest.

What runs.  One real-time instance, the default cell (two arms) with its bridge on a free
loopback TCP port.  A remote program in a process of its own (``Kali.connect``, as on
another machine) readies both arms and records ``--seconds`` of them swinging back and
forth, every servo tick.  Measured: the file's size, its ticks and gaps, the time from the
block's end to the file whole on the remote side (the fetch, ``RECORDED_CHUNK`` bytes a
call), the fetch rate, and how long a recording of a minute would take to fetch at that
rate; SIO's sensor-to-DAC latency while it fetches, against cyclictest's floor.

    .venv/bin/python scripts/bench_remote_record.py --seconds 20
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import numpy as np
from bench_remote_stream import free_port
from benchlib import ct_row, parse_histfile
from harness import DEFAULT_CONFIG, Floor, KaliRun, cell_config, table

from kali_daemons.core import layout
from kali_daemons.runtime import flightrec
from kali_daemons.runtime.instance import Instance

REMOTE = textwrap.dedent(
    """
    import json, sys, time
    from kali_daemons.client import Kali
    endpoint, name, seconds, path = sys.argv[1], sys.argv[2], float(sys.argv[3]), sys.argv[4]
    with Kali.connect(endpoint, name) as kali:
        kali.ready()
        arms = [kali.robot(n) for n in kali.names]
        homes = [a.read_joints() for a in arms]
        with kali.record(path) as status:
            end, sign = time.monotonic() + seconds, 1.0
            while time.monotonic() < end:  # every arm back and forth, as bench_recording's
                with kali.together():
                    moves = [a.move_joints(q + sign * 0.15, speed=0.5, wait=False)
                             for a, q in zip(arms, homes)]
                for m in moves:
                    m.wait(timeout=30)
                sign = -sign
            ended = time.monotonic()
        fetched = time.monotonic()
        print(json.dumps({"ended": ended, "fetched": fetched, "status": status}), flush=True)
    """
)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--seconds", type=float, default=20.0, help="the recording's length")
    args = ap.parse_args()
    name = f"benchrrec{os.getpid()}"
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = cell_config({"bridge.enabled": True, "bridge.listen": [endpoint]}, name, DEFAULT_CONFIG)
    tmp = Path(tempfile.mkdtemp(prefix="bench_remote_record."))
    hist, target = tmp / "cyclictest.hist", tmp / "remote.mcap"
    with KaliRun(cfg, log_dir=tmp, lockstep=False), Floor(
        int(args.seconds + 120), 1000, hist, spike_us=0, threads=os.cpu_count() or 1
    ) as ct:
        ct.start()
        remote = subprocess.run(
            [sys.executable, "-c", REMOTE, endpoint, name, str(args.seconds), str(target)],
            capture_output=True, text=True, timeout=args.seconds + 300,
        )  # fmt: skip
        if remote.returncode != 0:
            print(remote.stderr[-2000:])
            return 1
        result = json.loads(remote.stdout.splitlines()[-1])
        with Instance.attach(name) as inst:
            header = inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
            rows = flightrec.read_ring(header, flightrec.attach_ring(inst.arena, header))
            sio_us = rows[rows["tick"] >= 0]["latency_ns"] / 1e3  # the last 2 s: the fetch
            halt = inst.fault_text()
    floor = ct_row("cyclictest", parse_histfile(hist), "all", 1000)
    if halt is not None:
        print(f"halted: {halt}; cyclictest max {floor.max_us:.0f} µs (the floor)")
        return 1
    status = result["status"]
    size_mb = target.stat().st_size / 1e6
    fetch_s = result["fetched"] - result["ended"]
    rate = size_mb / fetch_s
    minute_mb = size_mb / args.seconds * 60.0
    rows_out = [
        (f"{args.seconds:g} s, 2 arms", f"{status['ticks']}", f"{status['gaps']}",
         f"{size_mb:.1f}", f"{fetch_s:.2f}", f"{rate:.1f}", f"{minute_mb / rate:.1f}"),
    ]  # fmt: skip
    print(table(
        ["recording", "ticks", "gaps", "MB", "fetch s", "MB/s", "a minute's fetch s"],
        rows_out,
        title="a remote program's recording, made on the controller and fetched, loopback",
        caption=(f"SIO's sensor-to-DAC p50/p99/max over the last 2 s (the fetch): "
                 f"{np.percentile(sio_us, 50):.0f}/{np.percentile(sio_us, 99):.0f}/"
                 f"{sio_us.max():.0f} µs; cyclictest p99 {floor.p99_us:.0f} µs, max "
                 f"{floor.max_us:.0f} µs (the floor)"),
    ))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(main())
