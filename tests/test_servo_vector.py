"""The built-in servos run over many joints in one call (issue 26 item 2): the compiled
``servo.vector`` steps (C, ``csrc/servo.c``) equal the per-joint Python ``step`` bit for bit,
the SV's unit (``sv.units``) takes exactly the joints it may, leaves the rest to the per-slot
path and equals its Python reference, no daemon imports numba, and on line a joint switches
between PID, PD and a plugin inside a running unit without a torque jump while the rest of
the unit runs on (lockstep).
"""

from __future__ import annotations

import math
import subprocess
import sys
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kali_daemons.core import layout
from kali_daemons.core.layout import SlotOp, SlotReset
from kali_daemons.servo import PD, PID, Handover, struct_view
from kali_daemons.servo.algorithms.vector import pd_vector_step, pid_vector_step
from kali_daemons.servo.sv.units import serve_unit, serve_unit_reference
from kali_daemons.wallclock import step_kali_clock

from .conftest import ByArm
from .test_servo_level import _ramp, servoing

T = 0.001  # s, the servo interval
TOL = 0.0
STEPS = {"pid": pid_vector_step, "pd": pd_vector_step}
ALGOS = {"pid": PID, "pd": PD}

finite = st.floats(-1.0, 1.0, allow_nan=False)
PID_PARAMS = st.fixed_dictionaries(
    {
        "kp": st.floats(0.0, 2e4),
        "ki": st.sampled_from([0.0, 1.0, 5e3, 3e5]),  # none, slow, fast: the reset clamps
        "kv": st.floats(0.0, 400.0),
        "fe": st.floats(1.0, 2000.0),
        "fv": st.floats(1.0, 2000.0),
        "integration_band": st.sampled_from([0.0, 1e-4, 0.01, 0.05, math.pi]),
        "integration_reset": st.sampled_from([0.0, 0.5, 10.0, 100.0]),
        "bias_tau": st.sampled_from([0.0, 0.01, 0.5]),
    }
)
PD_PARAMS = st.fixed_dictionaries(
    {
        "kp": st.floats(0.0, 2e4),
        "kv": st.floats(0.0, 400.0),
        "fv": st.floats(1.0, 2000.0),
        "bias_tau": st.sampled_from([0.0, 0.01, 0.5]),
    }
)
STATE = st.fixed_dictionaries(
    {
        "error": finite,
        "old_position": finite,
        "old_velocity": st.floats(-5.0, 5.0),
        "integral": st.floats(-100.0, 100.0),
        "bias": st.floats(-50.0, 50.0),
        "primed": st.sampled_from([0, 1]),
    }
)


def _joints(name: str, params: list[dict], states: list[dict]) -> np.ndarray:
    """A block of records of algorithm ``name``, one per joint: initialised with ``params``,
    then set to ``states`` (the integral within the joint's reset, as set_params keeps it)."""
    alg = ALGOS[name]
    block = np.zeros(len(params), alg.dtype)
    for j, (p, s) in enumerate(zip(params, states, strict=True)):
        alg.init(struct_view(block[j : j + 1]), p, T)
        for field, value in s.items():
            if field in (alg.dtype.names or ()):
                block[j][field] = value
        if name == "pid":
            reset = block[j]["integration_reset"]
            block[j]["integral"] = min(max(block[j]["integral"], -reset), reset)
    return block


def _assert_records_close(a: np.ndarray, b: np.ndarray, what: str) -> None:
    for field in a.dtype.names or ():
        np.testing.assert_allclose(
            a[field], b[field], rtol=TOL, atol=TOL, err_msg=f"{what} {field}"
        )


def _lockstep_compare(
    name: str,
    params: list[dict],
    states: list[dict],
    inputs: list[list[tuple[float, float]]],
    handover_at: int | None,
    handover: Handover,
) -> None:
    """Step every joint ``len(inputs)`` times both ways, the per-joint ``step`` on one copy
    and the vector step over all joints on the other; a hand-over of the first joint before
    step ``handover_at``.  Torques, errors, statuses and every field equal to 1e-12."""
    alg, vector = ALGOS[name], STEPS[name]
    reference = _joints(name, params, states)
    block = reference.copy()
    n = len(params)
    rows = np.arange(n, dtype=np.int64)
    torque, error, status = np.zeros(n), np.zeros(n), np.zeros(n, np.int32)
    for k, tick in enumerate(inputs):
        if k == handover_at:
            alg.handover(struct_view(reference[0:1]), handover)
            alg.handover(struct_view(block[0:1]), handover)  # as the SV: per slot, on the row
        demand = np.array([d for d, _ in tick])
        position = np.array([p for _, p in tick])
        vector(block, rows, demand, position, torque, error, status)
        for j in range(n):
            t, e, s = alg.step(struct_view(reference[j : j + 1]), demand[j], position[j])
            assert math.isclose(torque[j], t, rel_tol=TOL, abs_tol=TOL), (k, j, torque[j], t)
            assert math.isclose(error[j], e, rel_tol=TOL, abs_tol=TOL), (k, j, error[j], e)
            assert status[j] == s
        _assert_records_close(block, reference, f"{name} after step {k}")


