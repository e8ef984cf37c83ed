"""The schedulability check (``kali_daemons/servo/schedule.py``, ``kalictl check``; issue 26
item 5): response-time analysis on measured figures, a servo's step timed on its own
parameters, and a real-time instance refusing a servo that would not fit before anything
changes."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.core.errors import ScheduleError
from kali_daemons.core.layout import PowerState
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo import PID, registry_for, schedule, struct_view
from kali_daemons.servo.client import ServoClient
from kali_daemons.servo.schedule import Change, Figures, Task, predict

from .conftest import wait_for
from .system.test_faults import PLUGIN
from .test_launcher import kalictl

TASKS = [
    Task("wallclock", 0, 90, 1000.0, 40.0),
    Task("sio", 0, 85, 1000.0, 120.0),
    Task("sv.0", 0, 84, 1000.0, 30.0),
    Task("plant", 1, 83, 1000.0, 200.0),
    Task("sv.1", 1, 84, 1000.0, 25.0),
    Task("tg", 1, 80, 10_000.0, 300.0),
    Task("viewer", 1, 0, 40_000.0, 4000.0),
]


def _figures() -> Figures:
    return Figures(
        period_us=1000.0,
        sio_own_p99_us=120.0,
        servos_p99_us=90.0,
        latency_p99_us=205.0,
        ticks=2000,
        tasks=list(TASKS),
        cpu_load={0: 0.22, 1: 0.45},
        servo_procs=("sio", "sv.0", "sv.1"),
    )


def test_as_measured_the_tick_fits_and_says_why() -> None:
    v = predict(_figures())
    assert v.fits and v.response_us == 210.0 and v.limit_us == 800.0
    assert "SIO 120 µs + servos 90 µs" in v.text() and "CPU 1: 45 % busy" in v.text()


def test_a_cpu_full_in_its_busiest_slice_is_said_though_its_mean_fits() -> None:
    """The mean hides a burst: a CPU 62 % busy on average, full for the 20 ms the serious
    tolerance allows, starved the TG of a force cell (issue 27); the check says both."""
    fig = _figures()
    fig.cpu_peak, fig.peak_ms = {0: 0.31, 1: 0.99}, 20.0
    text = predict(fig).text()
    assert "CPU 0: 22 % busy (wallclock, sio, sv.0), 31 % in its busiest 20 ms: fits" in text
    assert "CPU 1: 45 % busy (plant, sv.1, tg, viewer), 99 % in its busiest 20 ms (full: " in text
    # a change's load is in every slice: the busiest too
    text = predict(fig, Change("costly", servo_us=100.0)).text()
    assert "CPU 1: 55 % busy (plant, sv.1, tg, viewer), 109 % in its busiest 20 ms (full: " in text


def test_a_cpu_held_by_real_time_work_past_the_kernels_share_is_overloaded() -> None:
    """Past 95 % of a CPU in real-time work the kernel takes the CPU from it for 50 ms a
    second (franky-sim at SCHED_FIFO on a slow machine: the TG's DEADLINE); the same load with
    a SCHED_OTHER process in it fits."""
    fig = _figures()
    fig.cpu_load, fig.cpu_rt_load = {0: 0.22, 1: 0.97}, {0: 0.22, 1: 0.96}
    v = predict(fig)
    assert not v.fits
    assert (
        "CPU 1: 97 % busy (plant, sv.1, tg, viewer), 96 % real-time (over the 95 % the kernel "
        "allows: it takes the CPU from them for 50 ms a second): OVERLOADED" in v.text()
    )
    fig.cpu_rt_load = {0: 0.22, 1: 0.30}
    assert predict(fig).fits
    # a real-time process run faster adds to the real-time share, a normal one does not
    fig.cpu_load, fig.cpu_rt_load = {0: 0.22, 1: 0.93}, {0: 0.22, 1: 0.93}
    assert not predict(fig, Change("rate tg 5 ms", process="tg", period_us=5000.0)).fits  # +3 %
    assert predict(fig, Change("rate viewer 30 ms", process="viewer", period_us=30000.0)).fits


def test_cpu_loads_are_the_mean_and_the_busiest_interval() -> None:
    """Process 0 on CPU 0 uses 5 of 20 ms then 20 of 20 ms; process 1 (CPU 1) 2 ms each."""
    ms = 1_000_000
    samples = [
        (0, {0: 0, 1: 0}),
        (20 * ms, {0: 5 * ms, 1: 2 * ms}),
        (40 * ms, {0: 25 * ms, 1: 4 * ms}),
    ]
    mean, peak = schedule.cpu_loads(samples, {0: 0, 1: 1})
    assert mean == pytest.approx({0: 25 / 40, 1: 0.1})
    assert peak == pytest.approx({0: 1.0, 1: 0.1})


def test_a_costly_servo_step_does_not_fit() -> None:
    v = predict(_figures(), Change("select 'x' on left joint 2", servo_us=650.0))
    assert not v.fits and v.response_us == 860.0
    assert "DOES NOT FIT" in v.text() and "+650.0 µs" in v.text()
    assert predict(_figures(), Change("cheap", servo_us=100.0)).fits
    # a wider margin refuses what a narrow one allows
    assert not predict(_figures(), Change("cheap", servo_us=100.0), margin=0.7).fits


def test_a_process_above_a_servo_on_its_cpu_preempts_the_tick() -> None:
    """The plant (83) is below sv.1 (84): its rate does not reach the tick.  Raise the TG
    above the SVs and run it every tick: its cycle is in every servo tick."""
    fig = _figures()
    fig.tasks = [t if t.name != "tg" else Task("tg", 1, 88, 10_000.0, 300.0) for t in TASKS]
    v = predict(fig, Change("rate tg 1 ms", process="tg", period_us=1000.0))
    assert v.response_us == 210.0  # ceil(210/1000) - ceil(210/10000) = 0 more releases
    fig.sio_own_p99_us = 1200.0  # a tick longer than the TG's new period: one more
    v = predict(fig, Change("rate tg 1 ms", process="tg", period_us=1000.0))
    assert v.response_us == 1290.0 + 300.0 * (2 - 1)
    # the TG's own load: 300 µs a ms on a CPU already 45 % busy
    v = predict(_figures(), Change("rate tg 0.5 ms", process="tg", period_us=500.0))
    assert not v.fits and "OVERLOADED" in v.text()


def test_response_time_analysis() -> None:
    """R = C + sum ceil(R/T) C over higher priorities, iterated (Joseph and Pandya)."""
    hi = Task("hi", 0, 90, 100.0, 30.0)
    lo = Task("lo", 0, 10, 1000.0, 100.0)
    # 100 → 100 + 2·30 = 160 → 100 + 2·30 = 160
    assert schedule._response(lo, [hi, lo]) == 160.0
    hog = Task("hog", 0, 90, 100.0, 95.0)
    assert schedule._response(lo, [hog, lo]) == float("inf")
    other_cpu = Task("other", 1, 99, 10.0, 9.0)
    assert schedule._response(lo, [other_cpu, lo]) == 100.0


def test_bad_margin_and_unknown_process_are_refused() -> None:
    with pytest.raises(ScheduleError, match=r"margin 1.5 must be in \[0, 1\)"):
        predict(_figures(), margin=1.5)
    with pytest.raises(ScheduleError, match="no clocked process 'nope'"):
        predict(_figures(), Change("rate nope", process="nope", period_us=1.0))


def test_a_step_is_timed_on_the_joints_own_parameters() -> None:
    reg = registry_for([str(PLUGIN)])
    faulty = reg.by_name("faulty")
    fast = schedule.step_cost_us(faulty, 0.001)
    assert 0.0 < fast < 500.0
    rec = np.zeros(1, faulty.dtype)
    faulty.init(struct_view(rec), {"fail": 3.0, "slow_ms": 2.0}, 0.001)
    slow = schedule.step_cost_us(faulty, 0.001, rec)
    # its 2 ms, not the default 50 ms; a sleep of 2 ms took 4.7 ms under the parallel suite
    assert 2000.0 <= slow < 20_000.0
    assert rec["fail"][0] == 3.0  # the joint's record is not written
    assert schedule.step_cost_us(PID, 0.001) < 500.0


def test_lockstep_has_no_deadlines(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        v = schedule.check(inst)
    assert v.fits and "lockstep: no deadlines" in v.text()


@pytest.mark.serial
def test_a_servo_that_would_not_fit_is_refused_before_it_runs(kali: Callable[..., str]) -> None:
    """Real time: kalictl check passes as measured; selecting a plugin whose step (on the
    joint's own parameters) takes 2 ms of a 1 ms tick is refused with the numbers, the joint
    keeps its servo, the arms keep servoing."""
    name = kali(lockstep=False, edits={r"^plugins: \[(.*)\]$": rf"plugins: [\1, {PLUGIN}]"})
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            client.power("left", True)
            wait_for(lambda: client.power_state("left") == PowerState.ON, what="left powered")
            time.sleep(0.5)  # a few hundred servo ticks for the flight recorder
            out = kalictl("-i", name, "check")
            assert out.returncode == 0, out.stdout + out.stderr
            assert "servo tick" in out.stdout and "fits" in out.stdout
            client.set_params("left", 2, {"fail": 3.0, "slow_ms": 2.0}, "faulty")
            out = kalictl("-i", name, "servo", "select", "left", "2", "faulty")
            assert out.returncode == 1, out.stdout + out.stderr
            assert "select 'faulty' on left joint 2 (was 'pid') refused" in out.stderr
            assert "DOES NOT FIT" in out.stderr
            assert client.active("left", 2) == "pid"
            assert inst.fault_text() is None
        finally:
            client.close()
