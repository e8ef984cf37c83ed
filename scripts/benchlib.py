"""Shared machinery of the real-time benchmarks (bench_wallclock.py, bench_servo.py, soak.py).

Kali side: copies of the arena's per-process counters (wake-up lateness histograms, missed
deadlines) taken at the start and end of a window and subtracted, since nothing in the arena
is reset.  Floor: Debian's ``cyclictest`` (rt-tests) run beside Kali with ``--laptop`` (never
touch /dev/cpu_dma_latency, DESIGN 10), its histogram and ``--spike`` log parsed, and the rule
that decides whether cyclictest "also saw" a Kali miss.  Machine facts: CPUs, kernel, steal
time, other real-time work that would make the numbers meaningless.  Output: one table row
format for every latency distribution, and a dataclass-to-JSON helper.

Percentiles are reported at upper bin edges in µs, as ``launcher.percentile`` does: Kali's
histograms have 1 µs bins below 1 ms and log bins (8 per octave) above (``layout.lateness_bin``),
cyclictest's has 1 µs bins, so the two are directly comparable below 1 ms.
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from kali_daemons.core import layout
from kali_daemons.runtime.instance import Instance, decode
from kali_daemons.tools import launcher

CT_PRIORITY = 80
CT_HIST_US = 20_000  # cyclictest histogram range; later wake-ups count as overflows
POLL_S = 1.0  # how often the (SCHED_OTHER) benchmark scans /proc for real-time threads
SHM_POLL_S = 0.1  # how often it lists /dev/shm for other Kali instances (cheap)
SPIKE_US = 300  # cyclictest logs every wake-up later than this, with its CLOCK_MONOTONIC time
SPIKE_FRACTION = 0.3  # cyclictest logs wake-ups later than this many periods (300 µs at 1 ms)
CT_THREADS = 2  # one cyclictest thread pinned per CPU, as bench_wallclock's default
SPIKE_NODES = 200_000
# The stall detector (soak.py): a second cyclictest above every Kali process, sampling each
# CPU four times a servo period, so a stall between the floor's 1 ms samples is seen too and
# no stall it logs can be Kali's own work (the floor, at SCHED_FIFO 80, waits for SIO and
# the SVs on its CPU).  Why not denser: it disturbs what it measures.  Its wake-ups are
# 18 µs late at p50 here (the VM delivering a timer), and at 100 µs they tripled Kali's
# misses: the two-arm demo in a loop, 60 s windows taken in turn, SIO missed 3-18 ticks a
# minute without it (mean 9), 12-42 with it at 100 µs (mean 29), 7-17 at 250 µs (mean 12).
DETECT_PRIORITY = 99
DETECT_INTERVAL_US = 250
DETECT_LOG_US = 50  # it logs every wake-up later than this (its own noise is 5-40 µs)
# A miss counts as the machine's doing when a stall of more than DETECT_STALL_FRACTION servo
# periods overlaps it (200 µs at 1 ms), or one CPU lost DETECT_LOST_FRACTION of a period
# inside it (100 µs) in pieces > DETECT_LOG_US.  Why 0.1: in the soaks, a disturbed CPU ran
# SIO's tick 3-6x slower (80 -> 470 µs with no system call) while the detector saw it lose
# only 50-200 µs a millisecond: what it logs is a lower bound on what the tick lost.
DETECT_STALL_FRACTION = 0.2
DETECT_LOST_FRACTION = 0.1
CYCLICTEST_MISSING = (
    "cyclictest not found; install Debian's rt-tests:\n    apt-get install rt-tests"
)


class BenchError(Exception):
    """The benchmark itself failed (not a PASS/FAIL verdict)."""


# --------------------------------------------------------------------------------------------
# Statistics


@dataclass
class Row:
    """One line of a table: a latency distribution and its deadline misses."""

    name: str
    cpu: str
    prio: str
    samples: int
    p50_us: float
    p99_us: float
    p999_us: float
    max_us: float
    over_period: int  # wake-ups >= one period late
    misses: int  # Kali: wall clock's missed-deadline count; cyclictest: over_period
    note: str = ""


def quantile_upper(hist: np.ndarray, upper_edges: np.ndarray, q: float) -> float:
    """The ``q`` quantile of ``hist`` at its bin's upper edge (``launcher.percentile``'s rule)."""
    total = int(hist.sum())
    if total == 0:
        return math.nan
    b = int(np.searchsorted(np.cumsum(hist), q * total, side="left"))
    return float(upper_edges[min(b, len(hist) - 1)])


KALI_UPPER = np.array([layout.bin_upper_us(b) for b in range(layout.HIST_BINS)])


def highest_upper(hist: np.ndarray, upper_edges: np.ndarray) -> float:
    """Upper edge of the highest non-empty bin, NaN for an empty histogram."""
    nz = np.flatnonzero(hist)
    return float(upper_edges[nz[-1]]) if nz.size else math.nan


# --------------------------------------------------------------------------------------------
# Kali side


@dataclass
class ProcSnap:
    """One process-table slot's counters at one instant (copies, not views)."""

    hist: np.ndarray
    misses: int
    signals: int
    acks: int
    late_max_ns: int
    max_consecutive_misses: int
    cpu: int
    priority: int
    pid: int
    exec_last_ns: int
    exec_max_ns: int
    period_ticks: int  # base ticks between its signals (an SV resting: more than SIO's)


