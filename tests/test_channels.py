"""Type 1-4 channels (thesis 3.2.1, 2.2.2): semantics, and races between real processes."""

from __future__ import annotations

import itertools
import math
import multiprocessing as mp
import os
import time
from collections.abc import Iterator
from fractions import Fraction
from uuid import uuid4

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kali_daemons.core.arena import Arena, segment_name
from kali_daemons.core.channels import Flag as ChannelFlag
from kali_daemons.core.channels import FlagArray, InterpolatingFifo, Record, RequestQueue
from kali_daemons.core.errors import ChannelError, QueueFullError

ARENA_BYTES = 1 << 20
PAYLOAD = np.dtype([("producer", "<u4"), ("i", "<u4")])
MOTION = np.dtype([("kind", "<u4"), ("target", "<f8", (3,)), ("speed", "<f8")])
PREFIX = f"t{os.getpid()}_"


def unique_instance() -> str:
    return f"{PREFIX}{uuid4().hex[:8]}"


@pytest.fixture(scope="module", autouse=True)
def nothing_left_in_dev_shm() -> Iterator[None]:
    yield
    left = [n for n in os.listdir("/dev/shm") if n.startswith(f"kali.{PREFIX}")]
    assert left == [], f"segments left behind: {left}"


@pytest.fixture
def instance() -> Iterator[tuple[str, Arena]]:
    name = unique_instance()
    arena = Arena.create(name, ARENA_BYTES)
    try:
        yield name, arena
    finally:
        arena.close()
        arena.unlink()


@pytest.fixture
def arena(instance: tuple[str, Arena]) -> Arena:
    return instance[1]


# --------------------------------------------------------------------------------------------
# Type 1 queue


def motion(kind: int, x: float = 0.0) -> dict[str, object]:
    return {"kind": kind, "target": [x, 0.0, 1.0], "speed": 0.5}


def test_queue_fifo_order_and_increasing_seq(arena: Arena) -> None:
    q = RequestQueue(arena, "tg.requests", MOTION, 8)
    out = np.zeros((), MOTION)
    assert q.get_into(out) is None and len(q) == 0 and q.peek_seq() is None
    seqs = [q.put(motion(k, float(k))) for k in range(5)]
    assert seqs == sorted(seqs) and len(set(seqs)) == 5
    assert len(q) == 5 and q.peek_seq() == seqs[0]
    for k, seq in enumerate(seqs):
        assert q.get_into(out) == seq
        assert int(out["kind"]) == k
        assert out["target"].tolist() == [float(k), 0.0, 1.0]
    assert q.get_into(out) is None
    one = np.zeros(1, MOTION)  # a 1-element record works too
    q.put(np.array((7, [1.0, 2.0, 3.0], 0.25), dtype=MOTION).reshape(()))
    assert q.get_into(one) is not None and int(one[0]["kind"]) == 7


def test_queue_full_refuses_and_overwrites_nothing(arena: Arena) -> None:
    q = RequestQueue(arena, "tg.requests", MOTION, 4)
    first = q.put(motion(100))
    for k in range(3):
        q.put(motion(101 + k))
    with pytest.raises(QueueFullError) as err:
        q.put(motion(999))
    assert str(err.value) == (
        f"channel: queue 'tg.requests' full: 4 of 4 entries unread (oldest seq {first}); "
        "entry refused, nothing overwritten"
    )
    with pytest.raises(QueueFullError):
        q.put(motion(998))
    assert q.rejected == 2 and len(q) == 4
    out = np.zeros((), MOTION)
    assert q.get_into(out) == first and int(out["kind"]) == 100
    got = []
    while q.get_into(out) is not None:
        got.append(int(out["kind"]))
    assert got == [101, 102, 103]


def test_one_producer_flooding_keeps_no_other_out_of_the_queue(arena: Arena) -> None:
    """With a share, each producer (told apart by a payload field) may hold at most that many
    unread entries: a flood meets QueueFullError naming its share while others still get in
    (before: the flooder filled all of it and every other producer was refused too)."""
    q = RequestQueue(arena, "tg.requests", MOTION, 8, share=("kind", 3))
    for _ in range(3):
        q.put(motion(1))
    with pytest.raises(QueueFullError, match=r"kind 1 already has 3 of its share of 3 entries"):
        q.put(motion(1))
    others = [q.put(motion(2)) for _ in range(3)] + [q.put(motion(3)) for _ in range(2)]
    assert len(others) == 5 and len(q) == 8
    with pytest.raises(QueueFullError, match=r"full: 8 of 8 entries unread"):
        q.put(motion(4))
    out = np.zeros((), MOTION)
    q.get_into(out)
    assert int(out["kind"]) == 1
    q.put(motion(1))  # its share has room again


