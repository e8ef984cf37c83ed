"""Benchmark: the Zenoh bridge (issue 29) in real time: telemetry latency and rate, request
round trips through ``Kali.connect``, the bridge's CPU share, and what it costs the servos.

What runs.  Four runs by default (``--runs``), each its own real-time instance with a
``--seconds`` window (20) beside ``cyclictest --laptop`` (the floor, harness ``Floor``), all
on bench_servo's ``1ms-2sv`` configuration (``bench_servo.config_for``'s overrides: 1 ms
servo period, two SVs, full feed-forward on every arm, the viewer serving and recording the
dashboard) with the ``bridge`` section on or off, listening on a free loopback TCP port
chosen at start:

- ``no-bridge``: default.yaml's two PUMAs, ``bridge.enabled: false``, the arms powered and
  kept moving by this script as bench_servo does (``bench_servo.warm_up`` / ``Motion``: a
  ±0.05 rad sinusoid on every joint pushed into the TG → SIO FIFOs);
- ``bridge``: the same with the bridge on (``bridge.telemetry_hz`` 100) and a telemetry
  subscriber in this process attached (a plain client session, ``access.client_config``);
- ``requests``: the two PUMAs, bridge on, subscriber attached, the arms powered and held (no
  FIFO motion: the TG moves them on request); a remote program (``Kali.connect``, opened and
  readied before the window) makes its requests inside the window;
- ``four``: bench_servo's ``four`` cell (two PUMAs, a UR5, a Panda: 25 joints) as ``bridge``,
  with ``arena_kib`` 6144 (as default.yaml's).

What is measured.

- Telemetry: the subscriber stamps each state sample on receipt (``time.monotonic_ns()``,
  CLOCK_MONOTONIC as the arena's) and subtracts the sample's ``due_ns`` (when SIO's tick of
  that sample was due): a sample's age.  The bridge samples on its own 10 ms timer, so up to
  one servo period of staleness is part of it, then its JSON and Zenoh's loopback TCP.  Per
  robot: p50 / p99 / max, the rate received over the window (expect ``telemetry_hz``), bridge
  cycles skipped (a tick step of k >= 2 bridge periods skips k - 1; a late cycle alone is a
  long step then a short one) and the longest step.  In the ``requests`` run this process
  also runs the floor's verbs (CPU-bound Python holding the GIL), which can delay the
  subscriber's receipt stamps by up to the 5 ms switch interval.
- Requests (``requests`` run), the wall time of each call in this process: ``read_joints``
  (200); kalictl verbs ``disable`` / ``enable`` of ``left`` alternating (20, each 0.1 s after
  the last so every one starts settled; kalictl's own commands wait until SIO reports the
  power state: ~25 ms off, ~90 ms on); ``status --json`` (10; a verb that waits for nothing:
  the bridge's own share); each verb also run locally in this process (``sessions.run_verb``,
  what the bridge itself runs: the floor of a verb); ``move_joints(..., wait=False)`` → its
  handle (20 small moves of ``left``, out and back, each waited for; the time to arrival is
  shown too).
- CPU: the scheduler's run time of the bridge process over the window (harness
  ``Window.cpu_pct``), % of one CPU; the remote program's session worker (``python -m
  kali_daemons.bridge.session``, a process of its own) and this script beside it; the
  bridge's wake-up lateness (its own timer, SCHED_OTHER on CPU 1 under the real-time
  processes there).
- Servo level: SIO's sensor-to-DAC histogram, the SVs' execution histograms and the clock's
  miss log over the window (``bench_servo.analyse``); SIO's cycle time has no histogram in the
  arena, so its median / p99 / max are of the last-cycle value sampled every 50 ms (~400
  samples, as bench_servo's).  Misses "cyclictest did not also see" as bench_servo judges them.

Goals (``harness.Goal``, judged on the ``bridge``, ``requests`` and ``four`` runs): telemetry
p99 <= 5 ms and the rate within 5 % of ``telemetry_hz`` (2 arms, worst robot); a verb's round
trip p50 <= 50 ms, judged per verb (``disable``, ``enable``, ``status --json``) beside the
same verb run locally (``enable``'s includes kalictl's wait for SIO's power-up, which the
local floor waits as long); ``read_joints`` p50 <= 5 ms; the bridge <= 15 % of a CPU with 2
arms, <= 25 % with 4; and the servos unaffected: sensor-to-DAC p99 with the bridge <= p99
without x 1.15 + 20 µs, and no miss cyclictest did not also see in the ``bridge`` run.  Exit
status 0 whatever the verdicts, 1 on errors, 2 if cyclictest is missing.

    cd /work/main && PYTHONPATH=$PWD .venv/bin/python scripts/bench_bridge.py     # ~2 min
    PYTHONPATH=$PWD .venv/bin/python scripts/bench_bridge.py --seconds 10 --runs bridge,requests
    PYTHONPATH=$PWD .venv/bin/python scripts/bench_bridge.py --wait-quiet 300 --json /tmp/bb.json

Run it alone (bench_servo's rule: other Kali instances or real-time work make the numbers
meaningless; the notes say so, and ``--wait-quiet S`` waits up to S seconds before each run for
other instances to stop).  Everything it starts is stopped on the way out, whatever
happened (harness ``KaliRun``, ``Floor``).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import shlex
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from bench_servo import (
    FEED_S,
    FIFO_HIGH,
    MISS_KINDS,
    RunResult,
    analyse,
    power_on,
    warm_up,
)
from benchlib import (
    CT_PRIORITY,
    CYCLICTEST_MISSING,
    SPIKE_FRACTION,
    BenchError,
    ForeignWatch,
    MissTail,
    Row,
    machine_facts,
    machine_line,
    parse_spikes,
    spikes_unlogged,
    to_json,
    unwind_on_sigterm,
    us,
    wait_quiet,
    window_row,
)
from harness import (
    CELLS,
    DEFAULT_CONFIG,
    Floor,
    Goal,
    KaliRun,
    Verdict,
    Window,
    add_run_options,
    cell_config,
    extras_overrides,
    interrupts,
    kept_logs,
    period_overrides,
    pick,
    say,
    sv_overrides,
    table,
)

from kali_daemons.bridge.sessions import run_verb
from kali_daemons.client import Kali
from kali_daemons.client.protocol import Keys
from kali_daemons.client.zenohconfig import client_config
from kali_daemons.core.errors import KaliError
from kali_daemons.core.layout import PowerState
from kali_daemons.runtime.config import KaliConfig
from kali_daemons.servo.client import ServoClient

PERIOD_US = 1000  # bench_servo's 1ms-2sv
N_SV = 2
TELEMETRY_HZ = 100.0  # bridge.telemetry_hz (the default)
SETTLE_S = 2.0  # after power-on, before the window (bench_servo's)
LEAD_IN_S = 1.0  # the subscriber receiving before the window opens
READS = 200  # read_joints round trips
VERBS = 20  # remote disable / enable of one arm, alternating
LOCAL_VERBS = 10  # the same run locally (run_verb): the floor
# after each power verb: the brakes engage plant.brake_delay_ms (50) after the amplifiers go
# off, and an enable within that delay powers up in ~40 ms instead of ~90-100 ms; settled,
# every enable (and disable) starts from the same state
VERB_SETTLE_S = 0.1
PLAIN_VERB = ("status", "--json")  # a verb that waits for nothing: the bridge's own share
PLAIN_VERBS = 10
MOVES = 20  # small joint moves, out and back
MOVE_RAD = 0.05  # each joint's excursion in a move
MOVE_SPEED = 0.5
MOVE_TIMEOUT_S = 10.0
MARGIN_S = 1.0  # a request phase stops this long before the window's end
ARM = "left"  # the arm the remote program works


@dataclass(frozen=True)
class Spec:
    """One run: a cell, the bridge on or off, and what happens in the window."""

    name: str
    cell: str = "pumas"  # harness CELLS
    bridge: bool = True
    work: str = "motion"  # "motion": bench_servo's FIFO sinusoid; "requests": a remote program


RUNS = {
    s.name: s
    for s in (
        Spec("no-bridge", bridge=False),
        Spec("bridge"),
        Spec("requests", work="requests"),
        Spec("four", cell="four"),
    )
}

GOAL_LATENCY = Goal("telemetry latency, 2 arms", "p99", "<=", 5000, "µs", source="issue 29")
GOAL_RATE = Goal("telemetry rate, 2 arms", "|rate - telemetry_hz|", "<=", 5, "%", source="issue 29")
# the bridge's own share of a verb: kalictl's own work (waiting for power, attaching) is the
# same wherever it runs, so the goal is on what the network, the bridge and its helper add
GOAL_VERB = Goal(
    "verb round trip through the bridge", "p50 - local p50", "<=", 50, "ms",
    source="issue 29",
)  # fmt: skip
VERB_WHY = {
    "disable": f"kalictl's wait for power OFF included; {ARM}, settled",
    "enable": f"kalictl's wait for SIO's power ON included (the floor waits as long); {ARM}, "
    "settled",
    " ".join(PLAIN_VERB): "no power wait: the bridge's own share beside the floor",
}
GOAL_READ = Goal("read_joints round trip", "p50", "<=", 5, "ms", source="issue 29")
GOAL_CPU = {
    "pumas": Goal("bridge CPU, 2 arms", "CPU", "<=", 15, "% of a CPU", source="issue 29"),
    "four": Goal("bridge CPU, 4 arms", "CPU", "<=", 25, "% of a CPU", source="issue 29"),
}
SERVO_FACTOR, SERVO_SLACK_US = 1.15, 20.0  # s2DAC p99 with <= without x 1.15 + 20 µs
GOAL_OWN_MISSES = Goal(
    "servo misses with the bridge", "misses not seen by cyclictest", "==", 0,
    source="issue 29 (bench_servo's rule)",
)  # fmt: skip


# --------------------------------------------------------------------------------------------
# Configuration


def free_port() -> int:
    """A TCP port nobody listens on at 127.0.0.1 now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def port_free(port: int) -> bool:
    """Whether ``port`` can be bound at 127.0.0.1 now (a run's bridge listens there)."""
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


