"""Soak: the two-arm demo in a loop for ``--minutes`` (30) in real time, beside cyclictest.

What runs.  ``--config`` (``config/default.yaml``) started in real-time mode as its own
instance (``soak<pid>``, never a user's), and ``scripts/example_carry.py`` (both arms pick
the bar up from its stand, carry it and put it back, with full feed-forward) run over and
over as a user runs it: one ``kalictl -i INSTANCE run`` client process per iteration, each
in its own session.  Through the window two hostile clients run beside it (issue 24;
``--no-hostile`` leaves them out): ``soak_flood.py`` under ``kalictl run``, flooding the
request queue with stops of the demo's arms and waiting for every outcome, and
``soak_locks.py``, taking and releasing every arena lock in turn, which the soak stops
(SIGSTOP) for ``STOP_S`` and continues for ``RUN_S`` at random, so it often sits stopped
holding a lock.  A flood outcome lost or left unresolved, or a hostile client that dies,
fails the soak.  The first iteration is the warm-up (power-on and calibration, the
daemons' first motions, BLAS and rerun buffers settling): the window opens when it ends and
closes when the first iteration that ends after ``--minutes`` ends, so both ends of the
window fall at the same point of the demo's cycle.  Two cyclictests run through the window:

- the floor, ``cyclictest --laptop`` (two threads, one pinned per CPU, SCHED_FIFO 80 or
  ``--ct-priority``, interval = the servo period), as in bench_servo.py: the lateness every
  process is compared with;
- the stall detector (``benchlib.DETECT_*``): two threads pinned per CPU at SCHED_FIFO 99,
  above every Kali process, waking every 250 µs and logging each wake-up later than 50 µs
  with its time.  It says when a CPU was gone: a stall it logs cannot be Kali's own work,
  and one between the floor's 1 ms samples is seen too (the floor, at the servo period,
  missed half-millisecond stalls, and below SIO and the SVs it waits for their work).  It
  is no denser because it disturbs what it measures: at 100 µs it tripled Kali's misses
  (``benchlib.DETECT_INTERVAL_US`` gives the measurement).

A halt (``Instance.fault_text``) ends the soak at once: the report names the fault and what
the detector saw of the machine before it (``benchlib.stalls_before``: the time each CPU lost
in the serious tolerance and in five times that before the halt, and its longest stall), and
the daemon logs and flight-recorder dump are kept.  So does a demo that fails
``MAX_FAILS_IN_ROW`` times in a row; a single failed iteration (nonzero exit; its stderr
tail is kept) is counted and the loop goes on.

What is measured, over the window (counters snapshotted when it opens and subtracted when it
closes, as bench_servo does; nothing in the arena is reset):

- Memory: VmRSS (/proc/PID/status) of every Kali process and of their children (the
  viewer's ``rerun`` web server, named ``viewer>rerun``), when the window opens and when it
  closes, and every ``--sample-s`` (30) between, from this SCHED_OTHER script.  The slope of
  a least-squares line through the samples (KiB/min) judges the trend, not only the two ends;
  "flat" is defined at ``GROWTH_FLOOR_KIB`` below.  The daemons run under ``mlockall``, so
  every page they map is resident: RSS is their whole footprint.  The web viewer's server
  keeps the dashboard's recent data for late browsers up to ``dashboard.server_memory_mib``
  (256 MiB) and grows until it holds that much: it is judged against that limit
  (``CAP_OVERHEAD``), and its slope over the window's last third says whether it levelled off.
- Wake-up lateness p50/p99/p99.9/max of every process from the arena's histograms (µs, upper
  bin edges, ``launcher.percentile``'s rule), beside cyclictest's, and each process's p99.9 /
  cyclictest's p99.9 (the note column).
- Missed deadlines per process (the wall clock's counters) and, read from its miss log as
  they come, those cyclictest did not also see (``benchlib.unexplained_misses``: no stall the
  detector logged overlaps the interval the process was unacknowledged), each with its time
  and SIO's timing around it from the flight recorder (``SioTail``).  Also seen means: a
  stall of more than 0.2 servo periods overlaps the miss, or one CPU lost 0.1 periods inside
  it in pieces (``benchlib.LostTime``: the detector's wake-ups later than 50 µs; the report
  also counts the misses left own with other limits, ``SENSITIVITY_US``).  The report
  gives how often a window anywhere in the run would count as also seen
  (``benchlib.chance_seen``): how much of "also seen" can be luck.  Only serious processes'
  misses judge the goal; the others (dynamics: its overruns skip a signal by design) are
  shown.  Not for the verdict, it also counts the misses left own when what the machine did
  up to ``LEAD_US`` before each miss counts too, with that rule's chance.
- The arena: bytes used and free, the largest free block, fragmentation and the number of
  blocks when the window opens and closes.  It should not change: Kali allocates at start-up
  and nothing after (allocation-static).
- The demo: iterations in the window, failures, durations p50/max.

How to read it.  The goal (issue 7): ``GOAL 30 min soak: PASS (memory flat, 0 misses
cyclictest did not also see)``; shorter runs print ``soak N min (the goal is 30 min)``.  FAIL
names every reason: a halt, a process whose memory is not flat, misses of Kali's own, miss-log
entries overwritten unread or stalls the detector counted after its log filled (either
leaves misses unmatched), failed demo iterations, an arena that changed, anything left behind
after the stop.  The host stalls every program here a few times a minute
by 0.3-9 ms (DESIGN 10), and every process misses the ticks a stall covers: compare with the
cyclictest row, not with zero.  Other real-time work beside the soak (a test suite's Kali
instance) makes the timing meaningless; the report says so (``NOT REPRESENTATIVE``) and
``--wait-quiet S`` waits up to S seconds for it to stop.  Exit status 0 on PASS, 1 on FAIL,
errors or an interrupt, 2 if cyclictest is missing.  Ctrl-C (or SIGTERM) stops the demo,
cyclictest and the instance and reports whether anything was left behind.

    .venv/bin/python scripts/soak.py                                  # 30 min
    .venv/bin/python scripts/soak.py --minutes 2
    .venv/bin/python scripts/soak.py --wait-quiet 600 --json /tmp/soak.json
"""

from __future__ import annotations

import argparse
import json
import math
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import textwrap
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from benchlib import (
    CT_PRIORITY,
    CT_THREADS,
    CYCLICTEST_MISSING,
    DETECT_INTERVAL_US,
    DETECT_LOG_US,
    DETECT_LOST_FRACTION,
    DETECT_PRIORITY,
    DETECT_STALL_FRACTION,
    SPIKE_NODES,
    BenchError,
    CtResult,
    ForeignWatch,
    KaliSnap,
    LostTime,
    MissTail,
    Row,
    chance_seen,
    cpu_times,
    ct_row,
    format_row,
    machine_facts,
    machine_line,
    parse_histfile,
    parse_spikes,
    row_head,
    signals_held,
    snapshot,
    spike_lines,
    spikes_unlogged,
    stalls_before,
    steal_ms,
    to_json,
    unexplained_misses,
    unwind_on_sigterm,
    wait_quiet,
    window_row,
)
from harness import Floor, KaliRun, cell_config, flight_dump, halt_window_ns

from kali_daemons.core import layout
from kali_daemons.core.errors import KaliError
from kali_daemons.runtime.config import KaliConfig
from kali_daemons.runtime.flightrec import attach_ring, read_ring
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher
from kali_daemons.tools.introspect import Introspector