def test_queue_wraps_around(arena: Arena) -> None:
    q = RequestQueue(arena, "q", PAYLOAD, 5)
    out = np.zeros((), PAYLOAD)
    last_seq = 0
    expected = 0
    sent = 0
    for cycle in range(200):
        for _ in range(cycle % 5 + 1):
            q.put({"producer": 0, "i": sent})
            sent += 1
        while (seq := q.get_into(out)) is not None:
            assert seq > last_seq and int(out["i"]) == expected
            last_seq, expected = seq, expected + 1
    assert expected == sent and q.rejected == 0


def test_queue_rejects_bad_entries(arena: Arena) -> None:
    q = RequestQueue(arena, "tg.requests", MOTION, 4)
    with pytest.raises(ChannelError, match=r"queue 'tg.requests': unknown field 'sped'"):
        q.put({"kind": 1, "target": [0, 0, 0], "sped": 1.0})
    with pytest.raises(ChannelError, match=r"queue 'tg.requests': field 'speed' missing"):
        q.put({"kind": 1, "target": [0, 0, 0]})
    with pytest.raises(ChannelError, match=r"field 'target' takes float64 of shape \(3,\).*\(2,\)"):
        q.put({"kind": 1, "target": [0.0, 1.0], "speed": 1.0})
    with pytest.raises(ChannelError, match=r"field 'kind'"):
        q.put({"kind": "fast", "target": [0, 0, 0], "speed": 1.0})
    with pytest.raises(ChannelError, match="expected one record"):
        q.put(np.zeros((), PAYLOAD))
    assert len(q) == 0 and q.rejected == 0
    with pytest.raises(ChannelError, match="get_into needs one preallocated record"):
        q.get_into(np.zeros(2, MOTION))


def test_queue_attacher_shares_and_geometry_is_checked(arena: Arena) -> None:
    q = RequestQueue(arena, "tg.requests", MOTION, 64)
    seq = q.put(motion(5))
    same = RequestQueue(arena, "tg.requests", MOTION, 64)
    assert len(same) == 1 and same.peek_seq() == seq
    with pytest.raises(ChannelError) as err:
        RequestQueue(arena, "tg.requests", MOTION, 32)
    assert str(err.value) == (
        "channel: queue 'tg.requests' exists with capacity 64, attach asked for 32"
    )
    with pytest.raises(ChannelError, match="entry_bytes"):
        RequestQueue(arena, "tg.requests", PAYLOAD, 64)


def _producer(instance: str, producer: int, count: int, capacity: int) -> None:
    with Arena.attach(instance) as arena:
        q = RequestQueue(arena, "mp.requests", PAYLOAD, capacity)
        ready = ChannelFlag(arena, "mp.go")
        while not ready.is_set():
            time.sleep(1e-3)
        for i in range(count):
            while True:
                try:
                    q.put({"producer": producer, "i": i})
                    break
                except QueueFullError:
                    time.sleep(2e-4)


def test_queue_four_spawned_producers_one_consumer(instance: tuple[str, Arena]) -> None:
    name, arena = instance
    producers, count, capacity = 4, 500, 32
    q = RequestQueue(arena, "mp.requests", PAYLOAD, capacity)
    go = ChannelFlag(arena, "mp.go")
    ctx = mp.get_context("spawn")
    procs = [
        ctx.Process(target=_producer, args=(name, p, count, capacity)) for p in range(producers)
    ]
    for p in procs:
        p.start()
    try:
        go.test_and_set()
        out = np.zeros((), PAYLOAD)
        seqs: list[int] = []
        items: list[tuple[int, int]] = []
        deadline = time.monotonic() + 30
        while len(items) < producers * count and time.monotonic() < deadline:
            seq = q.get_into(out)
            if seq is None:
                time.sleep(1e-4)
                continue
            seqs.append(seq)
            items.append((int(out["producer"]), int(out["i"])))
    finally:
        for p in procs:
            p.join(timeout=10)
            if p.is_alive():  # pragma: no cover - only on failure
                p.kill()
                p.join()
    assert [p.exitcode for p in procs] == [0] * producers
    assert len(items) == producers * count
    assert all(b > a for a, b in itertools.pairwise(seqs))
    assert sorted(items) == [(p, i) for p in range(producers) for i in range(count)]
    for p in range(producers):
        assert [i for (pp, i) in items if pp == p] == list(range(count))
    assert q.get_into(out) is None
    assert q.rejected > 0  # the producers did run into a full queue and retried


