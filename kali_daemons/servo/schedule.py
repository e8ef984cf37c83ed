"""Schedulability check (``kalictl check``, and before a servo select, a shadow trial or a rate
change): from what a running instance measures, predict whether the servo tick still fits
``1 - margin`` of its period after a change, and refuse the change with the numbers before
anything moves.

The model is fixed-priority response-time analysis over the processes as configured (CPU,
priority, period) with execution times measured on the running machine: the servo tick's
SIO and servo shares at p99 from the flight recorder, each clocked process's CPU time per
cycle, each CPU's load on average and in its busiest slice of the serious tolerance, and a
servo's ``step`` timed on a copy of the joint's data (a built-in, run in the SVs' compiled
unit, counts as free).  Lockstep has no deadlines: the check passes there.  The model in
full: docs/internals/servo-level.md.
"""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ..core import layout
from ..core.errors import ScheduleError
from ..runtime.flightrec import attach_ring, read_ring
from ..runtime.instance import Instance, decode
from .algorithms.algorithm import ServoAlgorithm, step_cost_us
from .client import ServoClient
from .sv import units

DEFAULT_MARGIN = 0.2  # the servo tick may take 80 % of its period, the rest is headroom
WINDOW_S = 0.5  # how long CPU times are sampled
# Real-time work may hold at most 95 % of a CPU: past it, while a normal task waits there, the
# kernel's fair server takes the CPU from every real-time process on it for 50 ms a second
# (decision 0004, "The kernel's share").
RT_SHARE = 0.95


@dataclass(frozen=True)
class Task:
    """One clocked process as the analysis sees it."""

    name: str
    cpu: int  # -1: not bound
    priority: int  # SCHED_FIFO priority, 0 for SCHED_OTHER
    period_us: float
    cost_us: float  # execution per cycle


@dataclass
class Figures:
    """What a running instance measured, in µs."""

    period_us: float  # the servo period
    sio_own_p99_us: float  # SIO's share of a tick (latency less its sleep for the servos)
    servos_p99_us: float  # the servos' share of a tick (SIO's sleep)
    latency_p99_us: float  # encoder read to DAC write
    ticks: int  # flight-recorder rows the percentiles come from
    tasks: list[Task] = field(default_factory=list)
    cpu_load: dict[int, float] = field(default_factory=dict)  # CPU → fraction of it used
    cpu_rt_load: dict[int, float] = field(default_factory=dict)  # ... by real-time processes
    # CPU → fraction used in its busiest slice of ``peak_ms`` (the serious miss tolerance)
    cpu_peak: dict[int, float] = field(default_factory=dict)
    peak_ms: float = 0.0
    on_cpu: dict[int, tuple[str, ...]] = field(default_factory=dict)  # every process there
    slot_cost_us: dict[int, float] = field(default_factory=dict)  # plugin slots' step cost
    servo_procs: tuple[str, ...] = ()  # SIO and the SVs


@dataclass
class Prediction:
    """The check's verdict, with the numbers that led to it."""

    fits: bool
    response_us: float  # predicted servo tick, encoder read to DAC write (p99)
    limit_us: float
    lines: list[str]

    def text(self) -> str:
        return "\n".join(self.lines)


def _p99(values: np.ndarray) -> float:
    return float(np.percentile(values, 99)) / 1000.0 if len(values) else 0.0


def _schedstat_ns(pid: int) -> int:
    try:
        with open(f"/proc/{pid}/schedstat") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 0


