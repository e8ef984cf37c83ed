"""An arm's state, read publicly (issue 55 item 1): ``Robot.read_state`` is one servo tick's
snapshot, every value of that tick, ``MotionSystem.read_state`` the object and its arms at one
tick, and a remote program reads the same through the bridge."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.client.state import ArmState, ObjectState
from kali_daemons.core import layout
from kali_daemons.core.errors import ServoError
from kali_daemons.core.layout import PowerState
from kali_daemons.wallclock import step_kali_clock

from .test_bridge import bridged  # noqa: F401  (the fixture)

JOINT_FIELDS = {  # ArmState's array: SIO's published joint record field, the same tick
    "q": "q", "qd": "qd", "q_d": "demand", "servo_torque": "servo_torque",
    "ff_torque": "ff_torque", "torque": "torque", "current": "current",
}  # fmt: skip


def test_read_state_is_one_servo_tick_of_a_moving_arm(kali: Callable[..., str]) -> None:
    """Tick by tick through a joint move in lockstep (SIO idle between steps, so its joint
    records hold the same tick): every array equals SIO's own, the demand's velocity is the
    demand's rate of change, the wrench is the sensor's, time advances a servo period a tick;
    power, calibration and the servos are as they stand."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready()
        left = k.robot("left")
        joints, slots = k.servo.level.joints, k.servo.level.slots
        span = k.inst.config.joints.span(0)
        period_s = k.inst.config.clock.servo_period_ms / 1e3
        move = left.move_joints(left.read_joints() + 0.2, wait=False)
        states: list[ArmState] = []
        while not move.done:
            step_kali_clock(k.inst, 1)
            s = left.read_state()
            states.append(s)
            assert s.tick == int(k.inst.clock["tick"]) - 1
            for field, column in JOINT_FIELDS.items():
                np.testing.assert_array_equal(getattr(s, field), joints[column][span], field)
            np.testing.assert_array_equal(s.qd_d, slots["demand_vel"][span])
            np.testing.assert_array_equal(s.wrench, left.read_wrench("tool"))
        assert len(states) > 500
        ticks = np.array([s.tick for s in states])
        assert (np.diff(ticks) == 1).all()
        times = np.array([s.time_s for s in states])
        np.testing.assert_allclose(np.diff(times), period_s)
        q_d = np.array([s.q_d for s in states])
        qd_d = np.array([s.qd_d for s in states])
        assert np.abs(qd_d).max() > 0.1, "the demand moved"
        # the velocity the servos are given with the demand (the dynamics process's central
        # differences at the TG's set-points, interpolated) carries the demand from start to
        # end, to within those differences' lag
        moved = q_d[-1] - q_d[0]
        np.testing.assert_allclose(qd_d.sum(axis=0) * period_s, moved, atol=0.1 * 0.2)
        qd = np.array([s.qd for s in states])
        assert np.abs(qd).max() > 0.1, "the arm moved"
        last = states[-1]
        assert last.robot == "left" and last.power == PowerState.ON and last.calibrated
        assert last.servos == tuple(k.servo.active("left", j) for j in range(1, 7))
        assert len(last.q) == left.n_joints and last.wrench is not None


def test_a_remote_program_reads_the_same_state(
    bridged: Callable[..., tuple[str, str]],  # noqa: F811
) -> None:
    """Through the bridge ``read_state`` returns an ``ArmState`` equal, value for value, to
    what a local program reads at the same tick."""
    name, endpoint = bridged()
    with Kali(name) as local, Kali.connect(endpoint, name) as remote:
        local.ready(["left"])
        step_kali_clock(local.inst, 50)
        here = local.robot("left").read_state()
        there = remote.robot("left").read_state()
        assert isinstance(there, ArmState)
        assert there.same(here), (there, here)
        mine = local.motion_system(["left", "right"]).read_state()
        theirs = remote.motion_system(["left", "right"]).read_state()
        assert isinstance(theirs, ObjectState) and theirs.same(mine), (theirs, mine)
        assert len(here.q) == local.inst.config.robots[0].n_joints
        assert here.tick == int(local.inst.clock["tick"]) - 1
        assert layout.FLIGHT_FIELDS[:4] == ("q", "qd", "demand", "demand_qd")