# --------------------------------------------------------------------------------------------
# Type 2 interpolating FIFO


def pops(fifo: InterpolatingFifo, n: int) -> tuple[list[np.ndarray], list[bool]]:
    out = np.empty(fifo.width)
    values, moved = [], []
    for _ in range(n):
        moved.append(fifo.pop_into(out))
        values.append(out.copy())
    return values, moved


def test_fifo_integer_ratio_is_linear_interpolation(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 3, 16, Fraction(10))
    pts = [
        np.array([0.0, 1.0, -2.0]),
        np.array([0.3, -0.7, 5.1]),
        np.array([1.7, 2.2, 5.1]),
        np.array([-3.3, 0.1, 0.123456789]),
    ]
    for p in pts:
        fifo.push(p)
    assert fifo.pending() == 4
    values, moved = pops(fifo, 1 + 3 * 10)
    assert all(moved)
    np.testing.assert_array_equal(values[0], pts[0])
    for j in range(1, 4):
        a, b = pts[j - 1], pts[j]
        for k in range(1, 10):  # the thesis formula; tick 10 lands exactly on B (below)
            expected = a + k * (b - a) / 10
            np.testing.assert_array_equal(values[1 + (j - 1) * 10 + (k - 1)], expected)
        np.testing.assert_array_equal(values[j * 10], b)
    assert fifo.pending() == 0 and fifo.underruns == 0


def test_fifo_fractional_ratio_five_halves(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 2, 8, Fraction(5, 2))
    p = [np.array([0.0, 10.0]), np.array([5.0, 0.0]), np.array([10.0, 0.0]),
         np.array([0.0, 2.5]), np.array([1.0, 1.0])]  # fmt: skip
    for x in p:
        fifo.push(x)
    # Closed form, r = 2.5: segments of 2, 3, 2, 3 ticks; increment (B - A)/2.5, last tick B.
    d1, d2, d3, d4 = ((p[j + 1] - p[j]) / 2.5 for j in range(4))
    expected = [
        p[0],
        p[0] + d1, p[1],
        p[1] + d2, p[1] + 2 * d2, p[2],
        p[2] + d3, p[3],
        p[3] + d4, p[3] + 2 * d4, p[4],
    ]  # fmt: skip
    np.testing.assert_array_equal(expected[1], [2.0, 6.0])  # sanity of the hand numbers
    values, moved = pops(fifo, len(expected) + 2)
    for got, want in zip(values, expected, strict=False):
        np.testing.assert_array_equal(got, want)
    assert moved == [True] * len(expected) + [False, False]
    np.testing.assert_array_equal(values[-1], p[4])
    assert fifo.underruns == 2


@settings(max_examples=100, deadline=None)
@given(
    den=st.integers(1, 20),
    extra=st.integers(0, 19),
    width=st.integers(1, 3),
    data=st.data(),
)
def test_fifo_property_segments_land_exactly(den: int, extra: int, width: int, data) -> None:
    num = min(20, den + extra)  # r = num/den >= 1, both terms in 1..20
    n_points = data.draw(st.integers(1, 12))
    coords = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
    pts = [np.array(data.draw(st.lists(coords, min_size=width, max_size=width)))
           for _ in range(n_points)]  # fmt: skip
    name = unique_instance()
    arena = Arena.create(name, ARENA_BYTES)
    try:
        fifo = InterpolatingFifo(arena, "f", width, 16, (num, den))
        for x in pts:
            fifo.push(x)
        out = np.empty(width)
        assert fifo.pop_into(out)
        np.testing.assert_array_equal(out, pts[0])
        total = 0
        for j in range(1, n_points):
            a, b = pts[j - 1], pts[j]
            lo, hi = np.minimum(a, b), np.maximum(a, b)
            n = 0
            while True:
                assert fifo.pop_into(out)
                n += 1
                assert np.all(lo <= out) and np.all(out <= hi)
                if n == math.floor(j * num / den) - total:
                    break
                assert n < 30
            np.testing.assert_array_equal(out, b)  # lands exactly on the set-point
            total += n
            assert total == j * num // den  # segment lengths average r
        before = out.copy()
        assert not fifo.pop_into(out)
        np.testing.assert_array_equal(out, before)
        assert fifo.underruns == 1
    finally:
        arena.close()
        arena.unlink()