def measure(inst: Instance, window_s: float = WINDOW_S) -> Figures:
    """Measure a running real-time instance (outside any cycle; takes ``window_s``)."""
    cfg = inst.config
    period_us = cfg.clock.servo_period_ms * 1000.0
    a = inst.arena
    if a.lookup(layout.KEY_FLIGHT) is None or a.lookup(layout.KEY_FLIGHT_RING) is None:
        raise ScheduleError("check: SIO has not laid out its flight recorder yet")
    header = a.existing(layout.KEY_FLIGHT, layout.FLIGHT)
    ring = attach_ring(a, header)
    data = read_ring(header, ring)
    del ring
    servoing = data[data["wait_ns"] > 0]  # ticks that fed a servo
    if len(servoing) < 100:
        raise ScheduleError(
            f"check: only {len(servoing)} servo ticks measured (at least 100 needed): "
            f"power a robot (kalictl enable) and check again"
        )
    own = servoing["latency_ns"] - servoing["wait_ns"]
    procs = inst.procs
    base_ns = int(inst.clock["base_tick_ns"])
    live = [i for i in range(layout.MAX_PROCESSES) if int(procs["pid"][i]) > 0]
    acks = {i: int(procs["acks"][i]) for i in live}
    slice_s = cfg.clock.serious_miss_tolerance_ms / 1000.0
    samples = [_sample(procs, live)]
    end = samples[0][0] + int(window_s * 1e9)
    while samples[-1][0] < end:
        time.sleep(min(slice_s, max(0.0, (end - samples[-1][0]) / 1e9)))
        samples.append(_sample(procs, live))
    cpus = {i: int(procs["cpu"][i]) for i in live}
    load, peak = cpu_loads(samples, cpus)
    rt = {i: cpu for i, cpu in cpus.items() if int(procs["priority"][i]) > 0}
    rt_load = cpu_loads(samples, rt)[0]
    tasks = []
    for i in live:  # every process loads its CPU; the clocked ones are tasks
        p = procs[i]
        if not int(p["periodic"]):
            continue
        cpu = cpus[i]
        cpu_ns = samples[-1][1][i] - samples[0][1][i]
        cycles = max(1, int(p["acks"]) - acks[i])
        per = int(p["period_ticks"]) * base_ns / 1000.0
        tasks.append(Task(decode(p["name"]), cpu, int(p["priority"]), per, cpu_ns / cycles / 1e3))
    return Figures(
        period_us=period_us,
        sio_own_p99_us=_p99(own),
        servos_p99_us=_p99(servoing["wait_ns"]),
        latency_p99_us=_p99(servoing["latency_ns"]),
        ticks=len(servoing),
        tasks=tasks,
        cpu_load=load,
        cpu_rt_load=rt_load,
        cpu_peak=peak,
        peak_ms=cfg.clock.serious_miss_tolerance_ms,
        on_cpu={
            cpu: tuple(decode(procs[i]["name"]) for i in live if cpus[i] == cpu)
            for cpu in set(cpus.values())
        },
        servo_procs=tuple(p.name for p in cfg.processes if p.kind in ("sio", "sv")),
    )


def _sample(procs: np.ndarray, live: list[int]) -> tuple[int, dict[int, int]]:
    """Now (monotonic ns) and each live process's CPU time so far (ns)."""
    return time.monotonic_ns(), {i: _schedstat_ns(int(procs["pid"][i])) for i in live}


def cpu_loads(
    samples: list[tuple[int, dict[int, int]]], cpus: dict[int, int]
) -> tuple[dict[int, float], dict[int, float]]:
    """Each CPU's load (the fraction of it its processes used) over ``samples`` (time and
    each process's CPU time so far, from ``_sample``), on average and in the busiest
    interval between two consecutive samples; ``cpus``: each process's CPU (-1 unbound)."""
    mean: dict[int, float] = {}
    peak: dict[int, float] = {}
    (t0, first), (t1, last) = samples[0], samples[-1]
    for i, cpu in cpus.items():
        mean[cpu] = mean.get(cpu, 0.0) + (last[i] - first[i]) / max(1, t1 - t0)
    for (ta, a), (tb, b) in itertools.pairwise(samples):
        used: dict[int, float] = {}
        for i, cpu in cpus.items():
            used[cpu] = used.get(cpu, 0.0) + (b[i] - a[i]) / max(1, tb - ta)
        for cpu, u in used.items():
            peak[cpu] = max(peak.get(cpu, 0.0), u)
    return mean, peak