def config_for(spec: Spec, instance: str, endpoint: str, tmp: Path) -> KaliConfig:
    """bench_servo's ``1ms-2sv`` on ``spec``'s cell (``bench_servo.config_for``'s overrides:
    1 ms period, two SVs, full feed-forward, the dashboard served and recorded) with the
    ``bridge`` section on, listening on ``endpoint``, or off."""
    overrides = {
        **period_overrides(PERIOD_US),
        **sv_overrides(DEFAULT_CONFIG, N_SV),
        **CELLS[spec.cell],
        **extras_overrides(True, tmp / f"{instance}.rrd"),
        "bridge.enabled": spec.bridge,
    }
    if spec.bridge:
        overrides |= {"bridge.listen": [endpoint], "bridge.telemetry_hz": TELEMETRY_HZ}
    return cell_config(overrides, instance, DEFAULT_CONFIG, spec.name)


# --------------------------------------------------------------------------------------------
# Telemetry: a subscriber in this process


class Subscriber:
    """A plain Zenoh client session subscribed to every robot's state: each sample stamped on
    receipt (before anything else is done with it) with its ``due_ns`` and tick."""

    def __init__(self, endpoint: str, instance: str) -> None:
        import zenoh

        self.samples: dict[str, list[tuple[int, int, int]]] = {}  # robot: (recv, due, tick)
        self.bad = 0
        self.lock = threading.Lock()
        self.session = zenoh.open(client_config(endpoint))
        try:
            self.sub = self.session.declare_subscriber(Keys(instance).robots, self._on_sample)
        except BaseException:
            self.session.close()
            raise

    def _on_sample(self, sample: Any) -> None:
        t = time.monotonic_ns()
        try:
            doc = json.loads(sample.payload.to_bytes())
            entry = (t, int(doc["due_ns"]), int(doc["tick"]))
            robot = str(doc["robot"])
        except (ValueError, KeyError, TypeError):
            self.bad += 1
            return
        with self.lock:
            self.samples.setdefault(robot, []).append(entry)

    def between(self, t0: int, t1: int) -> dict[str, np.ndarray]:
        """Per robot, the samples received in [t0, t1): an (n, 3) array of receipt, due, tick."""
        with self.lock:
            out = {}
            for robot, entries in self.samples.items():
                a = np.array(entries, dtype=np.int64).reshape(-1, 3)
                out[robot] = a[(a[:, 0] >= t0) & (a[:, 0] < t1)]
            return out

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.sub.undeclare()
        with contextlib.suppress(Exception):
            self.session.close()