def test_fifo_underrun_holds_and_resumes_without_jump(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 1, 4, (2, 1))
    out = np.array([42.0])
    assert not fifo.pop_into(out)  # never primed: out untouched
    assert out[0] == 42.0 and fifo.underruns == 1
    fifo.push([0.0])
    fifo.push([4.0])
    values, moved = pops(fifo, 6)
    assert [v[0] for v in values] == [0.0, 2.0, 4.0, 4.0, 4.0, 4.0]
    assert moved == [True, True, True, False, False, False]
    assert fifo.underruns == 4
    fifo.push([10.0])
    values, moved = pops(fifo, 3)
    assert [v[0] for v in values] == [7.0, 10.0, 10.0]  # starts from the held B = 4
    assert moved == [True, True, False]


def test_fifo_overflow_refuses_and_keeps_ring(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 2, 3, 1)
    for k in range(3):
        fifo.push(np.array([k, -k], dtype=float))
    with pytest.raises(ChannelError, match=r"fifo 'tg.fifo' full: 3 of 3 set-points unread"):
        fifo.push(np.array([9.0, 9.0]))
    assert fifo.overflows == 1 and fifo.pending() == 3
    values, _ = pops(fifo, 3)
    assert [v.tolist() for v in values] == [[0.0, 0.0], [1.0, -1.0], [2.0, -2.0]]


def test_fifo_refuses_bad_set_points(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 3, 4, (10, 1))
    with pytest.raises(ChannelError, match=r"component 1 is nan, must be finite; nothing"):
        fifo.push(np.array([0.0, np.nan, 0.0]))
    with pytest.raises(ChannelError, match="component 2 is inf"):
        fifo.push(np.array([0.0, 0.0, np.inf]))
    with pytest.raises(ChannelError, match=r"shape \(2,\), expected \(3,\)"):
        fifo.push(np.zeros(2))
    assert fifo.pending() == 0 and fifo.overflows == 0
    with pytest.raises(ChannelError, match=r"ratio 1/2 .* must be >= 1"):
        InterpolatingFifo(arena, "other", 3, 4, (1, 2))


def test_fifo_reset_holds_position_and_drops_pending(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 2, 4, (4, 1))
    fifo.push(np.array([100.0, 100.0]))
    fifo.reset(np.array([1.0, 2.0]))
    assert fifo.pending() == 0
    values, moved = pops(fifo, 2)
    assert [v.tolist() for v in values] == [[1.0, 2.0], [1.0, 2.0]] and moved == [False, False]
    fifo.push(np.array([5.0, 2.0]))
    values, moved = pops(fifo, 4)
    assert [v.tolist() for v in values] == [[2.0, 2.0], [3.0, 2.0], [4.0, 2.0], [5.0, 2.0]]
    assert all(moved)


def test_fifo_publishes_where_a_reset_holds_for_the_set_point_pushed_next(arena: Arena) -> None:
    """``held_before(i)``: the position of the latest reset, for set-point ``i`` pushed first
    after it (its predecessor, which the ring does not hold); nothing for any other index,
    before any reset, or while a reset is being written (the sequence lock is odd)."""
    fifo = InterpolatingFifo(arena, "tg.fifo", 2, 4, (4, 1))
    other = InterpolatingFifo(arena, "tg.fifo", 2, 4, (4, 1))  # the dynamics process's
    out = np.zeros(2)
    assert not other.held_before(0, out)
    fifo.push(np.array([100.0, 100.0]))
    fifo.reset(np.array([1.0, 2.0]))
    fifo.reset(np.array([3.0, 4.0]))  # the latest counts
    fifo.push(np.array([5.0, 4.0]))
    assert other.held_before(1, out) and out.tolist() == [3.0, 4.0]
    assert not other.held_before(0, out) and not other.held_before(2, out)
    resets = other._h["resets"]
    resets[...] = int(resets) + 1  # as while the consumer writes one
    assert not other.held_before(1, out)


