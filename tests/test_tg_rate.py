"""The TG's rate changed on line (``kalictl rate tg MS``, issue 5) in lockstep mode: the TG
follows its new period and the FIFOs their new ratio from the next set-point, so a motion
under way keeps its speed, arrives exactly and never starves SIO."""

from __future__ import annotations

import math
from collections.abc import Callable
from fractions import Fraction

import numpy as np
import pytest

from kali_daemons.client import Kali, set_control_rate
from kali_daemons.core.errors import ClockError
from kali_daemons.core.layout import RequestState
from kali_daemons.robots import puma560
from kali_daemons.tg import records
from kali_daemons.wallclock import step_kali_clock

from .test_launcher import kalictl
from .test_tg import LEFT, powered

SERVO_2MS = {
    r"^  servo_period_ms: 1 ": "  servo_period_ms: 2 ",
    r"^  tg_period_ms: 10 ": "  tg_period_ms: 5 ",
}


def move_with_rate_change(
    k: Kali, target: np.ndarray, change: Callable[[], None], at_fraction: float, servo_ms: int
) -> tuple[np.ndarray, int, float]:
    """Move the left arm to ``target``, calling ``change`` once ``at_fraction`` of the planned
    duration has run.  Returns SIO's demand at each servo tick from the request on, the
    FIFO underruns while the arm moved, and the planned duration (s)."""
    rs = k.servo.level.joints
    fifo = k.servo.level.fifo(0)
    start = rs["demand"][LEFT].copy()
    h = k.robot("left").move_joints(target, speed=0.5, wait=False)
    demands, underruns = [start], [fifo.underruns]
    first = 0  # the first servo tick the arm moved at
    changed = False
    for _ in range(20_000):
        step_kali_clock(k.inst, servo_ms)  # one SIO tick
        demands.append(rs["demand"][LEFT].copy())
        underruns.append(fifo.underruns)
        if not first and not np.array_equal(demands[-1], start):
            first = len(demands) - 1
        duration = float(k.status["duration_s"][records.find(k.status, h.seq)])
        if (
            first
            and not changed
            and (len(demands) - first) * servo_ms >= at_fraction * 1e3 * duration
        ):
            change()
            changed = True
        if h.done and np.array_equal(demands[-1], target):
            break
    assert changed and h.state == RequestState.DONE, h.message
    h.wait(0)
    d = np.array(demands)
    last = int(np.flatnonzero((d == target).all(axis=1))[0])
    step_kali_clock(k.inst, 50)
    assert np.array_equal(rs["demand"][LEFT], target)  # arrived exactly, and stays
    starved = underruns[last] - underruns[first - 1]  # an underrun holds the arm: not moving
    del rs, fifo
    return d[first - 1 : last + 1], starved, duration


def check_motion(d: np.ndarray, starved: int, duration: float, servo_ms: int, tg_ms: int) -> None:
    """Velocity within the limits, no underrun, and as long as planned (to a TG period:
    the last set-point's segment lasts a whole period, however little τ advanced)."""
    v = np.diff(d, axis=0) / (servo_ms / 1000)
    assert (np.abs(v) <= puma560.QD_MAX * 1.001).all(), np.abs(v).max(axis=0)
    assert starved == 0
    moved_ms = (len(d) - 1) * servo_ms
    assert 0 <= moved_ms - duration * 1000 < 2 * tg_ms, (moved_ms, duration)


def test_slower_tg_mid_motion_keeps_speed_and_arrives(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        tg = k.inst.slot_of("tg")
        target = k.servo.level.joints["demand"][LEFT] + np.radians([-30, -20, 25, 40, -30, 50])
        d, starved, duration = move_with_rate_change(
            k, target, lambda: set_control_rate(k.inst, "tg", 20), 0.3, servo_ms=1
        )
        check_motion(d, starved, duration, servo_ms=1, tg_ms=20)
        assert 1.0 < duration < 5.0
        assert int(k.inst.procs[tg]["period_ticks"]) == 20
        # after the change the demand's velocity steps only every 20 servo ticks (one
        # set-point per 20 ms TG tick): no step closer than that after the first 20 ms one
        v = np.diff(d, axis=0)
        steps = np.flatnonzero(np.abs(np.diff(v, axis=0)).max(axis=1) > 1e-12) + 1
        late = steps[steps > 0.5 * len(d)]
        assert len(late) > 10 and (np.diff(late) % 20 == 0).all(), np.diff(late)
        fifo = k.servo.level.fifo(0)
        assert fifo.ratio == fifo.segment_ratio == 20
        # back to 10 ms through the command line, mid-way home: faster set-points this time
        start = k.servo.level.joints["demand"][LEFT].copy()
        back = start - np.radians([-30, -20, 25, 40, -30, 50])

        def cli_rate() -> None:
            r = kalictl("-i", name, "rate", "tg", "10")
            assert r.returncode == 0 and "tg: period 10 ms" in r.stdout, r.stderr

        d, starved, duration = move_with_rate_change(k, back, cli_rate, 0.5, servo_ms=1)
        check_motion(d, starved, duration, servo_ms=1, tg_ms=20)
        assert fifo.ratio == fifo.segment_ratio == 10
        step_kali_clock(k.inst, 1000)
        assert np.abs(k.servo.level.joints["q"][LEFT] - back).max() < math.radians(0.05)
        assert k.inst.fault_text() is None
        del fifo


def test_fractional_ratio_change_and_too_short_a_period(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True, edits=SERVO_2MS)  # r = 5 ms / 2 ms = 5/2
    with powered(name) as k:
        tg = k.inst.slot_of("tg")
        fifo = k.servo.level.fifo(0)
        assert fifo.ratio == Fraction(5, 2)
        why = (
            r"wallclock: rate of 'tg': period 1 ms is shorter than the servo period 2 ms; "
            r"the TG must run at most as fast as the servos \(FIFO ratio >= 1\)"
        )
        with pytest.raises(ClockError, match=why):
            set_control_rate(k.inst, "tg", 1)
        r = kalictl("-i", name, "rate", "tg", "1")
        assert r.returncode == 1 and "period 1 ms is shorter than the servo period" in r.stderr
        for servo in ("sio", "sv.0"):
            with pytest.raises(ClockError, match=rf"rate of '{servo}': the servo period \(2 ms\)"):
                set_control_rate(k.inst, servo, 4)
        assert int(k.inst.procs[tg]["period_ticks"]) == 5  # nothing changed
        target = k.servo.level.joints["demand"][LEFT] + np.radians([-25, 15, -20, 30, 25, -40])
        d, starved, duration = move_with_rate_change(
            k, target, lambda: set_control_rate(k.inst, "tg", 8), 0.4, servo_ms=2
        )
        check_motion(d, starved, duration, servo_ms=2, tg_ms=8)
        assert fifo.ratio == fifo.segment_ratio == 4
        set_control_rate(k.inst, "tg", 2)  # as fast as the servos: r = 1 is allowed
        step_kali_clock(k.inst, 10)
        assert fifo.ratio == 1
        assert k.inst.fault_text() is None
        del fifo
