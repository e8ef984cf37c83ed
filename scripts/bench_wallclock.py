"""Benchmark: the wall clock driving four 1 ms processes, beside cyclictest as the floor.

What is measured.  A Kali instance (``config/bench_wallclock.yaml``: tg, sio, sv.0 and sv.1 all
at 1 ms, real-time mode) runs for ``--seconds`` while Debian's ``cyclictest`` (rt-tests) runs on
the same machine at the same time, so both see the same machine state.  For each of the four
1 ms processes, and for their union, the script reports the wake-up lateness (due time of the
tick to the moment the process returns from its semaphore wait; the arena's per-process
histogram) and the missed deadlines the wall clock counted.  For cyclictest it reports the same
percentiles from its histogram, and as its "misses" the wake-ups at least one period (1000 µs)
late.  Start-up is excluded: the Kali statistics are snapshotted when the window opens and
subtracted at the end (nothing in the arena is reset).

How to read it.  Percentiles are upper bin edges in µs, as ``launcher.percentile`` reports
them: Kali's histogram has 1 µs bins below 1 ms and log bins (8 per octave) above; cyclictest's
has 1 µs bins, so the two are directly comparable below 1 ms.  ``max`` is exact where the source
has it (cyclictest's summary; Kali's ``late_max_ns`` when it grew inside the window), else the
upper edge of the highest non-empty bin.  ``>=1ms`` counts wake-ups at least one period late on
every row (like for like); ``misses`` is the wall clock's missed-deadline counter for Kali rows
(a due tick whose previous signal was still unacknowledged; one stall can cost several) and the
``>=1ms`` count for cyclictest (which skips ahead after a stall, so one stall is one sample).
The targets (from the issue): p99.9 of the four processes together within 3x cyclictest's, and
no missed deadline that cyclictest does not also see.  For the second, cyclictest logs every
wake-up later than SPIKE_US with its CLOCK_MONOTONIC time (``--spike``) and the wall clock logs
every miss with the due times of the unacknowledged signal and of the tick that found it (the
arena's miss log); a Kali miss counts as "also seen" when a cyclictest stall overlaps it.
The verdicts are printed; the exit status is 0 whatever they are (1 on errors, 2 if cyclictest
is not installed).

Floor.  By default cyclictest runs two threads, one pinned per CPU (``-t 2 -a``), because the
four Kali processes are spread over both CPUs and a host stall of either vCPU then shows up on
both sides; ``--ct-threads 1`` runs the single floating thread of the issue's command instead.
``--floor-alone`` also runs cyclictest alone before Kali starts, to show how much the Kali
processes (SCHED_FIFO 84-90, above cyclictest's 80) disturb the floor measured beside them.

Placement (DESIGN 10 item 2), measured with this script in 30 s runs, interleaved: keeping
default.yaml's (clock, sio, sv.0 on CPU 0; plant, tg, sv.1 on CPU 1) gave p50 65-96 µs and
p99.9 218-567 µs for the four, with one halt in five runs; the four with the clock on CPU 0
had the lowest p50 on a calm machine (52 µs) but three halts in five (tg queues behind
everything there); all four on CPU 1 gave p50 79-104 µs; unbound gave p50 75-93 µs with two
halts in five.  The machine itself varied more than that (cyclictest p99.9 70-554 µs within
the hour), so default.yaml's placement is kept.

A halt is a DEADLINE fault: a serious process unacknowledged for longer than
``clock.serious_miss_tolerance_ms`` (20 ms in default.yaml) halts the instance, and the rows
then cover only the part of the window before it (the report says so).  With the earlier
tolerance of 3 consecutive misses, every 60 s run here halted on a host stall of one vCPU
(cyclictest saw up to 19 ms); ``--miss-tolerance MS`` overrides the tolerance.

    .venv/bin/python scripts/bench_wallclock.py                # 60 s, prints the table
    .venv/bin/python scripts/bench_wallclock.py --seconds 10 --json /tmp/bench.json
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from benchlib import (
    CYCLICTEST_MISSING,
    SHM_POLL_S,
    SPIKE_US,
    BenchError,
    ForeignWatch,
    Row,
    cpu_times,
    ct_row,
    kali_row,
    logged_misses,
    machine_facts,
    machine_line,
    parse_spikes,
    rate,
    run_cyclictest_alone,
    spikes_unlogged,
    steal_ms,
    to_json,
    unexplained_misses,
    unwind_on_sigterm,
    window_row,
)
from harness import Floor, Goal, KaliRun, Window, cell_config, rows_table

from kali_daemons.core import layout
from kali_daemons.core.errors import KaliError
from kali_daemons.runtime.config import KaliConfig, load_config

REPO = Path(__file__).resolve().parent.parent
DEFAULT_CONFIG = REPO / "config" / "bench_wallclock.yaml"
PERIOD_US = 1000  # the period of the processes under test and of cyclictest (-i)
GOAL_P999 = Goal("the clock chain's wake-up tail", "p99.9 kali (all) / cyclictest", "<=", 3.0, "x")
SETTLE_S = 1.0  # after start: let the first ticks' transients pass before the window opens
DRIVEN_KINDS = ("tg", "sio", "sv")  # clock-driven processes; the ones at 1 ms are under test


@dataclass
class Result:
    """Everything the script prints, also written by ``--json``."""

    machine: dict[str, object]
    config: str
    instance: str
    seconds: float
    cyclictest_command: str
    rows: list[Row]
    reference_rows: list[Row]
    sched_fifo: dict[str, int]
    clock_overruns: int
    clock_skipped_ticks: int
    max_consecutive_misses: dict[str, int]
    fault: str | None
    p999_ratio: float
    p999_pass: bool
    kali_misses: int
    cyclictest_over_period: int
    misses_logged: int  # Kali misses in the window found in the clock's miss log
    misses_kali_only: list[dict[str, object]]  # of those, the ones cyclictest did not also see
    cyclictest_stalls: int  # cyclictest wake-ups later than SPIKE_US
    misses_pass: bool
    floor_alone: Row | None = None
    floor_alone_command: str | None = None
    notes: list[str] = field(default_factory=list)


def under_test(cfg: KaliConfig) -> list[str]:
    """The clock-driven processes running every PERIOD_US, in config order."""
    names = [
        p.name
        for p in cfg.processes
        if p.kind in DRIVEN_KINDS and round(p.period_ms * 1000) == PERIOD_US
    ]
    if not names:
        raise BenchError(f"{cfg.source}: no tg/sio/sv process runs at {PERIOD_US // 1000} ms")
    return names


def measure(cfg: KaliConfig, seconds: int, ct_threads: int, floor_alone: bool) -> Result:
    """Start Kali, run cyclictest beside it for ``seconds``, stop Kali; the table's numbers."""
    instance = cfg.instance
    names = under_test(cfg)
    reference = [n for n in ("wallclock", "plant") if n in {p.name for p in cfg.processes}]
    facts = machine_facts()
    notes: list[str] = []
    where = "0,1" if ct_threads > 1 else "any"
    with tempfile.TemporaryDirectory(prefix="bench_wallclock.") as tmpdir:
        tmp = Path(tmpdir)
        alone_row, alone_cmd = None, None
        if floor_alone:
            cmd_alone, ct_alone = run_cyclictest_alone(seconds, ct_threads, tmp, PERIOD_US)
            alone_row = ct_row("cyclictest alone", ct_alone, where, PERIOD_US)
            alone_cmd = shlex.join(cmd_alone)
        floor = Floor(seconds, PERIOD_US, tmp / "cyclictest.hist", threads=ct_threads)
        watch = ForeignWatch(instance)
        watch.poll_rt()
        run = KaliRun(cfg, watch=watch, lockstep=False)
        with run, floor:
            inst = run.inst
            assert inst is not None
            time.sleep(SETTLE_S)
            ct = floor.start(watch)
            window = Window(inst, names + reference)
            s0 = window.open().kali
            stat0 = cpu_times()
            if s0.fault:
                raise BenchError(f"the instance halted before the window opened: {s0.fault}")
            end = s0.t_ns + seconds * 1_000_000_000
            while (left := end - time.monotonic_ns()) > 0:
                time.sleep(min(SHM_POLL_S, left / 1e9))
                watch.poll(ct, end)
            s1 = window.close().kali
            facts["steal_ms"] = steal_ms(stat0, cpu_times())
            logged = logged_misses(inst, names, s0.t_ns, s1.t_ns)
            sched = {n: s1.procs[n].priority for n in names + reference}
            ct_res, out = floor.finish()
            assert ct_res is not None
            stalls = parse_spikes(out, PERIOD_US)
            if unlogged := spikes_unlogged(out):
                notes.append(f"cyclictest's spike log filled: {unlogged} later stalls unlogged")
        notes += run.notes()

    rows = [floor.row(ct_res, cpu=where)]
    for n in names:
        rows.append(window_row(f"kali {n}", s0.procs[n], s1.procs[n], PERIOD_US))
    union = sum((s1.procs[n].hist - s0.procs[n].hist for n in names), np.zeros(1, np.int64))
    union_misses = sum(s1.procs[n].misses - s0.procs[n].misses for n in names)
    union_max = max(row.max_us for row in rows[1:])
    cpus = ",".join(sorted({str(s1.procs[n].cpu) if s1.procs[n].cpu >= 0 else "-" for n in names}))
    rows.append(
        kali_row(f"kali (all {len(names)})", union, union_misses, union_max, cpus, "", PERIOD_US)
    )
    ref_rows = [
        window_row(f"kali {n}", s0.procs[n], s1.procs[n], PERIOD_US, "not in union")
        for n in reference
    ]
    ct_row_ = rows[0]
    kali_all = rows[-1]
    ratio = kali_all.p999_us / ct_row_.p999_us
    notes += watch.notes()
    if s1.fault:
        notes.append(f"the instance halted during the window: {s1.fault}")
    if len(logged) < kali_all.misses:
        notes.append(
            f"the miss log holds {len(logged)} of the window's {kali_all.misses} misses "
            f"(it keeps the last {layout.MISS_LOG_LEN})"
        )
    kali_only = unexplained_misses(logged, stalls)
    expected = seconds * 1_000_000 // PERIOD_US
    short = [r.name for r in rows[1:-1] if r.samples < 0.98 * expected]
    if short:
        notes.append(f"fewer than 98 % of the {expected} expected wake-ups: {', '.join(short)}")
    return Result(
        machine=facts,
        config=cfg.source,
        instance=instance,
        seconds=(s1.t_ns - s0.t_ns) / 1e9,
        cyclictest_command=floor.text,
        rows=rows,
        reference_rows=ref_rows,
        sched_fifo=sched,
        clock_overruns=s1.overruns - s0.overruns,
        clock_skipped_ticks=s1.skipped_ticks - s0.skipped_ticks,
        max_consecutive_misses={n: s1.procs[n].max_consecutive_misses for n in names},
        fault=s1.fault,
        p999_ratio=ratio,
        p999_pass=bool(GOAL_P999.judge(ratio).met),
        kali_misses=kali_all.misses,
        cyclictest_over_period=ct_row_.misses,
        misses_logged=len(logged),
        misses_kali_only=kali_only,
        cyclictest_stalls=len(stalls),
        misses_pass=not kali_only and len(logged) == kali_all.misses,
        floor_alone=alone_row,
        floor_alone_command=alone_cmd,
        notes=notes,
    )