REPO = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG = REPO / "config" / "default.yaml"
DEMO = REPO / "scripts" / "example_carry.py"
DEMO_ROBOTS = ("left", "right")  # the arms example_carry.py moves
FLOOD = REPO / "scripts" / "soak_flood.py"  # issue 24: a client flooding requests
LOCKER = REPO / "scripts" / "soak_locks.py"  # issue 24: a client taking every lock in turn
# The locker is stopped (SIGSTOP) for a random STOP_S and then continued (SIGCONT) for a
# random RUN_S, over and over: a program under a debugger or Ctrl-Z now and then holding a
# lock.  Stops stay below the spinlock's 5 s wait, so the demo's own requests (which share
# the queue's producer lock with it) are delayed, never refused.
STOP_S = (0.01, 0.5)
RUN_S = (0.2, 2.0)
HOSTILE_EXIT_S = 10.0  # after SIGTERM, a hostile client's time to report and exit
GOAL_MINUTES = 30
POLL_S = 0.05  # the loop: miss log (512 entries, at most one per process and tick), fault, demo
SAMPLE_S = 30.0  # RSS sampling period (default of --sample-s)
ITERATION_TIMEOUT_S = 180.0  # an iteration takes ~10 s; the demo's own waits give up at 30 s
MAX_FAILS_IN_ROW = 3  # the demo failing this often in a row ends the soak (FAIL)
DEMO_STOP_S = 5.0  # after SIGINT, the demo's time to stop its arms (kalictl run) before SIGKILL
HALT_EXIT_S = 5.0  # after a halt, the demo's time to exit on its own (it hears of the halt)
# the stall detector's log holds a stall at one wake-up in this many: at 64 (1.6 %) a 30-min
# soak's log filled 17 min in (3.0 % of its wake-ups were later than DETECT_LOG_US), and the
# 101 misses after it could not be matched; 16 is ~1 M nodes, ~48 MB (-m locks them)
DETECT_SHARE = 16
CT_SLACK_S = 60  # cyclictest's -D beyond the window's longest end; it is stopped at the end
SENSITIVITY_US = (50, 100, 200, 1_000_000)  # lost-time limits the report compares (µs)
# The report also counts the machine's doings this long before a miss (not the verdict's
# rule): own misses came right after short stalls that ended just before the tick (soak P:
# 7 of 9 within 0.5 ms, against 3.8 % by chance), the tick then running 2-4x slower (traced).
LEAD_US = 500
SIO_BEFORE = 2  # SIO's ticks before a missed one whose timing the report gives
STDERR_LINES = 6  # of a failed iteration's stderr, kept and printed
# A serious clocked process signalled this long ago and not acknowledged while the wall clock
# ticked on: where its threads are is read (/proc); soak 4 halted on a TG that had not run
# for 27 ms with nothing lost on its CPU
STUCK_MS = 5
STUCK_POLL_S = 0.002  # how often the process table is looked at for one
STUCK_KEEP = 40  # records kept
STACK_FRAMES = 8  # of each thread's kernel stack
WIDTH = 100  # report columns (the cyclictest command and the machine line may be longer)

# "Flat" memory, per process, over the window: growth (end - start) <= the allowance AND the
# fitted trend over the window (slope x window length) <= the allowance, where the allowance
# is max(GROWTH_FLOOR_KIB, GROWTH_FRACTION x the start RSS).  Why these numbers:
# - 1 MiB floor: the allocators move RSS in steps that are not leaks.  Under mlockall every
#   mapping is resident at once: pymalloc takes 1 MiB arenas (Python >= 3.10, 64-bit), glibc
#   grows and trims its heap in >= 128 KiB steps and serves large numpy temporaries from fresh
#   mappings (mmap threshold adapts up to 32 MiB), so one step can land between two samples.
# - 2 % of the start: Kali's daemons are 140-290 MiB resident (Python, numpy, Pinocchio,
#   MuJoCo, rerun), so 3-6 MiB, a few such steps.  A leak of one 64-byte object per servo tick
#   (1 kHz) is 110 MiB in 30 min, one per TG tick (100 Hz) 11 MiB: both far beyond it.  What
#   30 min cannot resolve is a leak of a few KiB per demo iteration; longer runs can.
# - The trend is judged only from MIN_TREND_SAMPLES samples up: a line through fewer points
#   is decided by where one allocator step happens to fall.
GROWTH_FLOOR_KIB = 1024
GROWTH_FRACTION = 0.02
MIN_TREND_SAMPLES = 5
# The web viewer's server (rerun --serve-web, the viewer's child) keeps the dashboard's recent
# data for browsers that connect late, up to dashboard.server_memory_mib: it grows by design
# until it holds that much.  Its limit counts the data, not the server's own overhead: with
# a 16 MiB limit its RSS here levelled off ~25 MiB (1.6x) above where it started and crept
# to 1.9x over the next 2.5 min (at ~2 MiB/min).  It may grow by CAP_OVERHEAD x its limit.
CAP_OVERHEAD = 2.0


# --------------------------------------------------------------------------------------------
# Memory


def rss_kib(pid: int) -> int:
    """VmRSS of ``pid`` in KiB; -1 when the process is gone."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (OSError, ValueError):
        pass
    return -1


def proc_stat(pid: int) -> tuple[str, str, int, int] | None:
    """(comm, state, ppid, pgrp) from /proc/PID/stat; None when the process is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    comm = stat[stat.find("(") + 1 : stat.rfind(")")]
    fields = stat[stat.rfind(")") + 2 :].split()
    return comm, fields[0], int(fields[1]), int(fields[2])


def live_pids(match: Callable[[str, str, int, int], bool]) -> list[int]:
    """Pids of the live (not zombie) processes whose (comm, state, ppid, pgrp) ``match``."""
    out = []
    for entry in os.scandir("/proc"):
        st = proc_stat(int(entry.name)) if entry.name.isdigit() else None
        if st is not None and st[1] not in ("Z", "X") and match(*st):
            out.append(int(entry.name))
    return sorted(out)


class RssLog:
    """VmRSS samples of the Kali processes and their children over the window.

    Children (the viewer's rerun web server) are looked for at every sample, so one that
    starts late is tracked from then on.
    """

    def __init__(self, pids: dict[str, int], caps: dict[int, int]) -> None:
        self.pids = dict(pids)
        self.caps = caps  # pid → KiB it may grow by design (the web viewer's server)
        self.samples: dict[str, list[tuple[float, int]]] = {n: [] for n in pids}
        self.appeared: dict[str, float] = {}  # child → when it was first seen, s

    def discover(self, t_s: float) -> None:
        """Track every child of a Kali process not tracked yet, as ``parent>comm``."""
        parents = {pid: name for name, pid in self.pids.items() if ">" not in name}
        for pid in live_pids(lambda _c, _s, ppid, _g: ppid in parents):
            st = proc_stat(pid)
            if st is None or pid in self.pids.values():
                continue
            name = f"{parents[st[2]]}>{st[0]}"
            while name in self.pids:
                name += "'"
            self.pids[name] = pid
            self.samples[name] = []
            if t_s > 0:
                self.appeared[name] = t_s

    def sample(self, t_s: float) -> None:
        """One VmRSS reading of every tracked process at ``t_s`` into the window."""
        self.discover(t_s)
        for name, pid in self.pids.items():
            kib = rss_kib(pid)
            if kib >= 0:
                self.samples[name].append((t_s, kib))

    def alive(self) -> list[str]:
        """Tracked children still running (after the stop: left behind)."""
        return [f"{n} pid {p}" for n, p in self.pids.items() if ">" in n and rss_kib(p) >= 0]


@dataclass
class Memory:
    """One process's VmRSS over the window and its verdict."""

    name: str
    pid: int
    start_kib: int
    end_kib: int  # -1: gone before the window closed
    growth_kib: int
    allowance_kib: int
    slope_kib_min: float  # NaN: fewer than MIN_TREND_SAMPLES samples
    samples: int
    verdict: str  # flat, GROWS, TREND, GONE; for a capped process: capped, OVER, GONE
    cap_kib: int = 0  # what it may keep by design (the web viewer's server), 0: none
    last_third_slope_kib_min: float = math.nan  # over the window's last third


def fit_slope(samples: list[tuple[float, int]]) -> float:
    """Least-squares slope of (s, KiB) samples in KiB/min; NaN below MIN_TREND_SAMPLES."""
    t = np.array([s for s, _ in samples]) / 60.0
    if len(samples) < MIN_TREND_SAMPLES or np.ptp(t) == 0:
        return math.nan
    return float(np.polyfit(t, np.array([k for _, k in samples], dtype=float), 1)[0])


def judge_memory(
    name: str, pid: int, samples: list[tuple[float, int]], t_end: float, cap_kib: int = 0
) -> Memory:
    """The ``Memory`` row of one process from its samples (the last taken at ``t_end``).

    A process with a cap (the web viewer's server) may grow by CAP_OVERHEAD times its cap on
    top of the allowance; its trend is shown, not judged (it rises until its buffer is full),
    and its slope over the window's last third tells whether it has levelled off.
    """
    if not samples:
        return Memory(name, pid, -1, -1, 0, 0, math.nan, 0, "GONE", cap_kib)
    start = samples[0][1]
    end = samples[-1][1] if samples[-1][0] >= t_end - 1e-3 else -1  # sampled at the end
    allowance = max(GROWTH_FLOOR_KIB, round(GROWTH_FRACTION * start))
    allowance += round(CAP_OVERHEAD * cap_kib)
    slope = fit_slope(samples)
    growth = end - start if end >= 0 else 0
    window_min = (t_end - samples[0][0]) / 60.0
    if end < 0:
        verdict = "GONE"
    elif cap_kib:
        verdict = "OVER" if growth > allowance else "capped"
    elif growth > allowance:
        verdict = "GROWS"
    elif not math.isnan(slope) and slope * window_min > allowance:
        verdict = "TREND"
    else:
        verdict = "flat"
    last = fit_slope([x for x in samples if x[0] >= t_end - window_min * 60.0 / 3])
    return Memory(
        name, pid, start, end, growth, allowance, slope, len(samples), verdict, cap_kib, last
    )