def test_a_motion_system_s_state_is_its_object_and_arms_at_one_tick(
    kali: Callable[..., str],
) -> None:
    """The object's pose from the first arm's measured joints (as ``read_pose`` gives it) and
    from its demand, and both arms' states, all of one tick."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready()
        both = k.motion_system(["left", "right"])
        step_kali_clock(k.inst, 100)
        s = both.read_state()
        assert s.robots == ("left", "right") and [a.robot for a in s.arms] == ["left", "right"]
        assert {a.tick for a in s.arms} == {s.tick} == {int(k.inst.clock["tick"]) - 1}
        np.testing.assert_allclose(s.pose, both.read_pose(), atol=1e-12)
        assert np.abs(s.pose - s.pose_d)[:3, 3].max() < 0.002  # held where it is told
        for a in s.arms:
            assert a.same(k.robot(a.robot).read_state())


def test_the_simulator_s_truth_is_public_and_crosses_the_bridge(
    bridged: Callable[..., tuple[str, str]],  # noqa: F811
) -> None:
    """``kali.sim.truth(robot)`` (issue 55 item 4): the true joints within an encoder count of
    what SIO measured, the tool point where the true joints put the pad's tip, the object
    where the plant has it; a remote program reads the same values."""
    name, endpoint = bridged()
    with Kali(name) as local, Kali.connect(endpoint, name) as remote:
        local.ready(["left"])
        step_kali_clock(local.inst, 300)
        t = local.sim.truth("left")
        state = local.robot("left").read_state()
        per_count = local.inst.config.robots[0].type.drive.rad_per_count
        assert np.abs((t.q - state.q) / per_count).max() <= 1.0
        cfg = local.inst.config.robots[0]
        flange = local.robot("left").base @ local.flange_pose(t.q, 0)
        np.testing.assert_allclose(t.flange, flange)
        np.testing.assert_allclose(t.tool_point, flange[:3, 3] + flange[:3, 2] * cfg.ft.tool_tip_m)
        objects = local.inst.arena.existing(layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, 1)
        assert list(t.objects) == ["bar"] and t.held is None
        np.testing.assert_allclose(t.objects["bar"][:3, 3], objects["pose"][0][:3])
        assert abs(np.linalg.det(t.objects["bar"][:3, :3]) - 1.0) < 1e-9
        assert t.amps_on and not t.estop and t.plant_ticks > 0
        there = remote.sim.truth("left")
        assert there.same(t), (there, t)
        local.sim.simulated = False  # as on an instance whose arms are real hardware
        with pytest.raises(ServoError, match="real hardware has no truth"):
            local.sim.truth("left")


def test_one_call_selects_a_joint_servo_with_per_joint_parameters(
    kali: Callable[..., str],
) -> None:
    """``robot.select_joint_servos("pd", params)`` (issue 55 item 6): every joint on the PD
    with its own gains, handed over on one servo tick; a bad gain on one joint is refused
    naming it, before anything changed."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        gains = [{"kp": 1000.0 + 100 * j, "kv": 20.0 + j} for j in range(6)]
        bad = [dict(g) for g in gains]
        bad[3]["kp"] = -1.0
        with pytest.raises(ServoError, match="joint 4"):
            left.select_joint_servos("pd", bad)
        assert [k.servo.active("left", j) for j in range(1, 7)] == ["pid"] * 6
        tick = int(k.inst.clock["tick"])
        left.select_joint_servos("pd", gains)
        assert [k.servo.active("left", j) for j in range(1, 7)] == ["pd"] * 6
        assert int(k.inst.clock["tick"]) - tick <= 2  # one servo tick (lockstep: stepped)
        for j, g in enumerate(gains, start=1):
            got = k.servo.get_params("left", j)
            assert (got["kp"], got["kv"]) == (g["kp"], g["kv"]), (j, got)
        step_kali_clock(k.inst, 200)
        assert k.inst.fault_text() is None