def _inputs(n: int) -> st.SearchStrategy:
    """Steps of (demand, position) for ``n`` joints: small errors around the integration
    bands and large ones beyond them, the same joint moving from step to step."""
    pair = st.tuples(finite, st.sampled_from([0.0, 1e-5, 1e-4, 0.009, 0.05, 0.3])).map(
        lambda pe: (pe[0] + pe[1], pe[0])
    )
    return st.lists(st.lists(pair, min_size=n, max_size=n), min_size=1, max_size=40)


HANDOVER = st.builds(
    Handover,
    st.floats(-1.0, 1.0),
    st.floats(-3.0, 3.0),
    st.floats(-1.0, 1.0),
    st.floats(-0.1, 0.1),
    st.floats(-200.0, 200.0),
)


@settings(max_examples=150, deadline=None)
@given(
    data=st.data(),
    n=st.integers(1, 8),
    handover_at=st.one_of(st.none(), st.integers(0, 39)),
    handover=HANDOVER,
)
def test_the_vector_pid_equals_the_per_joint_step(
    data: st.DataObject, n: int, handover_at: int | None, handover: Handover
) -> None:
    params = data.draw(st.lists(PID_PARAMS, min_size=n, max_size=n))
    states = data.draw(st.lists(STATE, min_size=n, max_size=n))
    _lockstep_compare("pid", params, states, data.draw(_inputs(n)), handover_at, handover)


@settings(max_examples=100, deadline=None)
@given(
    data=st.data(),
    n=st.integers(1, 8),
    handover_at=st.one_of(st.none(), st.integers(0, 39)),
    handover=HANDOVER,
)
def test_the_vector_pd_equals_the_per_joint_step(
    data: st.DataObject, n: int, handover_at: int | None, handover: Handover
) -> None:
    params = data.draw(st.lists(PD_PARAMS, min_size=n, max_size=n))
    states = data.draw(st.lists(STATE, min_size=n, max_size=n))
    _lockstep_compare("pd", params, states, data.draw(_inputs(n)), handover_at, handover)


@pytest.mark.parametrize("side", [1.0, -1.0])
def test_the_vector_pid_integrates_at_the_band_edge_and_clamps_at_the_reset(side: float) -> None:
    """An error exactly at ±integration_band integrates (the band is closed), one just
    beyond does not; the integral stops exactly at ±integration_reset.  The error filter is
    set to pass the previous error through (lpfe1 = 0) so the error is exact."""
    band, reset = 0.01, 2.0
    params = [{"ki": 1e5, "integration_band": band, "integration_reset": reset}] * 3
    block = _joints("pid", params, [{"primed": 1}] * 3)
    block["lpfe1"], block["lpfe2"] = 0.0, 1.0
    block["error"] = side * np.array([band, np.nextafter(band, 1.0), band])
    block["integral"] = side * np.array([0.0, 0.0, reset - 1e-3])
    reference = block.copy()
    rows = np.arange(3, dtype=np.int64)
    out = np.zeros(3), np.zeros(3), np.zeros(3, np.int32)
    pid_vector_step(block, rows, np.zeros(3), np.zeros(3), *out)
    for j in range(3):
        PID.step(struct_view(reference[j : j + 1]), 0.0, 0.0)
    _assert_records_close(block, reference, "band edges")
    ki_t = block["ki_t"][0]
    assert block["integral"][0] == side * ki_t * band  # at the edge: integrated
    assert block["integral"][1] == 0.0  # beyond it: not
    assert block["integral"][2] == side * reset  # clamped exactly at the reset


# --------------------------------------------------------------------------------------------
# The SV's unit: which slots it takes


def _cell(n: int, plugin: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[str]]:
    """Slots and built-in blocks of ``n`` joints: joint j runs pid, pd or the plugin index
    ``plugin`` in turn, fed, each with a different demand."""
    slots = np.zeros(n, layout.SERVO_SLOT)
    names = [("pid", "pd", "plugin")[j % 3] for j in range(n)]
    slots["algo"] = [{"pid": 0, "pd": 1, "plugin": plugin}[a] for a in names]
    slots["enabled"] = 1
    slots["position"] = np.linspace(-0.5, 0.5, n)
    slots["demand"] = slots["position"] + np.linspace(0.001, 0.02, n)
    slots["ran_tick"] = -1
    pid = _joints("pid", [{"ki": 100.0}] * n, [{"primed": 1, "integral": 0.3}] * n)
    pd = _joints("pd", [{}] * n, [{"primed": 1, "bias": 1.5}] * n)
    return slots, pid, pd, names


