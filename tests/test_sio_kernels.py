"""The compiled kernels (``kali_daemons.core.kernels``) equal their numpy references bit for bit,
over random inputs: counters with wrap, masks, NaN and garbage safe limits, joints beyond
their limits, and range, runaway and current faults on the same tick (issue 26 item 2)."""

from __future__ import annotations

import contextlib
import math
import shutil
from collections.abc import Iterator
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kali_daemons.core import atomic, kernels, layout
from kali_daemons.core.arena import Arena
from kali_daemons.core.channels import ChannelError, InterpolatingFifo
from kali_daemons.core.errors import DaemonError
from kali_daemons.core.kernels import Kernel, copies
from kali_daemons.core.layout import FfState
from kali_daemons.hardware.mcgill import registers
from kali_daemons.sio.feedforward import RobotFeedforward
from kali_daemons.tools import launcher

from .conftest import unique_name

SETTINGS = settings(max_examples=150, deadline=None)
ODD_SAFE = (math.nan, -0.1, 0.0, 4.0, math.inf)  # limits a client may write: none valid


def arms(draw: st.DrawFn) -> tuple[int, ...]:
    """Joint counts of 1..4 arms, 1..8 joints each (one McGill board per arm)."""
    return tuple(draw(st.lists(st.integers(1, registers.BOARD_CHANNELS), min_size=1, max_size=4)))


def floats(draw: st.DrawFn, n: int, lo: float, hi: float) -> np.ndarray:
    values = st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    return np.array(draw(st.lists(values, min_size=n, max_size=n)), dtype=np.float64)


def bools(draw: st.DrawFn, n: int) -> np.ndarray:
    return np.array(draw(st.lists(st.booleans(), min_size=n, max_size=n)), dtype=bool)


