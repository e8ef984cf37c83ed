"""The benchmarks' judging rules (scripts/benchlib.py): how cyclictest's stalls are read and
when a Kali miss counts as "also seen by cyclictest" (issue 7's soak goal rests on it)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))

from benchlib import (
    LostTime,
    chance_seen,
    cyclictest_command,
    parse_spikes,
    spike_lines,
    spikes_unlogged,
    stalls_before,
    unexplained_misses,
)
from soak import SIO_BEFORE, judge_memory_until, sio_story

SPIKES = """\
# some header cyclictest may print
T: 0 Spike:     344: TS:  33612617925
T: 1 Spike:    1200: TS:  33612619000
spikes = 5
"""


def test_a_spike_is_a_stall_from_the_threads_previous_wake_up_to_the_late_one() -> None:
    """TS is the late wake-up (µs); the thread last ran one interval before its due time."""
    assert parse_spikes(SPIKES, 100) == [
        ((33612617925 - 344 - 100) * 1000, 33612617925 * 1000),
        ((33612619000 - 1200 - 100) * 1000, 33612619000 * 1000),
    ]
    assert parse_spikes(SPIKES, 100, min_us=344) == parse_spikes(SPIKES, 100)[1:]


def halt_text(stdout: str, t_ns: int) -> str:
    lines = spike_lines(stdout)
    return stalls_before(lines, LostTime(lines), t_ns, 20_000_000)


def test_a_halt_is_told_with_the_time_each_cpu_lost_before_it() -> None:
    """A host taking most of a CPU in short pieces halts Kali as surely as one long stall:
    the report gives the time lost in the window before the halt, not only the longest."""
    halt_us = 50_000_000
    pieces = (
        "".join(  # CPU 0 gone 400 µs of every 500 for the last 20 ms, CPU 1 a little
            f"T: 0 Spike: 400: TS: {halt_us - k * 500}\n" for k in range(40)
        )
        + f"T: 1 Spike: 300: TS: {halt_us - 5_000}\n"
    )
    text = halt_text(pieces, halt_us * 1000)
    assert text == (
        "time cyclictest's CPUs lost before the halt: in 20 ms CPU 0 16.0 ms, CPU 1 0.3 ms; "
        "in 100 ms CPU 0 16.0 ms, CPU 1 0.3 ms; "
        "longest stall in the second before it: CPU 0 0.4 ms (ended 0 ms before it), "
        "CPU 1 0.3 ms (ended 5 ms before it)"
    )
    earlier = "".join(  # the same 16 ms, ended 25 ms before a halt the tolerance decided
        f"T: 0 Spike: 400: TS: {halt_us - 25_000 - k * 500}\n" for k in range(40)
    )
    assert halt_text(earlier, halt_us * 1000).startswith(
        "time cyclictest's CPUs lost before the halt: in 20 ms nothing; in 100 ms CPU 0 16.0 ms; "
    )
    quiet = "T: 0 Spike: 60: TS: 10000000\n"  # long before: a halt of Kali's own
    assert halt_text(quiet, halt_us * 1000) == (
        "time cyclictest's CPUs lost before the halt: in 20 ms nothing; in 100 ms nothing; "
        "no stall in the second before it"
    )


def test_spikes_cyclictest_counted_but_did_not_log_are_counted() -> None:
    assert spikes_unlogged(SPIKES) == 3
    assert spikes_unlogged("spikes = 0\n") == 0


def test_a_miss_is_also_seen_only_when_a_stall_overlaps_its_window() -> None:
    stalls = [(1_000, 2_000), (10_000, 10_500)]
    misses = [
        {"signal_ns": 0, "due_ns": 999},  # ends before the first stall
        {"signal_ns": 1_500, "due_ns": 3_000},  # the first stall is in it
        {"signal_ns": 2_001, "due_ns": 9_999},  # between the stalls
        {"signal_ns": 10_400, "due_ns": 20_000},  # the second stall ends in it
    ]
    own = unexplained_misses(misses, stalls)
    assert own == [misses[0] | {"lost_us": {}}, misses[2] | {"lost_us": {}}]


def test_short_losses_of_one_cpu_add_up_to_a_stall() -> None:
    """Three 100 µs losses of CPU 0 inside a 1 ms miss: 300 µs lost, which a rule looking
    only for stalls > 200 µs would never see."""
    lines = [(0, 100, 1_100), (0, 100, 1_400), (0, 100, 1_800), (1, 60, 1_500), (0, 100, 5_000)]
    lost = LostTime(lines)
    assert lost.within(1_000_000, 2_000_000) == {0: 300_000, 1: 60_000}
    assert lost.within(1_050_000, 1_350_000) == {0: 100_000}  # CPU 1 lost nothing there
    miss = {"signal_ns": 1_000_000, "due_ns": 2_000_000}
    assert unexplained_misses([miss], [], lost, 300_000) == []
    own = unexplained_misses([miss], [], lost, 300_001)
    assert own == [miss | {"lost_us": {0: 300, 1: 60}}]


def test_a_lead_counts_what_the_machine_did_just_before_the_signal() -> None:
    """CPU 0 lost 190 µs ending 94 µs before the signal (soak P's first own miss): nothing
    inside the miss, but inside it with a 500 µs lead."""
    lost = LostTime([(0, 190, 906)])  # late 190 µs, woke at 906 µs: lost [716, 906] µs
    miss = {"signal_ns": 1_000_000, "due_ns": 2_000_000}
    assert unexplained_misses([miss], [], lost, 100_000) == [miss | {"lost_us": {}}]
    assert unexplained_misses([miss], [], lost, 100_000, lead_ns=500_000) == []
    assert unexplained_misses([miss], [], lost, 100_000, lead_ns=50_000) != []


def test_chance_seen_is_the_share_of_windows_the_rules_would_explain() -> None:
    # a 5 µs window starting in [5, 20] µs meets the stall [10, 20] µs: 15 % of [0, 100] µs
    stall = [(10_000, 20_000)]
    assert chance_seen(stall, None, 0, 5_000, 0, 105_000) == pytest.approx(0.15, abs=0.001)
    assert chance_seen([], None, 0, 5_000, 0, 105_000) == 0.0
    # or CPU 0 losing 10-11 and 11-12 µs: only windows holding both lose 2 µs, starts in [7, 10]
    lost = LostTime([(0, 1, 11), (0, 1, 12)])
    assert chance_seen([], lost, 2_000, 5_000, 0, 105_000) == pytest.approx(0.03, abs=0.001)


def test_chance_seen_agrees_with_placing_windows_at_random() -> None:
    rng = np.random.default_rng(7)
    starts = rng.integers(0, 1_000_000, 40)
    lengths = rng.integers(1, 5_000, 40)
    stalls = [(int(s), int(s) + int(d)) for s, d in zip(starts, lengths, strict=True)]
    w = 2_000
    misses = [{"signal_ns": int(x), "due_ns": int(x) + w} for x in rng.integers(0, 998_000, 20_000)]
    seen = 1 - len(unexplained_misses(misses, stalls)) / len(misses)
    assert chance_seen(stalls, None, 0, w, 0, 1_000_000) == pytest.approx(seen, abs=0.01)


def test_the_stall_detector_command_has_no_histogram() -> None:
    cmd = cyclictest_command(10, 2, None, 100, 200, 99, 1000)
    assert "-h" not in cmd and not any(a.startswith("--histfile") for a in cmd)
    assert cmd[cmd.index("-p") + 1] == "99" and cmd[cmd.index("-i") + 1] == "100"
    assert "--spike=200" in cmd and "--spike-nodes=1000" in cmd
    floor = cyclictest_command(10, 2, Path("/tmp/h"), 1000, 0)
    assert "-h" in floor and not any(a.startswith("--spike") for a in floor)


def test_every_cyclictest_thread_wakes_at_the_period_asked() -> None:
    """cyclictest's thread n wakes every interval + n x distance (500 µs unless ``-d`` says
    otherwise): without ``-d 0`` the floor sampled the second CPU every 1.5 ms and the stall
    detector every 750 µs, not 1 ms and 250 µs.  Every thread at the period asked for."""
    cmd = cyclictest_command(1, 2, None, 1000, 0)
    i = cmd.index("-p")
    del cmd[i : i + 2]  # SCHED_OTHER: as any user
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=30, check=True).stdout
    intervals = re.findall(r"^T:\s*(\d+) .*? I:\s*(\d+)", out, re.M)
    assert intervals == [("0", "1000"), ("1", "1000")], out


def test_cyclictest_logs_its_spikes_in_clock_monotonic(tmp_path: Path) -> None:
    """The miss log's times are CLOCK_MONOTONIC; a spike's TS must be on the same clock, or
    no stall would ever be matched with a miss.  --spike=0 is "off", so log wake-ups > 1 µs
    (nearly all, for a SCHED_OTHER thread)."""
    cmd = cyclictest_command(1, 1, None, 1000, 1, 0, 10_000)
    i = cmd.index("-p")
    del cmd[i : i + 2]  # SCHED_OTHER: runs anywhere, as any user
    t0 = time.monotonic_ns()
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=30, check=True).stdout
    t1 = time.monotonic_ns()
    stalls = parse_spikes(out, 1000)
    assert len(stalls) > 100, out[-500:]
    assert all(t0 <= end <= t1 for _, end in stalls)


def test_the_soak_tells_sio_s_own_work_from_the_servos_around_a_miss() -> None:
    """Each own miss's line gives SIO's ticks around it from the flight recorder: how late
    it woke, how long it took, how much of that it slept for the servos and how much CPU
    time it had; a tick it did not serve is absent from the ring and says so."""
    rows = [(98, 81, 235, 90, 140), (99, 278, 941, 120, 150), (101, 79, 289, 95, 190)]
    line = sio_story(100, rows)
    assert SIO_BEFORE == 2
    assert line == (
        "SIO (µs late, µs read to write, of which asleep for the servos, its CPU time): "
        "N-2 woke 81 took 235 (servos 90, ran 140); N-1 woke 278 took 941 (servos 120, "
        "ran 150); N not served; N+1 woke 79 took 289 (servos 95, ran 190)"
    )


def test_after_a_halt_the_soak_judges_memory_up_to_the_halt() -> None:
    """A halt makes the wall clock write the flight recorder's dump, ~3 MB of RSS once (seen
    with ``kalictl estop`` on an idle instance): the soak judges every process's memory over
    the samples before the halt, the last sampling instant before it as the end, so that step
    is not called a leak, a process that grew before it still is, and one whose samples
    stopped before that instant is GONE."""
    samples = {
        "wallclock": [(0.0, 40_000), (30.0, 40_010), (60.0, 40_020), (75.0, 43_100)],
        "sio": [(0.0, 40_000), (30.0, 42_000), (60.0, 44_000), (75.0, 44_000)],
        "sv.1": [(0.0, 40_000), (30.0, 40_000)],
    }
    pids = {"wallclock": 1, "sio": 2, "sv.1": 3}
    whole = {m.name: m.verdict for m in judge_memory_until(samples, pids, {}, 75.0, None)}
    assert whole == {"wallclock": "GROWS", "sio": "GROWS", "sv.1": "GONE"}
    halted = judge_memory_until(samples, pids, {}, 75.0, 70.0)
    assert {m.name: m.verdict for m in halted} == {
        "wallclock": "flat", "sio": "GROWS", "sv.1": "GONE",
    }  # fmt: skip
    assert {m.name: m.end_kib for m in halted}["wallclock"] == 40_020


def test_the_soak_reads_where_a_stuck_serious_process_is() -> None:
    """A serious clocked process signalled ``STUCK_MS`` ago, unacknowledged, while the clock
    ticked on: the soak's ``StuckWatch`` records, once per signal, each of its threads' state,
    wchan and kernel stack (here this test's own process stands in for it); a stall of the
    whole machine (the clock stood too) is not recorded, nor one acknowledged."""
    from types import SimpleNamespace

    from soak import STUCK_MS, StuckWatch

    from kali_daemons.core import layout

    procs = np.zeros(layout.MAX_PROCESSES, dtype=layout.PROCESS)
    procs["periodic"][3], procs["serious"][3], procs["pid"][3] = 1, 1, os.getpid()
    procs["periodic"][4], procs["pid"][4] = 1, os.getpid()  # not serious: never looked at
    clock = {"tick": 0, "base_tick_ns": 1_000_000}
    inst = SimpleNamespace(procs=procs, clock=clock, slot_of={"tg": 3, "viewer": 4}.get)
    watch = StuckWatch(inst, ["tg", "viewer"])  # type: ignore[arg-type]
    procs["signal_tick"][3:5], procs["ack_tick"][3:5] = 100, 99
    procs["release_ns"][3:5] = time.monotonic_ns() - 2 * STUCK_MS * 1_000_000
    clock["tick"] = 100 + STUCK_MS - 1  # the clock stood with it: the machine stalled
    watch.look()
    assert watch.records == []
    clock["tick"] = 100 + 2 * STUCK_MS
    watch.look()
    watch.look()  # the same signal: once
    assert len(watch.records) == 1, watch.records
    rec = watch.records[0]
    assert (rec["process"], rec["tick"], rec["clock_ticks"]) == ("tg", 100, 2 * STUCK_MS)
    assert float(rec["late_ms"]) >= 2 * STUCK_MS  # type: ignore[arg-type]
    main = rec["threads"][0]  # type: ignore[index]
    assert main.startswith(f"{os.getpid()} R wchan "), main
    procs["ack_tick"][3] = 100  # acknowledged, then signalled again and stuck
    procs["signal_tick"][3] = 120
    watch.look()
    assert len(watch.records) == 1
    clock["tick"] = 120 + STUCK_MS
    watch.look()
    assert [r["tick"] for r in watch.records] == [100, 120]