def judge_memory_until(
    samples: dict[str, list[tuple[float, int]]],
    pids: dict[str, int],
    caps: dict[int, int],
    t_end: float,
    halted_at: float | None,
) -> list[Memory]:
    """Every process's ``Memory`` row over the window (samples up to ``t_end``), or, after a
    halt at ``halted_at`` s, over the samples before it, ending at the last sampling instant
    before the halt: the halt's flight-recorder dump grows the wall clock by ~3 MB once (the
    dump, not a leak: ``kalictl estop`` on an idle instance shows the same)."""
    if halted_at is not None:
        before = [t for s in samples.values() for t, _ in s if t <= halted_at]
        t_end = max(before, default=0.0)
        samples = {n: [x for x in s if x[0] <= t_end] for n, s in samples.items()}
    return [judge_memory(n, pids[n], s, t_end, caps.get(pids[n], 0)) for n, s in samples.items()]


# --------------------------------------------------------------------------------------------
# Arena


@dataclass
class ArenaState:
    """The arena's occupancy at one instant (``Arena.stats``, as ``kalictl mem`` shows it)."""

    used_bytes: int
    used_blocks: int
    free_bytes: int
    free_fragments: int
    largest_free: int
    fragmentation: float
    blocks: list[tuple[str, int, int, bool]]  # key, offset, size, used


def arena_state(inst: Instance) -> ArenaState:
    """Copy the arena's statistics and block list (takes its directory lock briefly)."""
    s = inst.arena.stats()
    return ArenaState(
        s.used_bytes,
        s.used_blocks,
        s.free_bytes,
        s.free_fragments,
        s.largest_free,
        s.fragmentation,
        [(b.key, b.offset, b.size, b.used) for b in inst.arena.blocks()],
    )


def arena_changes(a: ArenaState, b: ArenaState) -> list[str]:
    """What differs between two block lists: blocks gone (-) and new (+); a block that moved
    or changed size is both."""
    before, after = set(a.blocks), set(b.blocks)
    out = [f"- {k or 'free'} @{o:#x} {s} B" for k, o, s, _ in sorted(before - after)]
    out += [f"+ {k or 'free'} @{o:#x} {s} B" for k, o, s, _ in sorted(after - before)]
    return out


# --------------------------------------------------------------------------------------------
# The demo


@dataclass
class Iteration:
    """One run of the demo."""

    index: int  # 0: the warm-up
    start_s: float  # into the window (the warm-up: before it, negative)
    seconds: float
    returncode: int | None  # None: stopped by this script (halt, timeout)
    error: str = ""  # why it failed: its stderr tail, or what stopped it
    halted: bool = False  # the system halted while it ran (the halt is the failure)


class Demo:
    """One iteration as a user runs it, ``kalictl -i INSTANCE run example_carry.py``, in its
    own session: a Ctrl-C of this script reaches it only through ``stop``, which then stops
    the arms the way a Ctrl-C under ``kalictl run`` does."""

    def __init__(self, kalictl: str, instance: str, stderr: Path) -> None:
        self.stderr = stderr
        self.t0 = time.monotonic()
        with open(stderr, "wb") as err:
            self.proc = subprocess.Popen(
                [kalictl, "-i", instance, "run", str(DEMO)],
                stdin=subprocess.DEVNULL,
                stdout=subprocess.DEVNULL,
                stderr=err,
                start_new_session=True,
            )

    def elapsed(self) -> float:
        """Seconds since it started."""
        return time.monotonic() - self.t0

    def done(self) -> bool:
        """True once it has exited (and been reaped)."""
        return self.proc.poll() is not None

    def wait(self, timeout: float) -> bool:
        """Wait up to ``timeout`` s for it to exit; True if it did."""
        try:
            self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            return False
        return True

    def stop(self) -> None:
        """SIGINT to its process group (kalictl run stops every arm on its path), then
        SIGKILL to whatever of it is left after DEMO_STOP_S; safe to call twice."""
        for sig in (signal.SIGINT, signal.SIGKILL):
            if not self.left():
                break
            try:
                os.killpg(self.proc.pid, sig)
            except ProcessLookupError:
                break
            self.wait(DEMO_STOP_S)
        self.proc.poll()

    def left(self) -> list[int]:
        """Its processes still running (kalictl run and the program): its process group."""
        group = self.proc.pid
        return live_pids(lambda _c, _s, _p, pgrp: pgrp == group)

    def tail(self) -> str:
        """The last STDERR_LINES lines of its stderr."""
        try:
            lines = self.stderr.read_text(errors="replace").strip().splitlines()
        except OSError:
            return ""
        return "\n".join(lines[-STDERR_LINES:])


class Hostiles:
    """The soak's two hostile clients (issue 24): ``soak_flood.py`` under ``kalictl run``
    (requests as fast as the queue takes them, every outcome waited for) and
    ``soak_locks.py`` (every arena lock taken and released in turn), which ``poll`` stops
    and continues at random.  ``finish`` ends both and returns what they reported."""

    def __init__(self, kalictl: str, instance: str, tmp: Path, seed: int) -> None:
        self.rng = random.Random(seed)
        self.procs: dict[str, subprocess.Popen[str]] = {}
        self.err = {name: tmp / f"{name}.stderr" for name in ("flood", "locker")}
        for name, cmd in (
            ("flood", [kalictl, "-i", instance, "run", str(FLOOD)]),
            ("locker", [sys.executable, str(LOCKER), instance]),
        ):
            with open(self.err[name], "w") as err:
                self.procs[name] = subprocess.Popen(
                    cmd,
                    stdin=subprocess.DEVNULL,
                    stdout=subprocess.PIPE,
                    stderr=err,
                    text=True,
                    start_new_session=True,
                )
        self.stopped = False
        self.stops = 0
        self.stopped_s = 0.0
        self.longest_stop_s = 0.0
        self._since = time.monotonic()
        self._next = self._since + self.rng.uniform(*RUN_S)

    def pids(self) -> list[int]:
        """The hostile clients' pids (so the foreign-work watch leaves them out)."""
        return [p.pid for p in self.procs.values()]

    def poll(self) -> None:
        """Stop or continue the locker when its random time is up."""
        now = time.monotonic()
        if now < self._next or self.procs["locker"].poll() is not None:
            return
        if self.stopped:
            os.kill(self.procs["locker"].pid, signal.SIGCONT)
            self.stopped_s += now - self._since
            self.longest_stop_s = max(self.longest_stop_s, now - self._since)
            self._next = now + self.rng.uniform(*RUN_S)
        else:
            os.kill(self.procs["locker"].pid, signal.SIGSTOP)
            self.stops += 1
            self._next = now + self.rng.uniform(*STOP_S)
        self.stopped = not self.stopped
        self._since = now

    def died(self) -> list[str]:
        """Hostile clients that have exited before ``finish``, with their status."""
        return [f"{n} (exit {p.returncode})" for n, p in self.procs.items() if p.poll() is not None]

    def finish(self) -> dict[str, object]:
        """Continue, end (SIGINT to the flood's ``kalictl run``, SIGTERM to the locker) and
        collect each one's last JSON line, exit status and stderr tail."""
        out: dict[str, object] = {"stops": self.stops, "stopped_s": round(self.stopped_s, 1)}
        out["longest_stop_s"] = round(self.longest_stop_s, 3)
        for name, p in self.procs.items():
            if p.poll() is None:
                os.killpg(p.pid, signal.SIGCONT)
                os.killpg(p.pid, signal.SIGINT if name == "flood" else signal.SIGTERM)
            try:
                text, _ = p.communicate(timeout=HOSTILE_EXIT_S)
            except subprocess.TimeoutExpired:
                os.killpg(p.pid, signal.SIGKILL)
                text, _ = p.communicate()
            lines = [t for t in (text or "").splitlines() if t.startswith("{")]
            try:
                last = json.loads(lines[-1]) if lines else {}
            except json.JSONDecodeError:
                last = {}
            err = self.err[name].read_text(errors="replace").strip().splitlines()
            out[name] = {"exit": p.returncode, "report": last, "stderr": err[-STDERR_LINES:]}
        return out


