"""The benchmark harness: what every benchmark and soak in scripts/ does the same way.

A benchmark is a scenario over these pieces (benchlib.py holds the statistics underneath):

- ``cell_config``: a config file with structured overrides, dotted paths into its YAML tree
  (``{"clock.servo_period_ms": 0.5, "processes.sv.count": 1, "robots.*.ff": "full"}``),
  validated by ``parse_config`` like any config;
- ``KaliRun``: an instance started from that config (real time or lockstep), attached, and
  always stopped and checked for leftovers on the way out, whatever happened;
- ``Floor``: ``cyclictest --laptop`` run beside the workload in the same window (DESIGN 10);
- ``Window``: two snapshots of the arena's statistics (process table, SIO's latency and SV
  histograms, the scheduler's run time per process), subtracted, since nothing in the arena
  is reset; ``flight_dump`` the flight recorder's dump of a halt;
- ``Goal``: a goal as data (metric, comparison, limit), judged into met / missed with the
  ratio to the floor measured in the same run;
- ``table``, ``rows_table``: report tables rendered with rich, as plain text;
- ``pss_kib``: a process's proportional and resident set size.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import math
import operator
import os
import shlex
import shutil
import signal
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TypeVar

import numpy as np
import yaml
from benchlib import (
    CT_PRIORITY,
    CT_THREADS,
    KALI_UPPER,
    SPIKE_NODES,
    SPIKE_US,
    BenchError,
    CtResult,
    ForeignWatch,
    KaliSnap,
    Row,
    ct_row,
    cyclictest_command,
    highest_upper,
    parse_histfile,
    period_label,
    quantile_upper,
    run_ns,
    signals_held,
    snapshot,
    stop_cyclictest,
    stop_instance,
    us,
)
from rich import box
from rich.console import Console
from rich.table import Table

from kali_daemons.core import layout
from kali_daemons.runtime.config import KaliConfig, load_config, ms_to_ns, parse_config
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import introspect, launcher
from kali_daemons.tools.introspect import Introspector

REPO = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG = REPO / "config" / "default.yaml"
T = TypeVar("T")
REPORT_WIDTH = 200  # characters of a rendered table (reports are read in logs, not a terminal)

# --------------------------------------------------------------------------------------------
# Config: a file plus structured overrides


def set_path(doc: Any, path: str, value: object) -> None:
    """Set the node at dotted ``path`` of a YAML tree to ``value``.

    Keys name mapping entries, whole numbers list items, ``*`` every item of a list (or
    every value of a mapping).  A missing mapping on the way is created (a section the file
    leaves out, e.g. ``dashboard``); anything else off the tree is a BenchError naming the
    whole path.  ``parse_config`` then checks the result like any config.
    """
    _set(doc, path.split("."), value, path)


def _set(doc: Any, keys: list[str], value: object, path: str) -> None:
    """``set_path``'s walk: ``keys`` are what is left of ``path``."""
    head, rest = keys[0], keys[1:]
    where = f"config override {path!r}"
    if not head:
        raise BenchError(f"{where}: empty key")
    if head == "*":
        items = list(doc.values()) if isinstance(doc, dict) else doc
        if not isinstance(items, list) or not rest:
            raise BenchError(f"{where}: '*' needs a list or mapping with keys below it")
        for item in items:
            _set(item, rest, value, path)
    elif isinstance(doc, list):
        try:
            index = int(head)
            node = doc[index]
        except (ValueError, IndexError):
            raise BenchError(f"{where}: no item {head!r} in a list of {len(doc)}") from None
        if rest:
            _set(node, rest, value, path)
        else:
            doc[index] = value
    elif not isinstance(doc, dict):
        raise BenchError(f"{where}: {type(doc).__name__} has no key {head!r}")
    elif not rest:
        doc[head] = value
    else:
        if doc.get(head) is None:
            doc[head] = {}
        _set(doc[head], rest, value, path)