def _response(task: Task, tasks: list[Task]) -> float:
    """Fixed-priority response time of ``task`` on its CPU, µs (inf if it never converges
    within its period): R = C + sum over higher-priority tasks j of ceil(R / T_j) C_j."""
    hp = [t for t in tasks if t.cpu == task.cpu and t.priority > task.priority and t is not task]
    r = task.cost_us
    for _ in range(100):
        nxt = task.cost_us + sum(math.ceil(r / t.period_us) * t.cost_us for t in hp)
        if nxt == r:
            return r
        if nxt > task.period_us:
            return math.inf
        r = nxt
    return r


@dataclass(frozen=True)
class Change:
    """What is about to change: a servo selected on a slot, or a process's period."""

    what: str  # for the report: "select 'slow' on left joint 2", "rate tg 2 ms"
    servo_us: float = 0.0  # added to the servos' share of a tick (a step's cost, net)
    process: str = ""  # a process whose period changes ...
    period_us: float = 0.0  # ... to this


def predict(
    fig: Figures, change: Change | None = None, margin: float = DEFAULT_MARGIN
) -> Prediction:
    """Whether the servo tick fits ``1 - margin`` of its period and every CPU its load,
    after ``change`` (None: as it runs now)."""
    if not 0.0 <= margin < 1.0:
        raise ScheduleError(f"check: margin {margin!r} must be in [0, 1)")
    limit = (1.0 - margin) * fig.period_us
    tasks = list(fig.tasks)
    load = dict(fig.cpu_load)
    rt_load = dict(fig.cpu_rt_load)
    response = fig.sio_own_p99_us + fig.servos_p99_us
    lines = [
        f"servo tick ({1e6 / fig.period_us:g} Hz, period {fig.period_us:.0f} µs), p99 over "
        f"{fig.ticks} ticks: SIO {fig.sio_own_p99_us:.0f} µs + servos "
        f"{fig.servos_p99_us:.0f} µs (encoder read to DAC write {fig.latency_p99_us:.0f} µs)"
    ]
    peak = dict(fig.cpu_peak)  # a change adds its load to every slice, the busiest too

    def add(cpu: int, share: float, realtime: bool = True) -> None:
        load[cpu] = load.get(cpu, 0.0) + share
        if realtime:
            rt_load[cpu] = rt_load.get(cpu, 0.0) + share
        if cpu in peak:
            peak[cpu] += share

    servo_tasks = [t for t in tasks if t.name in fig.servo_procs]
    process_fits = True  # a process whose period changes meets it (response-time analysis)
    if change is not None:
        lines.append(f"change: {change.what}")
        if change.servo_us:
            response += change.servo_us
            sv_cpus = {t.cpu for t in servo_tasks if t.name.startswith("sv")}
            busiest_cpu = max(sv_cpus, key=lambda c: load.get(c, 0.0), default=-1)
            add(busiest_cpu, change.servo_us / fig.period_us)
            lines.append(f"  servos {change.servo_us:+.1f} µs a tick (one SV runs the step)")
        if change.process:
            old = next((t for t in tasks if t.name == change.process), None)
            if old is None:
                raise ScheduleError(f"check: no clocked process {change.process!r}")
            new = Task(old.name, old.cpu, old.priority, change.period_us, old.cost_us)
            tasks[tasks.index(old)] = new
            share = old.cost_us * (1.0 / new.period_us - 1.0 / old.period_us)
            add(old.cpu, share, old.priority > 0)
            below = [t for t in servo_tasks if t.cpu == old.cpu and t.priority < old.priority]
            if below:  # it preempts the servo tick on that CPU
                extra = (
                    math.ceil(response / new.period_us) - math.ceil(response / old.period_us)
                ) * old.cost_us
                response += max(0.0, extra)
                lines.append(f"  preempts {below[0].name}: {max(0.0, extra):+.0f} µs a tick")
            r = _response(new, tasks)
            ok = process_fits = r <= new.period_us
            lines.append(
                f"  {new.name}: {new.cost_us:.0f} µs a cycle every {new.period_us:.0f} µs, "
                f"response {r:.0f} µs: {'fits' if ok else 'DOES NOT FIT'} its period"
            )
    fits = response <= limit and process_fits
    lines.append(
        f"servo tick {response:.0f} µs of at most {limit:.0f} µs ({100 * (1 - margin):.0f} % "
        f"of the period): {'fits' if fits else 'DOES NOT FIT'}"
    )
    for cpu in sorted(load):
        names = ", ".join(fig.on_cpu.get(cpu) or [t.name for t in tasks if t.cpu == cpu])
        rt = rt_load.get(cpu, 0.0)
        throttled = cpu >= 0 and rt >= RT_SHARE
        ok = load[cpu] < 1.0 and not throttled
        fits = fits and ok
        where = f"CPU {cpu}" if cpu >= 0 else "unbound"
        busiest = ""
        if cpu in peak:  # full for a serious tolerance: the lowest there starve
            top = peak[cpu]
            full = " (full: a process below the others there waits it out)" if top >= 0.95 else ""
            busiest = f", {100 * top:.0f} % in its busiest {fig.peak_ms:g} ms{full}"
        if throttled:
            busiest += (
                f", {100 * rt:.0f} % real-time (over the {100 * RT_SHARE:.0f} % the kernel "
                "allows: it takes the CPU from them for 50 ms a second)"
            )
        lines.append(
            f"{where}: {100 * load[cpu]:.0f} % busy ({names}){busiest}: "
            f"{'fits' if ok else 'OVERLOADED'}"
        )
    return Prediction(fits, response, limit, lines)


