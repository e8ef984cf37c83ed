"""Cartesian motion through the trajectory generator (issue 5), end to end in lockstep mode:
straight lines of one arm's tool, the whole-path check and its refusals, stops, and the halt
when a checked path has no joint solution at run time."""

from __future__ import annotations

import itertools
import math
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from kali_daemons.client import Kali, MotionFailedError, pose
from kali_daemons.core import layout
from kali_daemons.core.errors import ServoError
from kali_daemons.core.layout import CalibState, MotionKind, PowerState, RequestState
from kali_daemons.hardware.mcgill import registers
from kali_daemons.robots import puma560
from kali_daemons.robots.cell import base_transform, inverse
from kali_daemons.robots.puma560 import kinematics
from kali_daemons.tg import records
from kali_daemons.tg.cartesian import CartesianMotion, encode_config
from kali_daemons.tg.planner import LEAD, Motion, Planner
from kali_daemons.tg.profiles import MotionError
from kali_daemons.tg.records import StatusRecords
from kali_daemons.wallclock import step_kali_clock

from .conftest import boards_of

SQUARE_TOL_M = 0.002  # the measured tool path stays this close to the commanded lines
LEFT = slice(0, puma560.ROBOT.n_joints)  # the default cell's left PUMA: the first flat joints


@contextmanager
def calibrated(name: str, robots: tuple[str, ...] = ("left",)) -> Iterator[Kali]:
    """Attach, power both arms and calibrate ``robots``."""
    with Kali(name) as kali:
        step_kali_clock(kali.inst, 30)
        for robot in kali.names:
            kali.servo.power(robot, True)
        step_kali_clock(kali.inst, 1500)
        assert [kali.servo.power_state(r) for r in kali.names] == [PowerState.ON] * 2
        for robot in robots:
            kali.servo.calibrate(robot)
        for _ in range(60):
            step_kali_clock(kali.inst, 50)
            if all(kali.servo.calibration(r)[0] == CalibState.DONE for r in robots):
                break
        assert all(kali.servo.calibrated(r) for r in robots), [
            kali.servo.calibration(r) for r in robots
        ]
        yield kali