def cell_config(
    overrides: dict[str, object],
    instance: str,
    base: Path = DEFAULT_CONFIG,
    label: str = "",
) -> KaliConfig:
    """``base`` with ``overrides`` applied in order and instance name ``instance``, parsed.

    ``label`` names the variant in every error message (``default.yaml (1ms-2sv)``).
    """
    cfg = load_config(base)
    doc = yaml.safe_load(cfg.text)
    for path, value in {**overrides, "instance": instance}.items():
        set_path(doc, path, value)
    source = f"{base} ({label})" if label else str(base)
    return parse_config(yaml.safe_dump(doc, sort_keys=False), source, cfg.base_dir)


def robots(*arms: tuple[str, str, float, float, float]) -> list[dict[str, object]]:
    """A cell's ``robots`` list from (name, model, base x, y, yaw°) tuples."""
    return [
        {"name": n, "model": m, "base_xyz": [x, y, 0.0], "base_yaw_deg": yaw}
        for n, m, x, y, yaw in arms
    ]


# The cells the benchmarks run, as ``robots`` overrides of default.yaml (``pumas``: as it is).
# ``mixed``: a PUMA facing a Panda (issue 25); ``four``: two PUMAs, a UR5 and a Panda on the
# corners of a 1.8 m square, facing its centre: 6 + 6 + 6 + 7 = 25 joints, in an arena of 6 MiB
# (default.yaml's 4 MiB is short of the 4222 KiB its flight ring, feed-forward and requests
# need: the config parser refuses it, naming the size).
CELLS: dict[str, dict[str, object]] = {
    "pumas": {},
    "one": {"robots": robots(("left", "puma560", -0.6, 0.0, 0.0))},
    "mixed": {
        "robots": robots(("left", "puma560", -0.6, 0.0, 0.0), ("right", "panda", 0.6, 0.0, 180.0))
    },
    "four": {
        "robots": robots(
            ("left", "puma560", -0.9, -0.9, 45.0),
            ("right", "puma560", 0.9, 0.9, -135.0),
            ("ur", "ur5", 0.9, -0.9, 135.0),
            ("panda", "panda", -0.9, 0.9, -45.0),
        ),
        "arena_kib": 6144,
    },
    # the shipped cell with its parts watched by a camera (the camera process running)
    "watched": {"scene": "scenes/watched.yaml"},
}


def file_cell(path: Path) -> dict[str, object]:
    """The ``robots`` of config file ``path`` as an override: its cell on another file's
    clock and processes (a file like config/mixed.yaml writes only its robots and leaves every
    other section to the parser's defaults, which default.yaml writes out)."""
    return {"robots": yaml.safe_load(load_config(path).text)["robots"]}


DEFAULT_SUBSTEP_MS = 0.5  # config/default.yaml's plant.substep_ms


def period_overrides(period_us: int) -> dict[str, object]:
    """Base tick, servo period and the plant's period at ``period_us`` (fresh encoders every
    servo tick), in whole ms where it is whole; MuJoCo's substep no longer than the plant's
    period (it must divide it)."""
    ms: float = period_us // 1000 if period_us % 1000 == 0 else period_us / 1000
    overrides: dict[str, object] = {
        "clock.base_tick_ms": ms,
        "clock.servo_period_ms": ms,
        "processes.plant.period_ms": ms,
    }
    if ms < DEFAULT_SUBSTEP_MS:
        overrides["plant.substep_ms"] = ms
    return overrides


def sv_overrides(base: Path, n_sv: int) -> dict[str, object]:
    """``n_sv`` servo workers on the first ``n_sv`` of the CPUs ``base`` gives them."""
    sv = yaml.safe_load(load_config(base).text)["processes"]["sv"]
    cpus = list(sv.get("cpus") or [])
    if len(cpus) < n_sv:
        raise BenchError(f"{base}: processes.sv.cpus {cpus} has < {n_sv} CPUs")
    return {"processes.sv.count": n_sv, "processes.sv.cpus": cpus[:n_sv]}


def extras_overrides(on: bool, record: Path | None = None) -> dict[str, object]:
    """The dynamics and viewer processes working (full feed-forward on every arm, the
    dashboard also recorded to ``record``) or left out."""
    if on:
        return {"robots.*.ff": "full", "dashboard.record": str(record) if record else None}
    return {"processes.dynamics.enabled": False, "processes.viewer.enabled": False}


# --------------------------------------------------------------------------------------------
# An instance, always stopped


