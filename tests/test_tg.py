"""The trajectory generator end to end (issue 5, joint mode so far), in lockstep mode: user
programs' requests through the Type 1 queue, set-points through the FIFOs, statuses back."""

from __future__ import annotations

import math
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from fractions import Fraction
from types import SimpleNamespace

import numpy as np
import pytest

from kali_daemons.client import Kali, MotionFailedError, MotionHandle, pose
from kali_daemons.client.robot import Robot
from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.core.channels import InterpolatingFifo
from kali_daemons.core.joints import per_joint
from kali_daemons.core.layout import CalibState, FaultCode, MotionKind, PowerState, RequestState
from kali_daemons.robots import puma560
from kali_daemons.robots.cell import base_transform, inverse
from kali_daemons.runtime.config import KaliConfig, ms_to_ns
from kali_daemons.servo.level import FIFO_CAPACITY
from kali_daemons.tg import planner as tgd
from kali_daemons.tg import records
from kali_daemons.tg.planner import Planner
from kali_daemons.tg.profiles import MotionError
from kali_daemons.tg.records import write_status
from kali_daemons.tg.requests import check_request
from kali_daemons.tools import launcher
from kali_daemons.wallclock import step_kali_clock

from .conftest import make_config, unique_name

LEFT = slice(0, puma560.ROBOT.n_joints)  # the default cell's left PUMA: the first flat joints


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
        rs = k.servo.level.joints  # per joint, flat; the left arm's are LEFT
        start = rs["demand"][LEFT].copy()
        target = start + np.radians([-20, -10, 15, 30, -20, 40])  # j1 away from the right arm
        h = left.move_joints(target, speed=1.0, wait=False)
        demands = []
        for _ in range(3000):  # 3 s
            step_kali_clock(k.inst, 1)
            demands.append(rs["demand"][LEFT].copy())
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
        duration = float(k.status["duration_s"][records.find(k.status, h.seq)])
        assert 0.5 < duration < 2.0
        step_kali_clock(k.inst, 1000)
        assert np.abs(rs["q"][LEFT] - target).max() < math.radians(0.05)
        assert k.inst.fault_text() is None
        del rs