@dataclass
class KaliSnap:
    """The counters of every process of interest, the clock record and the fault record."""

    t_ns: int
    procs: dict[str, ProcSnap]
    tick: int
    overruns: int
    skipped_ticks: int
    fault: str | None


def snapshot(inst: Instance, names: list[str]) -> KaliSnap:
    """Copy the statistics of ``names`` out of the arena (outside any cycle; reads only)."""
    procs: dict[str, ProcSnap] = {}
    t = time.monotonic_ns()  # CLOCK_MONOTONIC: the clock of the arena's due times
    for name in names:
        p = inst.procs[inst.slot_of(name)]
        procs[name] = ProcSnap(
            hist=np.array(p["hist"], dtype=np.int64),
            misses=int(p["misses"]),
            signals=int(p["signals"]),
            acks=int(p["acks"]),
            late_max_ns=int(p["late_max_ns"]),
            max_consecutive_misses=int(p["max_consecutive_misses"]),
            cpu=int(p["cpu"]),
            priority=int(p["priority"]),
            pid=int(p["pid"]),
            exec_last_ns=int(p["exec_last_ns"]),
            exec_max_ns=int(p["exec_max_ns"]),
            period_ticks=int(p["period_ticks"]),
        )
    c = inst.clock
    return KaliSnap(
        t, procs, int(c["tick"]), int(c["overruns"]), int(c["skipped_ticks"]), inst.fault_text()
    )


def kali_row(
    name: str,
    hist: np.ndarray,
    misses: int,
    max_us: float | None,
    cpu: str,
    prio: str,
    period_us: int,
    note: str = "",
) -> Row:
    """A table row from a window histogram; ``max_us`` None: the highest bin's upper edge."""
    return Row(
        name=name,
        cpu=cpu,
        prio=prio,
        samples=int(hist.sum()),
        p50_us=quantile_upper(hist, KALI_UPPER, 0.50),
        p99_us=quantile_upper(hist, KALI_UPPER, 0.99),
        p999_us=quantile_upper(hist, KALI_UPPER, 0.999),
        max_us=highest_upper(hist, KALI_UPPER) if max_us is None else max_us,
        over_period=int(hist[layout.lateness_bin(period_us * 1000) :].sum()),
        misses=misses,
        note=note,
    )


def window_row(name: str, a: ProcSnap, b: ProcSnap, period_us: int, note: str = "") -> Row:
    """The wake-up row of one process over the window between snapshots ``a`` and ``b``."""
    hist = b.hist - a.hist
    exact = b.late_max_ns / 1e3 if b.late_max_ns > a.late_max_ns else None
    prio = str(b.priority) if b.priority else "OTHER"
    cpu = str(b.cpu) if b.cpu >= 0 else "-"
    return kali_row(name, hist, b.misses - a.misses, exact, cpu, prio, period_us, note)