class KaliRun:
    """An instance started from ``cfg`` and attached; stopped and checked on exit.

    ``with KaliRun(cfg, log_dir=tmp, lockstep=True) as run:`` (keywords beyond ``log_dir``
    and ``watch`` go to ``launcher.start``) gives ``run.inst`` (the arena) and
    ``run.pids``; on the way out, whatever happened, the instance is stopped with SIGINT and
    SIGTERM held back, its daemons reaped, and what is left of it, if anything, is in
    ``run.left_behind``.  ``watch`` learns the daemons' pids so it does not count them as
    foreign real-time work.
    """

    def __init__(
        self,
        cfg: KaliConfig,
        log_dir: Path | None = None,
        watch: ForeignWatch | None = None,
        **start: Any,
    ) -> None:
        self.cfg = cfg
        self.instance = cfg.instance
        self.start_kwargs = start  # launcher.start's keyword arguments: lockstep=..., record=...
        self.log_dir = log_dir
        self.watch = watch
        self.pids: dict[str, int] = {}
        self.inst: Instance | None = None
        self.left_behind: list[str] = []
        if log_dir is not None:  # the daemons' logs in log_dir/<instance> (launcher.log_dir)
            os.environ["KALI_LOG_DIR"] = str(log_dir)

    def __enter__(self) -> KaliRun:
        return self.start()

    def start(self) -> KaliRun:
        """Start and attach (``with`` does this); on a failure nothing is left running."""
        report = launcher.start(self.cfg, instance=self.instance, **self.start_kwargs)
        self.pids = dict(report.pids)
        if self.watch is not None:
            self.watch.exclude.update(self.pids.values())
        try:
            self.inst = Instance.attach(self.instance)
        except BaseException:
            self.stop()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def stop(self) -> None:
        """Detach, stop the instance, reap its daemons; safe to call twice."""
        if self.inst is not None:
            self.inst.close()
            self.inst = None
        if self.pids:
            self.left_behind = stop_instance(self.instance, list(self.pids.values()))
            self.pids = {}

    def notes(self) -> list[str]:
        """The report's note on leftovers, if any."""
        if not self.left_behind:
            return []
        return [f"left behind after two stops: {', '.join(self.left_behind)}"]

    def cpu_of(self, name: str) -> str:
        """Where process ``name`` is bound, as the CPU % table groups it."""
        cpu = self.cfg.process(name).cpu
        return f"cpu{cpu}" if cpu is not None else "unbound"


# --------------------------------------------------------------------------------------------
# The floor: cyclictest beside the workload


class Floor:
    """``cyclictest --laptop`` over ``seconds`` beside the workload (DESIGN 10).

    ``start()`` when the window opens, ``finish()`` after it (cyclictest runs its whole
    ``-D``): its histogram and its stdout (the ``--spike`` log).  Leaving the ``with``
    ends a cyclictest still running and removes its /dev/shm file.  With ``out``/``err``
    paths its output goes to files (a soak's log can be long) and ``finish`` reads them.
    """

    def __init__(
        self,
        seconds: int,
        period_us: int,
        histfile: Path | None,
        spike_us: int = SPIKE_US,
        priority: int = CT_PRIORITY,
        threads: int = CT_THREADS,
        out: Path | None = None,
        err: Path | None = None,
        spike_nodes: int = SPIKE_NODES,
    ) -> None:
        self.seconds = seconds
        self.period_us = period_us
        self.histfile = histfile
        self.priority = priority
        self.out, self.err = out, err
        self.command = cyclictest_command(
            seconds, threads, histfile, period_us, spike_us, priority, spike_nodes
        )
        self.proc: subprocess.Popen[str] | None = None

    @property
    def text(self) -> str:
        """The command line as the report prints it."""
        return shlex.join(self.command)

    def start(self, watch: ForeignWatch | None = None) -> subprocess.Popen[str]:
        """Start cyclictest now (the window opens)."""
        if self.out is not None and self.err is not None:
            with self.out.open("w") as out, self.err.open("w") as err:
                self.proc = subprocess.Popen(self.command, stdout=out, stderr=err, text=True)
        else:
            self.proc = subprocess.Popen(
                self.command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
            )
        if watch is not None:
            watch.exclude.add(self.proc.pid)
        return self.proc

    def finish(self, timeout: float = 30.0) -> tuple[CtResult | None, str]:
        """Wait for cyclictest's end: its histogram (None without a histfile) and stdout."""
        assert self.proc is not None, "Floor.finish before start"
        out, err = self.proc.communicate(timeout=timeout)
        if self.out is not None:
            out = self.out.read_text()
            err = self.err.read_text() if self.err else ""
        if self.proc.returncode != 0:
            raise BenchError(f"cyclictest exited {self.proc.returncode}: {(err or '').strip()}")
        hist = parse_histfile(self.histfile) if self.histfile is not None else None
        return hist, out or ""

    def stop(self) -> None:
        """End cyclictest now if it still runs (SIGINT: it exits cleanly); safe twice."""
        with signals_held():
            stop_cyclictest(self.proc)

    def stopped_output(self, what: str = "cyclictest") -> str:
        """After ``stop``: its stdout (from ``out``); a BenchError unless it ended cleanly or
        by the SIGINT of ``stop``."""
        assert self.proc is not None and self.out is not None
        if self.proc.returncode not in (0, -signal.SIGINT):
            err = self.err.read_text().strip() if self.err else ""
            raise BenchError(f"{what} exited {self.proc.returncode}: {err}")
        return self.out.read_text()

    def row(self, ct: CtResult, name: str = "cyclictest", cpu: str = "0,1") -> Row:
        """The floor's row in a wake-up table."""
        return ct_row(name, ct, cpu, self.period_us, self.priority)

    def __enter__(self) -> Floor:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