def test_a_unit_runs_exactly_the_fed_builtins_with_nothing_to_do_first() -> None:
    """Of one robot's slots ``lo..hi-1``, the unit claims (busy = the SV's number) and runs
    the fed PID and PD joints with no mailbox operation, no reset and the servo enabled;
    plugins, a pending operation, a reset, a disabled servo, an unfed or claimed slot are
    left as they are for the per-slot path.  What it runs equals the per-joint step."""
    n, me, tick, sv = 12, 2, 77, 1
    slots, pid, pd, names = _cell(n, plugin=2)
    busy = slots["busy"]
    slots["op"][3] = SlotOp.GET  # a pid with a mailbox operation
    slots["reset"][4] = SlotReset.SHIFT  # a pd with a reset
    slots["enabled"][6] = 0  # a pid disabled
    busy[7] = layout.SLOT_NOT_FED  # a pd not fed
    busy[9] = 1  # a pid another SV has claimed
    reference = {"pid": pid.copy(), "pd": pd.copy()}
    left = np.zeros(n, np.int64)
    lo, hi = 0, 10  # the robot: joints 10 and 11 belong to another
    ran, n_left, fault, _ = serve_unit(slots, pid, pd, lo, hi, 0, 1, me, tick, sv, 5, left)
    expect = [j for j in range(lo, hi) if names[j] != "plugin" and j not in (3, 4, 6, 7, 9)]
    assert (ran, n_left, fault) == (len(expect), 0, -1)
    assert [j for j in range(n) if busy[j] == me] == expect
    assert [j for j in range(n) if slots["ran_tick"][j] == tick] == expect
    for j in range(n):
        if j in expect:
            alg = ALGOS[names[j]]
            t, e, s = alg.step(struct_view(reference[names[j]][j : j + 1]), *_inputs_of(slots, j))
            assert math.isclose(slots["torque"][j], t, rel_tol=TOL, abs_tol=TOL)
            assert math.isclose(slots["error"][j], e, rel_tol=TOL, abs_tol=TOL)
            assert (slots["status"][j], slots["sv"][j], slots["exec_ns"][j]) == (s, sv, 5)
        else:  # untouched: its slot and both its records
            assert slots["torque"][j] == 0.0 and slots["ran_tick"][j] == -1
            assert busy[j] in (0, layout.SLOT_NOT_FED, 1) and busy[j] != me
    _assert_records_close(pid, reference["pid"], "pid block")
    _assert_records_close(pd, reference["pd"], "pd block")


def _inputs_of(slots: np.ndarray, j: int) -> tuple[float, float]:
    return float(slots["demand"][j]), float(slots["position"][j])


def test_a_non_finite_torque_in_a_unit_is_reported_and_the_rest_runs_on() -> None:
    """A joint whose step gives a non-finite torque (here a NaN demand) gets torque 0 and
    no ``ran_tick``, counts as done, and is reported with its torque for the SV's halt; the
    unit's other joints run."""
    slots, pid, pd, _ = _cell(6, plugin=2)
    slots["demand"][1] = math.nan  # a pd joint
    left = np.zeros(6, np.int64)
    ran, n_left, fault, torque = serve_unit(slots, pid, pd, 0, 6, 0, 1, 1, 5, 0, 0, left)
    assert (ran, n_left, fault) == (4, 0, 1) and math.isnan(torque)
    assert slots["torque"][1] == 0.0 and slots["ran_tick"][1] == -1
    assert list(slots["ran_tick"]) == [5, -1, -1, 5, 5, -1]  # 2 and 5 are the plugin's


SLOT_CASE = st.fixed_dictionaries(
    {
        "busy": st.sampled_from([0, 0, 0, 1, 3, layout.SLOT_NOT_FED]),
        "op": st.sampled_from([0, 0, 0, int(SlotOp.GET)]),
        "reset": st.sampled_from([0, 0, 0, int(SlotReset.SHIFT)]),
        "enabled": st.sampled_from([1, 1, 1, 0]),
        "algo": st.sampled_from([0, 1, 0, 1, 2, 99]),  # pid, pd, a plugin, garbage
        "demand": st.one_of(finite, st.sampled_from([math.nan, math.inf])),
        "position": finite,
    }
)