def logged_misses(
    inst: Instance, names: list[str], t0_ns: int, t1_ns: int
) -> list[dict[str, object]]:
    """The misses of ``names`` in the clock's miss log whose due tick lies in [t0, t1]."""
    return [
        m
        for m in launcher.recent_misses(inst)
        if m["process"] in names and t0_ns <= int(m["due_ns"]) <= t1_ns
    ]


class MissTail:
    """Every miss the wall clock logs from now on, read as it comes.

    The arena's miss log keeps only the last MISS_LOG_LEN; polled often enough (the clock
    logs at most one miss per process and tick), nothing is lost, however many a window has.
    """

    def __init__(self, inst: Instance) -> None:
        self.inst = inst
        self.seen = int(inst.misses["count"])
        self.rows: list[dict[str, object]] = []
        self.lost = 0  # overwritten before they were read

    def poll(self) -> None:
        """Copy the entries logged since the last poll (the clock writes each before counting)."""
        log = self.inst.misses
        count = int(log["count"])
        first = max(self.seen, count - layout.MISS_LOG_LEN)
        self.lost += first - self.seen
        for k in range(first, count):
            e = log["entries"][k % layout.MISS_LOG_LEN]
            slot = int(e["slot"])
            self.rows.append(
                {
                    "tick": int(e["tick"]),
                    "process": decode(self.inst.procs[slot]["name"]),
                    "slot": slot,
                    "signal_ns": int(e["signal_ns"]),
                    "due_ns": int(e["due_ns"]),
                    "consecutive": int(e["consecutive"]),
                }
            )
        self.seen = count

    def between(self, names: list[str], t0_ns: int, t1_ns: int) -> list[dict[str, object]]:
        """The misses of ``names`` whose due tick lies in [t0, t1]."""
        return [
            m for m in self.rows if m["process"] in names and t0_ns <= int(m["due_ns"]) <= t1_ns
        ]


@contextlib.contextmanager
def signals_held() -> Iterator[None]:
    """Hold SIGINT/SIGTERM back (delivered afterwards), so cleanup is not cut short."""
    held = {signal.SIGINT, signal.SIGTERM}
    old = signal.pthread_sigmask(signal.SIG_BLOCK, held)
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, old)


def stop_instance(instance: str, pids: list[int]) -> list[str]:
    """Stop ``instance``, reap its daemons (this script started them: they would stay zombies
    until it exits) and check nothing of it is left; what was left, if anything."""
    with signals_held():
        launcher.stop(instance)
        for pid in pids:
            with contextlib.suppress(ChildProcessError):
                os.waitpid(pid, os.WNOHANG)
        left = launcher.shm_objects(instance) + [
            f"pid {p}" for p in launcher.instance_pids(instance)
        ]
        if left:
            launcher.stop(instance)
            left = launcher.shm_objects(instance) + [
                f"pid {p}" for p in launcher.instance_pids(instance)
            ]
    return left


# --------------------------------------------------------------------------------------------
# cyclictest side


def cyclictest_command(
    seconds: int,
    threads: int,
    histfile: Path | None,
    period_us: int,
    spike_us: int = SPIKE_US,
    priority: int = CT_PRIORITY,
    spike_nodes: int = SPIKE_NODES,
) -> list[str]:
    """The cyclictest command line (``--laptop``: never touch /dev/cpu_dma_latency), every
    thread waking every ``period_us`` (``-d 0``: by default thread n adds n x 500 µs).

    With a ``histfile``, the histogram of every wake-up's lateness (``parse_histfile``).
    With ``spike_us`` > 0, every wake-up later than that is logged with its time
    (``parse_spikes``), the first ``spike_nodes`` of them (``spikes_unlogged``).
    """
    cmd = ["cyclictest", "--laptop", "-m", "-p", str(priority), "-i", str(period_us)]
    cmd += [
        "-t",
        str(threads),
        "-d",
        "0",
    ]  # every thread at the period (the default adds 500 µs a thread)
    if threads > 1:
        cmd.append("-a")  # thread N on CPU N
    cmd += ["-q", "-D", f"{seconds}s"]
    if histfile is not None:
        cmd += ["-h", str(CT_HIST_US), f"--histfile={histfile}"]
    if spike_us > 0:
        cmd += [f"--spike={spike_us}", f"--spike-nodes={spike_nodes}"]
    return cmd


