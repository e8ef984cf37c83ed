"""The FR3's compiled kernels (``kali_franka_read``, ``_write``, ``_control``) equal their
numpy references bit for bit over random states and torques: torques beyond the FR3's limits
and jumps beyond its torque rate, arms powered, enabling, off or halted."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import numpy as np
import posix_ipc
from hypothesis import given, settings
from hypothesis import strategies as st

from kali_daemons.core.layout import PowerState
from kali_daemons.hardware.franka.arms import TAU_RATE_MAX, FrankaArms, FrankaDriver
from kali_daemons.hardware.franka.registers import FRANKA_ARM
from kali_daemons.robots import robot_type

from .conftest import unique_name

SETTINGS = settings(max_examples=100, deadline=None)
FR3 = robot_type("fr3")


@contextmanager
def link_semaphores(n: int) -> Iterator[list[posix_ipc.Semaphore]]:
    """``n`` links' wake-up semaphores, removed afterwards."""
    sems = [posix_ipc.Semaphore(f"/{unique_name('fk')}", posix_ipc.O_CREX, 0o600) for _ in range(n)]
    try:
        yield sems
    finally:
        for sem in sems:
            sem.unlink()
            sem.close()


def floats(draw: st.DrawFn, n: int, lo: float, hi: float) -> np.ndarray:
    values = st.floats(lo, hi, allow_nan=False, allow_infinity=False)
    return np.array(draw(st.lists(values, min_size=n, max_size=n)), dtype=np.float64)


def two_drivers(n_arms: int) -> tuple[FrankaDriver, FrankaDriver]:
    """Two drivers on two copies of ``n_arms`` FR3 records: one for the kernels, one for the
    references."""
    return tuple(  # type: ignore[return-value]
        FrankaDriver([FR3] * n_arms, np.zeros(n_arms, FRANKA_ARM), 1e-3) for _ in range(2)
    )


@SETTINGS
@given(st.data())
def test_read_and_write_equal_their_references(data: st.DataObject) -> None:
    n_arms = data.draw(st.integers(1, 4))
    compiled, reference = two_drivers(n_arms)
    n = compiled.n
    q_state = floats(data.draw, n_arms * 8, -3.0, 3.0).reshape(n_arms, 8)
    seq = np.array(data.draw(st.lists(st.integers(0, 2**63), min_size=n_arms, max_size=n_arms)))
    last = floats(data.draw, n, -90.0, 90.0)
    torque = floats(data.draw, n, -200.0, 200.0)
    for d in (compiled, reference):
        d.arms["q"] = q_state
        d.arms["seq"] = seq
        d.last[:] = last
    q = [np.zeros(n), np.zeros(n)]
    current = [np.zeros(n), np.zeros(n)]
    clamped = [np.zeros(n, bool), np.zeros(n, bool)]
    compiled.bind(q[0], torque, current[0], clamped[0])
    compiled.read(q[0])
    compiled.write(torque, current[0], clamped[0])
    reference.read_reference(q[1], reference.seen)
    reference.write_reference(torque, current[1], clamped[1])
    for a, b in ((q, q), (current, current), (clamped, clamped)):
        assert a[0].tobytes() == b[1].tobytes()
    assert compiled.seen.tobytes() == reference.seen.tobytes()
    assert compiled.arms.tobytes() == reference.arms.tobytes()
    step = TAU_RATE_MAX * 1e-3
    within = np.abs(last) <= compiled.torque_limit  # a torque sent before (within its limit)
    assert (np.abs(current[0] - last)[within] <= step + 1e-12).all()  # the FR3's rate held
    assert (np.abs(current[0]) <= compiled.torque_limit).all()  # and its limit, always


@SETTINGS
@given(st.data())
def test_control_equals_its_reference(data: st.DataObject) -> None:
    n_arms = data.draw(st.integers(1, 4))
    states = [PowerState.OFF, PowerState.ENABLING, PowerState.ON]
    power = np.array(
        data.draw(st.lists(st.sampled_from(states), min_size=n_arms, max_size=n_arms)), np.uint8
    )
    halted = data.draw(st.booleans())
    fault = np.array([1 if halted else 0], dtype=np.uint32)
    tau = floats(data.draw, n_arms * 8, -80.0, 80.0).reshape(n_arms, 8)
    seen = np.array(data.draw(st.lists(st.integers(0, 2**63), min_size=n_arms, max_size=n_arms)))
    with link_semaphores(n_arms) as sems:
        arms = []
        for _ in range(2):
            a = FrankaArms(np.zeros(n_arms, FRANKA_ARM), [FR3] * n_arms, sems, 1e-3)
            a._arms["tau"] = tau
            a.driver.seen[:] = seen
            a.driver.last[:] = 1.0
            arms.append(a)
        compiled, reference = arms
        n = compiled.driver.n
        compiled.driver.bind(np.zeros(n), np.zeros(n), np.zeros(n), np.zeros(n, bool))
        _, _, control = compiled.tick_kernels(power, np.zeros(n_arms, np.int32), power * 0, fault)
        assert control() == 1
        for k in range(n_arms):
            reference.control(k, int(power[k]), 0, False, halted)
        assert reference.end_tick()
        assert compiled._arms.tobytes() == reference._arms.tobytes()
        assert compiled.driver.last.tobytes() == reference.driver.last.tobytes()
        assert [s.value for s in sems] == [2] * n_arms  # each link woken by each control
        compiled.close()