def servo_change(client: ServoClient, robot: str, joint: int, name: str) -> Change:
    """The change of selecting servo ``name`` on ``robot``'s ``joint``: its step's cost less
    the joint's current servo's, a built-in run by the SVs' compiled unit counting as free."""
    level = client.level
    registry = level.registry
    i = client.slot(robot, joint)
    _, new = client.algorithm(name)
    current = registry[int(level.slot_structs[i].algo)]
    period_s = level.cfg.clock.servo_period_ms / 1000.0

    def cost(alg: ServoAlgorithm) -> float:
        if alg.name in units.ALGORITHMS:
            return 0.0
        return step_cost_us(alg, period_s, level.data[i][registry.index(alg.name)])

    delta = cost(new) - cost(current)
    return Change(f"select '{name}' on {robot} joint {joint} (was '{current.name}')", delta)


def shadow_change(client: ServoClient, robot: str, joint: int, name: str) -> Change:
    """The change of a shadow trial of servo ``name`` on ``robot``'s ``joint``: its step's
    cost, and the robot's joints leaving the SVs' compiled unit for the per-slot path (SIO
    feeds a robot in trial whole: ``kali_daemons.servo.shadow``), each built-in then a Python
    step."""
    level = client.level
    registry = level.registry
    i = client.slot(robot, joint)
    idx, new = client.algorithm(name)
    period_s = level.cfg.clock.servo_period_ms / 1000.0
    delta = step_cost_us(new, period_s, level.data[i][idx])
    span = level.map.span(client.robot_index(robot))
    for m in range(span.start, span.stop):
        a = int(level.slot_structs[m].algo)
        if 0 <= a < len(registry) and registry[a].name in units.ALGORITHMS:
            delta += step_cost_us(registry[a], period_s, level.data[m][a])
    return Change(f"shadow '{name}' on {robot} joint {joint}", delta)


def check(
    inst: Instance, change: Change | None = None, margin: float = DEFAULT_MARGIN
) -> Prediction:
    """Measure ``inst`` and predict (``kalictl check``, and before a change); lockstep has no
    deadlines and always fits."""
    if inst.lockstep:
        return Prediction(True, 0.0, 0.0, ["lockstep: no deadlines, nothing to check"])
    return predict(measure(inst), change, margin)


def guard(inst: Instance, change: Change, warn: bool, echo: Callable[[str], None]) -> None:
    """Before ``change``: refuse it with the prediction (ScheduleError) when it would not fit;
    with ``warn``, print the prediction and let it go ahead."""
    verdict = check(inst, change)
    if verdict.fits:
        return
    if warn:
        echo(f"warning: {verdict.text()}")
        return
    raise ScheduleError(
        f"{change.what} refused: the servo tick would not fit its CPUs "
        f"(--warn to do it anyway)\n{verdict.text()}"
    )