def kalictl_path() -> str:
    """The kalictl beside this Python (the venv's), else the one on PATH."""
    beside = Path(sys.executable).parent / "kalictl"
    found = str(beside) if beside.is_file() else shutil.which("kalictl")
    if found is None:
        raise BenchError(f"no kalictl beside {sys.executable} or on PATH (scripts/setup.sh)")
    return found


# --------------------------------------------------------------------------------------------
# SIO's side of a miss


# a flight-recorder row as the soak keeps it: tick, then µs late, read to write, asleep for
# the servos, SIO's CPU time (the ring's fields below, in that order)
SioRow = tuple[int, int, int, int, int]
SIO_ROW_FIELDS = ("late_ns", "latency_ns", "wait_ns", "ran_ns")


class SioTail:
    """SIO's timing around every serious miss, from the flight recorder's ring, read as the
    misses come (the ring holds FLIGHT_SECONDS, the loop polls every POLL_S): the ticks
    ``SIO_BEFORE`` before the missed one to the one after, each as (tick, how late SIO woke,
    how long it took from reading the board to writing it, how much of that it slept for the
    servos, and the CPU time it had), in µs.  A miss of Kali's own is then told apart: SIO
    woke late (its CPU was busy or gone), or its tick ran long, in the servos' work, in its
    own, or in neither (its own share far above its CPU time: the CPU did something else).
    """

    def __init__(self, inst: Instance, tail: MissTail, serious: set[str]) -> None:
        a = inst.arena
        self.header = a.existing(layout.KEY_FLIGHT, layout.FLIGHT)
        self.ring = attach_ring(a, self.header)
        self.tail = tail
        self.serious = serious
        self.read = len(tail.rows)
        self.ticks: dict[int, list[SioRow]] = {}

    def poll(self) -> None:
        """Copy the ring's rows around the ticks of the serious misses logged since."""
        new = self.tail.rows[self.read :]
        self.read = len(self.tail.rows)
        ticks = {int(m["tick"]) for m in new if m["process"] in self.serious}
        if not ticks:
            return
        data = read_ring(self.header, self.ring)
        for tick in ticks - self.ticks.keys():
            near = data[(data["tick"] >= tick - SIO_BEFORE) & (data["tick"] <= tick + 1)]
            self.ticks[tick] = [
                (int(r["tick"]), *(int(r[f]) // 1000 for f in SIO_ROW_FIELDS))  # type: ignore[misc]
                for r in near
            ]


def sio_story(tick: int, rows: list[SioRow]) -> str:
    """SIO's ticks around a missed ``tick`` as one line: ``N-1 woke 40 took 280 (servos
    90, ran 150)`` ...; a tick SIO did not serve (it missed it) is absent from the ring, and
    says so."""
    served = {t: (late, took, wait, ran) for t, late, took, wait, ran in rows}
    parts = []
    for t in range(tick - SIO_BEFORE, tick + 2):
        rel = "N" if t == tick else f"N{t - tick:+d}"
        if t in served:
            late, took, wait, ran = served[t]
            parts.append(f"{rel} woke {late} took {took} (servos {wait}, ran {ran})")
        else:
            parts.append(f"{rel} not served")
    head = "SIO (µs late, µs read to write, of which asleep for the servos, its CPU time): "
    return head + "; ".join(parts)


# --------------------------------------------------------------------------------------------
# The soak


@dataclass
class SoakResult:
    """Everything the report prints, also written by ``--json``."""

    instance: str
    config: str
    minutes: float
    sample_s: float
    period_us: int = 0
    machine: dict[str, object] = field(default_factory=dict)
    cyclictest_command: str = ""
    ct_priority: int = CT_PRIORITY
    detector_command: str = ""
    detect_us: int = 0  # a stall longer than this overlapping a miss: the machine's
    lost_us: int = 0  # or a CPU lost this long inside the miss
    log_dir: str = ""
    warmup: Iteration | None = None
    iterations: list[Iteration] = field(default_factory=list)  # in the window
    window_s: float = math.nan  # from the end of the warm-up to the last iteration's end
    memory: list[Memory] = field(default_factory=list)
    rss_samples: dict[str, list[tuple[float, int]]] = field(default_factory=dict)
    children_appeared: dict[str, float] = field(default_factory=dict)
    wakeup: list[Row] = field(default_factory=list)  # cyclictest first, then every process
    misses: dict[str, dict[str, int]] = field(default_factory=dict)  # per process
    unexplained: list[dict[str, object]] = field(default_factory=list)  # with t_s, clock
    misses_lost: int = 0  # miss-log entries overwritten before they were read
    detector_stalls: int = 0
    detector_unlogged: int = 0  # stalls the detector counted after its log filled
    chance_seen: float = math.nan  # share of 1-period windows the machine would explain
    sensitivity: list[dict[str, float]] = field(default_factory=list)  # other lost limits
    lead: dict[str, float] = field(default_factory=dict)  # own with LEAD_US before counted
    arena_start: ArenaState | None = None
    arena_end: ArenaState | None = None
    arena_changes: list[str] = field(default_factory=list)
    clock_overruns: int = 0
    clock_skipped_ticks: int = 0
    fault: str | None = None
    halted_at_s: float | None = None  # into the window (or the warm-up iteration)
    halted_in_warmup: bool = False
    halt_stalls: str | None = None
    flight_dump: str | None = None
    tg_longest: dict[str, float] | None = None  # the TG's longest tick and its parts, µs
    tg_at_halt: dict[str, object] | None = None  # where the TG was in its tick at the halt
    stuck: list[dict[str, object]] = field(default_factory=list)  # StuckWatch.records
    left_behind: list[str] = field(default_factory=list)
    stopped_cleanly: bool = False  # the stop ran and its check was done
    problems: list[str] = field(default_factory=list)  # each one fails the soak
    notes: list[str] = field(default_factory=list)
    error: str | None = None
    verdict: str = ""
    hostile: bool = True  # the flood and locker clients ran beside the demo (issue 24)
    hostiles: dict[str, object] = field(default_factory=dict)  # Hostiles.finish
    hostiles_died: list[str] = field(default_factory=list)  # exited inside the window


def run_iteration(
    demo: Demo, index: int, t0_ns: int, inst: Instance, poll: Callable[[], None]
) -> Iteration:
    """Poll until ``demo`` ends (or the system halts, or it times out) and say how it went."""
    it = Iteration(index, (time.monotonic_ns() - t0_ns) / 1e9 - demo.elapsed(), 0.0, None)
    while not demo.done():
        time.sleep(POLL_S)
        poll()
        if inst.fault["active"]:
            it.halted = True
            break
        if demo.elapsed() > ITERATION_TIMEOUT_S:
            break
    it.seconds = demo.elapsed()
    if it.halted:
        demo.wait(HALT_EXIT_S)  # a waiting program hears of the halt and exits
    if not demo.done():
        demo.stop()
        why = "the system halted" if it.halted else f"timed out after {it.seconds:.0f} s"
        it.error = f"stopped: {why}\n{demo.tail()}".strip()
        return it
    it.returncode = demo.proc.returncode
    it.error = demo.tail() if it.returncode else ""
    return it


def waits_on(pid: int, tid: str) -> str:
    """What thread ``tid`` of ``pid`` waits on in a futex call: the mapping holding the futex
    word (a semaphore's /dev/shm file, or anonymous memory: a lock of the program's own),
    from /proc/<tid>/syscall and /proc/<pid>/maps; '' when it is in no futex call."""
    try:
        fields = Path(f"/proc/{pid}/task/{tid}/syscall").read_text().split()
        if not fields or fields[0] != "202":  # x86-64 futex
            return ""
        addr = int(fields[1], 16)
        for line in Path(f"/proc/{pid}/maps").read_text().splitlines():
            parts = line.split()
            lo, hi = (int(x, 16) for x in parts[0].split("-"))
            if lo <= addr < hi:
                return f"futex at {addr:#x} in {parts[5] if len(parts) > 5 else '[anon]'}"
    except (OSError, ValueError, IndexError):
        return ""
    return f"futex at {addr:#x}, unmapped"


def thread_places(pid: int) -> list[str]:
    """Each thread of process ``pid``, the main thread first (then by id: ids wrap around,
    so a later thread's may be lower): its id, scheduler state, wchan, the futex it waits
    on and the top of its kernel stack (/proc; the stack needs root), one line each; [] if
    it is gone."""
    out = []
    try:
        tids = sorted(os.listdir(f"/proc/{pid}/task"), key=lambda t: (int(t) != pid, int(t)))
    except OSError:
        return out
    for tid in tids:
        base = Path(f"/proc/{pid}/task/{tid}")
        try:
            state = (base / "stat").read_text().rsplit(")", 1)[1].split()[0]
            wchan = (base / "wchan").read_text().strip() or "-"
            try:
                frames = (base / "stack").read_text().splitlines()[:STACK_FRAMES]
            except OSError:
                frames = []
        except OSError:
            continue
        stack = " < ".join(f.split()[-1] for f in frames if f.strip())
        on = waits_on(pid, tid)
        out.append(f"{tid} {state} wchan {wchan}{f' ({on})' if on else ''}: {stack or '-'}")
    return out


class StuckWatch:
    """Where a serious clocked process is while it sits signalled and unacknowledged and the
    wall clock ticks on (``STUCK_MS``): a thread looks at the process table every
    ``STUCK_POLL_S`` and, once per signal, reads each of that process's threads' state,
    wchan and kernel stack (``thread_places``).  A stall of the whole machine stops the clock
    too, so it is not recorded.  ``records``: up to ``STUCK_KEEP``."""

    def __init__(
        self, inst: Instance, names: list[str], phase: Callable[[], object] | None = None
    ) -> None:
        procs = inst.procs
        self.phase = phase  # the TG's place in its tick (Introspector.tg_now), or None
        self.procs, self.clock = procs, inst.clock
        slots = [(n, inst.slot_of(n)) for n in names]
        self.slots = [
            (n, i, int(procs["pid"][i]))
            for n, i in slots
            if int(procs["periodic"][i]) and int(procs["serious"][i])
        ]
        base_ns = int(inst.clock["base_tick_ns"])
        self.after_ns = STUCK_MS * 1_000_000
        self.after_ticks = max(1, self.after_ns // base_ns)
        self.records: list[dict[str, object]] = []
        self._seen: dict[str, int] = {}  # per process: the signal already recorded
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="stuck-watch", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(1.0)

    def look(self) -> None:
        """One look at the process table (what the thread does every ``STUCK_POLL_S``)."""
        procs = self.procs
        now = time.monotonic_ns()
        tick = int(self.clock["tick"])
        for name, slot, pid in self.slots:
            sig = int(procs["signal_tick"][slot])
            if int(procs["ack_tick"][slot]) >= sig or self._seen.get(name) == sig:
                continue
            late_ns = now - int(procs["release_ns"][slot])
            if late_ns < self.after_ns or tick - sig < self.after_ticks:
                continue
            self._seen[name] = sig
            self.records.append(
                {
                    "process": name,
                    "tick": sig,
                    "late_ms": round(late_ns / 1e6, 2),
                    "clock_ticks": tick - sig,
                    "tg_phase": self.phase() if self.phase is not None else None,
                    "threads": thread_places(pid),
                }
            )

    def _run(self) -> None:
        while not self._stop.wait(STUCK_POLL_S) and len(self.records) < STUCK_KEEP:
            self.look()


def soak(res: SoakResult, cfg: KaliConfig, tmp: Path) -> None:
    """Start the instance, warm up, run the demo in a loop through the window beside
    cyclictest, stop everything; fills ``res`` (also when interrupted)."""
    instance = res.instance
    names = [p.name for p in cfg.processes]
    res.period_us = round(cfg.clock.servo_period_ms * 1000)
    res.machine = machine_facts()
    watch = ForeignWatch(instance)
    watch.poll_rt()
    run = KaliRun(cfg, log_dir=tmp, watch=watch, lockstep=False)  # tmp is kept on a failure
    res.log_dir = str(launcher.log_dir(instance))  # $KALI_LOG_DIR/<instance>
    histfile, ct_out, ct_err = (tmp / f"cyclictest.{x}" for x in ("hist", "out", "err"))
    ct_seconds = math.ceil(res.minutes * 60 + ITERATION_TIMEOUT_S) + CT_SLACK_S
    floor = Floor(ct_seconds, res.period_us, histfile, 0, res.ct_priority, out=ct_out, err=ct_err)
    res.cyclictest_command = floor.text
    # the stall detector: room to log a stall at one wake-up in DETECT_SHARE (~47 B a node)
    res.detect_us = round(DETECT_STALL_FRACTION * res.period_us)
    res.lost_us = round(DETECT_LOST_FRACTION * res.period_us)
    wakeups = ct_seconds * CT_THREADS * 1_000_000 // DETECT_INTERVAL_US
    nodes = max(SPIKE_NODES, wakeups // DETECT_SHARE)
    detector = Floor(
        ct_seconds, DETECT_INTERVAL_US, None, DETECT_LOG_US, DETECT_PRIORITY,
        out=tmp / "detector.out", err=tmp / "detector.err", spike_nodes=nodes,
    )  # fmt: skip
    res.detector_command = detector.text
    kalictl = kalictl_path()
    demo: Demo | None = None
    hostiles: Hostiles | None = None
    rss: RssLog | None = None
    stuck: StuckWatch | None = None
    real_offset = time.time_ns() - time.monotonic_ns()
    try:
        run.start()
        inst = run.inst
        assert inst is not None
        # warm-up: the first iteration, outside the window
        demo = Demo(kalictl, instance, tmp / "demo.0.stderr")
        warm_t0 = time.monotonic_ns()
        it = run_iteration(demo, 0, warm_t0, inst, watch.poll_shm)
        it.start_s = -it.seconds
        res.warmup = it
        if it.halted:
            res.fault = inst.fault_text()
            res.halted_in_warmup = True
            res.halted_at_s = (int(inst.fault["time_ns"]) - real_offset - warm_t0) / 1e9
            res.flight_dump = flight_dump(inst)
            return
        # the window
        det = detector.start(watch)
        ct = floor.start(watch)
        if res.hostile:
            hostiles = Hostiles(kalictl, instance, tmp, os.getpid())
            watch.exclude.update(hostiles.pids())
        ct_end = time.monotonic_ns() + ct_seconds * 1_000_000_000
        tail = MissTail(inst)
        sio = SioTail(inst, tail, {p.name for p in cfg.processes if p.serious})
        stuck_spy = Introspector(inst)
        stuck = StuckWatch(inst, names, stuck_spy.tg_now)
        stuck.start()
        s0 = snapshot(inst, names)
        t0 = s0.t_ns
        stat0 = cpu_times()
        res.arena_start = arena_state(inst)
        dash = launcher.dashboard(inst)
        web_cap = {dash.web_pid: cfg.dashboard.server_memory_mib * 1024} if dash else {}
        rss = RssLog(run.pids, web_cap)
        rss.sample(0.0)
        next_sample = t0 + int(res.sample_s * 1e9)
        end = t0 + int(res.minutes * 60e9)

        def poll() -> None:
            nonlocal next_sample
            tail.poll()
            sio.poll()
            watch.poll(ct, ct_end)
            watch.poll(det, ct_end)
            if hostiles is not None:
                hostiles.poll()
            now = time.monotonic_ns()
            if now >= next_sample:
                rss.sample((now - t0) / 1e9)
                next_sample += int(res.sample_s * 1e9)

        fails_in_row = 0
        s1: KaliSnap | None = None
        while True:
            index = len(res.iterations) + 1
            demo = Demo(kalictl, instance, tmp / f"demo.{index}.stderr")
            it = run_iteration(demo, index, t0, inst, poll)
            res.iterations.append(it)
            if it.returncode != 0:
                (tmp / f"demo.{index}.stderr").replace(tmp / f"failed.{index}.stderr")
            if it.halted:
                spy = Introspector(inst)
                res.tg_at_halt = spy.tg_now()  # first: a tick that never ended is there now
                spy.close()
                s1 = snapshot(inst, names)
                res.fault = inst.fault_text()
                t_fault = int(inst.fault["time_ns"]) - real_offset
                res.halted_at_s = (t_fault - t0) / 1e9
                res.flight_dump = flight_dump(inst)
                break
            fails_in_row = fails_in_row + 1 if it.returncode != 0 else 0
            if fails_in_row >= MAX_FAILS_IN_ROW:
                res.problems.append(
                    f"the demo failed {fails_in_row} times in a row; the soak stopped "
                    f"after {(time.monotonic_ns() - t0) / 60e9:.1f} of {res.minutes:g} min"
                )
                break
            (tmp / f"demo.{index}.stderr").unlink(missing_ok=True)
            if time.monotonic_ns() >= end:
                break
        if s1 is None:
            s1 = snapshot(inst, names)
            if inst.fault["active"]:  # halted after the last iteration ended
                res.fault = inst.fault_text()
                res.halted_at_s = (int(inst.fault["time_ns"]) - real_offset - t0) / 1e9
                res.flight_dump = flight_dump(inst)
        res.window_s = (s1.t_ns - t0) / 1e9
        spy = Introspector(inst)
        res.tg_longest = spy.tg_longest()
        spy.close()
        stuck.stop()
        stuck_spy.close()
        res.stuck = stuck.records
        if hostiles is not None:
            res.hostiles_died = hostiles.died()
            res.hostiles = hostiles.finish()
            hostiles = None
        rss.sample(res.window_s)
        res.arena_end = arena_state(inst)
        res.machine["steal_ms"] = steal_ms(stat0, cpu_times())
        tail.poll()
        sio.poll()
        res.misses_lost = tail.lost
        logged = tail.between(names, t0, s1.t_ns)
        for m in logged:
            if m["process"] in sio.serious:
                m["sio"] = sio.ticks.get(int(m["tick"]), [])
        detector.stop()
        floor.stop()
        floor.stopped_output()
        det_text = detector.stopped_output("detector")
        stalls = parse_spikes(det_text, DETECT_INTERVAL_US, res.detect_us)
        lines = spike_lines(det_text)
        lost = LostTime(lines)
        res.detector_unlogged = spikes_unlogged(det_text)
        if res.halted_at_s is not None:
            t_halt = t0 + int(res.halted_at_s * 1e9)
            res.halt_stalls = stalls_before(lines, lost, t_halt, halt_window_ns(cfg))
        hist = parse_histfile(histfile)
        analyse(res, cfg, s0, s1, hist, logged, stalls, lost, t0, real_offset)
    finally:
        with signals_held():
            if stuck is not None:
                stuck.stop()
            if demo is not None:
                demo.stop()
            if hostiles is not None:
                res.hostiles = hostiles.finish()
            detector.stop()
            floor.stop()
            run.stop()
            res.left_behind = list(run.left_behind)
            if demo is not None:
                res.left_behind += [f"demo pid {p}" for p in demo.left()]
            if rss is not None and math.isfinite(res.window_s):
                res.memory = judge_memory_until(
                    rss.samples, rss.pids, rss.caps, res.window_s, res.halted_at_s
                )
                res.rss_samples = rss.samples
                res.children_appeared = rss.appeared
            if rss is not None:
                res.left_behind += rss.alive()
            res.stopped_cleanly = True
        res.notes += watch.notes()


def analyse(
    res: SoakResult,
    cfg: KaliConfig,
    s0: KaliSnap,
    s1: KaliSnap,
    ct_hist: CtResult,
    logged: list[dict[str, object]],
    stalls: list[tuple[int, int]],
    lost: LostTime,
    t0: int,
    real_offset: int,
) -> None:
    """Turn the snapshots, the miss log and cyclictest's output into the report's figures."""
    period = res.period_us
    ct = ct_row("cyclictest", ct_hist, "0,1", period, res.ct_priority)
    res.wakeup = [ct]
    for p in cfg.processes:
        row = window_row(f"kali {p.name}", s0.procs[p.name], s1.procs[p.name], period)
        ratio = row.p999_us / ct.p999_us if ct.p999_us else math.nan
        row.note = f"{ratio:.2f}x"
        res.wakeup.append(row)
    own = unexplained_misses(logged, stalls, lost, res.lost_us * 1000)
    for m in own:
        m["t_s"] = round((int(m["due_ns"]) - t0) / 1e9, 3)
        real_ms = (int(m["due_ns"]) + real_offset) // 1_000_000
        m["clock"] = time.strftime("%H:%M:%S", time.localtime(real_ms // 1000))
        m["clock"] += f".{real_ms % 1000:03d}"
    res.unexplained = own[:1000]
    for p in cfg.processes:
        res.misses[p.name] = {
            "serious": int(p.serious),
            "total": s1.procs[p.name].misses - s0.procs[p.name].misses,
            "logged": sum(m["process"] == p.name for m in logged),
            "unexplained": sum(m["process"] == p.name for m in own),
        }
    res.detector_stalls = len(stalls)
    res.chance_seen = chance_seen(stalls, lost, res.lost_us * 1000, period * 1000, t0, s1.t_ns)
    serious = [m for m in logged if cfg.process(str(m["process"])).serious]
    for limit_us in SENSITIVITY_US:  # how the verdict's rule compares with stricter, looser
        res.sensitivity.append(
            {
                "lost_us": limit_us,
                "own": len(unexplained_misses(serious, stalls, lost, limit_us * 1000)),
                "chance": chance_seen(stalls, lost, limit_us * 1000, period * 1000, t0, s1.t_ns),
            }
        )
    lim = res.lost_us * 1000
    res.lead = {
        "lead_us": LEAD_US,
        "own": len(unexplained_misses(serious, stalls, lost, lim, LEAD_US * 1000)),
        "chance": chance_seen(stalls, lost, lim, (period + LEAD_US) * 1000, t0, s1.t_ns),
    }
    res.clock_overruns = s1.overruns - s0.overruns
    res.clock_skipped_ticks = s1.skipped_ticks - s0.skipped_ticks
    assert res.arena_start is not None and res.arena_end is not None
    res.arena_changes = arena_changes(res.arena_start, res.arena_end)


def judge(res: SoakResult) -> None:
    """Collect every reason the soak fails into ``res.problems`` and set ``res.verdict``."""
    p = res.problems
    if res.error:
        p.append(f"error: {res.error}")
    if res.fault:
        where = "the warm-up iteration" if res.halted_in_warmup else "the window"
        p.append(f"halted {res.halted_at_s:.1f} s into {where}: {res.fault}")
    grew = [f"{m.name} {m.verdict}" for m in res.memory if m.verdict not in ("flat", "capped")]
    if grew:
        p.append(f"memory not flat: {', '.join(grew)}")
    serious = [n for n, m in res.misses.items() if m["serious"]]
    own = sum(res.misses[n]["unexplained"] for n in serious)
    if own:
        p.append(f"{own} misses of serious processes cyclictest did not also see")
    if res.detector_unlogged:
        p.append(
            f"the stall detector's log filled: {res.detector_unlogged} later stalls unlogged, "
            "so misses after it filled could not be matched"
        )
    unread = sum(res.misses[n]["total"] - res.misses[n]["logged"] for n in serious)
    if unread > 0:
        p.append(f"{unread} misses were overwritten in the miss log unread: not matched")
    its = res.iterations + ([res.warmup] if res.warmup is not None else [])
    failed = sum(it.returncode != 0 and not it.halted for it in its)
    if failed:
        p.append(f"{failed} of {len(its)} demo iterations failed (the warm-up included)")
    if res.arena_changes:
        p.append(f"the arena changed while running ({len(res.arena_changes)} blocks)")
    p += hostile_problems(res)
    if res.left_behind:
        p.append(f"left behind after the stop: {', '.join(res.left_behind)}")
    if not res.memory and not res.fault and not res.error:
        p.append("no window was measured")
    goal = (
        f"GOAL {GOAL_MINUTES} min soak"
        if res.minutes >= GOAL_MINUTES
        else f"soak {res.minutes:g} min (the goal is {GOAL_MINUTES} min)"
    )
    if p:
        res.verdict = f"{goal}: FAIL ({'; '.join(p)})"
    else:
        res.verdict = f"{goal}: PASS (memory flat, 0 misses cyclictest did not also see)"
    if any(n.startswith("NOT REPRESENTATIVE") for n in res.notes):
        res.verdict += " - NOT REPRESENTATIVE, see the notes"


def hostile_problems(res: SoakResult) -> list[str]:
    """Why the hostile clients fail the soak: one died inside the window, the flood lost an
    outcome or left a request unresolved, or one of them did nothing."""
    if not res.hostile or not res.hostiles:
        return []
    p = [f"a hostile client exited inside the window: {d}" for d in res.hostiles_died]
    flood = res.hostiles.get("flood", {})
    locker = res.hostiles.get("locker", {})
    fr: dict[str, int] = flood.get("report", {})  # type: ignore[union-attr]
    lr: dict[str, int] = locker.get("report", {})  # type: ignore[union-attr]
    if not fr:
        p.append(f"the flood reported nothing (exit {flood.get('exit')})")
    elif fr.get("lost", 0) or fr.get("unresolved", 0):
        p.append(
            f"the flood lost {fr.get('lost', 0)} outcomes and left {fr.get('unresolved', 0)} "
            f"requests unresolved of {fr.get('requests', 0)}"
        )
    elif not fr.get("requests"):
        p.append("the flood put no request")
    if not lr.get("taken"):
        p.append(f"the locker took no lock (exit {locker.get('exit')})")
    return p


# --------------------------------------------------------------------------------------------
# Output


def wrap(text: str) -> list[str]:
    """A long report line as lines of at most WIDTH columns, the rest indented."""
    return textwrap.wrap(text, WIDTH, subsequent_indent="    ", break_on_hyphens=False)


def _kib(v: int) -> str:
    return "-" if v < 0 else str(v)


def _slope(v: float) -> str:
    return "-" if math.isnan(v) else f"{v:+.1f}"


def format_report(r: SoakResult) -> str:
    """The whole report: set-up, memory, wake-ups, misses, arena, demo, verdict."""
    lines = [
        f"=== soak: {DEMO.name} in a loop, {r.minutes:g} min window, real time ===",
        f"kali: {r.config}, instance '{r.instance}', servo period {r.period_us} µs",
    ]
    if r.machine:
        lines.append(machine_line(r.machine))
    if "steal_ms" in r.machine:
        steal: dict[str, float] = r.machine["steal_ms"]  # type: ignore[assignment]
        lines.append(
            "vCPU steal time in the window: "
            + ", ".join(f"{c} {v:.0f} ms" for c, v in steal.items())
        )
    if r.cyclictest_command:
        lines.append(f"cyclictest (the floor): {r.cyclictest_command}")
    if r.detector_command:
        lines.append(f"stall detector: {r.detector_command}")
    w = r.warmup
    if w is not None and r.halted_in_warmup:
        lines.append(f"warm-up iteration: halted after {w.seconds:.1f} s; no window")
    elif w is not None:
        lines.append(
            f"window: {r.window_s:.1f} s, opened after the warm-up iteration ({w.seconds:.1f} s"
            f"{', FAILED' if w.returncode != 0 else ''}), closed at the end of the last one"
        )
        if w.error:
            lines += ["  warm-up: " + t for t in w.error.splitlines()]
    parts = (format_memory, format_wakeup, format_misses, format_arena, format_demo, format_hostile)
    for part in parts:
        lines += ["", *part(r)]
    lines.append("")
    if r.fault:
        where = "the warm-up iteration" if r.halted_in_warmup else "the window"
        lines += wrap(f"HALTED {r.halted_at_s:.1f} s into {where}: {r.fault}")
        if r.halt_stalls:
            lines += wrap(f"  {r.halt_stalls}")
        lines += wrap(f"  flight recorder: {r.flight_dump or 'no dump'}; logs in {r.log_dir}")
    else:
        lines.append("halt: none")
    if r.fault:
        t = r.tg_at_halt
        where = "between ticks"
        if t:
            where = f"{t['phase']} for {float(t['for_us']):.0f} µs (request {t['seq']})"
        lines += wrap(f"TG at the halt: {where}")
    if r.tg_longest:
        t = r.tg_longest
        lines += wrap(
            f"TG's longest tick: {t['wall_us']:.0f} µs at tick {t['tick']:.0f} "
            f"({t['cpu_us']:.0f} µs CPU): {t['requests']:.0f} requests taken in "
            f"{t['requests_us']:.0f} µs, starting waiting ones {t['starting_us']:.0f} µs, "
            f"{t['motions']:.0f} motions {t['motions_us']:.0f} µs"
        )
    if r.stuck:
        lines += wrap(
            f"stuck: {len(r.stuck)} times a serious process sat signalled and unacknowledged "
            f"{STUCK_MS} ms while the clock ticked on; where its threads were:"
        )
        for rec in r.stuck[:10]:
            lines += wrap(
                f"  {rec['process']} signalled at tick {rec['tick']}, {rec['late_ms']} ms ago "
                f"({rec['clock_ticks']} clock ticks); the TG: {rec['tg_phase'] or 'between ticks'}"
            )
            for t in rec["threads"]:  # type: ignore[attr-defined]
                lines += wrap(f"    {t}")
    left = ", ".join(r.left_behind) if r.left_behind else "nothing"
    lines += wrap(f"left behind after the stop: {left} (processes, /dev/shm objects)")
    for n in r.notes:
        lines += wrap(f"note: {n}")
    lines += ["", r.verdict]
    return "\n".join(lines)


def format_memory(r: SoakResult) -> list[str]:
    """RSS per process at the window's ends, growth, allowance, trend, verdict."""
    if not r.memory:
        return ["memory: not measured"]
    head = (
        f"{'memory (VmRSS KiB)':<20} {'pid':>7} {'start':>8} {'end':>8} {'growth':>8} "
        f"{'allowed':>8} {'KiB/min':>8} {'verdict':>8}"
    )
    lines = [head, "-" * len(head)]
    for m in r.memory:
        lines.append(
            f"{m.name:<20} {m.pid:>7} {_kib(m.start_kib):>8} {_kib(m.end_kib):>8} "
            f"{m.growth_kib:>+8} {m.allowance_kib:>8} {_slope(m.slope_kib_min):>8} "
            f"{m.verdict:>8}"
        )
    n = max(m.samples for m in r.memory)
    end = "at its end" if r.halted_at_s is None else "up to the halt (its dump is not a leak)"
    lines.append(
        f"{n} samples, every {r.sample_s:g} s from the window's start and {end}; KiB/min: "
        "least-squares slope"
    )
    lines.append(
        f"flat: growth and slope x window both <= max({GROWTH_FLOOR_KIB} KiB, "
        f"{GROWTH_FRACTION:.0%} of start); slope judged from {MIN_TREND_SAMPLES} samples"
    )
    for m in r.memory:
        if m.cap_kib:
            lines += wrap(
                f"{m.name}: the web viewer's server keeps up to {m.cap_kib // 1024} MiB "
                f"(dashboard.server_memory_mib) for late browsers: allowed {CAP_OVERHEAD:g}x "
                f"that on top, trend not judged; last third of the window "
                f"{_slope(m.last_third_slope_kib_min)} KiB/min"
            )
    lines += [f"{n} appeared {t:.0f} s into the window" for n, t in r.children_appeared.items()]
    return lines


def format_wakeup(r: SoakResult) -> list[str]:
    """Wake-up lateness of every process beside cyclictest's, with the p99.9 ratio."""
    if not r.wakeup:
        return ["wake-up lateness: not measured"]
    head = row_head(r.period_us, "wake-up lateness")
    lines = [head, "-" * len(head)]
    lines += [format_row(row) for row in r.wakeup]
    lines.append("note column: p99.9 / cyclictest p99.9")
    return lines


def format_misses(r: SoakResult) -> list[str]:
    """Misses per process, those cyclictest did not also see, and when each of those came."""
    if not r.misses:
        return ["missed deadlines: not measured"]
    head = f"{'missed deadlines':<20} {'serious':>7} {'total':>7} {'logged':>7} {'own':>7}"
    lines = [head, "-" * len(head)]
    for name, m in r.misses.items():
        lines.append(
            f"{name:<20} {'yes' if m['serious'] else 'no':>7} {m['total']:>7} "
            f"{m['logged']:>7} {m['unexplained']:>7}"
        )
    lines += wrap(
        f"own: the stall detector saw no stall > {r.detect_us} µs overlap the miss (it logged "
        f"{r.detector_stalls}), and no CPU lose {r.lost_us} µs inside it in pieces > "
        f"{DETECT_LOG_US} µs; a {r.period_us} µs window anywhere would be put down to the "
        f"machine {r.chance_seen:.1%} of the time; wall clock overruns {r.clock_overruns}, "
        f"skipped ticks {r.clock_skipped_ticks}"
    )
    if r.sensitivity:

        def limit(us: float) -> str:
            return "stalls only" if us >= 1_000_000 else f"{us:g} µs"

        lines += wrap(
            "the lost-time limit against others (serious misses left own; a window's chance to "
            "count as the machine's): "
            + "; ".join(
                f"{limit(x['lost_us'])}: {x['own']:g} own, {x['chance']:.1%}" for x in r.sensitivity
            )
        )
    if r.lead:
        lines += wrap(
            f"counting also the {r.lead['lead_us']:g} µs before each miss (a tick right after "
            f"a stall runs slower): {r.lead['own']:g} own, {r.lead['chance']:.1%}; not the "
            "goal's rule"
        )
    for m in r.unexplained[:20]:
        lost: dict[int, int] = m.get("lost_us", {})  # type: ignore[assignment]
        gone = ", ".join(f"CPU {c} {v} µs" for c, v in sorted(lost.items())) or "nothing"
        lines.append(
            f"  own miss: {m['process']} at {m['t_s']:.3f} s ({m['clock']}), tick {m['tick']}, "
            f"{m['consecutive']} in a row; lost inside it: {gone}"
        )
        if "sio" in m:  # a serious process's miss
            rows: list[SioRow] = m["sio"]  # type: ignore[assignment]
            lines += wrap(f"    {sio_story(int(m['tick']), rows)}")
    if len(r.unexplained) > 20:
        lines.append(f"  ... and {len(r.unexplained) - 20} more (--json has them)")
    if r.misses_lost:
        lines.append(f"{r.misses_lost} miss-log entries were overwritten before they were read")
    return lines


def format_arena(r: SoakResult) -> list[str]:
    """The arena's occupancy at the window's ends, and what changed."""
    if r.arena_start is None or r.arena_end is None:
        return ["arena: not measured"]
    head = (
        f"{'arena':<20} {'used B':>9} {'blocks':>7} {'free B':>9} {'fragments':>9} "
        f"{'largest free':>12} {'fragmentation':>13}"
    )
    lines = [head, "-" * len(head)]
    for what, a in (("start", r.arena_start), ("end", r.arena_end)):
        lines.append(
            f"{what:<20} {a.used_bytes:>9} {a.used_blocks:>7} {a.free_bytes:>9} "
            f"{a.free_fragments:>9} {a.largest_free:>12} {a.fragmentation:>13.1%}"
        )
    if r.arena_changes:
        lines += wrap(f"CHANGED while running: {'; '.join(r.arena_changes[:6])}")
    else:
        lines.append("unchanged while running (allocation-static): every block where it was")
    return lines


def format_demo(r: SoakResult) -> list[str]:
    """Iterations in the window, failures (with their stderr), durations."""
    its = r.iterations
    failed = [it for it in its if it.returncode != 0]
    stopped = sum(it.halted for it in its)
    if not its:
        return ["demo iterations: none in the window"]
    d = np.array([it.seconds for it in its])
    lines = [
        f"demo iterations in the window: {len(its)}, failed {len(failed) - stopped}"
        + (f" (and {stopped} ended by the halt)" if stopped else "")
        + f"; duration p50 {np.median(d):.1f} s, min {d.min():.1f} s, max {d.max():.1f} s"
    ]
    for it in failed[:5]:
        rc = "stopped" if it.returncode is None else f"exit {it.returncode}"
        rc += ", at the halt" if it.halted else ""
        lines.append(f"  iteration {it.index} at {it.start_s:.0f} s ({rc}):")
        lines += ["    " + t for t in (it.error or "(no stderr)").splitlines()]
    return lines


def format_hostile(r: SoakResult) -> list[str]:
    """What the flood and the locker did, and what the locker's stops were."""
    if not r.hostile:
        return ["hostile clients: none (--no-hostile)"]
    h = r.hostiles
    if not h:
        return ["hostile clients: did not run"]
    flood = h.get("flood", {})
    locker = h.get("locker", {})
    fr = flood.get("report", {})  # type: ignore[union-attr]
    lr = locker.get("report", {})  # type: ignore[union-attr]
    lines = [
        "hostile clients beside the demo:",
        "  flood (kalictl run soak_flood.py): "
        + ", ".join(f"{k} {v}" for k, v in fr.items())
        + f"; exit {flood.get('exit')}",
        "  locker (soak_locks.py): "
        + ", ".join(f"{k} {v}" for k, v in lr.items())
        + f"; exit {locker.get('exit')}; stopped {h.get('stops')} times for "
        f"{h.get('stopped_s')} s in all, longest {h.get('longest_stop_s')} s",
    ]
    for name in ("flood", "locker"):
        part = h.get(name, {})
        if part.get("exit") not in (0, None):  # type: ignore[union-attr]
            lines += [f"  {name} stderr: {t}" for t in part.get("stderr", [])]  # type: ignore[union-attr]
    return lines


# --------------------------------------------------------------------------------------------
# Main


def main(argv: list[str] | None = None) -> int:
    """Parse options, soak, print the report and the verdict."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument(
        "--minutes", type=float, default=GOAL_MINUTES, help=f"window (default {GOAL_MINUTES})"
    )
    ap.add_argument(
        "--config",
        type=Path,
        default=DEFAULT_CONFIG,
        help="Kali config to start (default config/default.yaml); its instance name is not "
        "used: the soak's instance is soak<pid>",
    )
    ap.add_argument(
        "--sample-s",
        type=float,
        default=SAMPLE_S,
        metavar="S",
        help=f"RSS sampling period (default {SAMPLE_S:g})",
    )
    ap.add_argument(
        "--ct-priority",
        type=int,
        default=CT_PRIORITY,
        metavar="P",
        help=f"cyclictest's SCHED_FIFO priority (default {CT_PRIORITY}, as bench_servo)",
    )
    ap.add_argument(
        "--wait-quiet",
        type=float,
        default=0.0,
        metavar="S",
        help="first wait up to S seconds for other Kali instances (a test suite's) to stop; "
        "they make the timing meaningless (default 0: do not wait, just report them)",
    )
    ap.add_argument(
        "--json", type=Path, default=None, metavar="PATH", help="also write the results to PATH"
    )
    ap.add_argument(
        "--no-hostile",
        action="store_true",
        help="run the demo alone, without the request flood and the lock-taking client that "
        "is stopped and continued at random (issue 24's soak runs them)",
    )
    args = ap.parse_args(argv)
    if args.minutes <= 0:
        ap.error("--minutes must be > 0")
    if args.sample_s < 1:
        ap.error("--sample-s must be >= 1")
    if not 1 <= args.ct_priority <= 99:
        ap.error("--ct-priority must be 1..99")
    unwind_on_sigterm()  # SIGTERM unwinds through soak()'s finally, like Ctrl-C
    if shutil.which("cyclictest") is None:
        print(f"soak: {CYCLICTEST_MISSING}", file=sys.stderr)
        return 2
    if os.sched_getscheduler(0) != os.SCHED_OTHER:
        print("soak: note: this script runs real-time; run it SCHED_OTHER", file=sys.stderr)
    res = SoakResult(f"soak{os.getpid()}", str(args.config), args.minutes, args.sample_s)
    res.ct_priority = args.ct_priority
    res.hostile = not args.no_hostile
    tmp = Path(tempfile.mkdtemp(prefix="soak."))
    t_start = time.monotonic()
    try:
        cfg = cell_config({}, res.instance, args.config)
        res.config = cfg.source
        robots = [r.name for r in cfg.robots]
        if any(n not in robots for n in DEMO_ROBOTS):
            raise BenchError(f"{cfg.source}: robots {robots}; {DEMO.name} moves {DEMO_ROBOTS}")
        wait_quiet(args.wait_quiet, "soak")
        print(
            f"soak: instance {res.instance}, {args.minutes:g} min window after one warm-up "
            f"iteration of {DEMO.name}",
            file=sys.stderr,
            flush=True,
        )
        soak(res, cfg, tmp)
    except KeyboardInterrupt:
        left = ", ".join(res.left_behind) if res.left_behind else "nothing"
        cleaned = "stopped the demo, cyclictest and the instance" if res.stopped_cleanly else ""
        print(
            f"soak: interrupted after {time.monotonic() - t_start:.0f} s "
            f"({len(res.iterations)} iterations in the window); {cleaned}; left behind: {left}",
            file=sys.stderr,
        )
        shutil.rmtree(tmp, ignore_errors=True)
        return 1
    except (KaliError, BenchError, OSError, subprocess.SubprocessError) as exc:
        res.error = f"{type(exc).__name__}: {exc}"
    judge(res)
    status = 1 if res.problems else 0
    try:
        print(format_report(res), flush=True)
        if args.json is not None:
            doc = to_json(res)
            doc["memory_rule"] = {
                "growth_floor_kib": GROWTH_FLOOR_KIB,
                "growth_fraction": GROWTH_FRACTION,
                "min_trend_samples": MIN_TREND_SAMPLES,
                "cap_overhead": CAP_OVERHEAD,
            }
            args.json.write_text(json.dumps(doc, indent=2) + "\n")
    except BrokenPipeError:  # e.g. | head
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    if status:
        print(f"soak: daemon logs and demo stderr kept in {tmp}", file=sys.stderr)
    else:
        shutil.rmtree(tmp, ignore_errors=True)
    return status


if __name__ == "__main__":
    sys.exit(main())