def spike_lines(stdout: str) -> list[tuple[int, int, int]]:
    """cyclictest's ``T: n Spike: LAT: TS: US`` lines as (thread, late_us, ts_us).

    TS is the late wake-up in µs of CLOCK_MONOTONIC, the clock Kali's miss log uses; with
    ``-a`` thread n runs on CPU n.
    """
    out = []
    for line in stdout.splitlines():
        parts = line.replace(":", " ").split()
        if len(parts) >= 6 and parts[0] == "T" and parts[2] == "Spike" and parts[4] == "TS":
            out.append((int(parts[1]), int(parts[3]), int(parts[5])))
    return out


def parse_spikes(stdout: str, interval_us: int, min_us: int = 0) -> list[tuple[int, int]]:
    """The wake-ups later than ``min_us`` as stall intervals (start_ns, end_ns).

    A late wake-up shows that its thread (its CPU, ``-a``) did not run from its due time
    until TS, and that it last ran at its previous wake-up, one ``interval_us`` before: the
    stall may have begun anywhere after that, which cyclictest cannot see, so it starts there.
    """
    return [
        ((ts - late - interval_us) * 1000, ts * 1000)
        for _, late, ts in spike_lines(stdout)
        if late > min_us
    ]


def spikes_unlogged(stdout: str) -> int:
    """Late wake-ups cyclictest counted (its ``spikes = N`` line) but did not log: it logs
    the first ``--spike-nodes`` and drops the rest, so a miss after its log filled would
    look like Kali's own."""
    total = 0
    for line in stdout.splitlines():
        if line.startswith("spikes = "):
            total = int(line.split("=", 1)[1])
    return max(0, total - len(spike_lines(stdout)))


class LostTime:
    """How long each CPU was gone, from a cyclictest's logged wake-ups (``spike_lines``).

    A wake-up ``late`` µs late shows its CPU (``-a``) did not run its thread from the due
    time until TS: [TS - late, TS] was lost, at least.  Several short losses add up to as
    much as one long stall: a servo tick that needs most of its period misses either way,
    and a rule that looks only for long stalls sees none of the short ones.
    """

    def __init__(self, lines: list[tuple[int, int, int]]) -> None:
        self.cpus: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for cpu in sorted({t for t, _, _ in lines}):
            mine = sorted((ts, late) for t, late, ts in lines if t == cpu)
            ends = np.array([ts for ts, _ in mine], dtype=np.int64) * 1000
            starts = ends - np.array([late for _, late in mine], dtype=np.int64) * 1000
            self.cpus[cpu] = (starts, ends)

    def within(self, lo_ns: int, hi_ns: int) -> dict[int, int]:
        """Per CPU, the ns it lost inside [lo, hi] (only CPUs that lost some)."""
        out = {}
        for cpu, (starts, ends) in self.cpus.items():
            a = int(np.searchsorted(ends, lo_ns, side="right"))
            b = int(np.searchsorted(starts, hi_ns, side="left"))
            if b > a:
                lost = np.minimum(ends[a:b], hi_ns) - np.maximum(starts[a:b], lo_ns)
                out[cpu] = int(lost[lost > 0].sum())
        return out