# --------------------------------------------------------------------------------------------
# Windows over the arena's statistics


@dataclass
class Dist:
    """A duration distribution over a window (not a wake-up lateness)."""

    name: str
    samples: int
    p50_us: float
    p99_us: float
    p999_us: float
    max_us: float
    over_period: int  # samples >= one servo period
    note: str = ""


def dist(
    name: str, hist: np.ndarray, max0_ns: int, max1_ns: int, period_us: int, note: str = ""
) -> Dist:
    """A ``Dist`` from a window histogram; exact max when the running maximum grew."""
    exact = max1_ns / 1e3 if max1_ns > max0_ns else highest_upper(hist, KALI_UPPER)
    return Dist(
        name=name,
        samples=int(hist.sum()),
        p50_us=quantile_upper(hist, KALI_UPPER, 0.50),
        p99_us=quantile_upper(hist, KALI_UPPER, 0.99),
        p999_us=quantile_upper(hist, KALI_UPPER, 0.999),
        max_us=exact,
        over_period=int(hist[layout.lateness_bin(period_us * 1000) :].sum()),
        note=note,
    )


@dataclass
class ServoSnap:
    """The servo level's counters (SIO's sensor-to-DAC histogram, the SVs' execution
    histograms and servo counts) at one instant, copied out of its control record."""

    latency_hist: np.ndarray
    latency_max_ns: int
    sv_exec_hist: np.ndarray  # (n_sv, HIST_BINS)
    sv_exec_max_ns: np.ndarray
    sv_servos: np.ndarray


def servo_snapshot(ctrl: np.ndarray, n_sv: int) -> ServoSnap:
    """Copy the servo level's statistics out of ``ServoLevel.ctrl`` (reads only)."""
    return ServoSnap(
        latency_hist=np.array(ctrl["latency_hist"], dtype=np.int64),
        latency_max_ns=int(ctrl["latency_max_ns"]),
        sv_exec_hist=np.array(ctrl["sv_exec_hist"][:n_sv], dtype=np.int64),
        sv_exec_max_ns=np.array(ctrl["sv_exec_max_ns"][:n_sv], dtype=np.int64),
        sv_servos=np.array(ctrl["sv_servos"][:n_sv], dtype=np.int64),
    )


@dataclass
class Snap:
    """One end of a window: the process table, the servo level (if asked), every process's
    scheduler run time and this script's CPU time."""

    kali: KaliSnap
    servo: ServoSnap | None
    run_ns: dict[str, int]
    own_cpu_ns: int
    extra: Any = None