def test_fifo_attacher_shares_state_and_geometry_is_checked(arena: Arena) -> None:
    tg = InterpolatingFifo(arena, "tg.fifo", 2, 8, Fraction(5, 2))
    sio = InterpolatingFifo(arena, "tg.fifo", 2, 8, (10, 4))  # same ratio, unreduced
    tg.push(np.array([1.0, 1.0]))
    assert sio.pending() == 1
    out = np.empty(2)
    assert sio.pop_into(out) and out.tolist() == [1.0, 1.0]
    other = InterpolatingFifo(arena, "tg.fifo", 2, 8, 3)  # the ratio is the FIFO's, not ours
    assert other.ratio == other.segment_ratio == Fraction(5, 2)
    with pytest.raises(ChannelError, match="exists with width 2, attach asked for 3"):
        InterpolatingFifo(arena, "tg.fifo", 3, 8, Fraction(5, 2))
    with pytest.raises(ChannelError, match="exists with capacity 8, attach asked for 4"):
        InterpolatingFifo(arena, "tg.fifo", 2, 4, Fraction(5, 2))
    with pytest.raises(ChannelError, match=r"ratio 1/2 .* must be >= 1"):
        InterpolatingFifo(arena, "tg.fifo", 2, 8, (1, 2))  # still checked when attaching


# The ratio changes on line (the TG's period, kalictl rate tg MS).


def segments(fifo: InterpolatingFifo, n: int) -> list[list[float]]:
    """The outputs of the next ``n`` segments of a width-1 FIFO, one list each."""
    out = np.empty(1)
    segs: list[list[float]] = []
    for _ in range(n):
        seg = []
        while True:
            assert fifo.pop_into(out)
            seg.append(float(out[0]))
            if int(fifo._seg_done) == int(fifo._seg_ticks):
                break
            assert len(seg) < 100
        segs.append(seg)
    return segs


def primed(fifo: InterpolatingFifo) -> InterpolatingFifo:
    """``fifo`` after its first pop, which takes the first set-point exactly."""
    out = np.empty(1)
    assert fifo.pop_into(out)
    return fifo


def test_fifo_ratio_change_applies_from_the_next_set_point(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 1, 16, 10)
    for x in (0.0, 10.0, 20.0):  # queued before the change: they keep 10 ticks each
        fifo.push([x])
    fifo.set_ratio(20)
    assert fifo.ratio == 20 and fifo.segment_ratio == 10
    for x in (40.0, 60.0):
        fifo.push([x])
    fifo.set_ratio(Fraction(5, 2))
    for x in (65.0, 70.0, 75.0):
        fifo.push([x])
    segs = segments(primed(fifo), 7)
    assert [len(s) for s in segs] == [10, 10, 20, 20, 2, 3, 2]
    assert segs[0] == [float(k) for k in range(1, 11)]  # 1 per tick, landing on 10
    assert segs[2] == [20.0 + k for k in range(1, 21)]  # 1 per tick over 20 ticks
    assert segs[4:] == [[62.0, 65.0], [67.0, 69.0, 70.0], [72.0, 75.0]]  # (B - A)/2.5
    assert fifo.segment_ratio == Fraction(5, 2)
    assert (int(fifo._h["ratio_num"]), int(fifo._h["ratio_den"])) == (5, 2)
    assert fifo.underruns == 0 and fifo.pending() == 0


def test_fifo_ratio_change_rules(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 1, 16, 4)
    fifo.push([0.0])
    fifo.set_ratio(3)
    fifo.set_ratio(2)  # no push between: replaces the first
    fifo.push([2.0])
    fifo.set_ratio(Fraction(3, 2))  # with a push between: each keeps its own set-points
    fifo.push([5.0])
    fifo.push([8.0])
    # 2 ticks (the 3 was replaced), then 3/2: 1 tick, then 2
    assert segments(primed(fifo), 3) == [[1.0, 2.0], [5.0], [7.0, 8.0]]
    fifo.push([9.0])
    assert segments(fifo, 1) == [[9.0]]  # 1, 2, 1, 2, ...: floor(j 3/2) ticks in all
    # the same ratio again is no change: the accumulator carries on, no tick lost
    fifo.set_ratio((6, 4))
    for x in (11.0, 14.0, 17.0, 20.0):
        fifo.push([x])
    assert [len(s) for s in segments(fifo, 4)] == [2, 1, 2, 1]


