"""The trajectory generator end to end (issue 5, joint mode so far), in lockstep mode: user
programs' requests through the Type 1 queue, set-points through the FIFOs, statuses back."""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from kali_daemons import layout
from kali_daemons.client import Kali, MotionFailedError
from kali_daemons.layout import FaultCode, MotionKind, PowerState, RequestState
from kali_daemons.robots import puma560
from kali_daemons.tg.daemon import TrajectoryGenerator, write_status
from kali_daemons.tg.profiles import MotionError
from kali_daemons.wallclock import step_kali_clock


@contextmanager
def powered(name: str) -> Iterator[Kali]:
    """Attach, power both arms and let them settle."""
    with Kali(name) as kali:
        step_kali_clock(kali.inst, 30)
        for robot in kali.names:
            kali.servo.power(robot, True)
        step_kali_clock(kali.inst, 1500)
        assert [kali.servo.power_state(r) for r in kali.names] == [PowerState.ON] * 2
        yield kali


def test_move_joints_arrives_smoothly_and_together(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        rs = k.servo.level.robots
        start = rs["demand"][0].copy()
        target = start + np.radians([20, -10, 15, 30, -20, 40])
        h = left.move_joints(target, speed=1.0, wait=False)
        demands = []
        for _ in range(3000):  # 3 s
            step_kali_clock(k.inst, 1)
            demands.append(rs["demand"][0].copy())
            if h.done and len(demands) > 50 and np.array_equal(demands[-1], target):
                break
        assert h.state == RequestState.DONE, h.message
        h.wait(0)
        d = np.array(demands)
        np.testing.assert_allclose(d[-1], target, atol=1e-12)
        v = np.diff(d, axis=0) / 1e-3  # servo-rate demand velocity
        assert (np.abs(v) <= puma560.QD_MAX * 1.001).all(), np.abs(v).max(axis=0)
        # SIO interpolates linearly between 10 ms set-points (thesis 2.2.2): the velocity is
        # constant within a TG period and changes between them by at most a_max · 10 ms
        jumps = np.abs(np.diff(v, axis=0)).max(axis=0)
        assert (jumps <= puma560.QDD_MAX * 0.010 * 1.001 + 1e-6).all(), jumps
        progress = (d - start) / (target - start)
        assert np.abs(progress - progress[:, :1]).max() < 1e-9  # every joint together
        duration = float(k.status["duration_s"][h.seq % layout.STATUS_RING])
        assert 0.5 < duration < 2.0
        step_kali_clock(k.inst, 1000)
        assert np.abs(rs["q"][0] - target).max() < math.radians(0.05)
        assert k.inst.fault_text() is None
        del rs


def test_requests_queue_behind_each_other_and_stop_on_the_path(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        rs = k.servo.level.robots
        start = rs["demand"][0].copy()
        a = start + np.radians([10, 0, 0, 0, 0, 0])
        first = left.move_joints(a, speed=0.5, wait=False)
        second = left.move_joints(start, speed=0.5, wait=False)
        step_kali_clock(k.inst, 20)
        assert first.state == RequestState.RUNNING and second.state == RequestState.QUEUED
        for _ in range(300):
            step_kali_clock(k.inst, 10)
            if first.done:
                break
        assert first.state == RequestState.DONE
        step_kali_clock(k.inst, 200)
        assert second.state == RequestState.RUNNING
        second.cancel()  # decelerates to rest on the way back
        for _ in range(100):
            step_kali_clock(k.inst, 10)
            if second.done:
                break
        assert second.state == RequestState.STOPPED, second.message
        with pytest.raises(MotionFailedError, match="stopped"):
            second.wait(0)
        step_kali_clock(k.inst, 30)  # SIO takes the set-points the TG had pushed ahead
        q1 = rs["demand"][0, 0]
        assert start[0] < q1 < a[0]  # stopped between the two, on the joint path
        step_kali_clock(k.inst, 100)
        assert rs["demand"][0, 0] == q1  # and holds there
        del rs


def test_bad_requests_are_refused_and_nothing_moves(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        rs = k.servo.level.robots
        before = rs["demand"].copy()
        for bad, why in (
            ([0, 0, 0], r"shape \(3,\), expected \(6,\)"),
            ([0, 0, math.nan, 0, 0, 0], "joint 3: target nan"),
            ([0, 0, 0, 0, 0, 5.0], "joint 6: target 286.48° outside its range"),
            ("abc", "is not 6 numbers"),
        ):
            with pytest.raises(MotionError, match=why):
                left.move_joints(bad, wait=False)
        with pytest.raises(MotionError, match=r"speed 2, must be in \(0, 1\]"):
            left.move_joints(before[0], speed=2, wait=False)
        # a rogue client writes garbage straight into the queue: the TG refuses it
        rogue = np.zeros((), dtype=layout.MOTION_REQUEST)
        rogue["kind"] = MotionKind.JOINTS
        rogue["n_robots"] = 1
        rogue["robots"][0] = 3  # no such robot
        seq_robot = k.queue.put(rogue)
        rogue["robots"][0] = 0
        rogue["joints"][0] = np.nan
        rogue["speed_scale"] = 0.5
        seq_nan = k.queue.put(rogue)
        rogue["kind"] = 99
        seq_kind = k.queue.put(rogue)
        step_kali_clock(k.inst, 20)
        st = k.status
        for seq, why in (
            (seq_robot, "robot index 3"),
            (seq_nan, "joint 1: target nan"),
            (seq_kind, "motion kind 99"),
        ):
            rec = st[seq % layout.STATUS_RING]
            assert int(rec["seq"]) == seq and int(rec["state"]) == RequestState.REFUSED
            assert why in bytes(rec["message"]).decode(), bytes(rec["message"])
        step_kali_clock(k.inst, 100)
        assert np.array_equal(rs["demand"], before)
        assert k.inst.fault_text() is None
        del rs, st


def test_a_halt_wakes_the_waiting_program_with_the_fault(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        start = k.servo.level.robots["demand"][0].copy()
        h = left.move_joints(start + np.radians([30, 0, 0, 0, 0, 0]), speed=0.2, wait=False)
        step_kali_clock(k.inst, 100)
        assert h.state == RequestState.RUNNING
        queued = left.move_joints(start, wait=False)
        k.inst.raise_fault(FaultCode.ESTOP, "test", "operator pressed the e-stop")
        for handle in (h, queued):  # the clock has stopped, the program hears it at once
            with pytest.raises(MotionFailedError, match=r"halted: ESTOP .*operator pressed"):
                handle.wait(1.0)
        k.inst.clear_fault()  # kalictl reset: the TG's first tick tells every request
        step_kali_clock(k.inst, 1)
        assert h.state == RequestState.HALTED and queued.state == RequestState.HALTED
        assert "operator pressed the e-stop" in h.message
        assert k.servo.power_state("left") == PowerState.OFF  # and power stays off


def test_a_status_record_taken_over_never_shows_its_new_seq_with_the_old_state() -> None:
    """The TG reuses status record seq % STATUS_RING while clients poll it (seq, then state):
    a client must never see its seq with the DONE of the request that had the record before.
    Writer and reader threads switch every few bytecodes, between any two stores."""
    status = np.zeros(1, dtype=layout.REQUEST_STATUS)
    rec = status[0]
    arrived = [0]  # the last seq the writer has marked DONE
    seen_early: list[int] = []
    stop = threading.Event()

    def writer() -> None:
        for seq in range(1, 20_001):
            write_status(rec, seq, RequestState.QUEUED)
            write_status(rec, seq, RequestState.RUNNING)
            write_status(rec, seq, RequestState.DONE, "arrived")
            arrived[0] = seq
        stop.set()

    def reader() -> None:
        while not stop.is_set():
            seq = int(rec["seq"])
            state = int(rec["state"])
            if state == RequestState.DONE and seq > arrived[0]:
                seen_early.append(seq)

    old = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    try:
        threads = [threading.Thread(target=writer), threading.Thread(target=reader)]
        for t in threads:
            t.start()
        for t in threads:
            t.join(60)
    finally:
        sys.setswitchinterval(old)
    assert arrived[0] == 20_000
    assert not seen_early, f"{len(seen_early)} polls saw a seq DONE before it began"


class _Waiting:
    """The TG's start of waiting requests, with ``_start`` noting what it would start."""

    _start_waiting = TrajectoryGenerator._start_waiting
    _robots_of = TrajectoryGenerator._robots_of
    _spent = TrajectoryGenerator._spent

    def __init__(self, check_until: int) -> None:
        self.n_robots = 2
        self.lockstep = False  # real time: the share is wall time
        self.motions: list[object] = []
        self.waiting: list[tuple[int, np.void]] = []
        self._check_until = check_until
        self.started: list[int] = []

    def _unpowered(self, robots: list[int]) -> str:
        return ""

    def _start(self, seq: int, req: np.void, robots: list[int]) -> None:
        self.started.append(seq)

    def wait(self, seq: int, kind: MotionKind, robot: int) -> None:
        req = np.zeros((), dtype=layout.MOTION_REQUEST)
        req["kind"], req["n_robots"], req["robots"][0] = kind, 1, robot
        self.waiting.append((seq, req[()]))


@pytest.mark.parametrize("share", ["left", "spent"])
def test_a_path_is_planned_only_while_the_tick_s_check_share_lasts(share: str) -> None:
    """Planning a Cartesian path costs as much CPU as a slice of checks (two planned in one
    tick took the TG 19 ms on its shared CPU): once the tick's check share is spent a path
    waits for the next tick, in order behind it the requests for its robots, while a joint
    move of another robot starts."""
    now = time.monotonic_ns()
    tg = _Waiting(now + 10**9 if share == "left" else now - 1)
    tg.wait(1, MotionKind.PATH, 0)
    tg.wait(2, MotionKind.JOINTS, 0)  # behind the path: same robot
    tg.wait(3, MotionKind.JOINTS, 1)
    tg._start_waiting()
    if share == "left":
        assert tg.started == [1, 3] and [seq for seq, _ in tg.waiting] == [2]
    else:
        assert tg.started == [3] and [seq for seq, _ in tg.waiting] == [1, 2]