@settings(max_examples=150, deadline=None)
@given(
    data=st.data(),
    n=st.integers(1, 10),
    ticks=st.integers(1, 4),
    pid_state=STATE,
    pd_state=STATE,
    params=PID_PARAMS,
)
def test_the_compiled_unit_equals_its_python_reference(
    data: st.DataObject, n: int, ticks: int, pid_state: dict, pd_state: dict, params: dict
) -> None:
    """Over random slots (fed or not, claimed by another SV, an operation or a reset
    pending, disabled, a plugin or garbage algorithm, a NaN or infinite demand), the kernel
    claims, runs and reports exactly what ``serve_unit_reference`` does over the per-joint
    Python steps, tick after tick: every slot field and every record, bit for bit."""
    cases = data.draw(st.lists(SLOT_CASE, min_size=n, max_size=n))
    lo = data.draw(st.integers(0, n - 1))
    hi = data.draw(st.integers(lo, n))
    slots = np.zeros(n, layout.SERVO_SLOT)
    slots["ran_tick"] = -1
    pid = _joints("pid", [params] * n, [pid_state] * n)
    pd = _joints("pd", [{}] * n, [pd_state] * n)
    ours = slots, pid, pd
    theirs = slots.copy(), pid.copy(), pd.copy()
    for tick in range(ticks):
        for s, _, _ in (ours, theirs):  # this tick's feed: the joints move on
            for j, case in enumerate(cases):
                for field, value in case.items():
                    s[field][j] = value + 0.01 * tick if field == "position" else value
        left = np.zeros(n, np.int64)
        got = serve_unit(*ours, lo, hi, 0, 1, 2, tick, 1, 7 + tick, left)
        want = serve_unit_reference(*theirs, lo, hi, 0, 1, 2, tick, 1, 7 + tick, left)
        assert got[:3] == want[:3], (tick, got, want)
        assert got[3] == want[3] or (math.isnan(got[3]) and math.isnan(want[3])), (got, want)
        for a, b in zip(ours, theirs, strict=True):  # field by field: copies skip padding
            for field in a.dtype.names or ():
                assert a[field].tobytes() == b[field].tobytes(), (tick, field, a[field], b[field])


def test_no_daemon_loads_numba() -> None:
    """The servo path's kernels are C (csrc/): importing the SV or SIO daemon loads
    neither numba nor llvmlite (~127 MB RSS, all of it locked by mlockall)."""
    code = (
        "import sys, kali_daemons.servo.sv.daemon, kali_daemons.sio.daemon;"
        "import kali_daemons.servo.sv.units;"
        "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numba', 'llvmlite')))"
    )
    done = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=120
    )
    assert done.stdout.strip() == "[]", done.stdout[:300]


# --------------------------------------------------------------------------------------------
# Lockstep: switching inside a running unit


def test_a_joint_switched_between_pid_pd_and_a_plugin_in_a_unit_stays_bumpless(
    kali: Callable[..., str],
) -> None:
    """The left arm's joint 2, moving under gravity, is switched on line pid → pd → bwpd
    (the example plugin) → pid → bwpd → pd → pid, a tick apart in lockstep.  At each switch
    the torque moves no more than the servo's own tick-to-tick change (+1 N·m), every other
    joint of both arms runs every tick (the rest of the unit keeps running), and the arms
    hold: no fault."""
    name = kali(lockstep=True)
    with servoing(name) as (inst, client):
        r = ByArm(client.level)
        slots = client.level.slots
        _ramp(client, 0, 1, 0.15, 150)  # joint 2 moving for 1.5 s
        step_kali_clock(inst, 300)
        jumps, usual = [], []
        for algorithm in ("pd", "bwpd", "pid", "bwpd", "pd", "pid"):
            steps = []
            for _ in range(50):
                before = float(r["servo_torque"][0, 1])
                step_kali_clock(inst, 1)
                steps.append(abs(float(r["servo_torque"][0, 1]) - before))
            usual.append(max(steps))
            before = float(r["servo_torque"][0, 1])
            client.select("left", 2, algorithm, wait=False)
            step_kali_clock(inst, 1)
            tick = int(inst.clock["tick"]) - 1
            assert client.active("left", 2) == algorithm
            assert (slots["ran_tick"] == tick).all(), slots["ran_tick"]  # nothing skipped
            jumps.append(abs(float(r["servo_torque"][0, 1]) - before))
            step_kali_clock(inst, 20)
            tick = int(inst.clock["tick"]) - 1
            assert (slots["ran_tick"] == tick).all(), slots["ran_tick"]
        for jump, normal in zip(jumps, usual, strict=True):
            assert jump <= normal + 1.0, f"torque jumps {jumps} N·m, usual changes {usual}"
        assert inst.fault_text() is None
        del r, slots