RATIOS = [Fraction(1), Fraction(10), Fraction(20), Fraction(5, 2), Fraction(7, 3), Fraction(4, 3)]


@settings(max_examples=100, deadline=None)
@given(
    first=st.sampled_from(RATIOS),
    plan=st.lists(st.tuples(st.sampled_from(RATIOS), st.floats(-1e3, 1e3)), max_size=25),
)
def test_fifo_property_ratio_changes_stay_exact(
    first: Fraction, plan: list[tuple[Fraction, float]]
) -> None:
    """Any sequence of changes: each segment lasts its set-point's ratio, counted from the
    last change (floor(j r) ticks after it), and lands exactly on its set-point."""
    name = unique_instance()
    arena = Arena.create(name, ARENA_BYTES)
    try:
        fifo = InterpolatingFifo(arena, "f", 1, 32, first)
        fifo.push([0.0])
        for r, x in plan:
            if r != fifo.ratio:
                fifo.set_ratio(r)
            fifo.push([x])
        segs = segments(primed(fifo), len(plan))
        ratio, j = first, 0
        starts = [0.0, *(x for _, x in plan)][: len(plan)]
        for (r, x), a, seg in zip(plan, starts, segs, strict=True):
            if r != ratio:
                ratio, j = r, 0
            j += 1
            assert len(seg) == math.floor(j * ratio) - math.floor((j - 1) * ratio)
            assert seg[-1] == x
            lo, hi = min(a, x), max(a, x)
            assert all(lo <= v <= hi for v in seg)
        assert fifo.underruns == 0
    finally:
        arena.close()
        arena.unlink()


def test_fifo_attachers_adopt_a_changed_ratio(arena: Arena) -> None:
    tg = InterpolatingFifo(arena, "tg.fifo", 1, 8, 10)
    sio = InterpolatingFifo(arena, "tg.fifo", 1, 8, 10)
    tg.push([0.0])
    tg.push([10.0])
    tg.set_ratio(20)
    tg.push([30.0])
    out = np.empty(1)
    for _ in range(1 + 10 + 5):  # into the new segment
        assert sio.pop_into(out)
    assert out[0] == 15.0 and sio.segment_ratio == 20
    # a restarted SIO and a user program pass the config's ratio: they adopt the FIFO's
    sio2 = InterpolatingFifo(arena, "tg.fifo", 1, 8, 10)
    user = InterpolatingFifo(arena, "tg.fifo", 1, 8, (10, 1))
    assert sio2.ratio == user.ratio == sio2.segment_ratio == 20
    values, _ = pops(sio2, 15)
    assert [v[0] for v in values] == [16.0 + k for k in range(15)]  # resumes mid-segment
    user.push([50.0])  # stamped 20 too
    assert [v[0] for v in pops(sio2, 20)[0]] == [31.0 + k for k in range(20)]
    # a consumer attaching while a change is pending takes it at its set-point
    tg.set_ratio(5)
    tg.push([55.0])
    sio3 = InterpolatingFifo(arena, "tg.fifo", 1, 8, 10)
    assert sio3.segment_ratio == 20 and sio3.ratio == 5
    assert [v[0] for v in pops(sio3, 6)[0]] == [51.0, 52.0, 53.0, 54.0, 55.0, 55.0]
    assert sio3.segment_ratio == 5 and sio3.underruns == 1


def test_fifo_set_ratio_refuses_invalid_ratios(arena: Arena) -> None:
    fifo = InterpolatingFifo(arena, "tg.fifo", 1, 8, 10)
    for bad, why in (
        ((1, 2), r"ratio 1/2 \(servo rate / TG rate\) must be >= 1"),
        (0, r"ratio 0 .* must be >= 1"),
        ((3, 0), r"ratio \(3, 0\) is not a fraction"),
        ("fast", r"ratio 'fast' is not a fraction"),
        (Fraction(2**33, 3), r"ratio 8589934592/3 has terms above 4294967294"),
    ):
        with pytest.raises(ChannelError, match=f"fifo 'tg.fifo': {why}"):
            fifo.set_ratio(bad)
    assert fifo.ratio == 10  # nothing changed


# --------------------------------------------------------------------------------------------
# Type 3 flags, Type 4 records