def unexplained_misses(
    misses: list[dict[str, object]],
    stalls: list[tuple[int, int]],
    lost: LostTime | None = None,
    lost_limit_ns: int = 0,
    lead_ns: int = 0,
) -> list[dict[str, object]]:
    """The Kali misses during which cyclictest saw no stall: Kali's own, not the machine's.

    A miss means the process did not acknowledge between its signal's due time and the next
    due tick; cyclictest "also saw it" when one of its stalls (``parse_spikes``: from the
    thread's last wake-up before a late one to the late one) overlaps that interval, or,
    with ``lost``, when one CPU lost at least ``lost_limit_ns`` inside it in short pieces.
    With ``lead_ns`` the interval starts that long before the signal: what the machine did
    just before a tick counts too.  Each miss of Kali's own is returned with ``lost_us``:
    what each CPU lost inside it.
    """
    starts = np.array(sorted(s for s, _ in stalls), dtype=np.int64)
    ends = np.array([e for _, e in sorted(stalls)], dtype=np.int64)
    out = []
    for m in misses:
        lo, hi = int(m["signal_ns"]) - lead_ns, int(m["due_ns"])
        k = int(np.searchsorted(starts, hi, side="right"))  # stalls starting before hi
        if k and ends[:k].max() >= lo:
            continue
        inside = lost.within(lo, hi) if lost is not None else {}
        if inside and max(inside.values()) >= lost_limit_ns:
            continue
        out.append(m | {"lost_us": {c: v // 1000 for c, v in inside.items()}})
    return out


def chance_seen(
    stalls: list[tuple[int, int]],
    lost: LostTime | None,
    lost_limit_ns: int,
    window_ns: int,
    t0_ns: int,
    t1_ns: int,
    n: int = 20_000,
) -> float:
    """The share of ``n`` windows ``window_ns`` long, evenly spaced over [t0, t1], that
    ``unexplained_misses`` would count as also seen: how often a miss placed at random would
    be put down to the machine, so how much an "also seen" can be luck."""
    step = (t1_ns - t0_ns - window_ns) / n
    if step <= 0:
        return math.nan
    starts = (t0_ns + np.arange(n) * step).astype(np.int64)
    windows: list[dict[str, object]] = [
        {"signal_ns": int(x), "due_ns": int(x) + window_ns} for x in starts
    ]
    return 1.0 - len(unexplained_misses(windows, stalls, lost, lost_limit_ns)) / n


def stalls_before(
    lines: list[tuple[int, int, int]], lost: LostTime, t_ns: int, window_ns: int
) -> str:
    """What cyclictest saw of the machine when Kali halted at ``t_ns`` (CLOCK_MONOTONIC), from
    its ``spike_lines`` and their ``LostTime``: the time each CPU (thread, ``-a``) lost in the
    ``window_ns`` before it (the serious tolerance: what decides a halt) and in five times
    that, and its longest stall ending in the second before or just after.

    Lost time, because a host that takes most of a CPU in pieces of a few hundred µs halts
    Kali as surely as one long stall: a soak halted with CPU 0 losing 15 ms of the 20 before,
    when its longest stall was 1.5 ms.  Another halted with nothing lost: that one was
    Kali's.  Five windows, because a stall can end before the tolerance does: the clock
    counts a late process's misses only in ticks it runs, and the process may still be
    finishing the tick the stall slowed (a soak's SIO halt came 48 ms after its last
    acknowledgement, CPU 0 having lost 25 ms of the 30 before the last 20).
    """

    def lost_in(ns: int) -> str:
        per_cpu = lost.within(t_ns - ns, t_ns)
        cpus = ", ".join(f"CPU {c} {v / 1e6:.1f} ms" for c, v in sorted(per_cpu.items()))
        return f"in {ns / 1e6:g} ms {cpus or 'nothing'}"

    head = f"time cyclictest's CPUs lost before the halt: {lost_in(window_ns)}; "
    head += lost_in(5 * window_ns)
    longest: dict[int, tuple[int, int]] = {}
    for thread, late_us, ts_us in lines:
        end_ns = ts_us * 1000
        near = t_ns - 1_000_000_000 <= end_ns <= t_ns + 100_000_000
        if near and late_us > longest.get(thread, (0, 0))[0]:
            longest[thread] = (late_us, end_ns)
    if not longest:
        return f"{head}; no stall in the second before it"

    def when(end_ns: int) -> str:
        d = (t_ns - end_ns) / 1e6
        return f"{d:.0f} ms before it" if d >= 0 else f"{-d:.0f} ms after it"

    return f"{head}; longest stall in the second before it: " + ", ".join(
        f"CPU {c} {late / 1000:.1f} ms (ended {when(end)})"
        for c, (late, end) in sorted(longest.items())
    )


@dataclass
class CtResult:
    """cyclictest's histogram (all threads summed) and its summary lines."""

    hist: np.ndarray  # CT_HIST_US 1 µs bins, then one overflow bin
    max_us: list[int]
    overflows: list[int]
    threads: int


def parse_histfile(path: Path) -> CtResult:
    """Read a ``--histfile``: rows ``bin count [count ...]`` then ``# Max Latencies:`` etc."""
    hist = np.zeros(CT_HIST_US + 1, dtype=np.int64)
    max_us: list[int] = []
    overflows: list[int] = []
    threads = 0
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            key, _, rest = line[1:].partition(":")
            values = [int(v) for v in rest.split()] if rest.strip() else []
            if key.strip() == "Max Latencies":
                max_us = values
            elif key.strip() == "Histogram Overflows":
                overflows = values
            continue
        parts = line.split()
        if not parts:
            continue
        b = int(parts[0])
        counts = [int(v) for v in parts[1:]]
        threads = max(threads, len(counts))
        if 0 <= b < CT_HIST_US:
            hist[b] += sum(counts)
    if threads == 0 or not max_us:
        raise BenchError(f"cyclictest histogram {path} has no data or no summary lines")
    hist[CT_HIST_US] = sum(overflows)
    return CtResult(hist, max_us, overflows, threads)


def ct_row(name: str, ct: CtResult, cpu: str, period_us: int, priority: int = CT_PRIORITY) -> Row:
    """The table row of one cyclictest run (percentiles at upper bin edges, like Kali's)."""
    upper = np.arange(1, CT_HIST_US + 2, dtype=np.float64)
    upper[CT_HIST_US] = max(max(ct.max_us), CT_HIST_US)  # overflow bin: up to the true max
    over = int(ct.hist[period_us:].sum())
    return Row(
        name=name,
        cpu=cpu,
        prio=str(priority),
        samples=int(ct.hist.sum()),
        p50_us=quantile_upper(ct.hist, upper, 0.50),
        p99_us=quantile_upper(ct.hist, upper, 0.99),
        p999_us=quantile_upper(ct.hist, upper, 0.999),
        max_us=float(max(ct.max_us)),
        over_period=over,
        misses=over,
        note=f"{ct.threads} thread{'s' if ct.threads > 1 else ''}",
    )


def stop_cyclictest(ct: subprocess.Popen[str] | None) -> None:
    """End a cyclictest that is still running and leave nothing of it behind.

    SIGINT first: cyclictest then exits cleanly and removes its /dev/shm/cyclictest<pid>
    (SIGKILL would leave that file); SIGKILL only if it has not gone within 2 s.
    """
    if ct is None:
        return
    if ct.poll() is None:
        ct.send_signal(signal.SIGINT)
        try:
            ct.wait(timeout=2.0)
        except subprocess.TimeoutExpired:
            ct.kill()
            ct.wait()
    Path(f"/dev/shm/cyclictest{ct.pid}").unlink(missing_ok=True)


def run_cyclictest_alone(
    seconds: int, threads: int, tmp: Path, period_us: int
) -> tuple[list[str], CtResult]:
    """Run cyclictest to completion with nothing of Kali running."""
    histfile = tmp / "cyclictest-alone.hist"
    cmd = cyclictest_command(seconds, threads, histfile, period_us)
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=seconds + 30, check=False)
    if proc.returncode != 0:
        raise BenchError(f"cyclictest exited {proc.returncode}: {proc.stderr.strip()}")
    return cmd, parse_histfile(histfile)


# --------------------------------------------------------------------------------------------
# Machine facts


def foreign_rt_tasks(exclude: set[int]) -> dict[int, str]:
    """User-space SCHED_FIFO/RR threads not in ``exclude`` (pids): {tid: command line}.

    Other programs at real-time priority (e.g. another Kali instance started by a test suite)
    compete with both sides of the benchmark on two CPUs and make the numbers meaningless.
    """
    found: dict[int, str] = {}
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit() or int(entry.name) in exclude:
            continue
        try:
            tasks = os.listdir(f"/proc/{entry.name}/task")
        except OSError:
            continue
        for tid in tasks:
            try:
                stat = Path(f"/proc/{entry.name}/task/{tid}/stat").read_text()
            except OSError:
                continue
            fields = stat[stat.rfind(")") + 2 :].split()
            state, ppid, policy = fields[0], int(fields[1]), int(fields[38])  # fields 3, 4, 41
            if entry.name == "2" or ppid == 2 or policy not in (os.SCHED_FIFO, os.SCHED_RR):
                continue  # kernel threads, and everything not real-time
            if state in ("Z", "X"):
                continue  # exited, not yet reaped (e.g. a previous run's daemons): never runs
            try:
                argv = Path(f"/proc/{entry.name}/cmdline").read_bytes().split(b"\0")
            except OSError:
                argv = [b"?"]
            found[int(tid)] = " ".join(a.decode(errors="replace") for a in argv if a)[:100]
    return found


class ForeignWatch:
    """Other real-time work beside the benchmark: foreign RT threads, other Kali instances.

    A test suite's Kali instance (lockstep mode never sleeps, at SCHED_FIFO 80-90) can come
    and go within a second, so /dev/shm is listed every SHM_POLL_S and /proc every POLL_S.
    """

    def __init__(self, instance: str) -> None:
        self.own_segment = "kali." + instance
        self.exclude = {os.getpid()}
        self.rt: dict[int, str] = {}
        self.rt_polls = 0
        self.rt_polls_with = 0
        self.segments: set[str] = set()
        self._next_rt = 0

    def poll(self, ct: subprocess.Popen[str], end_ns: int) -> None:
        """Once per turn of a window's loop: /dev/shm every call, /proc every POLL_S, and a
        BenchError if cyclictest ended more than 2 s before the window's end ``end_ns``."""
        self.poll_shm()
        now = time.monotonic_ns()
        if now < self._next_rt:
            return
        self._next_rt = now + int(POLL_S * 1e9)
        self.poll_rt()
        if ct.poll() is not None and now < end_ns - 2_000_000_000:
            err = ct.stderr.read() if ct.stderr else ""
            raise BenchError(f"cyclictest exited early ({ct.returncode}): {err}")

    def poll_shm(self) -> None:
        """Note every other Kali segment in /dev/shm."""
        for name in os.listdir("/dev/shm"):
            if name.startswith("kali.") and name != self.own_segment:
                self.segments.add(name)

    def poll_rt(self) -> None:
        """Note every real-time thread that is not the benchmark's."""
        seen = foreign_rt_tasks(self.exclude)
        self.rt_polls += 1
        self.rt_polls_with += bool(seen)
        self.rt.update(seen)

    def notes(self) -> list[str]:
        """Warnings for the report; empty when the machine was the benchmark's alone."""
        notes = []
        if self.rt:
            some = "; ".join(f"{tid}: {cmd}" for tid, cmd in sorted(self.rt.items())[:3])
            notes.append(
                f"NOT REPRESENTATIVE: {len(self.rt)} foreign real-time threads ran beside the "
                f"benchmark (in {self.rt_polls_with} of {self.rt_polls} scans of /proc), "
                f"e.g. {some}"
            )
        if self.segments:
            notes.append(
                "NOT REPRESENTATIVE: other Kali instances existed during the window "
                f"(/dev/shm/{', /dev/shm/'.join(sorted(self.segments))})"
            )
        return notes


def wait_quiet(limit_s: float, who: str, max_load: float | None = None) -> None:
    """Wait up to ``limit_s`` for other Kali instances (e.g. a test suite's) to go away, and
    with ``max_load`` for the 1-minute load average to drop below it; ``who`` (the
    benchmark's name) says so on stderr once."""
    deadline = time.monotonic() + limit_s
    said = False
    while True:
        others = [n for n in os.listdir("/dev/shm") if n.startswith("kali.")]
        load = os.getloadavg()[0]
        busy = max_load is not None and load >= max_load
        if not (others or busy) or time.monotonic() > deadline:
            return
        if not said:
            what = f"{len(others)} other Kali instances ({', '.join(others[:3])}) to stop"
            if max_load is not None:
                what += f" and the load average to drop below {max_load:g} (now {load:.2f})"
            print(f"{who}: waiting up to {limit_s:g} s for {what}", file=sys.stderr, flush=True)
            said = True
        time.sleep(1.0)


def cpu_times() -> dict[str, list[int]]:
    """Per-CPU counters of /proc/stat in USER_HZ ticks: {"cpu0": [user, nice, ..., steal]}."""
    out = {}
    for line in Path("/proc/stat").read_text().splitlines():
        name, *values = line.split()
        if name.startswith("cpu") and name != "cpu":
            out[name] = [int(v) for v in values]
    return out


def steal_ms(before: dict[str, list[int]], after: dict[str, list[int]]) -> dict[str, float]:
    """Time the hypervisor ran something else instead of each vCPU (field 8, steal), in ms."""
    tick_ms = 1000 / os.sysconf("SC_CLK_TCK")
    return {c: (after[c][7] - before[c][7]) * tick_ms for c in sorted(after) if c in before}


def machine_facts() -> dict[str, object]:
    """What the numbers depend on: CPUs, kernel, load, RT throttling, cyclictest version."""
    facts: dict[str, object] = {
        "nproc": len(os.sched_getaffinity(0)),
        "kernel": os.uname().release,
        "loadavg": Path("/proc/loadavg").read_text().split()[:3],
    }
    try:
        facts["sched_rt_runtime_us"] = int(Path("/proc/sys/kernel/sched_rt_runtime_us").read_text())
    except OSError:
        facts["sched_rt_runtime_us"] = None
    out = subprocess.run(["cyclictest", "--help"], capture_output=True, text=True, check=False)
    first = (out.stdout or out.stderr).splitlines()
    facts["cyclictest"] = first[0].strip() if first else "unknown"
    return facts


def run_ns(pid: int) -> int:
    """Scheduler run time of every thread of ``pid``, ns (/proc schedstat, exact unlike utime's
    ticks; host stalls count as run time); -1 when the process is gone."""
    try:
        return sum(
            int((task / "schedstat").read_text().split()[0])
            for task in Path(f"/proc/{pid}/task").iterdir()
        )
    except (OSError, ValueError):
        return -1


def machine_line(m: dict[str, object]) -> str:
    """``machine_facts`` as one report line."""
    load = " ".join(m["loadavg"])  # type: ignore[arg-type]
    return (
        f"machine: nproc {m['nproc']}, kernel {m['kernel']}, load {load}, "
        f"sched_rt_runtime_us {m['sched_rt_runtime_us']}, {m['cyclictest']}"
    )


# --------------------------------------------------------------------------------------------
# Output


def us(v: float) -> str:
    """A µs figure for a table: whole µs, ``nan`` when there is none."""
    return "nan" if math.isnan(v) else f"{v:.0f}"


def rate(count: int, samples: int) -> str:
    """``count`` per 100k ``samples``."""
    return f"{1e5 * count / samples:.1f}" if samples else "nan"


def period_label(period_us: int) -> str:
    """``1ms`` or ``500us``: the column heading of wake-ups at least one period late."""
    return f"{period_us // 1000}ms" if period_us % 1000 == 0 else f"{period_us}us"


def row_head(period_us: int, first: str = "", width: int = 18) -> str:
    """The heading of a table of ``Row``s."""
    late = ">=" + period_label(period_us)
    return (
        f"{first:<{width}} {'cpu':>4} {'prio':>5} {'samples':>8} {'p50':>6} {'p99':>6} "
        f"{'p99.9':>6} {'max':>7} {late:>7} {'misses':>6}  (lateness in µs)"
    )


def format_row(row: Row, width: int = 18) -> str:
    """One ``Row`` under ``row_head``."""
    text = (
        f"{row.name:<{width}} {row.cpu:>4} {row.prio:>5} {row.samples:>8} "
        f"{us(row.p50_us):>6} {us(row.p99_us):>6} {us(row.p999_us):>6} "
        f"{us(row.max_us):>7} {row.over_period:>7} {row.misses:>6}"
    )
    return text + (f"  {row.note}" if row.note else "")


def to_json(result: object) -> dict[str, object]:
    """A result dataclass as plain JSON (NaN as null)."""

    def clean(v: object) -> object:
        if isinstance(v, float) and math.isnan(v):
            return None
        if isinstance(v, dict):
            return {k: clean(x) for k, x in v.items()}
        if isinstance(v, list | tuple):
            return [clean(x) for x in v]
        return v

    return clean(asdict(result))  # type: ignore[call-overload, return-value]


def _terminate(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def unwind_on_sigterm() -> None:
    """Make SIGTERM unwind like Ctrl-C, so every ``finally`` stops its Kali instance."""
    signal.signal(signal.SIGTERM, _terminate)