def test_requests_queue_behind_each_other_and_stop_on_the_path(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        rs = k.servo.level.joints  # per joint, flat; the left arm's are LEFT
        start = rs["demand"][LEFT].copy()
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
        q1 = rs["demand"][LEFT.start]
        assert start[0] < q1 < a[0]  # stopped between the two, on the joint path
        step_kali_clock(k.inst, 100)
        assert rs["demand"][LEFT.start] == q1  # and holds there
        del rs


def test_bad_requests_are_refused_and_nothing_moves(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        rs = k.servo.level.joints  # per joint, flat; the left arm's are LEFT
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
            left.move_joints(before[LEFT], speed=2, wait=False)
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
            rec = st[records.find(st, seq)]
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
        start = k.servo.level.joints["demand"][LEFT].copy()
        # away from the right arm (towards it, the TG's check would refuse it)
        h = left.move_joints(start + np.radians([-30, 0, 0, 0, 0, 0]), speed=0.2, wait=False)
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
    """The TG gives a status record to a new request while clients poll it (seq, then state):
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

    _start_waiting = Planner._start_waiting
    _robots_of = Planner._robots_of
    _spent = Planner._spent
    _blend_into = Planner._blend_into

    def __init__(self, check_until: int) -> None:
        self.n_robots = 2
        self.lockstep = False  # real time: the share is wall time
        self.motions: list[object] = []
        self.waiting: list[tuple[int, np.void]] = []
        self._check_until = check_until
        self.started: list[int] = []

    def _cannot_move(self, robots: list[int]) -> str:
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


# ---------------------------------------------------------------------------- a mixed cell

MIXED = {r"^(  - \{name: right, model: )puma560": r"\1panda"}  # PUMA 560 left, Panda right


class BareTg:
    """The TG configured by its own ``on_configure`` over a bare arena, no processes: the test
    lays SIO's records out (every arm powered and calibrated, holding its type's home pose)
    and the programs' load records (nothing held),
    puts requests in the TG's queue and plays SIO, taking each FIFO's demands at the servo
    rate into the joints' records."""

    def __init__(self, cfg: KaliConfig, arena: Arena) -> None:
        self.cfg = cfg
        jm = cfg.joints
        robots = arena.record(layout.KEY_ROBOTS, layout.ROBOT_STATE, jm.n_robots)
        robots["power"] = PowerState.ON
        robots["calibrated"] = 1
        robots["calib_state"] = CalibState.DONE
        self.joints = arena.record(layout.KEY_JOINTS, layout.JOINT_STATE, jm.total)
        self.joints["demand"] = per_joint([r.type.q_home for r in cfg.robots])
        arena.record(layout.KEY_LOADS, layout.LOAD, jm.n_robots)  # the programs': none held
        servo_ns, tg_ns = ms_to_ns(cfg.clock.servo_period_ms), ms_to_ns(cfg.clock.tg_period_ms)
        self.ratio = Fraction(tg_ns, servo_ns)
        clock = np.zeros((), layout.CLOCK)
        clock["base_tick_ns"] = servo_ns
        procs = np.zeros(1, layout.PROCESS)
        procs["period_ticks"] = int(self.ratio)
        self.fault = np.zeros((), layout.FAULT)
        inst = SimpleNamespace(
            config=cfg, arena=arena, lockstep=True, clock=clock, procs=procs, fault=self.fault
        )
        self.tg = Planner(inst, "tg", 0)  # type: ignore[arg-type]
        self.sio = [  # SIO's ends of the FIFOs: attaching checks their width
            InterpolatingFifo(
                arena, layout.KEY_FIFO.format(robot=r.name), r.n_joints, FIFO_CAPACITY, self.ratio
            )
            for r in cfg.robots
        ]
        self.demand = jm.split(self.joints["demand"])
        for fifo, q in zip(self.sio, self.demand, strict=True):
            fifo.reset(q.copy())
        self.tick = 0

    def put(self, kind: MotionKind, robots: list[int], **fields: object) -> int:
        """Queue a request as a client would (``joints``: one row per robot); its seq."""
        req = np.zeros((), dtype=layout.MOTION_REQUEST)
        req["kind"] = kind
        req["n_robots"] = len(robots)
        req["robots"][: len(robots)] = robots
        for name, value in fields.items():
            if name == "joints":
                for i, row in enumerate(value):  # type: ignore[arg-type]
                    req["joints"][i, : len(row)] = row
            elif name in ("grasps", "config"):
                req[name][: len(robots)] = value
            else:
                req[name] = value
        return self.tg.queue.put(req)

    def run(self, seq: int, max_ticks: int = 2000) -> tuple[RequestState, str]:
        """TG ticks, each followed by its servo ticks of SIO, until request ``seq`` has ended
        and its set-points have been taken."""
        for _ in range(max_ticks):
            self.tg.cycle(self.tick)
            for _ in range(int(self.ratio)):
                for fifo, q in zip(self.sio, self.demand, strict=True):
                    fifo.pop_into(q)
            self.tick += 1
            rec = self.tg.status[records.find(self.tg.status, seq)]
            if int(rec["seq"]) == seq and int(rec["state"]) in layout.TERMINAL_STATES:
                return RequestState(int(rec["state"])), bytes(rec["message"]).decode()
        raise AssertionError(f"request {seq} not over within {max_ticks} TG ticks")


@pytest.fixture
def bare_arena() -> Iterator[Arena]:
    """A fresh 16 MiB arena (a TG's records and FIFOs), unlinked afterwards."""
    name = unique_name("tg")
    a = Arena.create(name, 16 << 20)
    yield a
    a.close()
    launcher.stop(name)


def _outcomes(tg: Planner, seqs: list[int]) -> list[bool]:
    """Which of ``seqs`` the TG has taken and answered (its status record is the request's)."""
    return [records.find(tg.status, s) >= 0 for s in seqs]


@pytest.mark.parametrize("mode", ["real time", "lockstep"])
def test_requests_are_taken_only_while_the_tick_s_share_lasts(
    bare_arena: Arena, monkeypatch: pytest.MonkeyPatch, mode: str
) -> None:
    """Taking a request (its checks, its claim, its status) costs the TG's CPU as planning
    does: in a soak, eight flooded requests took one tick 16 ms of wall time on the TG's
    shared CPU (3 ms of CPU).  Requests are taken only while the tick's share lasts (wall
    time in real time, in lockstep REQUEST_WORK each of LOCKSTEP_CHECK_SAMPLES, so a run
    there stays bit for bit), at least one a tick; the rest wait in the queue, in order."""
    cell = BareTg(make_config("share"), bare_arena)
    tg = cell.tg
    if mode == "real time":
        tg.lockstep = False
        monkeypatch.setattr(tgd, "CHECK_SHARE", 0.0)  # the share spent as the tick begins
        per_tick = 1
    else:
        per_tick = 3  # a share of three requests' work: it binds before MAX_REQUESTS_PER_TICK
        monkeypatch.setattr(tgd, "LOCKSTEP_CHECK_SAMPLES", per_tick * tgd.REQUEST_WORK)
    seqs = [cell.put(MotionKind.STOP, [0]) for _ in range(2 * per_tick + 1)]
    for tick in range(3):
        tg.cycle(tick)
        taken = min(len(seqs), (tick + 1) * per_tick)
        assert _outcomes(tg, seqs) == [True] * taken + [False] * (len(seqs) - taken)
    assert all(
        int(tg.status[records.find(tg.status, s)]["state"]) == RequestState.DONE for s in seqs
    )


def test_a_mixed_cell_moves_each_arm_over_its_own_joints(bare_arena: Arena) -> None:
    """A PUMA 560 (6 joints) and a Panda (7) in one cell: the TG's FIFOs and set-points are 6
    and 7 wide, a joint move of both arms and a Cartesian path of both holding one object plan
    and arrive, and a request naming a joint the arm does not have is refused."""
    cfg = make_config("mixed", MIXED)
    assert [r.n_joints for r in cfg.robots] == [6, 7] and cfg.joints.total == 13
    cell = BareTg(cfg, bare_arena)
    tg = cell.tg
    assert [f.width for f in tg.fifos] == [6, 7]
    puma, panda = (r.type for r in cfg.robots)

    # joint mode: both arms, each its own joint count
    q_left = puma.q_home + np.radians([-10, -5, 5, 10, -10, 15])  # away from the Panda
    q_right = panda.q_home + np.radians([-10, 5, 10, 5, -5, 10, 20])
    seq = cell.put(MotionKind.JOINTS, [0, 1], joints=[q_left, q_right], speed_scale=0.8)
    assert cell.run(seq) == (RequestState.DONE, "")
    np.testing.assert_array_equal(cell.demand[0], q_left)
    np.testing.assert_array_equal(cell.demand[1], q_right)
    setpoints = tg.tg_robots["setpoint"]
    np.testing.assert_array_equal(setpoints[0, :6], q_left)
    np.testing.assert_array_equal(setpoints[1, :7], q_right)
    assert not setpoints[0, 6:].any() and not setpoints[1, 7:].any()

    # Cartesian: both arms hold one object (its frame at the PUMA's flange) and lift it 3 cm
    bases = [base_transform(r.base_xyz, r.base_yaw_deg) for r in cfg.robots]
    start = [cell.demand[0].copy(), cell.demand[1].copy()]
    flanges = [
        b @ t.kinematics.fkine(q) for b, t, q in zip(bases, (puma, panda), start, strict=True)
    ]
    obj = flanges[0]
    grasps = np.array([inverse(obj) @ f for f in flanges])
    target = obj.copy()
    target[2, 3] += 0.03
    poses = np.zeros((layout.MAX_SEGMENTS, 4, 4))
    poses[0] = target
    seq = cell.put(
        MotionKind.PATH, [0, 1], n_segments=1, poses=poses, grasps=grasps, config=[0, 0],
        speed=0.05, angular_speed=0.5, transition_s=0.0,
    )  # fmt: skip
    assert cell.run(seq) == (RequestState.DONE, "")
    for k, (b, t) in enumerate(zip(bases, (puma, panda), strict=True)):
        assert cell.demand[k].shape == (t.n_joints,)
        lifted = b @ t.kinematics.fkine(cell.demand[k].copy())
        np.testing.assert_allclose(lifted[:3, 3], flanges[k][:3, 3] + [0, 0, 0.03], atol=1e-6)
        np.testing.assert_allclose(lifted[:3, :3], flanges[k][:3, :3], atol=1e-6)
        np.testing.assert_array_equal(setpoints[k, : t.n_joints], cell.demand[k])
    assert panda.kinematics.config_of(cell.demand[1]) == panda.kinematics.config_of(start[1])

    # a seventh joint for the PUMA, a NaN seventh for the Panda: refused, nothing moves
    before = cell.joints["demand"].copy()
    seq = cell.put(MotionKind.JOINTS, [0], joints=[np.append(cell.demand[0], 0.5)], speed_scale=0.5)
    state, message = cell.run(seq)
    assert state == RequestState.REFUSED
    assert "robot 'left' (puma560) has 6 joints, but the request gives joint 7" in message
    req = np.zeros((), dtype=layout.MOTION_REQUEST)
    req["kind"], req["n_robots"], req["robots"][0] = MotionKind.JOINTS, 1, 1
    req["speed_scale"] = 0.5
    req["joints"][0, :6] = cell.demand[1][:6]
    req["joints"][0, 6] = math.nan
    with pytest.raises(MotionError, match="robot 'right' joint 7: target nan"):
        check_request(req[()], tg.names, tg.types)
    np.testing.assert_array_equal(cell.joints["demand"], before)


def test_move_joints_refuses_a_count_other_than_the_arm_s() -> None:
    """The client checks the joint count before anything is queued, naming the robot, its
    type and its count (no instance needed: the check comes first)."""
    cfg = make_config("mixed", MIXED)
    kali = SimpleNamespace(names=[r.name for r in cfg.robots], inst=SimpleNamespace(config=cfg))
    left, right = Robot(kali, 0), Robot(kali, 1)  # type: ignore[arg-type]
    assert (left.n_joints, right.n_joints) == (6, 7)
    assert (left.span, right.span) == (slice(0, 6), slice(6, 13))
    with pytest.raises(
        MotionError,
        match=r"move_joints: robot 'right' \(panda, 7 joints\): 6 values given, shape \(6,\), "
        r"expected \(7,\)",
    ):
        right.move_joints(np.zeros(6))
    with pytest.raises(MotionError, match=r"robot 'left' \(puma560, 6 joints\): 7 values given"):
        left.move_joints(np.zeros(7))


def finish(k: Kali, handle: MotionHandle, ticks: int = 5000) -> None:
    """Step the clock until ``handle``'s request is over (at most ``ticks``); it arrived."""
    for _ in range(ticks // 10):
        if handle.done:
            break
        step_kali_clock(k.inst, 10)
    handle.wait(0)


def test_a_mixed_cell_moves_the_panda_in_joints_and_in_a_line(kali: Callable[..., str]) -> None:
    """End to end in lockstep: the Panda beside a PUMA arrives at a 7-joint target and, once
    calibrated, lifts its flange 3 cm in a straight line."""
    name = kali(lockstep=True, edits=MIXED)
    with powered(name) as k:
        right = k.robot("right")
        assert [f.width for f in k.fifos] == [6, 7] and right.read_joints().shape == (7,)
        target = k.start_point(1) + np.radians([10, -5, 5, 5, -5, 10, 15])
        h = right.move_joints(target, speed=0.5, wait=False)
        finish(k, h)
        np.testing.assert_array_equal(k.tg_robots["setpoint"][1, :7], target)
        step_kali_clock(k.inst, 500)
        assert np.abs(right.read_joints() - target).max() < math.radians(0.05)
        k.servo.calibrate("right")
        for _ in range(100):
            step_kali_clock(k.inst, 50)
            if k.servo.calibration("right")[0] in (CalibState.DONE, CalibState.FAILED):
                break
        assert k.servo.calibrated("right"), k.servo.calibration("right")
        here = right.read_pose()
        h = right.move_line(pose(here[:3, 3] + [0, 0, 0.03], here), speed=0.05, wait=False)
        finish(k, h)
        step_kali_clock(k.inst, 500)
        np.testing.assert_allclose(right.read_pose()[:3, 3], here[:3, 3] + [0, 0, 0.03], atol=2e-4)
        assert k.inst.fault_text() is None


def test_a_refusal_names_its_subsystem_once() -> None:
    """The status message of a request refused by a MotionError is its words without the
    error's "motion: " (the client's MotionFailedError names the subsystem once: "motion:
    request 3 refused: joint move refused: ..."); anything else is named whole."""
    from kali_daemons.tg.requests import refusal

    assert refusal(MotionError("joint move refused: x")) == "joint move refused: x"
    checked = "request refused: it could not be checked (ValueError: bad)"
    assert refusal(ValueError("bad")) == checked