def test_flag_test_and_set_and_holder(arena: Arena) -> None:
    flag = ChannelFlag(arena, "estop")
    assert not flag.is_set() and flag.holder() == 0
    assert flag.test_and_set()
    assert not flag.test_and_set()  # already set: refused, holder unchanged
    assert flag.is_set() and flag.holder() == os.getpid()
    same = ChannelFlag(arena, "estop")
    assert same.holder() == os.getpid()
    same.clear()
    assert not flag.is_set() and flag.holder() == 0
    assert flag.test_and_set()


def test_flag_array_slots_are_independent(arena: Arena) -> None:
    slots = FlagArray(arena, "sv.slots", 6)
    assert len(slots) == 6
    assert slots.test_and_set(2) and slots.test_and_set(5)
    assert [slots.is_set(i) for i in range(6)] == [False, False, True, False, False, True]
    assert slots.holder(2) == os.getpid() and slots.holder(0) == 0
    slots.clear(2)
    assert [slots.is_set(i) for i in range(6)] == [False] * 5 + [True]
    with pytest.raises(ChannelError, match=r"flags 'sv.slots': index 6, allowed 0..5"):
        slots.test_and_set(6)
    with pytest.raises(ChannelError, match="exists with count 6, attach asked for 8"):
        FlagArray(arena, "sv.slots", 8)


def _racer(instance: str, me: int, rounds: int, barrier) -> None:
    with Arena.attach(instance) as arena:
        flag = ChannelFlag(arena, "race.flag")
        wins = Record(arena, "race.wins", np.dtype("u1"), 2 * rounds).data
        for r in range(rounds):
            barrier.wait()
            won = flag.test_and_set()
            wins[me * rounds + r] = 1 if won and flag.holder() == os.getpid() else 0
            barrier.wait()
            if won:
                flag.clear()
        del wins


def test_flag_race_between_two_spawned_processes(instance: tuple[str, Arena]) -> None:
    name, arena = instance
    rounds = 1000
    ChannelFlag(arena, "race.flag")
    wins = Record(arena, "race.wins", np.dtype("u1"), 2 * rounds)
    ctx = mp.get_context("spawn")
    barrier = ctx.Barrier(2)
    procs = [ctx.Process(target=_racer, args=(name, me, rounds, barrier)) for me in (0, 1)]
    for p in procs:
        p.start()
    for p in procs:
        p.join(timeout=30)
        if p.is_alive():  # pragma: no cover - only on failure
            p.kill()
            p.join()
    assert [p.exitcode for p in procs] == [0, 0]
    per_round = wins.data.reshape(2, rounds).sum(axis=0)
    assert per_round.tolist() == [1] * rounds


def test_record_is_a_plain_shared_view(arena: Arena) -> None:
    dtype = np.dtype([("tick", "<i8"), ("q", "<f8", (6,))])
    writer = Record(arena, "viewer.state", dtype)
    reader = Record(arena, "viewer.state", dtype)
    writer.data["tick"] = 7
    writer.data["q"] = np.arange(6.0)
    assert int(reader.data["tick"]) == 7 and reader.data["q"].tolist() == list(range(6))
    many = Record(arena, "viewer.joints", np.dtype("<f8"), 12)
    assert many.data.shape == (12,)
    with pytest.raises(ChannelError, match="exists with size 96 B, attach asked for 64 B"):
        Record(arena, "viewer.joints", np.dtype("<f8"), 8)


def test_instance_segment_name_is_ours(instance: tuple[str, Arena]) -> None:
    name, _ = instance
    assert os.path.exists("/dev/shm" + segment_name(name))


def test_threads_sharing_a_queue_object_put_whole_entries(arena: Arena) -> None:
    """A program and its periodic function (a thread, ``Kali.control``) put through one
    queue object: each stages its entry in its own buffer, under a lock that excludes
    threads, so every entry arrives whole and in each thread's order."""
    import threading

    q = RequestQueue(arena, "q", PAYLOAD, 4096)
    errors: list[BaseException] = []

    def producer(p: int) -> None:
        try:
            for i in range(1000):
                q.put({"producer": p, "i": i})
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=producer, args=(p,)) for p in (1, 2, 3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[0]
    out = np.zeros((), dtype=PAYLOAD)
    seen: dict[int, list[int]] = {1: [], 2: [], 3: []}
    while q.get_into(out) is not None:
        seen[int(out["producer"])].append(int(out["i"]))
    assert all(v == list(range(1000)) for v in seen.values())