@dataclass
class Window:
    """A measurement window: ``open()`` and ``close()`` snapshot, the figures subtract.

    ``names`` are the processes whose table rows are copied, ``pids`` those whose run time
    is read, ``ctrl`` the servo level's control record (``ServoLevel.ctrl``) with ``n_sv``
    workers, ``extra`` anything else a benchmark copies at both ends (e.g. FIFO underruns).
    """

    inst: Instance
    names: list[str]
    pids: dict[str, int] = field(default_factory=dict)
    ctrl: np.ndarray | None = None
    n_sv: int = 0
    extra: Callable[[], Any] | None = None
    a: Snap | None = None
    b: Snap | None = None

    def snap(self) -> Snap:
        """Copy everything the window subtracts (outside any cycle; reads only)."""
        return Snap(
            kali=snapshot(self.inst, self.names),
            servo=None if self.ctrl is None else servo_snapshot(self.ctrl, self.n_sv),
            run_ns={n: run_ns(pid) for n, pid in self.pids.items()},
            own_cpu_ns=time.process_time_ns(),
            extra=None if self.extra is None else self.extra(),
        )

    def open(self) -> Snap:
        """The window's start."""
        self.a = self.snap()
        return self.a

    def close(self) -> Snap:
        """The window's end (a halt's, when the clock has stopped); once only."""
        if self.b is None:
            self.b = self.snap()
        return self.b

    @property
    def closed(self) -> bool:
        """True once ``close`` has run."""
        return self.b is not None

    @property
    def wall_ns(self) -> int:
        """The window's length in CLOCK_MONOTONIC ns."""
        assert self.a is not None and self.b is not None
        return self.b.kali.t_ns - self.a.kali.t_ns

    def cpu_pct(self, name: str) -> float:
        """Process ``name``'s share of one core over the window, % (NaN if it went away)."""
        assert self.a is not None and self.b is not None
        r0, r1 = self.a.run_ns.get(name, -1), self.b.run_ns.get(name, -1)
        wall = self.wall_ns
        return 100.0 * (r1 - r0) / wall if r0 >= 0 and r1 >= 0 and wall > 0 else math.nan

    def own_cpu_pct(self) -> float:
        """This script's share of one core over the window, %."""
        assert self.a is not None and self.b is not None
        wall = self.wall_ns
        return 100.0 * (self.b.own_cpu_ns - self.a.own_cpu_ns) / wall if wall > 0 else math.nan


def halt_window_ns(cfg: KaliConfig) -> int:
    """How far back from a halt the machine's lost time is counted: as long as Kali may go
    without a servo tick before it halts (the serious tolerance, or the boards' watchdog)."""
    return ms_to_ns(max(cfg.clock.serious_miss_tolerance_ms, cfg.plant.watchdog_ms))


def flight_dump(inst: Instance) -> str | None:
    """The flight recorder's dump of the halt, once the wall clock has written it (≤ 2 s)."""
    spy = Introspector(inst)
    try:
        deadline = time.monotonic() + 2.0
        while (f := spy.flight()) is not None and f["pending"] and time.monotonic() < deadline:
            time.sleep(0.05)
        return None if f is None else f["last_dump"]
    finally:
        spy.close()


# --------------------------------------------------------------------------------------------
# Memory


def pss_kib(pid: int) -> tuple[int, int]:
    """(PSS, RSS) of ``pid`` in KiB (``kali_daemons.tools.introspect.pss_kib``); (-1, -1) when it
    is gone, so a table row says so instead of the run failing.

    PSS shares each page among the processes that map it, so the PSS of a set of processes
    adds up to what the set costs the machine; RSS counts a shared library in every process.
    """
    try:
        return introspect.pss_kib(pid)
    except OSError:
        return -1, -1


# --------------------------------------------------------------------------------------------
# In-process timing


def time_per_op(body: Callable[[int], object], n: int, repeats: int) -> tuple[float, float]:
    """Best and median ns per iteration of ``body(n)`` (which runs ``n`` iterations itself),
    over ``repeats`` runs: the best is what the code costs, the median what the machine gave."""
    per_op = []
    for _ in range(repeats):
        t0 = time.perf_counter_ns()
        body(n)
        per_op.append((time.perf_counter_ns() - t0) / n)
    return min(per_op), statistics.median(per_op)


# --------------------------------------------------------------------------------------------
# Goals as data

