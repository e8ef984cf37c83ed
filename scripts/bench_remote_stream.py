"""Benchmark: a remote pose stream's latency through the bridge, in real time, beside
cyclictest (issue 55's goal: p99 <= 5 ms on loopback).

What runs.  One real-time instance, the default cell with its bridge on a free loopback TCP
port.  A remote program in a process of its own (``Kali.connect``, as on another machine)
readies the left arm, opens ``left.stream()`` and sends ``--sends`` poses at ``--hz``, each
1 µm higher than the last (the arm barely moves), stamping each send's start and return
(CLOCK_MONOTONIC, which every process here shares).  This process watches the stream's shared
transform in the arena (the record the TG reads every tick) and stamps each write as it
appears; it also knows when the TG's next tick started after it (the clock's ticks).

What is measured, per send: ``call``, the remote's send round trip (the call through Zenoh
to the program's session on the controller and back); ``to TG input``, the send's start to
the shared transform written (what the TG reads at its next tick); ``to TG tick``, to the
start of that next TG tick (adds up to one TG period by design: the TG samples its inputs
once a tick).  cyclictest's p99 beside it is the machine's floor.

    .venv/bin/python scripts/bench_remote_stream.py --sends 2000 --hz 200
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np
import yaml
from benchlib import ct_row, cyclictest_command, parse_histfile, stop_cyclictest
from harness import DEFAULT_CONFIG, KaliRun, cell_config, table

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.runtime import flightrec

POLL_S = 100e-6  # how often this process looks for the stream's writes
SENDER = textwrap.dedent(
    """
    import json, sys, time
    import numpy as np
    from kali_daemons.client import Kali

    endpoint, name, sends, hz = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4])
    with Kali.connect(endpoint, name) as kali:
        kali.ready(["left"])
        left = kali.robot("left")
        with left.stream(lifetime=0.5) as s:
            pose = left.read_pose()
            print(json.dumps({"frame": s.frame.index}), flush=True)
            sys.stdin.readline()  # the watcher is ready
            starts, ends = [], []
            period = 1.0 / hz
            due = time.monotonic()
            for i in range(sends):
                pose[2, 3] += 1e-6
                starts.append(time.monotonic_ns())
                s.send(pose)
                ends.append(time.monotonic_ns())
                due += period
                time.sleep(max(0.0, due - time.monotonic()))
        print(json.dumps({"starts": starts, "ends": ends}), flush=True)
    """
)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def pct(values: np.ndarray) -> tuple[str, str, str]:
    """p50, p99 and max of ``values`` (ns) in ms."""
    p50, p99, top = (float(np.percentile(values, q)) / 1e6 for q in (50, 99, 100))
    return f"{p50:.2f}", f"{p99:.2f}", f"{top:.2f}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sends", type=int, default=2000)
    ap.add_argument("--hz", type=float, default=200.0, help="the remote's send rate")
    ap.add_argument(
        "--set", nargs=2, action="append", metavar=("PATH", "YAML"),
        help="a config override, e.g. --set bridge.cpu 0",
    )  # fmt: skip
    args = ap.parse_args()
    name = f"benchstream{os.getpid()}"
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    overrides: dict[str, object] = {"bridge.enabled": True, "bridge.listen": [endpoint]}
    overrides.update((path, yaml.safe_load(value)) for path, value in args.set or [])
    cfg = cell_config(overrides, name, DEFAULT_CONFIG)
    tmp = Path(tempfile.mkdtemp(prefix="bench_remote_stream."))
    hist = tmp / "cyclictest.hist"
    seconds = int(args.sends / args.hz + 60)
    with KaliRun(cfg, log_dir=tmp, lockstep=False), Kali(name) as kali:
        ct = subprocess.Popen(
            cyclictest_command(seconds, os.cpu_count() or 1, hist, 1000, spike_us=0),
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, text=True,
        )  # fmt: skip
        sender = subprocess.Popen(
            [sys.executable, "-c", SENDER, endpoint, name, str(args.sends), str(args.hz)],
            stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert sender.stdin is not None and sender.stdout is not None
            frame = kali.frames[json.loads(sender.stdout.readline())["frame"]]
            clock = kali.inst.clock
            tg_ticks = round(cfg.clock.tg_period_ms / cfg.clock.base_tick_ms)
            seen_ns, seen_tick = [], []
            writes = int(frame["writes"])
            sender.stdin.write("go\n")
            sender.stdin.flush()
            deadline = time.monotonic() + args.sends / args.hz + 30
            while len(seen_ns) < args.sends and time.monotonic() < deadline:
                time.sleep(POLL_S)  # not a spin: a core spun here is one the bridge lacks
                w = int(frame["writes"])
                if w != writes:  # one or more writes since the last look
                    now = time.monotonic_ns()
                    tick = int(clock["tick"])
                    for _ in range(w - writes):
                        seen_ns.append(now)
                        seen_tick.append(tick)
                    writes = w
            result = json.loads(sender.stdout.readline())
            sender.wait(timeout=60)
            header = kali.inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
            rows = flightrec.read_ring(header, flightrec.attach_ring(kali.inst.arena, header))
            sio_us = rows[rows["tick"] >= 0]["latency_ns"] / 1e3  # the last ticks, streaming
            start_ns = int(clock["t0_ns"])
            base_ns = int(clock["base_tick_ns"])
        finally:
            if sender.poll() is None:
                sender.kill()
            stop_cyclictest(ct)
    n = min(len(seen_ns), len(result["starts"]))
    starts = np.array(result["starts"][:n])
    call = np.array(result["ends"][:n]) - starts
    to_input = np.array(seen_ns[:n]) - starts
    next_tg = (np.array(seen_tick[:n]) // tg_ticks + 1) * tg_ticks  # the TG tick that reads it
    to_tick = start_ns + next_tg * base_ns - starts
    floor = ct_row("cyclictest", parse_histfile(hist), "all", 1000)
    rows = [
        ("call (round trip)", *pct(call)),
        ("send -> TG input", *pct(to_input)),
        ("send -> TG tick", *pct(to_tick)),
    ]
    print(table(
        ["latency", "p50 ms", "p99 ms", "max ms"],
        rows,
        title=f"remote pose stream through the bridge, {n} sends at {args.hz:g} Hz, loopback",
        caption=(f"goal: send -> TG input p99 <= 5 ms; the TG ticks every "
                 f"{cfg.clock.tg_period_ms:g} ms; the bridge on CPU {cfg.bridge.cpu}; SIO's "
                 f"sensor-to-DAC p50/p99/max meanwhile {np.percentile(sio_us, 50):.0f}/"
                 f"{np.percentile(sio_us, 99):.0f}/{sio_us.max():.0f} µs; cyclictest p99 "
                 f"{floor.p99_us:.0f} µs, max {floor.max_us:.0f} µs (the floor)"),
    ))  # fmt: skip


if __name__ == "__main__":
    sys.exit(main())
