"""Cartesian motion planning for motion systems (``tg.cartesian``), in-process: T6 of each arm
from the object's path, joint set-points on the commanded lines, and the whole-path check."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.robots import puma560, robot_type
from kali_daemons.robots.cell import base_transform, inverse
from kali_daemons.robots.puma560 import kinematics
from kali_daemons.robots.puma560.kinematics import CONFIGS, KinematicsError
from kali_daemons.tg.cartesian import CartesianMotion, decode_config, encode_config
from kali_daemons.tg.planner import LOCKSTEP_CHECK_SAMPLES, Motion, Planner
from kali_daemons.tg.profiles import MotionError

DT = 0.01
LEFT = base_transform((-0.6, 0.0, 0.0), 0.0)
RIGHT = base_transform((0.6, 0.0, 0.0), 180.0)

PUMA = puma560.ROBOT
PANDA = robot_type("panda")


def world_pose(base: np.ndarray, q: np.ndarray) -> np.ndarray:
    return base @ kinematics.fkine(np.asarray(q, dtype=float))


def translated(t: np.ndarray, dxyz: tuple[float, float, float]) -> np.ndarray:
    out = t.copy()
    out[:3, 3] += np.array(dxyz)
    return out


def one_arm(q0: np.ndarray, targets: list[np.ndarray], **kw: object) -> CartesianMotion:
    args = {"speed": 0.2, "angular_speed": 1.0, "transition_s": 0.1, **kw}
    return CartesianMotion(
        ["left"], [PUMA], [LEFT], [np.eye(4)], q0[None], [kw.pop("config", None)], targets,
        args["speed"], args["angular_speed"], args["transition_s"], DT,
    )  # fmt: skip


def test_config_bytes_round_trip_and_bad_ones_are_refused() -> None:
    kin = PUMA.kinematics
    assert decode_config(encode_config(None, kin), kin) is None
    for c in CONFIGS:
        assert decode_config(encode_config(c, kin), kin) == c
    for bad in (1, 7, 0x10, 0x7F, 0x88, 0xFF):
        with pytest.raises(MotionError, match="configuration byte"):
            decode_config(bad, kin)


def test_base_transform_and_inverse() -> None:
    t = base_transform((0.6, 0.1, 0.2), 180.0)
    np.testing.assert_allclose(t @ np.array([1.0, 0, 0, 1]), [-0.4, 0.1, 0.2, 1], atol=1e-12)
    np.testing.assert_allclose(inverse(t) @ t, np.eye(4), atol=1e-12)


def test_line_set_points_lie_on_the_line_and_are_continuous() -> None:
    q0 = np.array(puma560.QN)
    start = world_pose(LEFT, q0)
    goal = translated(start, (0.0, 0.15, 0.1))
    plan = one_arm(q0, [goal])
    plan.check_all()
    a, b = start[:3, 3], goal[:3, 3]
    u = (b - a) / np.linalg.norm(b - a)
    prev = q0.copy()
    steps = 0
    tau = 0.0
    while tau < plan.duration:
        tau = min(tau + DT, plan.duration)
        q = plan.sample(tau)[0].copy()
        p = world_pose(LEFT, q)
        off = (p[:3, 3] - a) - np.dot(p[:3, 3] - a, u) * u
        assert np.linalg.norm(off) < 1e-6  # on the line: FK(IK(T)) = T
        np.testing.assert_allclose(p[:3, :3], start[:3, :3], atol=1e-9)  # orientation kept
        assert (np.abs(q - prev) / DT <= puma560.QD_MAX * (1 + 1e-9)).all()
        assert kinematics.config_of(q) == kinematics.config_of(q0)
        prev = q
        steps += 1
    np.testing.assert_allclose(world_pose(LEFT, prev), goal, atol=1e-9)
    assert steps == plan.n_samples


def test_two_arms_holding_one_object_agree_on_it_at_every_sample() -> None:
    q_left = q_right = np.array(puma560.QN)  # the arms face each other, flanges 0.3 m apart
    obj = translated(world_pose(LEFT, q_left), (0.0, 0.15, 0.0))  # the object between them
    g_left = inverse(obj) @ world_pose(LEFT, q_left)
    g_right = inverse(obj) @ world_pose(RIGHT, q_right)
    target = translated(obj, (0.0, 0.05, 0.08))
    plan = CartesianMotion(
        ["left", "right"], [PUMA, PUMA], [LEFT, RIGHT], [g_left, g_right],
        np.array([q_left, q_right]), [None, None], [target], 0.1, 0.5, 0.1, DT,
    )  # fmt: skip
    plan.check_all()
    for i in range(1, plan.n_samples + 1):
        rows = plan.sample(min(i * DT, plan.duration))
        o_left = world_pose(LEFT, rows[0]) @ inverse(g_left)
        o_right = world_pose(RIGHT, rows[1]) @ inverse(g_right)
        np.testing.assert_allclose(o_left, o_right, atol=1e-9)
    np.testing.assert_allclose(o_left, target, atol=1e-9)


def test_a_puma_and_a_panda_hold_one_object_each_with_its_own_joints() -> None:
    """A motion system of a 6-joint and a 7-joint arm: each starts, is checked and sampled
    over its own joint count, and a start of another length is refused, naming the arm,
    its type and its count."""
    q_left, q_right = np.array(puma560.QN), PANDA.q_home.copy()
    obj = world_pose(LEFT, q_left)
    g_left = np.eye(4)
    g_right = inverse(obj) @ RIGHT @ PANDA.kinematics.fkine(q_right)
    target = translated(obj, (0.0, 0.03, 0.05))
    plan = CartesianMotion(
        ["left", "right"], [PUMA, PANDA], [LEFT, RIGHT], [g_left, g_right],
        [q_left, q_right], [None, None], [target], 0.1, 0.5, 0.0, DT,
    )  # fmt: skip
    plan.check_all()
    rows = plan.sample(plan.duration)
    assert [r.shape for r in rows] == [(6,), (7,)]
    o_right = RIGHT @ PANDA.kinematics.fkine(rows[1]) @ inverse(g_right)
    np.testing.assert_allclose(world_pose(LEFT, rows[0]), target, atol=1e-9)
    np.testing.assert_allclose(o_right, target, atol=1e-6)
    with pytest.raises(MotionError, match=r"robot 'right' \(panda, 7 joints\) starts at 6 joint"):
        CartesianMotion(
            ["left", "right"], [PUMA, PANDA], [LEFT, RIGHT], [g_left, g_right],
            [q_left, q_right[:6]], [None, None], [target], 0.1, 0.5, 0.0, DT,
        )  # fmt: skip


def test_arms_that_do_not_hold_the_object_where_their_grasps_say_are_refused() -> None:
    q = np.array(puma560.QN)
    obj = world_pose(LEFT, q)
    off = translated(np.eye(4), (0.005, 0.0, 0.0))
    with pytest.raises(MotionError, match=r"'left' and 'right' do not hold the object.*5\.0 mm"):
        CartesianMotion(
            ["left", "right"], [PUMA, PUMA], [LEFT, LEFT], [np.eye(4), off], np.array([q, q]),
            [None, None], [translated(obj, (0, 0, 0.1))], 0.1, 0.5, 0.1, DT,
        )  # fmt: skip


def test_arms_starting_at_rest_hold_the_object_where_they_are_measured() -> None:
    """Issue 24: two arms gripped a bar while one sagged off its set-point; demands that kept
    the set-points' geometry kept the two servos fighting through the bar until a wrist
    torque halted the system.  Given where arms at rest really are, the other arm's grasp is
    taken from that: arm 0's first set-point stays, the other's moves to the measured
    geometry, and the path keeps it.  A measured disagreement beyond the tolerance is
    refused as such."""
    q_left = np.array(puma560.QN)
    q_right = q_left.copy()
    q_right[0] += 0.3
    g_left = np.eye(4)
    obj = world_pose(LEFT, q_left)
    g_right = inverse(obj) @ world_pose(LEFT, q_right)  # the set-points agree exactly
    sagged = q_right.copy()
    sagged[1] -= 0.002  # 2 mrad in the shoulder: 1.1 mm at the flange
    target = translated(obj, (0.0, 0.0, 0.05))

    def plan(measured: list[np.ndarray] | None) -> CartesianMotion:
        p = CartesianMotion(
            ["left", "right"], [PUMA, PUMA], [LEFT, LEFT], [g_left, g_right],
            [q_left, q_right], [None, None], [target], 0.1, 0.5, 0.0, DT, measured=measured,
        )  # fmt: skip
        p.check_all()
        return p

    def right_in_left(q_l: np.ndarray, q_r: np.ndarray) -> np.ndarray:
        return inverse(world_pose(LEFT, q_l)) @ world_pose(LEFT, q_r)

    kept = plan(None)  # moving: the set-points' geometry, as before
    first = kept.sample(DT)
    np.testing.assert_allclose(right_in_left(*first), right_in_left(q_left, q_right), atol=1e-9)
    at_rest = plan([q_left, sagged])
    first = at_rest.sample(DT)
    np.testing.assert_allclose(world_pose(LEFT, first[0]), world_pose(LEFT, kept.sample(DT)[0]))
    measured = right_in_left(q_left, sagged)
    np.testing.assert_allclose(right_in_left(*first), measured, atol=1e-9)
    end = at_rest.sample(at_rest.duration)
    np.testing.assert_allclose(world_pose(LEFT, end[0]), target, atol=1e-9)
    np.testing.assert_allclose(right_in_left(*end), measured, atol=1e-9)
    far = q_right.copy()
    far[1] -= 0.006  # 3.2 mm: beyond GRASP_TOL_M
    with pytest.raises(
        MotionError, match=r"as measured at rest, their object poses differ by 3\.2 mm"
    ):
        plan([q_left, far])
    with pytest.raises(MotionError, match=r"robot 'right' \(puma560, 6 joints\) is measured at 5"):
        plan([q_left, sagged[:5]])


def test_check_refuses_with_segment_arm_and_reason() -> None:
    q0 = np.array(puma560.QN)
    start = world_pose(LEFT, q0)
    # a target out of reach is refused as such, before the path is walked
    a = translated(start, (0.0, 0.1, 0.0))
    b = translated(a, (1.0, 0.0, 0.0))
    with pytest.raises(MotionError, match=r"targets\[1\] at .*robot 'left': pose out of reach"):
        one_arm(q0, [a, b])
    # segment 2 of 2 nearly stretches the arm on its way to a reachable target: the wrist
    # spins (joint 5 near 0 there) faster than joint 4 may turn
    c = translated(a, (0.2785, 0.0, 0.0))
    with pytest.raises(MotionError, match=r"segment 2 of 2, 18.8\d s .*'left' needs joint 4 at"):
        one_arm(q0, [a, c], speed=0.02).check_all()
    one_arm(q0, [a, translated(a, (0.27, 0.0, 0.0))], speed=0.02).check_all()  # short of it
    # turning the flange so that joint 5 passes 0: the wrist singularity
    q_w = q0.copy()
    q_w[3:5] = np.radians([90, 20])
    t = world_pose(LEFT, q_w)
    q_goal = q_w.copy()
    q_goal[4] = math.radians(-20)
    goal = world_pose(LEFT, q_goal)
    goal[:3, 3] = t[:3, 3]
    with pytest.raises(MotionError, match=r"wrist singularity \(joint 5 at"):
        one_arm(q_w, [goal]).check_all()
    # a fast turn about the approach axis needs joint 6 above its 120°/s
    spin = t.copy()
    c, s = math.cos(1.5), math.sin(1.5)
    spin[:3, :3] = t[:3, :3] @ np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    with pytest.raises(MotionError, match=r"needs joint 6 at [\d.]+°/s, above its limit 120°/s"):
        one_arm(q_w, [spin], angular_speed=4.0).check_all()
    one_arm(q_w, [spin], angular_speed=1.0).check_all()  # slower: fine
    # a configuration other than the arm's
    with pytest.raises(MotionError, match=r"in configuration 'ruf', the request asks for 'luf'"):
        one_arm(q0, [a], config=kinematics.Config.from_string("luf"))


class _OneRecord:
    """The TG's ``records`` for a checker of one motion at a time: its record is 0."""

    def index(self, seq: int) -> int:
        return 0