def run_until(kali: Kali, handle: object, ticks: int, every: int = 10) -> list[np.ndarray]:
    """Step until ``handle`` is done (and the arm settled); the measured joints every ``every``."""
    seen = []
    for _ in range(ticks // every):
        step_kali_clock(kali.inst, every)
        seen.append(kali.servo.level.joints["q"].copy())
        if handle.done:  # type: ignore[attr-defined]
            break
    step_kali_clock(kali.inst, 300)
    seen.append(kali.servo.level.joints["q"].copy())
    return seen


def distance_to_polyline(p: np.ndarray, corners: list[np.ndarray]) -> float:
    best = math.inf
    for a, b in itertools.pairwise(corners):
        ab = b - a
        s = min(1.0, max(0.0, float(np.dot(p - a, ab) / np.dot(ab, ab))))
        best = min(best, float(np.linalg.norm(p - (a + s * ab))))
    return best


def test_square_of_the_tool_stays_on_its_lines(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with calibrated(name) as k:
        left = k.robot("left")
        start = left.read_pose()
        np.testing.assert_allclose(
            left.read_t6(), kinematics.fkine(left.read_joints()), atol=1e-9
        )  # Pinocchio's T6 is the closed form's
        side = 0.10
        offsets = [(0, side, 0), (0, side, side), (0, 0, side), (0, 0, 0)]
        corners = [pose(start[:3, 3] + np.array(o), start) for o in offsets]
        q0 = left.read_joints()
        h = left.move_path(corners, speed=0.1, transition_s=0.1, wait=False)
        assert h.state in (RequestState.QUEUED, RequestState.RUNNING)
        seen = run_until(k, h, 8000)
        h.wait(0)
        base = left.base
        polyline = [start[:3, 3]] + [c[:3, 3] for c in corners]
        worst = 0.0
        for q in seen:
            p = (base @ kinematics.fkine(q[LEFT]))[:3, 3]
            worst = max(worst, distance_to_polyline(p, polyline))
        assert worst < SQUARE_TOL_M, f"tool {worst * 1000:.2f} mm off the square's lines"
        end = left.read_pose()
        assert np.linalg.norm(end[:3, 3] - start[:3, 3]) < 5e-4  # the servo's rest error
        demand = left.base @ kinematics.fkine(k.servo.level.joints["demand"][LEFT])
        np.testing.assert_allclose(demand[:3, 3], start[:3, 3], atol=1e-6)  # set-points: exact
        assert kinematics.config_of(left.read_joints()) == kinematics.config_of(q0)
        assert k.inst.fault_text() is None


def test_bad_paths_are_refused_with_the_reason_and_nothing_moves(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with calibrated(name) as k:
        left, right = k.robot("left"), k.robot("right")
        with pytest.raises(ServoError, match=r"robot 'right' is not calibrated"):
            right.move_line(right.read_pose())
        here = left.read_pose()
        p = here[:3, 3]
        demand = k.servo.level.joints["demand"][LEFT].copy()
        q_wrist = k.servo.level.joints["demand"][LEFT].copy()
        q_wrist[4] = math.radians(3)  # joint 5 at 3°: 2° inside the wrist singularity's margin
        near_wrist = left.base @ kinematics.fkine(q_wrist)
        table = [
            (
                {"targets": [pose(p + np.array([1.5, 0, 0]), here)]},
                r"targets\[0\] at .*'left': pose out of reach",
            ),
            (
                {"targets": [pose(p + np.array([0, 0, 0.1]), here)], "config": "lun"},
                r"configuration 'ruf'.*asks for 'lun'",
            ),
            (
                {"targets": [near_wrist]},
                r"segment 1 of 1, .*'left' comes within .* wrist singularity",
            ),
            ({"targets": [pose(p + np.array([0, 0, 0.1]), here)], "speed": 0.0}, r"speed 0.0 m/s"),
            ({"targets": [pose(p + np.array([0, 0, 0.1]), here)], "speed": math.nan}, r"speed nan"),
            ({"targets": [np.full((4, 4), np.nan)]}, r"targets\[0\]: not finite"),
            ({"targets": [np.eye(3)]}, r"targets\[0\]: shape \(3, 3\)"),
            ({"targets": []}, r"no targets; give at least one pose"),
            (
                {"targets": [pose(p + np.array([0, 0, 0.1]), here)], "config": "xyz"},
                r"expected three letters",
            ),
            (
                {"targets": [pose(p + np.array([0, 0, 0.01]), here)], "transition_s": 1.0},
                r"shorter than transition_s",
            ),
        ]
        for kw, why in table:
            with pytest.raises(MotionError, match=why):
                left.move_path(**{"transition_s": 0.1, **kw})
        step_kali_clock(k.inst, 50)
        np.testing.assert_array_equal(k.servo.level.joints["demand"][LEFT], demand)
        # the TG checks again whatever the client did: a raw request with a target in a wall
        poses = np.zeros((layout.MAX_SEGMENTS, 4, 4))
        poses[0] = pose(p + np.array([2.0, 0, 0]), here)
        grasp = np.eye(4)
        h = k._request(
            MotionKind.PATH,
            [0],
            n_segments=1,
            poses=poses,
            grasps=grasp[None],
            config=[0],
            speed=0.1,
            angular_speed=0.5,
            transition_s=0.1,
        )
        step_kali_clock(k.inst, 20)
        assert h.state == RequestState.REFUSED and "out of reach" in h.message, h.message
        h = k._request(
            MotionKind.PATH,
            [1],
            n_segments=1,
            poses=poses,
            grasps=grasp[None],
            config=[encode_config(None, puma560.ROBOT.kinematics)],
            speed=0.1,
            angular_speed=0.5,
            transition_s=0.1,
        )
        step_kali_clock(k.inst, 5)
        assert h.state == RequestState.REFUSED and "not calibrated" in h.message, h.message
        with pytest.raises(MotionFailedError, match="refused"):
            h.wait(0)
        step_kali_clock(k.inst, 50)
        np.testing.assert_array_equal(k.servo.level.joints["demand"][LEFT], demand)
        assert k.inst.fault_text() is None


def test_a_path_queued_behind_a_joint_move_is_checked_from_where_that_ends(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with calibrated(name) as k:
        left = k.robot("left")
        q0 = left.read_joints()
        here = left.read_pose()
        q1 = q0 + np.radians([10, 0, 0, 0, 0, 0])
        first = left.move_joints(q1, speed=0.5, wait=False)
        # where the joint move ends, the tool is 10° round joint 1: the line starts there
        there = left.base @ kinematics.fkine(q1)
        second = left.move_line(pose(there[:3, 3] + np.array([0, 0, 0.05]), here), wait=False)
        run_until(k, second, 6000)
        first.wait(0)
        second.wait(0)
        end = left.read_pose()[:3, 3]
        assert np.linalg.norm(end - (there[:3, 3] + np.array([0, 0, 0.05]))) < 2e-4
        assert k.inst.fault_text() is None


def test_a_line_checked_over_several_ticks_starts_as_far_ahead_of_sio_as_any_motion(
    kali: Callable[..., str],
) -> None:
    """A path whose check ends in a later tick than its planning starts with LEAD set-points
    in the FIFO, like a joint move or a path checked at once.  It once started one short
    (the tick's loop did not advance a motion whose check ended in it), so SIO's demand ran a
    set-point late: the two-arm carry's internal force rose from 19 to 47 N once the check
    share was counted from the tick's start and checks ended a tick later."""
    name = kali(lockstep=True)
    with calibrated(name) as k:
        left = k.robot("left")
        here = left.read_pose()
        fifo = k.fifos[0]
        h = left.move_line(pose(here[:3, 3] + np.array([0, 0, 0.1]), here), speed=0.02, wait=False)
        ticks_checking = 0
        while h.state in (RequestState.QUEUED, RequestState.FREE):
            step_kali_clock(k.inst, 10)  # one TG tick
            ticks_checking += 1
            assert ticks_checking < 500, h.state
        assert ticks_checking > 1, "the check ended at once: this test needs a longer path"
        # after the TG tick it started in and that tick's servo ticks, SIO has taken one
        assert fifo.pending() == LEAD - 1
        run_until(k, h, 8000)
        assert h.state == RequestState.DONE, h.message
        assert k.inst.fault_text() is None


def test_a_stop_ends_a_line_at_rest_on_it(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with calibrated(name) as k:
        left = k.robot("left")
        here = left.read_pose()
        goal = pose(here[:3, 3] + np.array([0, -0.2, 0]), here)  # away from the right arm
        h = left.move_line(goal, speed=0.1, wait=False)
        step_kali_clock(k.inst, 800)
        assert h.state == RequestState.RUNNING
        h.cancel()
        run_until(k, h, 2000)
        assert h.state == RequestState.STOPPED
        p = left.read_pose()[:3, 3]
        assert 0.01 < here[1, 3] - p[1] < 0.19
        assert distance_to_polyline(p, [here[:3, 3], goal[:3, 3]]) < SQUARE_TOL_M
        assert k.inst.fault_text() is None


class _TgMethods:
    """The TG's own motion-ending methods over a real instance's records, for the one case the
    check leaves no way to reach from outside: no joint solution at run time."""

    _advance = Planner._advance
    _next_tau = Planner._next_tau
    _kinematics_halt = Planner._kinematics_halt
    _end_motion = Planner._end_motion
    _say = Planner._say

    def __init__(self, k: Kali) -> None:
        self.inst = k.inst
        self.name = "tg"
        self.names = k.names
        self.dt = k.tg_dt
        self.fifos = k.fifos
        self.status = k.status
        self.tg_robots = k.tg_robots
        self._setpoint_of = [
            k.tg_robots["setpoint"][i, : r.n_joints] for i, r in enumerate(k.inst.config.robots)
        ]
        self._progress = k.status["progress"]
        self.records = StatusRecords(k.status)
        self.motions: list[Motion] = []


def test_no_joint_solution_at_run_time_stops_the_motion_and_halts(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with calibrated(name) as k:
        left = k.robot("left")
        q0 = k.start_point(0)
        start = left.base @ kinematics.fkine(q0)
        plan = CartesianMotion(
            ["left"], [left.type], [left.base], [np.eye(4)], q0[None], [None],
            [pose(start[:3, 3] + np.array([0, 0, 0.05]), start)], 0.1, 0.5, 0.1, k.tg_dt,
        )  # fmt: skip
        plan.check_all()
        # the arm's base "moves" after the check (nothing outside the TG can do this)
        plan._to_base[0] = inverse(base_transform((-3.0, 0.0, 0.0), 0.0))
        tg = _TgMethods(k)
        tg.records.allocate(77, os.getpid())
        m = Motion(77, [0], plan)
        tg.motions.append(m)
        k.tg_robots["busy_seq"][0] = 77
        tg._advance(m)
        assert tg.motions == [] and int(k.tg_robots["busy_seq"][0]) == 0
        rec = k.status[records.find(k.status, 77)]
        assert int(rec["state"]) == RequestState.HALTED
        text = k.inst.fault_text()
        assert text is not None and "SINGULARITY" in text, text
        assert "motion system 'left', request 77: no joint solution at segment 1 of 1" in text
        assert "out of reach" in text
        csr = boards_of(k.inst)["csr"]
        assert not (csr & registers.CSR_NO_DISABLE).any()  # every amplifier cut by the halt
        del csr