# --------------------------------------------------------------------------------------------
# Output


def format_report(r: Result, cfg: KaliConfig) -> str:
    """The plain-text report: machine facts, command, the table, the verdicts."""
    m = r.machine
    fifo = ", ".join(f"{n} {p}" if p else f"{n} REFUSED" for n, p in r.sched_fifo.items())
    granted = all(p > 0 for n, p in r.sched_fifo.items() if cfg.process(n).priority > 0)
    lines = [
        machine_line(m),
        "vCPU steal time in the window (host ran something else): "
        + ", ".join(f"{c} {v:.0f} ms" for c, v in m["steal_ms"].items()),
        f"SCHED_FIFO granted: {'yes' if granted else 'NO'} (procs priority: {fifo})",
        f"kali: {r.config}, instance '{r.instance}', serious_miss_tolerance_ms "
        f"{cfg.clock.serious_miss_tolerance_ms}, window {r.seconds:.1f} s after {SETTLE_S:g} s "
        "settling",
        f"cyclictest: {r.cyclictest_command}",
    ]
    if r.floor_alone_command:
        lines.append(f"cyclictest alone (before Kali): {r.floor_alone_command}")
    lines.append("")
    extra = ([r.floor_alone] if r.floor_alone else []) + r.reference_rows
    lines.append(rows_table(PERIOD_US, "", r.rows, extra))
    if extra:
        lines.append("(after the rule: for reference)")
    lines.append("")
    verdict = "PASS" if r.p999_pass else "FAIL"
    lines.append(
        f"p99.9 ratio kali (all) / cyclictest: {r.rows[-1].p999_us:.0f} / "
        f"{r.rows[0].p999_us:.0f} µs = {r.p999_ratio:.2f}x  (target {GOAL_P999.op} "
        f"{GOAL_P999.limit:g}x)  {verdict}"
    )
    verdict = "PASS" if r.misses_pass else "FAIL"
    consec = ", ".join(f"{n} {v}" for n, v in r.max_consecutive_misses.items())
    lines.append(
        f"missed deadlines: kali {r.kali_misses} ({r.misses_logged} in the miss log), "
        f"{len(r.misses_kali_only)} of them without a cyclictest stall > {SPIKE_US} µs "
        f"overlapping (cyclictest: {r.cyclictest_stalls} such stalls, "
        f"{r.cyclictest_over_period} wake-ups >= {PERIOD_US} µs late)  {verdict}"
    )
    for m in r.misses_kali_only[:10]:
        lines.append(
            f"  kali-only miss: {m['process']} at tick {m['tick']} ({m['consecutive']} in a row)"
        )
    ct, kall = r.rows[0], r.rows[-1]
    lines.append(
        f"  per 100k wake-ups: kali misses {rate(kall.misses, kall.samples)}, kali >= "
        f"{PERIOD_US} µs late {rate(kall.over_period, kall.samples)}, cyclictest >= "
        f"{PERIOD_US} µs late {rate(ct.over_period, ct.samples)} (one stall costs every process "
        "a miss per tick it covers; cyclictest counts it once per thread)"
    )
    lines.append(
        f"wall clock: overruns {r.clock_overruns}, skipped_ticks {r.clock_skipped_ticks} "
        f"in the window; max consecutive misses since start: {consec}"
    )
    lines += [f"note: {n}" for n in r.notes]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Parse options, run the benchmark, print the report; the exit status."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=int, default=60, help="measurement window (default 60)")
    ap.add_argument(
        "--config",
        type=Path,
        default=DEFAULT_CONFIG,
        help=f"Kali config (default {DEFAULT_CONFIG.relative_to(REPO)})",
    )
    ap.add_argument("--instance", default=None, help="instance name (default: the config's)")
    ap.add_argument(
        "--ct-threads",
        type=int,
        choices=(1, 2),
        default=2,
        help="cyclictest threads: 2 = one pinned per CPU (default), 1 = floating",
    )
    ap.add_argument(
        "--floor-alone",
        action="store_true",
        help="also run cyclictest alone before Kali (doubles the run time)",
    )
    ap.add_argument(
        "--miss-tolerance",
        type=int,
        default=None,
        metavar="MS",
        help="override clock.serious_miss_tolerance_ms (default: the config's), so that a host "
        "stall of one vCPU does not halt the instance in the middle of the window",
    )
    ap.add_argument(
        "--json", type=Path, default=None, metavar="PATH", help="also write the numbers to PATH"
    )
    args = ap.parse_args(argv)
    if args.seconds < 1:
        ap.error("--seconds must be >= 1")
    # SIGTERM (and SIGINT) unwind through measure()'s finally: the instance is always stopped.
    unwind_on_sigterm()
    if shutil.which("cyclictest") is None:
        print(f"bench_wallclock: {CYCLICTEST_MISSING}", file=sys.stderr)
        return 2
    try:
        tolerance = args.miss_tolerance
        overrides = {} if tolerance is None else {"clock.serious_miss_tolerance_ms": tolerance}
        instance = args.instance or load_config(args.config).instance
        label = "" if tolerance is None else f"--miss-tolerance {tolerance}"
        cfg = cell_config(overrides, instance, args.config, label)
        result = measure(cfg, args.seconds, args.ct_threads, args.floor_alone)
        print(format_report(result, cfg))
        if args.json is not None:
            args.json.write_text(json.dumps(to_json(result), indent=2) + "\n")
    except (KaliError, BenchError, OSError, subprocess.SubprocessError) as exc:
        print(f"bench_wallclock: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("bench_wallclock: interrupted; the instance was stopped", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