COMPARE: dict[str, Callable[[float, float], bool]] = {
    "<": operator.lt,
    "<=": operator.le,
    ">": operator.gt,
    ">=": operator.ge,
    "==": operator.eq,
}


@dataclass(frozen=True)
class Goal:
    """A goal as data: ``metric`` compared by ``op`` with ``limit`` (in ``unit``).

    ``source`` says where it comes from (an issue), ``floor`` names the figure of the same
    run it is set beside (e.g. cyclictest's p99.9, or real time for a lockstep speed).
    """

    name: str
    metric: str
    op: str
    limit: float
    unit: str = ""
    source: str = ""
    floor: str = ""

    def __post_init__(self) -> None:
        if self.op not in COMPARE:
            raise BenchError(f"goal {self.name!r}: comparison {self.op!r} not in {list(COMPARE)}")

    def judge(self, value: float | None, floor: float | None = None, why: str = "") -> Verdict:
        """Met or missed (not measured for None or NaN), with the ratio to ``floor``."""
        measured = value is not None and not math.isnan(value)
        met = COMPARE[self.op](value, self.limit) if measured else None  # type: ignore[arg-type]
        ratio = value / floor if measured and floor else math.nan  # type: ignore[operator]
        return Verdict(self, value if measured else math.nan, met, ratio, why)


@dataclass
class Verdict:
    """A goal judged on one run's figure."""

    goal: Goal
    value: float
    met: bool | None  # None: not measured
    ratio_to_floor: float
    why: str = ""

    @property
    def word(self) -> str:
        """``met``, ``MISSED`` or ``not measured``."""
        return "not measured" if self.met is None else "met" if self.met else "MISSED"

    def line(self) -> str:
        """``GOAL name: met (metric 12.3 x >= 10 x; 12.30x the floor)``."""
        g = self.goal
        head = f"GOAL {g.name}: {self.word}"
        if self.met is None or math.isnan(self.value):
            return head + (f" ({self.why})" if self.why else "")
        unit = "" if not g.unit else g.unit if g.unit.startswith("x") else f" {g.unit}"
        body = f"{g.metric} {self.value:.3g}{unit} {g.op} {g.limit:g}{unit}"
        if not math.isnan(self.ratio_to_floor):
            body += f"; {self.ratio_to_floor:.2f}x {g.floor or 'the floor'}"
        return f"{head} ({body})" + (f"; {self.why}" if self.why else "")


# --------------------------------------------------------------------------------------------
# Report rendering


# rich's SIMPLE_HEAD (a rule under the heading), with a rule between sections as well
RULED = box.Box("    \n    \n ── \n    \n ── \n    \n    \n    \n")


def table(
    columns: Sequence[str | tuple[str, str]],
    rows: Iterable[Sequence[object]],
    title: str = "",
    caption: str = "",
) -> str:
    """A table rendered with rich as plain text: ``columns`` are headings (right-aligned)
    or (heading, "left"); a row of None is a rule (e.g. before the rows for reference)."""
    t = Table(title=title or None, caption=caption or None, box=RULED, pad_edge=False)
    for c in columns:
        heading, justify = (c, "right") if isinstance(c, str) else c
        t.add_column(heading, justify=justify)  # type: ignore[arg-type]
    for r in rows:
        if r is None:
            t.add_section()
            continue
        t.add_row(*("" if v is None else str(v) for v in r))
    return render(t)


def render(renderable: object) -> str:
    """Any rich renderable as plain text (no colour, no terminal needed)."""
    buf = io.StringIO()
    Console(file=buf, width=REPORT_WIDTH, color_system=None, force_terminal=False).print(renderable)
    lines = [line.rstrip() for line in buf.getvalue().splitlines()]
    return "\n".join(lines).strip("\n")  # the box's blank top and bottom lines


def rows_table(
    period_us: int, first: str, rows: Sequence[Row], reference: Sequence[Row] = ()
) -> str:
    """A wake-up lateness table of ``Row``s (µs); ``reference`` rows after a rule."""
    cols: list[str | tuple[str, str]] = [
        (first, "left"),
        "cpu",
        "prio",
        "samples",
        "p50",
        "p99",
        "p99.9",
        "max",
        ">=" + period_label(period_us),
        "misses",
        ("note", "left"),
    ]

    def cells(r: Row) -> list[object]:
        return [
            r.name, r.cpu, r.prio, r.samples, us(r.p50_us), us(r.p99_us), us(r.p999_us),
            us(r.max_us), r.over_period, r.misses, r.note,
        ]  # fmt: skip

    body: list[Sequence[object] | None] = [cells(r) for r in rows]
    if reference:
        body += [None, *(cells(r) for r in reference)]
    return table(cols, body, caption="lateness in µs")  # type: ignore[arg-type]


