"""The benchmarks' judging rules (scripts/benchlib.py): how cyclictest's stalls are read and
when a Kali miss counts as "also seen by cyclictest" (issue 7's soak goal rests on it)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))

from benchlib import (
    chance_overlap,
    cyclictest_command,
    parse_spikes,
    spikes_unlogged,
    unexplained_misses,
)

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
    assert own == [misses[0], misses[2]]
    assert unexplained_misses(misses[:1], []) == misses[:1]


def test_chance_overlap_is_the_share_of_window_starts_that_meet_a_stall() -> None:
    # a 5 ns window starting in [5, 20] meets the stall [10, 20]
    assert chance_overlap([(10, 20)], 5, 0, 100) == pytest.approx(0.15)
    # overlapping stalls count once: starts in [5, 30]
    assert chance_overlap([(10, 20), (12, 30)], 5, 0, 100) == pytest.approx(0.25)
    # a stall inside an earlier one adds nothing
    assert chance_overlap([(10, 40), (15, 20)], 5, 0, 100) == pytest.approx(0.35)
    # clipped to the window: starts in [0, 10] of [0, 100]
    assert chance_overlap([(-50, 10)], 5, 0, 100) == pytest.approx(0.10)
    assert chance_overlap([], 5, 0, 100) == 0.0


def test_chance_overlap_agrees_with_placing_windows_at_random() -> None:
    rng = np.random.default_rng(7)
    starts = rng.integers(0, 1_000_000, 40)
    stalls = [
        (int(s), int(s) + int(d)) for s, d in zip(starts, rng.integers(1, 5_000, 40), strict=True)
    ]
    w = 2_000
    miss_starts = rng.integers(0, 1_000_000 - w, 20_000)
    misses = [{"signal_ns": int(x), "due_ns": int(x) + w} for x in miss_starts]
    seen = 1 - len(unexplained_misses(misses, stalls)) / len(misses)
    assert chance_overlap(stalls, w, 0, 1_000_000 - w) == pytest.approx(seen, abs=0.01)


def test_the_stall_detector_command_has_no_histogram() -> None:
    cmd = cyclictest_command(10, 2, None, 100, 200, 99, 1000)
    assert "-h" not in cmd and not any(a.startswith("--histfile") for a in cmd)
    assert cmd[cmd.index("-p") + 1] == "99" and cmd[cmd.index("-i") + 1] == "100"
    assert "--spike=200" in cmd and "--spike-nodes=1000" in cmd
    floor = cyclictest_command(10, 2, Path("/tmp/h"), 1000, 0)
    assert "-h" in floor and not any(a.startswith("--spike") for a in floor)


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