class _Checker:
    """The TG's ``_check`` over one motion, with ``_run`` recorded instead of run."""

    _check = Planner._check
    _spent = Planner._spent

    def __init__(self, until_ns: int, lockstep: bool = False) -> None:
        self.check_ns = 2_500_000  # CHECK_SHARE of a 10 ms period
        self._check_until = until_ns
        self.lockstep = lockstep
        self._work = 0
        self._progress = np.zeros(layout.STATUS_RING)
        self.records = _OneRecord()
        self.ran: list[Motion] = []

    def _run(self, m: Motion) -> None:
        self.ran.append(m)


def test_a_ticks_path_check_ends_with_the_ticks_check_share() -> None:
    """The check's slice ends CHECK_SHARE of a period after the TG's tick began, so planning
    in the same tick (or another motion's check) leaves it less: a tick whose share is spent
    checks one sample (so every check still ends) and returns; the TG once took 7.5 ms of its
    10 ms tick for a plan and a whole slice on top, and an FR3's path (numerical IK) overran
    its share by eight samples."""
    q0 = np.array(puma560.QN)
    start = world_pose(LEFT, q0)
    plan = one_arm(q0, [translated(start, (0.0, 0.0, 0.2))], speed=0.05)
    m = Motion(5, [0], plan, checking=True, check=plan)
    spent = _Checker(time.monotonic_ns() - 1)
    spent._check(m)
    assert plan.checked == 1 and m.checking and spent.ran == []
    ample = _Checker(time.monotonic_ns() + 60_000_000_000)
    ample._check(m)
    assert plan.checked == plan.n_samples and not m.checking and ample.ran == [m]