def dist_table(first: str, dists: Sequence[Dist], late: str = ">=period") -> str:
    """A table of ``Dist``s (µs)."""
    cols = [(first, "left"), "samples", "p50", "p99", "p99.9", "max", late, ("note", "left")]
    body = [
        [d.name, d.samples, us(d.p50_us), us(d.p99_us), us(d.p999_us), us(d.max_us),
         d.over_period, d.note]
        for d in dists
    ]  # fmt: skip
    return table(cols, body, caption="µs")  # type: ignore[arg-type]


# --------------------------------------------------------------------------------------------
# Runs


def pick(known: dict[str, T], what: str) -> Callable[[str], list[T]]:
    """An argparse ``type`` for ``--runs a,b``: the named entries of ``known``, in the given
    order; an unknown name is refused with the list of known ones."""

    def parse(text: str) -> list[T]:
        out = []
        for name in (t.strip() for t in text.split(",")):
            if name not in known:
                raise argparse.ArgumentTypeError(
                    f"unknown {what} {name!r}; {what}s: {', '.join(known)}"
                )
            out.append(known[name])
        return out

    return parse


def retry_warmup(
    attempt: Callable[[], Any],
    halted_before_window: Callable[[Any], str | None],
    attempts: int,
    who: str,
    between: Callable[[], None] | None = None,
) -> tuple[Any, list[str]]:
    """Run ``attempt`` up to ``attempts`` times while it halts before its window opened (a
    host stall in start-up measures nothing); the result and the earlier halts' texts."""
    earlier: list[str] = []
    for k in range(1, attempts + 1):
        res = attempt()
        fault = halted_before_window(res)
        if fault is None or k == attempts:
            return res, earlier
        earlier.append(fault)
        say(f"{who}: halted before the window opened ({fault}); attempt {k + 1}/{attempts}")
        if between is not None:
            between()
    raise AssertionError("unreachable")


def add_run_options(ap: argparse.ArgumentParser) -> None:
    """``--wait-quiet S`` and ``--json PATH``, as every benchmark of runs takes them."""
    ap.add_argument(
        "--wait-quiet",
        type=float,
        default=0.0,
        metavar="S",
        help="before each run, wait up to S seconds for other Kali instances (a test suite's) "
        "to stop; they make the numbers meaningless (default 0: do not wait, just report them)",
    )
    ap.add_argument(
        "--json", type=Path, default=None, metavar="PATH", help="also write the numbers to PATH"
    )


def say(text: str) -> None:
    """A progress line on stderr (the report goes to stdout)."""
    print(text, file=sys.stderr, flush=True)


@dataclass
class Status:
    """What ``interrupts`` makes of the way a benchmark ended: its exit status."""

    code: int = 0


@contextlib.contextmanager
def interrupts(who: str) -> Iterator[Status]:
    """Ctrl-C, SIGTERM (``unwind_on_sigterm``) and a closed stdout (``| head``) end the
    benchmark quietly with exit status 1; every ``finally`` inside has stopped its instance."""
    status = Status()
    try:
        yield status
    except KeyboardInterrupt:
        say(f"{who}: interrupted; the instance was stopped")
        status.code = 1
    except BrokenPipeError:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        say(f"{who}: output closed; the other runs skipped")
        status.code = 1


@contextlib.contextmanager
def kept_logs(tmp: Path, who: str, keep: Callable[[], bool]) -> Iterator[Path]:
    """Remove the run's temporary directory on the way out unless ``keep()`` (a fault or an
    error: the daemons' logs and dumps are then kept, and the path said on stderr)."""
    try:
        yield tmp
    finally:
        if keep():
            print(f"{who}: daemon logs kept in {tmp}", file=sys.stderr)
        else:
            shutil.rmtree(tmp, ignore_errors=True)