@dataclass
class Telemetry:
    """One robot's telemetry over a window, as received."""

    robot: str
    samples: int
    rate_hz: float
    p50_us: float
    p99_us: float
    max_us: float
    min_us: float
    skipped: int  # bridge cycles skipped by the ticks: a step of k >= 2 periods skips k - 1
    longest_ms: float  # the longest step between two samples' SIO ticks
    repeats: int  # samples with the tick of the one before (SIO had not ticked)


def telemetry_stats(
    robot: str, a: np.ndarray, seconds: float, period_ticks: int, tick_ms: float
) -> Telemetry:
    """``a``'s latencies (receipt - due) and rate; skipped cycles counted from the ticks (a
    late cycle is a long step followed by a short one: nothing lost)."""
    if len(a) == 0:
        nan = math.nan
        return Telemetry(robot, 0, 0.0, nan, nan, nan, nan, 0, nan, 0)
    lat_us = (a[:, 0] - a[:, 1]) / 1e3
    steps = np.diff(a[:, 2])
    big = steps[steps >= 2 * period_ticks]
    skipped = int(np.sum(big // period_ticks - 1))
    return Telemetry(
        robot=robot,
        samples=len(a),
        rate_hz=len(a) / seconds,
        p50_us=float(np.percentile(lat_us, 50)),
        p99_us=float(np.percentile(lat_us, 99)),
        max_us=float(lat_us.max()),
        min_us=float(lat_us.min()),
        skipped=skipped,
        longest_ms=float(steps.max()) * tick_ms if len(steps) else math.nan,
        repeats=int(np.sum(steps == 0)),
    )


# --------------------------------------------------------------------------------------------
# Requests: a remote program


@dataclass
class Timings:
    """Wall times of one kind of call, ms."""

    name: str
    ms: list[float] = field(default_factory=list)
    planned: int = 0
    note: str = ""
    group: str = ""  # a verb's: "enable", ... (the goal's), "enable local" (its floor)

    def q(self, p: float) -> float:
        return float(np.percentile(self.ms, p)) if self.ms else math.nan


def timed(f: Any, *args: Any, **kwargs: Any) -> tuple[float, Any]:
    """``f(*args, **kwargs)``'s wall time in ms, and its value."""
    t = time.perf_counter_ns()
    value = f(*args, **kwargs)
    return (time.perf_counter_ns() - t) / 1e6, value


def requests(
    remote: Any, instance: str, client: ServoClient, end_ns: int, poll: Any
) -> list[Timings]:
    """The remote program's requests inside the window, each phase cut short (and said so)
    when the window's end is less than MARGIN_S away; ``poll()`` between calls."""
    arm = remote.robot(ARM)
    reads = Timings("read_joints", planned=READS)
    remote_verbs = {
        v: Timings(f"verb {v} {ARM}", planned=VERBS // 2, group=v) for v in ("disable", "enable")
    }
    local_verbs = {
        v: Timings(f"verb {v} {ARM}, local (floor)", planned=LOCAL_VERBS // 2, group=f"{v} local")
        for v in ("disable", "enable")
    }
    words = " ".join(PLAIN_VERB)
    remote_plain = Timings(f"verb {words} (no power wait)", planned=PLAIN_VERBS, group=words)
    local_plain = Timings(
        f"verb {words}, local (floor)", planned=LOCAL_VERBS // 2, group=f"{words} local"
    )
    accept = Timings("move_joints(wait=False) -> handle", planned=MOVES)
    arrive = Timings("move_joints -> arrived (handle.wait)", planned=MOVES)
    ready = Timings(f"ready([{ARM!r}]) after the verbs", planned=1)

    def time_left() -> bool:
        poll()
        return time.monotonic_ns() < end_ns - MARGIN_S * 1e9

    for _ in range(READS):
        if not time_left():
            break
        reads.ms.append(timed(arm.read_joints)[0])
    for i in range(VERBS):  # the arm is on: disable first, end enabled
        verb = ("disable", "enable")[i % 2]
        if not time_left():
            break
        remote_verbs[verb].ms.append(timed(remote.verb, verb, ARM)[0])
        want = PowerState.ON if verb == "enable" else PowerState.OFF
        if client.power_state(ARM) != want:
            raise BenchError(f"after a remote {verb}: {ARM} is {client.power_state(ARM).name}")
        time.sleep(VERB_SETTLE_S)
    for _ in range(PLAIN_VERBS):
        if not time_left():
            break
        remote_plain.ms.append(timed(remote.verb, *PLAIN_VERB)[0])
    for _ in range(LOCAL_VERBS // 2):
        if not time_left():
            break
        local_plain.ms.append(timed(run_verb, instance, PLAIN_VERB[0], list(PLAIN_VERB[1:]))[0])
    for i in range(LOCAL_VERBS):
        verb = ("disable", "enable")[i % 2]
        if not time_left():
            break
        took, answer = timed(run_verb, instance, verb, [ARM])
        if not answer["ok"]:
            raise BenchError(f"local kalictl {verb} {ARM}: {answer['error'].strip()}")
        local_verbs[verb].ms.append(took)
        time.sleep(VERB_SETTLE_S)
    if client.power_state(ARM) != PowerState.ON:  # a phase cut short after a disable
        power_on_one(client)
    ready.ms.append(timed(remote.ready, [ARM])[0])
    centre = arm.read_joints()
    signs = np.where(np.arange(len(centre)) % 2 == 0, 1.0, -1.0)
    for i in range(MOVES):
        if not time_left():
            break
        target = centre + (MOVE_RAD * signs if i % 2 == 0 else 0.0)
        t = time.perf_counter_ns()
        handle = arm.move_joints(target, speed=MOVE_SPEED, wait=False)
        accept.ms.append((time.perf_counter_ns() - t) / 1e6)
        handle.wait(timeout=MOVE_TIMEOUT_S)
        arrive.ms.append((time.perf_counter_ns() - t) / 1e6)
    out = [reads, *remote_verbs.values(), *local_verbs.values(), remote_plain, local_plain]
    out += [ready, accept, arrive]
    for t in out:
        if len(t.ms) < t.planned:
            t.note = f"{len(t.ms)} of {t.planned}: the window ended"
    return out


def power_on_one(client: ServoClient) -> None:
    """Power ARM again and wait for it (a phase cut short left it off)."""
    client.power(ARM, True)
    deadline = time.monotonic() + 5.0
    while client.power_state(ARM) != PowerState.ON and time.monotonic() < deadline:
        time.sleep(0.01)


# --------------------------------------------------------------------------------------------
# One run


@dataclass
class Result:
    """One run's figures (``--json`` writes them)."""

    run: str
    cell: str
    bridge: bool
    work: str
    instance: str = ""
    arms: str = ""
    seconds: float = math.nan
    servo: RunResult | None = None
    telemetry: list[Telemetry] = field(default_factory=list)
    malformed_samples: int = 0
    bridge_cpu_pct: float = math.nan
    worker_cpu_pct: float = math.nan  # the remote program's session worker
    own_cpu_pct: float = math.nan  # this script: the subscriber (and the remote program)
    kali_cpu_pct: float = math.nan  # every Kali process, summed
    bridge_wakeup: Row | None = None
    sio_cycle_us: list[float] = field(default_factory=list)  # sampled: median, p99, max
    connect_ms: float = math.nan
    ready_ms: float = math.nan
    timings: list[Timings] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    error: str | None = None


def measure(spec: Spec, seconds: int, tmp: Path, port: int) -> Result:
    """Start ``spec``'s instance, warm it up, measure one window beside cyclictest."""
    instance = f"bbr{os.getpid()}-{spec.name}"
    endpoint = f"tcp/127.0.0.1:{port}"
    res = Result(spec.name, spec.cell, spec.bridge, spec.work, instance)
    cfg = config_for(spec, instance, endpoint, tmp)
    models = ", ".join(r.model for r in cfg.robots)
    res.arms = f"{len(cfg.robots)} arms ({models}: {cfg.joints.total} joints)"
    servo = RunResult(spec.name, PERIOD_US, N_SV, instance, cfg.source, seconds, 0.0)
    servo.arms, servo.machine = res.arms, machine_facts()
    servo.spike_us = round(SPIKE_FRACTION * PERIOD_US)
    res.servo = servo
    names = [p.name for p in cfg.processes]
    sv_names = [p.name for p in cfg.processes if p.kind == "sv"]
    miss_names = [p.name for p in cfg.processes if p.kind in MISS_KINDS]
    floor = Floor(seconds, PERIOD_US, tmp / f"{instance}.ct.hist", servo.spike_us, CT_PRIORITY)
    servo.cyclictest_command = floor.text
    watch = ForeignWatch(instance)
    watch.poll_rt()
    sio_samples: list[int] = []
    run = KaliRun(cfg, log_dir=tmp, watch=watch, lockstep=False)
    try:
        with run, floor, contextlib.ExitStack() as stack:
            inst = run.inst
            assert inst is not None
            client = ServoClient(inst)
            stack.callback(client.close)
            fifos = [client.level.fifo(k) for k in range(len(client.names))]
            motion, remote, pids = None, None, dict(run.pids)
            if spec.work == "motion":
                motion = warm_up(inst, client, fifos, cfg.clock.tg_period_ms / 1000.0)
                if motion is None:
                    servo.fault = inst.fault_text()
                    raise BenchError(f"halted before the window opened: {servo.fault}")
            else:
                power_on(inst, client)
                res.connect_ms, remote = timed(Kali.connect, endpoint, instance)
                stack.callback(remote.close)
                res.ready_ms = timed(remote.ready, [ARM])[0]
                sessions = remote.status()["bridge"]["sessions"]
                if sessions:
                    pids["session"] = int(sessions[0]["pid"])
                watch.exclude.update(pids.values())
                time.sleep(SETTLE_S)
            sub = None
            if spec.bridge:
                sub = Subscriber(endpoint, instance)
                stack.callback(sub.close)
            lead_end = time.monotonic() + LEAD_IN_S
            while motion is not None and time.monotonic() < lead_end:
                motion.feed()
                time.sleep(FEED_S)
            if motion is None:
                time.sleep(LEAD_IN_S)
            else:
                motion.pending_min, motion.pending_max = FIFO_HIGH, 0
            ct = floor.start(watch)
            tail = MissTail(inst)
            window = Window(inst, names, pids, client.level.ctrl, N_SV)
            s0 = window.open()
            t0 = s0.kali.t_ns
            end = t0 + seconds * 1_000_000_000
            sio_rec = inst.procs[inst.slot_of("sio")]
            next_sample = [t0]

            def poll() -> None:
                """Between calls and motion feeds: the miss log, a halt (the window closes
                there), SIO's last cycle every FEED_S, foreign work and cyclictest."""
                tail.poll()
                now = time.monotonic_ns()
                if not window.closed and inst.fault["active"]:
                    window.close()
                    servo.fault = inst.fault_text()
                    servo.halted_at_s = (now - t0) / 1e9
                if not window.closed and now >= next_sample[0]:
                    sio_samples.append(int(sio_rec["exec_last_ns"]))
                    next_sample[0] = now + int(FEED_S * 1e9)
                watch.poll(ct, end)

            if remote is not None:
                try:
                    res.timings = requests(remote, instance, client, end, poll)
                except (KaliError, TimeoutError) as exc:
                    res.notes.append(f"the requests stopped: {type(exc).__name__}: {exc}")
            while (left := end - time.monotonic_ns()) > 0:
                time.sleep(min(FEED_S, left / 1e9))
                poll()
                if motion is not None and not window.closed:
                    with contextlib.suppress(KaliError):
                        motion.feed()
            s1 = window.close()
            tail.poll()
            logged = tail.between(miss_names, t0, s1.kali.t_ns)
            if tail.lost:
                res.notes.append(f"{tail.lost} miss-log entries were overwritten unread")
            res.seconds = window.wall_ns / 1e9
            if sub is not None:
                every = round(1e3 / TELEMETRY_HZ / cfg.clock.base_tick_ms)
                got, empty = sub.between(t0, s1.kali.t_ns), np.zeros((0, 3), dtype=np.int64)
                res.telemetry = [
                    telemetry_stats(
                        r.name, got.get(r.name, empty), res.seconds, every, cfg.clock.base_tick_ms
                    )
                    for r in cfg.robots
                ]
                res.malformed_samples = sub.bad
                a, b = s0.kali.procs["bridge"], s1.kali.procs["bridge"]
                period = round(cfg.process("bridge").period_ms * 1000)
                res.bridge_wakeup = window_row("kali bridge", a, b, period, "self-timed")
            res.bridge_cpu_pct = window.cpu_pct("bridge") if spec.bridge else math.nan
            res.worker_cpu_pct = window.cpu_pct("session") if "session" in pids else math.nan
            res.own_cpu_pct = window.own_cpu_pct()
            res.kali_cpu_pct = sum(window.cpu_pct(n) for n in run.pids)
            ct_res, out = floor.finish()
            assert ct_res is not None
            stalls = parse_spikes(out, PERIOD_US)
            if unlogged := spikes_unlogged(out):
                res.notes.append(f"cyclictest's spike log filled: {unlogged} stalls unlogged")
    finally:
        res.notes += run.notes()
    analyse(servo, cfg, window, ct_res, logged, stalls, sio_samples, ["sio", *sv_names])
    res.sio_cycle_us = sio_cycle(sio_samples)
    res.notes += servo.notes + watch.notes()
    if motion is not None and motion.stopped:
        res.notes.append(f"the motion stopped: {motion.stopped}")
    return res


# --------------------------------------------------------------------------------------------
# Output


def pct(v: float) -> str:
    return "nan" if math.isnan(v) else f"{v:.1f}"


def ms(v: float) -> str:
    return "nan" if math.isnan(v) else f"{v:.2f}"


def telemetry_table(results: list[Result]) -> str:
    cols = [("run", "left"), ("robot", "left"), "samples", "rate Hz", "% of telemetry_hz",
            "p50", "p99", "max", "min", "skipped", "longest step ms", "repeats", "ct p99",
            "ct max"]  # fmt: skip
    rows: list[list[object] | None] = []
    for r in results:
        if not r.telemetry:
            continue
        ct = r.servo.wakeup[0] if r.servo and r.servo.wakeup else None
        if rows:
            rows.append(None)
        for t in r.telemetry:
            rows.append([
                r.run, t.robot, t.samples, f"{t.rate_hz:.1f}", pct(100 * t.rate_hz / TELEMETRY_HZ),
                us(t.p50_us), us(t.p99_us), us(t.max_us), us(t.min_us), t.skipped,
                f"{t.longest_ms:g}", t.repeats,
                us(ct.p99_us) if ct else "", us(ct.max_us) if ct else "",
            ])  # fmt: skip
    return table(
        cols,  # type: ignore[arg-type]
        rows,  # type: ignore[arg-type]
        title=f"telemetry latency: receipt - due_ns of the sample's SIO tick, at "
        f"{TELEMETRY_HZ:g} Hz",
        caption="µs; skipped: bridge cycles missing by the samples' ticks, longest step: "
        "between two samples' SIO ticks, repeats: a tick sent twice; ct: cyclictest's wake-up "
        "lateness in the same window",
    )


def requests_table(r: Result) -> str:
    cols = [("request", "left"), "n", "p50", "p99", "max", "min", ("note", "left")]
    rows: list[list[object] | None] = [
        ["Kali.connect (before the window)", 1, ms(r.connect_ms), "", "", "", ""],
        [f"ready([{ARM!r}]) (before the window)", 1, ms(r.ready_ms), "", "", "", ""],
        None,
    ]
    for t in r.timings:
        rows.append([t.name, len(t.ms), ms(t.q(50)), ms(t.q(99)), ms(max(t.ms, default=math.nan)),
                     ms(min(t.ms, default=math.nan)), t.note])  # fmt: skip
    return table(
        cols,  # type: ignore[arg-type]
        rows,  # type: ignore[arg-type]
        title=f"request round trips through Kali.connect ({r.arms}, run {r.run})",
        caption="ms, wall time of the call in this process; kalictl enable / disable wait for "
        "SIO's power state; local: the verb run in this process",
    )


def cpu_table(results: list[Result]) -> str:
    cols = [("run", "left"), ("cell", "left"), "bridge", "session worker", "this script",
            "all Kali", "bridge wake-up p50", "p99", "max", "misses", ("note", "left")]  # fmt: skip
    rows = []
    for r in results:
        w = r.bridge_wakeup
        wake = [us(w.p50_us), us(w.p99_us), us(w.max_us), w.misses] if w else ["", "", "", ""]
        note = "one subscriber" if r.bridge else "no bridge"
        if r.work == "requests":
            note += ", a remote program"
        rows.append([r.run, r.arms, pct(r.bridge_cpu_pct), pct(r.worker_cpu_pct),
                     pct(r.own_cpu_pct), pct(r.kali_cpu_pct), *wake, note])  # fmt: skip
    return table(
        cols,  # type: ignore[arg-type]
        rows,
        title="CPU over the window, % of one CPU (scheduler run time)",
        caption="this script: the subscriber (and the remote program); wake-up: the bridge's "
        "lateness, µs",
    )


def servo_table(results: list[Result]) -> str:
    cols = [("run", "left"), "bridge", "s2DAC p50", "p99", "max", "SV exec p99",
            "SIO cycle med/p99/max", "misses (own)", "halted", "ct p99", "ct max",
            ("note", "left")]  # fmt: skip
    rows = []
    for r in results:
        s = r.servo
        if s is None or s.latency is None:
            continue
        lat, ct = s.latency, s.wakeup[0]
        cyc = r.sio_cycle_us
        own = own_misses(s)
        note = {"motion": "FIFO sinusoid", "requests": "held; remote requests"}[r.work]
        rows.append([
            r.run, "on" if r.bridge else "off", us(lat.p50_us), us(lat.p99_us), us(lat.max_us),
            ",".join(us(d.p99_us) for d in s.sv_exec), "/".join(us(v) for v in cyc),
            f"{s.misses} ({own})", "no" if s.fault is None else f"{s.halted_at_s or 0:.1f}s",
            us(ct.p99_us), us(ct.max_us), f"{r.arms}; {note}",
        ])  # fmt: skip
    return table(
        cols,  # type: ignore[arg-type]
        rows,
        title="servo level with and without the bridge (bench_servo's 1ms-2sv: full "
        "feed-forward, dashboard)",
        caption="µs; misses of tg, sio, sv (in brackets: those cyclictest did not also see); "
        "SIO cycle: last-cycle value sampled every 50 ms",
    )


def sio_cycle(samples: list[int]) -> list[float]:
    """SIO's cycle (wake → ack) from the last-cycle values sampled: median, p99, max µs."""
    v = np.array(samples, dtype=float) / 1e3
    if not len(v):
        return [math.nan] * 3
    return [float(np.median(v)), float(np.percentile(v, 99)), float(v.max())]


def own_misses(s: RunResult) -> int:
    """bench_servo's count of misses cyclictest did not also see (unmatched ones count)."""
    return s.misses_kali_only + s.misses - s.misses_logged


def verdicts(results: list[Result]) -> list[Verdict]:
    """Every goal on the run it is judged on (not measured when that run did not run)."""
    by = {r.run: r for r in results if r.error is None}
    out: list[Verdict] = []

    def missing(goal: Goal, run: str) -> Verdict:
        why = "not run" if run not in {r.run for r in results} else "the run failed"
        return goal.judge(None, why=why)

    b = by.get("bridge")
    if b is None or not b.telemetry:
        out += [missing(GOAL_LATENCY, "bridge"), missing(GOAL_RATE, "bridge")]
    else:
        worst = max(b.telemetry, key=lambda t: t.p99_us)
        out.append(GOAL_LATENCY.judge(worst.p99_us, why=f"worst robot: {worst.robot}"))
        off = max(b.telemetry, key=lambda t: abs(t.rate_hz - TELEMETRY_HZ))
        dev = 100 * abs(off.rate_hz - TELEMETRY_HZ) / TELEMETRY_HZ
        out.append(GOAL_RATE.judge(dev, why=f"worst robot: {off.robot} {off.rate_hz:.1f} Hz"))
    q = by.get("requests")
    if q is None or not q.timings:
        out += [missing(GOAL_VERB, "requests"), missing(GOAL_READ, "requests")]
    else:
        t = {x.name: x for x in q.timings}
        groups = {x.group: x for x in q.timings if x.group}
        for verb in ("disable", "enable", " ".join(PLAIN_VERB)):
            remote, local = groups.get(verb), groups.get(f"{verb} local")
            goal = replace(GOAL_VERB, name=f"{GOAL_VERB.name} ({verb})")
            why = VERB_WHY.get(verb, "")
            if remote and local:
                why = f"p50 {remote.q(50):.1f} ms remote, {local.q(50):.1f} ms local; {why}"
            share = remote.q(50) - local.q(50) if remote and local else None
            out.append(goal.judge(share, why=why))
        out.append(GOAL_READ.judge(t["read_joints"].q(50)))
    for run, cell in (("bridge", "pumas"), ("four", "four")):
        r = by.get(run)
        goal = GOAL_CPU[cell]
        out.append(missing(goal, run) if r is None else goal.judge(r.bridge_cpu_pct))
    on, off = by.get("bridge"), by.get("no-bridge")
    if on is None or off is None or on.servo is None or off.servo is None:
        why = "needs the runs no-bridge and bridge"
        out.append(Goal("servo level with the bridge", "s2DAC p99", "<=", math.nan).judge(
            None, why=why))  # fmt: skip
        out.append(GOAL_OWN_MISSES.judge(None, why=why) if on is None else misses_verdict(on))
    else:
        assert on.servo.latency is not None and off.servo.latency is not None
        p99_off = off.servo.latency.p99_us
        goal = Goal(
            "servo level with the bridge", "s2DAC p99", "<=",
            p99_off * SERVO_FACTOR + SERVO_SLACK_US, "µs", source="issue 29",
            floor="without the bridge",
        )  # fmt: skip
        out.append(
            goal.judge(
                on.servo.latency.p99_us,
                p99_off,
                why=f"limit = {us(p99_off)} µs without x {SERVO_FACTOR} + {SERVO_SLACK_US:g} µs",
            )
        )
        out.append(misses_verdict(on))
    return out


def misses_verdict(r: Result) -> Verdict:
    """No miss cyclictest did not also see in run ``r`` (a halt misses it)."""
    s = r.servo
    assert s is not None
    v = GOAL_OWN_MISSES.judge(own_misses(s), why=f"{s.misses} misses in all")
    if s.fault:
        v.met, v.why = False, f"halted: {s.fault}"
    return v


def report(results: list[Result], argv: list[str], port: int) -> str:
    """Everything the benchmark prints, after the runs."""
    m = next((r.servo.machine for r in results if r.servo and r.servo.machine), machine_facts())
    ct = next((r.servo.cyclictest_command for r in results if r.servo), "")
    lines = [
        "=== bench_bridge: the Zenoh bridge (issue 29) in real time ===",
        "command: " + shlex.join([Path(sys.executable).name, "scripts/bench_bridge.py", *argv]),
        machine_line(m),
        f"config: bench_servo's 1ms-2sv (config/default.yaml, 1 ms servo, 2 SVs, full "
        f"feed-forward, dashboard) + bridge on tcp/127.0.0.1:{port}, telemetry_hz "
        f"{TELEMETRY_HZ:g}, SCHED_OTHER on CPU 1; the four-arm cell with arena_kib "
        f"{CELLS['four']['arena_kib']}",
        f"floor: {ct}",
        "",
    ]
    for r in results:
        head = f"run {r.run}: {r.arms}, bridge {'on' if r.bridge else 'off'}, {r.work}"
        if r.error:
            lines.append(f"{head}: ERROR {r.error}")
        else:
            lines.append(f"{head}, window {r.seconds:.1f} s")
        lines += [f"  note: {n}" for n in r.notes]
    lines.append("")
    if any(r.telemetry for r in results):
        lines += [telemetry_table(results), ""]
    for r in results:
        if r.timings or not math.isnan(r.connect_ms):
            lines += [requests_table(r), ""]
    if any(r.error is None for r in results):
        lines += [cpu_table([r for r in results if r.error is None]), ""]
        lines += [servo_table(results), ""]
        lines += servo_difference(results)
    lines += [v.line() for v in verdicts(results)]
    return "\n".join(lines)


def servo_difference(results: list[Result]) -> list[str]:
    """The ``bridge`` run beside ``no-bridge``: the servo figures with / without."""
    by = {r.run: r for r in results if r.error is None and r.servo and r.servo.latency}
    on, off = by.get("bridge"), by.get("no-bridge")
    if on is None or off is None:
        return []
    a, b = on.servo, off.servo
    assert a is not None and b is not None and a.latency is not None and b.latency is not None

    def pair(x: float, y: float) -> str:
        return f"{us(x)}/{us(y)} ({x - y:+.0f} µs)"

    pairs = enumerate(zip(a.sv_exec, b.sv_exec, strict=True))
    sv = ", ".join(f"sv.{k} {pair(x.p99_us, y.p99_us)}" for k, (x, y) in pairs)
    la, lb = a.latency, b.latency
    return [
        f"with / without the bridge: sensor-to-DAC p50 {pair(la.p50_us, lb.p50_us)}, p99 "
        f"{pair(la.p99_us, lb.p99_us)}, max {pair(la.max_us, lb.max_us)}; SV exec p99 {sv}; "
        "sio wake-up p99.9 "
        f"{pair(a.wakeup[1].p999_us, b.wakeup[1].p999_us)}; misses {a.misses}/{b.misses} "
        f"(own {own_misses(a)}/{own_misses(b)}); cyclictest p99 "
        f"{pair(a.wakeup[0].p99_us, b.wakeup[0].p99_us)}, max "
        f"{pair(a.wakeup[0].max_us, b.wakeup[0].max_us)} (the floor in each)",
        "",
    ]


# --------------------------------------------------------------------------------------------
# Main


def main(argv: list[str] | None = None) -> int:
    """Parse options, run each selected run, print the tables and the goals."""
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=int, default=20, help="window per run (default 20)")
    ap.add_argument(
        "--runs",
        type=pick(RUNS, "run"),
        default=list(RUNS.values()),
        help=f"comma-separated subset of {','.join(RUNS)} (default: all, in that order)",
    )
    add_run_options(ap)
    args = ap.parse_args(argv)
    if args.seconds < 5:
        ap.error("--seconds must be >= 5")
    unwind_on_sigterm()
    if shutil.which("cyclictest") is None:
        print(f"bench_bridge: {CYCLICTEST_MISSING}", file=sys.stderr)
        return 2
    port = free_port()
    tmp = Path(tempfile.mkdtemp(prefix="bench_bridge."))
    results: list[Result] = []
    with interrupts("bench_bridge") as status, kept_logs(tmp, "bench_bridge", lambda: any(
        r.error or (r.servo and r.servo.fault) for r in results
    )):  # fmt: skip
        for i, spec in enumerate(args.runs):
            wait_quiet(args.wait_quiet, "bench_bridge")
            if spec.bridge and not port_free(port):
                old, port = port, free_port()
                say(f"bench_bridge: port {old} is taken now; the bridge listens on {port}")
            say(f"bench_bridge: run {i + 1}/{len(args.runs)} {spec.name} ({args.seconds} s window)")
            try:
                res = measure(spec, args.seconds, tmp, port)
            except (KaliError, BenchError, OSError, subprocess.SubprocessError) as exc:
                res = Result(spec.name, spec.cell, spec.bridge, spec.work, arms=f"cell {spec.cell}")
                res.error = f"{type(exc).__name__}: {exc}"
            results.append(res)
        print(report(results, argv, port), flush=True)
        if args.json is not None:
            doc = {"runs": [to_json(r) for r in results]}
            args.json.write_text(json.dumps(doc, indent=2) + "\n")
    return max(status.code, int(any(r.error for r in results)))


if __name__ == "__main__":
    sys.exit(main())