def flat_map(counts: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    robot_of = np.repeat(np.arange(len(counts)), counts)
    joint_of = np.concatenate([np.arange(c) for c in counts])
    return robot_of, joint_of


def same(a: np.ndarray, b: np.ndarray) -> None:
    """Bit for bit (NaN payloads and signed zeros included)."""
    assert a.dtype == b.dtype and a.shape == b.shape
    assert a.tobytes() == b.tobytes(), f"\n{a!r}\n{b!r}"


@st.composite
def encoder_case(draw: st.DrawFn) -> dict[str, object]:
    counts = arms(draw)
    n = sum(counts)
    ints = st.integers(-(2**31), 2**31 - 1)
    return {
        "counts": counts,
        "words": np.array(draw(st.lists(st.integers(0, 0xFFFF), min_size=n, max_size=n))),
        "acc": np.array(draw(st.lists(ints, min_size=n, max_size=n)), dtype=np.int32),
        "prev": np.array(
            draw(st.lists(st.one_of(st.integers(0, 4095), ints), min_size=n, max_size=n)),
            dtype=np.int32,
        ),
        "offset": floats(draw, n, -4.0, 4.0),
        "rpc": floats(draw, n, -1e-3, 1e-3),
    }


@SETTINGS
@given(encoder_case())
def test_read_equals_the_reference_with_wrap_and_32_bit_accumulation(c: dict) -> None:
    counts, n = c["counts"], len(c["acc"])
    robot_of, joint_of = flat_map(counts)
    boards = np.zeros(len(counts), registers.IO_BOARD)  # the register record, strided fields
    boards["encoder"][robot_of, joint_of] = c["words"]
    acc, prev, q = c["acc"].copy(), c["prev"].copy(), np.zeros(n)
    enc = boards["encoder"]
    Kernel(
        "kali_read",
        (boards,),
        n=n,
        encoders=enc.ctypes.data,
        enc_off=kernels.channel_offsets(enc, robot_of, joint_of),
        acc=acc,
        prev=prev,
        offset=c["offset"],
        rad_per_count=c["rpc"],
        q=q,
        modulo=kernels.COUNTER_MODULO,
        half=kernels.COUNTER_HALF,
    )()
    ref_acc, ref_prev, ref_q = c["acc"].copy(), c["prev"].copy(), np.zeros(n)
    raw = c["words"].astype(np.int32)
    kernels.read_reference(raw, ref_acc, ref_prev, c["offset"], c["rpc"], ref_q)
    same(acc, ref_acc)
    same(prev, ref_prev)
    same(q, ref_q)


@SETTINGS
@given(st.data())
def test_velocity_equals_the_reference(data: st.DataObject) -> None:
    n = data.draw(st.integers(1, 32))
    q, q_prev, qd = (floats(data.draw, n, -10.0, 10.0) for _ in range(3))
    gain, b = data.draw(st.floats(0.0, 1e4)), data.draw(st.floats(0.0, 1.0))
    k_prev, k_qd = q_prev.copy(), qd.copy()
    Kernel("kali_velocity", n=n, q=q, q_prev=k_prev, qd=k_qd, gain=gain, b=b)()
    kernels.velocity_reference(q, q_prev, qd, gain, b)
    same(k_prev, q_prev)
    same(k_qd, qd)


@st.composite
def checks_case(draw: st.DrawFn) -> dict[str, object]:
    counts = arms(draw)
    n = sum(counts)
    q_min = floats(draw, n, -3.0, 0.0)
    q_max = q_min + floats(draw, n, 0.1, 5.0)
    safe = floats(draw, n, 0.01, math.pi)
    for i in range(n):  # garbage limits from clients (DESIGN 7)
        if draw(st.integers(0, 4)) == 0:
            safe[i] = draw(st.sampled_from(ODD_SAFE))
    return {
        "counts": counts,
        "q": floats(draw, n, -4.0, 4.0),
        "demand": floats(draw, n, -4.0, 4.0),
        "q_min": q_min,
        "q_max": q_max,
        "range_check": np.array(draw(st.lists(st.integers(0, 3), min_size=n, max_size=n)), "u1"),
        "fed": bools(draw, n),
        "safe": safe,
        "safe_ok": floats(draw, n, 0.01, math.pi),
    }


@SETTINGS
@given(checks_case())
def test_checks_name_the_same_joint_and_fault_as_the_reference(c: dict) -> None:
    """Range before runaway within a robot, robots in order; the valid safe limits taken."""
    counts = c["counts"]
    n = len(c["q"])
    bounds = np.array([0, *np.cumsum(counts)], dtype=np.int64)
    js = np.zeros(n, layout.JOINT_STATE)  # the client-written fields are record fields
    js["range_check"], js["safe"] = c["range_check"], c["safe"]
    safe_ok = c["safe_ok"].copy()
    found = Kernel(
        "kali_checks",
        n=n,
        n_robots=len(counts),
        bounds=bounds,
        q=c["q"],
        demand=c["demand"],
        q_min=c["q_min"],
        q_max=c["q_max"],
        range_check=js["range_check"],
        fed=c["fed"],
        safe=js["safe"],
        safe_ok=safe_ok,
        pi=math.pi,
    )()
    ref_ok = c["safe_ok"].copy()
    args = ("q", "demand", "q_min", "q_max", "range_check", "fed", "safe")
    expected = kernels.checks_reference(bounds, *(c[a] for a in args), ref_ok)
    assert found == expected
    same(safe_ok, ref_ok)


def test_range_and_runaway_on_the_same_tick_report_the_first_robots_range() -> None:
    """Robot 0: joint 2 runs away, joint 4 is beyond its range; robot 1 is beyond too: the
    halt names robot 0's joint 4 (range), as SIO's per-robot walk did."""
    counts, n = (6, 6), 12
    bounds = np.array([0, 6, 12], dtype=np.int64)
    q, demand = np.zeros(n), np.zeros(n)
    q_min, q_max = np.full(n, -1.0), np.full(n, 1.0)
    demand[1] = 0.5  # runaway on robot 0 joint 2 (safe 0.1)
    q[3] = 1.5  # robot 0 joint 4 beyond q_max
    q[7] = -2.0  # robot 1 joint 2 beyond q_min
    fed, check = np.ones(n, bool), np.ones(n, "u1")
    safe = np.full(n, 0.1)
    args = (q, demand, q_min, q_max, check, fed, safe)
    kernel = Kernel(
        "kali_checks",
        n=n,
        n_robots=len(counts),
        bounds=bounds,
        **dict(
            zip(("q", "demand", "q_min", "q_max", "range_check", "fed", "safe"), args, strict=True)
        ),
        safe_ok=np.full(n, 0.1),
        pi=math.pi,
    )
    assert kernel() == 3 == kernels.checks_reference(bounds, *args, np.full(n, 0.1))
    q[3] = 0.0  # without the range fault, robot 0's runaway comes first
    assert kernel() == n + 1 == kernels.checks_reference(bounds, *args, np.full(n, 0.1))
    fed[:6] = False  # robot 0 not fed: robot 1's range
    assert kernel() == 7 == kernels.checks_reference(bounds, *args, np.full(n, 0.1))


@SETTINGS
@given(st.data())
def test_feed_equals_the_reference(data: st.DataObject) -> None:
    n = data.draw(st.integers(1, 32))
    names = ("demand", "q", "qd", "vel", "acc", "ff")
    demand, q, qd, vel, acc, ff = (floats(data.draw, n, -10.0, 10.0) for _ in names)
    fed = bools(data.draw, n)
    choices = np.array([0, layout.ARM_FREE, layout.ARM_HELD], dtype=np.uint32)
    mark = choices[data.draw(st.lists(st.integers(0, 2), min_size=n, max_size=n))]
    slots, ref_slots = np.zeros(n, layout.SERVO_SLOT), np.zeros(n, layout.SERVO_SLOT)
    slots["busy"] = ref_slots["busy"] = 7
    ctrl, ref_ctrl = np.ones((), layout.SERVO_CTRL), np.ones((), layout.SERVO_CTRL)
    count = Kernel(
        "kali_feed",
        (ctrl,),
        n=n,
        demand=demand,
        q=q,
        qd=qd,
        fed=fed,
        slot_demand=slots["demand"],
        slot_position=slots["position"],
        slot_velocity=slots["velocity"],
        slot_busy=slots["busy"],
        not_fed=layout.SLOT_NOT_FED,
        ctrl_fed=ctrl["fed"].ctypes.data,
        ctrl_done=ctrl["done"].ctypes.data,
        demand_vel=vel,
        demand_acc=acc,
        ff=ff,
        slot_demand_vel=slots["demand_vel"],
        slot_demand_acc=slots["demand_acc"],
        slot_ff=slots["ff"],
        mark=mark,
    )()
    assert count == kernels.feed_reference(
        demand, q, qd, fed, ref_slots, layout.SLOT_NOT_FED, ref_ctrl, vel, acc, ff, mark
    )
    same(slots, ref_slots)
    same(ctrl, ref_ctrl)


@st.composite
def output_case(draw: st.DrawFn) -> dict[str, object]:
    counts = arms(draw)
    n = sum(counts)
    gkt = floats(draw, n, 1.0, 30.0) * np.where(bools(draw, n), 1.0, -1.0)
    limit = floats(draw, n, 0.5, 10.0)
    return {
        "counts": counts,
        "slot_torque": floats(draw, n, -400.0, 400.0),
        "ff": floats(draw, n, -200.0, 200.0),
        "fed": bools(draw, n),
        "gkt": gkt,
        "limit": limit,
        "codes_per_amp": floats(draw, n, 10.0, 2000.0),  # past full scale: codes clip
        "over": np.array(draw(st.lists(st.integers(0, 50), min_size=n, max_size=n)), np.int64),
        "ticks": np.array(draw(st.lists(st.integers(1, 50), min_size=n, max_size=n)), np.int64),
    }


@SETTINGS
@given(output_case())
def test_torques_dac_and_current_check_equal_the_reference(c: dict) -> None:
    """Torque sum (fed joints), currents clamped, DAC codes rounded and clipped, and the
    current counter naming the same first joint, on the boards' per-arm DAC registers."""
    counts = c["counts"]
    n = len(c["fed"])
    robot_of, joint_of = flat_map(counts)
    dacs = np.zeros(len(counts), registers.DAC_BOARD)
    codes = dacs["code"]
    slot = np.zeros(n, layout.SERVO_SLOT)
    slot["torque"] = c["slot_torque"]
    servo, ff, torque = np.zeros(n), c["ff"].copy(), np.zeros(n)
    current, clamped, over = np.zeros(n), np.zeros(n, bool), c["over"].copy()
    fed = c["fed"]
    Kernel(
        "kali_torques",
        n=n,
        slot_torque=slot["torque"],
        fed=fed,
        servo_torque=servo,
        ff=ff,
        torque=torque,
    )()
    Kernel(
        "kali_dac",
        (dacs,),
        n=n,
        torque=torque,
        gkt=c["gkt"],
        current_limit=c["limit"],
        codes_per_amp=c["codes_per_amp"],
        current=current,
        clamped=clamped,
        dacs=codes.ctypes.data,
        dac_off=kernels.channel_offsets(codes, robot_of, joint_of),
        zero=float(registers.DAC_ZERO),
        top=4095.0,
    )()
    first = Kernel(
        "kali_current_check",
        n=n,
        torque=torque,
        fed=fed,
        clamped=clamped,
        over=over,
        current_ticks=c["ticks"],
    )()
    r_servo, r_ff, r_torque = np.zeros(n), c["ff"].copy(), np.zeros(n)
    r_current, r_clamped, r_over = np.zeros(n), np.zeros(n, bool), c["over"].copy()
    kernels.torques_reference(c["slot_torque"], fed, r_servo, r_ff, r_torque)
    r_codes = kernels.dac_reference(
        r_torque, c["gkt"], c["limit"], c["codes_per_amp"], r_current, r_clamped,
        float(registers.DAC_ZERO), 4095.0,
    )  # fmt: skip
    r_first = kernels.current_check_reference(r_torque, fed, r_clamped, r_over, c["ticks"])
    for a, b in ((servo, r_servo), (ff, r_ff), (torque, r_torque), (current, r_current)):
        same(a, b)
    same(clamped, r_clamped)
    same(codes[robot_of, joint_of], r_codes)
    assert not codes[np.ones_like(codes, bool) & (np.arange(8) >= np.array(counts)[:, None])].any()
    same(over, r_over)
    assert first == r_first


@SETTINGS
@given(st.data())
def test_copies_publish_each_array_into_its_record_field(data: st.DataObject) -> None:
    n = data.draw(st.integers(1, 32))
    q = floats(data.draw, n, -10.0, 10.0)
    acc = np.array(data.draw(st.lists(st.integers(-(2**31), 2**31 - 1), min_size=n, max_size=n)))
    acc = acc.astype(np.int32)
    js = np.zeros(n, layout.JOINT_STATE)
    copies([(q, js["q"]), (acc, js["acc"])])()
    same(js["q"].copy(), q)
    same(js["acc"].copy(), acc)
    assert not js["qd"].any() and not js["prev"].any()


def test_the_library_is_built_once_per_source_and_reloaded(tmp_path, monkeypatch) -> None:
    """A fresh directory gets the library on the first build; its name carries the source's
    hash, so an edited source (csrc/) never loads a stale one."""
    monkeypatch.setenv("KALI_KERNEL_DIR", str(tmp_path))
    path = kernels.library_path()
    assert path.parent == tmp_path and path.name.startswith("controller-")
    assert not path.exists()
    assert kernels.build() == path and path.exists()
    assert [p.name for p in tmp_path.iterdir()] == [path.name]  # no temporary left


def test_the_librarys_structs_mirror_the_records_dtypes() -> None:
    """The servo kernels step the arena's slot and built-in records in place: each C struct
    has its dtype's fields, at the same offsets, of the same size and kind, and its size."""
    lib = kernels.load()
    for record, (number, dtype) in kernels.RECORDS.items():
        fields, size = kernels.struct_fields(lib, number)
        assert fields == kernels.dtype_fields(dtype), record
        assert size == dtype.itemsize, record


def test_a_library_whose_struct_differs_from_the_dtype_is_refused(tmp_path) -> None:
    """A kernel_args.h whose PD struct has two fields swapped builds, but is refused at load
    with an error naming the record, the field and both layouts; so is a dtype that has moved."""
    csrc = tmp_path / "csrc"
    shutil.copytree(kernels.CSRC, csrc)
    text = kernels.HEADER.read_text()
    struct = "typedef struct {\n    double kp;\n    double kv;"
    assert struct in text
    swapped = text.replace(struct, "typedef struct {\n    double kv;\n    double kp;")
    (csrc / kernels.HEADER.name).write_text(swapped)
    path = kernels.build(tmp_path / "kernels-swapped.so", csrc / "controller.c")
    with pytest.raises(DaemonError, match=r"PD_DTYPE: field 'kp' is .* \(8, 8, 'f'\) in C, "):
        kernels.open_library(path)
    moved = np.dtype([("busy", "<u4"), *layout.SERVO_SLOT.descr[2:]], align=True)  # no op
    here = kernels.library_path()
    refused = r"SERVO_SLOT: field 'op_algo' is .* \(8, 4, 'u'\) in C, \(4, 4, 'u'\) in the"
    with pytest.raises(DaemonError, match=refused):
        kernels.check_record(kernels.load(), here, "layout.SERVO_SLOT", 0, moved)


# ---------------------------------------------------------------------------- feed-forward


@pytest.fixture(scope="module")
def ff_fifo() -> Iterator[InterpolatingFifo]:
    """A robot's FIFO (six joints) in a small arena: the test sets its header as SIO's pops
    would leave it (head, the segment's ticks and those done)."""
    name = unique_name("ff")
    a = Arena.create(name, 1 << 20)
    yield InterpolatingFifo(a, layout.KEY_FIFO.format(robot="r"), 6, 16, Fraction(10))
    a.close()
    launcher.stop(name)


@st.composite
def ff_tick(draw: st.DrawFn, n: int) -> dict[str, object]:
    """One servo tick's inputs: the mode word (a client's garbage too), a robot-level servo
    or not, the dynamics process's heartbeat (fresh, old, garbage), the FIFO's segment and
    the rows of A and B present, missing, being written (FF_NO_KEY) or holding NaN."""
    values = st.floats(-50, 50, allow_nan=False, allow_infinity=False)
    rows = {}
    for which in ("a", "b"):
        cells = draw(st.lists(values, min_size=3 * n, max_size=3 * n))
        row = np.array(cells).reshape(3, n)
        if draw(st.integers(0, 9)) == 0:
            row[draw(st.integers(0, 2)), draw(st.integers(0, n - 1))] = draw(
                st.sampled_from([math.nan, math.inf, -math.inf])
            )
        rows[which] = (row, draw(st.sampled_from(["there", "there", "there", "gone", "busy"])))
    ticks = draw(st.integers(0, 12))
    return {
        "mode": draw(st.sampled_from([0, 1, 2, 2, 2, 3, 255])),
        "arm": draw(st.booleans()),
        "age": draw(st.sampled_from([0, 1, 5, 50, 51, -3, 2**62, -(2**62)])),
        "head": draw(st.sampled_from([0, 1, 2, 511, 512, 1000, 2**63 + 5])),
        "seg": (ticks, draw(st.integers(0, ticks + 1))),
        "rows": rows,
    }


@SETTINGS
@given(st.data())
def test_feedforward_equals_the_reference_tick_for_tick(
    ff_fifo: InterpolatingFifo, data: st.DataObject
) -> None:
    """``kali_feedforward`` (``RobotFeedforward.compiled``) gives what ``update`` gives, bit
    for bit, tick after tick from the same start: the torque, velocity and acceleration out,
    the state, weight (its ramp), stale counts and the missing count, through garbage mode
    words, stale and garbage heartbeats, missing, half-written and NaN rows."""
    n = 6
    records = np.zeros(2, dtype=layout.FEEDFORWARD)
    start = data.draw(
        st.sampled_from(
            [
                (0, 0.0, FfState.OFF),
                (2, 1.0, FfState.ON),
                (1, 0.3, FfState.STALE),
                (7, 0.0, FfState.OFF),
            ]
        )
    )
    records["mode"], records["weight"], records["state"] = start
    outs = np.zeros((2, 3, n))
    limits = {"heartbeat_limit": 50, "missing_limit": 3, "step": 0.2}
    ref = RobotFeedforward(
        records, 0, ff_fifo, outs[0, 0], vel=outs[0, 1], acc=outs[0, 2], **limits
    )
    ker = RobotFeedforward(
        records, 1, ff_fifo, outs[1, 0], vel=outs[1, 1], acc=outs[1, 2], **limits
    ).compiled()
    for tick in range(100, 100 + data.draw(st.integers(1, 12))):
        t = data.draw(ff_tick(n))
        atomic.store64(ff_fifo.segment_addresses()[0], t["head"])
        ff_fifo._seg_ticks[...], ff_fifo._seg_done[...] = t["seg"]
        records["mode"] = t["mode"]
        records["heartbeat_tick"] = tick - t["age"]
        records["key"] = layout.FF_NO_KEY
        for which, key in (("a", t["head"] - 1), ("b", t["head"])):
            row, how = t["rows"][which]
            if key < 0 or how == "gone":
                continue
            r = key % layout.FF_ROWS
            for field, values in zip(("tau", "qd", "qdd"), row, strict=True):
                records[field][:, r, :n] = values
            records["key"][:, r] = key if how == "there" else layout.FF_NO_KEY
        ref.arm = ker.arm = t["arm"]
        with np.errstate(invalid="ignore"):  # inf - inf in a garbage row: NaN, as in SIO
            ref.update(tick)
        ker.step(tick)
        same(outs[1], outs[0])
        for field in ("state", "weight", "stale_ticks", "stale_events"):
            assert records[field][1] == records[field][0], field
        assert (ker.weight, ker.missing, ker.stale) == (ref.weight, ref.missing, ref.stale)


# ---------------------------------------------------------------------------- the demand


@contextlib.contextmanager
def small_arena() -> Iterator[Arena]:
    """A fresh 1 MiB arena, unlinked afterwards (one per example: a directory holds 256
    blocks, a FIFO takes four)."""
    name = unique_name("pop")
    a = Arena.create(name, 1 << 20)
    try:
        yield a
    finally:
        a.close()
        launcher.stop(name)


@st.composite
def fifo_ops(draw: st.DrawFn, width: int) -> list[tuple[str, object]]:
    """What the TG (pushes, ratio changes), a client's garbage (a stamp no ``set_ratio``
    writes) and SIO (pops, resets) do to a FIFO, in some order: set-points within, at and
    beyond the bound, NaN among them; pops past the end (underruns)."""
    value = st.one_of(
        st.floats(-5, 5, allow_nan=False), st.sampled_from([10.0, -10.0, 11.0, math.nan, math.inf])
    )
    row = st.lists(value, min_size=width, max_size=width).map(np.array)
    ops = st.one_of(
        st.tuples(st.just("push"), row),
        st.tuples(st.just("pop"), st.integers(1, 12)),
        st.tuples(st.just("ratio"), st.sampled_from([(10, 1), (5, 2), (1, 1), (7, 3)])),
        st.tuples(st.just("stamp"), st.sampled_from([0, 3, 2 | 5 << 32, 7 | 2 << 32])),
        st.tuples(st.just("reset"), st.floats(-1, 1).map(lambda x: np.full(width, x))),
    )
    return draw(st.lists(ops, min_size=1, max_size=40))


@SETTINGS
@given(st.data())
def test_the_compiled_pop_equals_pop_into_tick_for_tick(data: st.DataObject) -> None:
    """``kali_fifo_pop`` (``InterpolatingFifo.compiled_pop``) gives what ``pop_into`` gives,
    bit for bit, pop after pop from the same pushes: the demand, the return, the header
    (head, segment, accumulator, ratio, rejected and underrun counts) and the A/B/output
    state, through fractional ratios changed on line, garbage stamps and set-points refused
    for NaN or beyond the bound."""
    width = data.draw(st.integers(1, layout.MAX_JOINTS))
    ops = data.draw(fifo_ops(width))
    with small_arena() as arena:
        _pop_alike(arena, width, ops)


def _pop_alike(arena: Arena, width: int, ops: list[tuple[str, object]]) -> None:
    """Apply ``ops`` to two FIFOs, popping one by ``pop_into`` and one by its kernel, and
    compare them after every pop."""
    ref, com = (
        InterpolatingFifo(arena, f"fifo.{w}", width, 8, Fraction(10), bound=10.0)
        for w in ("ref", "com")
    )
    out = np.zeros((2, width))
    pop = com.compiled_pop(out[1])
    for op, arg in ops:
        for f in (ref, com):
            if op == "push":
                with contextlib.suppress(ChannelError):  # full, or not finite: refused
                    f.push(arg)
            elif op == "ratio":
                f.set_ratio(arg)
            elif op == "stamp":  # on the newest set-point, as garbage would land
                tail = atomic.load64(f._tail_addr)
                if tail:
                    f._stamps[(tail - 1) % 8] = arg
            elif op == "reset":
                f.reset(arg)
        if op != "pop":
            continue
        for _ in range(arg):
            got = (ref.pop_into(out[0]), pop())
            assert got[1] == int(got[0])
            same(out[1], out[0])
            assert com._h.tobytes() == ref._h.tobytes()
            for a, b in (
                (com._cur, ref._cur),
                (com._start, ref._start),
                (com._target, ref._target),
            ):
                same(a, b)
    with pytest.raises(AssertionError, match="popped by its kernel"):
        com.pop_into(out[1])


def test_a_ratio_change_mid_fraction_restarts_both_accumulators_alike() -> None:
    """A ratio taken while a fractional one has accumulated part of a tick (5/2: segments of
    2, 3, 2, ... ticks) drops that part in both (channels.py's rule), then 7/3 runs on."""
    ops: list[tuple[str, object]] = [("ratio", (5, 2))]
    ops += [("push", np.full(6, float(i))) for i in range(4)]
    ops += [("pop", 6), ("ratio", (7, 3))]
    ops += [("push", np.full(6, float(i))) for i in range(4, 8)]
    ops += [("pop", 12), ("pop", 12)]
    with small_arena() as arena:
        _pop_alike(arena, 6, ops)