def test_in_lockstep_a_ticks_path_check_is_a_count_of_samples_not_wall_time() -> None:
    """Lockstep: each tick checks LOCKSTEP_CHECK_SAMPLES path samples whatever the clock on
    the wall says (spent long ago, or an hour left), so the tick a path starts on depends on
    simulated time only (issue 24 item 7: the wall-time slice made identical runs differ)."""
    q0 = np.array(puma560.QN)
    start = world_pose(LEFT, q0)
    for until in (time.monotonic_ns() - 1, time.monotonic_ns() + 3_600_000_000_000):
        plan = one_arm(q0, [translated(start, (0.0, 0.0, 0.2))], speed=0.05)
        m = Motion(5, [0], plan, checking=True, check=plan)
        tg = _Checker(until, lockstep=True)
        ticks = 0
        while m.checking:
            tg._work = 0  # as each cycle begins
            tg._check(m)
            ticks += 1
            assert plan.checked == min(plan.n_samples, ticks * LOCKSTEP_CHECK_SAMPLES)
        assert ticks == -(-plan.n_samples // LOCKSTEP_CHECK_SAMPLES) and tg.ran == [m]


def test_check_goes_in_slices_and_sampling_fails_loudly_if_the_path_breaks() -> None:
    q0 = np.array(puma560.QN)
    start = world_pose(LEFT, q0)
    plan = one_arm(q0, [translated(start, (0.0, 0.0, 0.2))], speed=0.05)
    assert plan.n_samples > 300
    assert not plan.check_some(100) and plan.checked == 100
    while not plan.check_some(100):
        pass
    assert plan.checked == plan.n_samples
    plan._to_base[0] = inverse(base_transform((-3.0, 0.0, 0.0), 0.0))  # the arm "moved" away
    with pytest.raises(KinematicsError, match="out of reach"):
        plan.sample(DT)
