"""Motion that changes while it runs (issue 28 items 1 and 2, ``kali_daemons/tg/tracking.py``),
end to end in lockstep: a tool follows a shared transform a program moves, exactly while it
moves within the limits and rate-limited (and counted) beyond them; NaN, a transform that is
not rigid, and one not written within its lifetime stop the arm on its path with the reason;
a loop that does not close is refused; pose and joint streams follow and stop when they stop.
Set-points are read from the TG's record (``tg.robots.setpoint``) after each TG tick."""

from __future__ import annotations

import itertools
import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali, MotionFailedError
from kali_daemons.core import layout
from kali_daemons.core.errors import MotionError
from kali_daemons.core.layout import RequestState
from kali_daemons.tg import records
from kali_daemons.tg.planner import LEAD
from kali_daemons.tg.tracking import follow, rotation, rotvec, write_frame
from kali_daemons.wallclock import step_kali_clock

TG_TICKS = 10  # base ticks per TG tick (config/default.yaml: 1 ms and 10 ms)
DT = 0.01


def tg_tick(k: Kali, n: int = 1) -> None:
    step_kali_clock(k.inst, TG_TICKS * n)


def setpoint_pose(k: Kali, name: str) -> np.ndarray:
    """The tool pose of the robot's last TG set-point (world)."""
    r = k.robot(name)
    q = k.tg_robots["setpoint"][r.index, : r.n_joints]
    return r.base @ r.type.kinematics.fkine(q.copy()) @ r.tool


def ready_left(k: Kali) -> np.ndarray:
    """Ready the left arm; its tool pose at the set-point it holds."""
    k.ready(["left"])
    step_kali_clock(k.inst, 200)
    r = k.robot("left")
    return r.base @ r.type.kinematics.fkine(k.start_point(r.index)) @ r.tool


def turn(robot: object, degrees: float, joint: int = 1) -> np.ndarray:
    """A joint vector of ``robot`` (its joint count) turning ``joint`` (1-based) by
    ``degrees``, the others not at all."""
    out = np.zeros(robot.n_joints)  # type: ignore[attr-defined]
    out[joint - 1] = math.radians(degrees)
    return out


def write_raw(k: Kali, index: int, pose: np.ndarray) -> None:
    """Write shared transform ``index`` as the record allows, past the client's checks."""
    write_frame(k.frames[index : index + 1].reshape(()), int(k.inst.clock["tick"]), pose, None)


def wait_over(k: Kali, handle: object, ticks: int = 200) -> None:
    for _ in range(ticks):
        if handle.done:  # type: ignore[attr-defined]
            return
        tg_tick(k)
    raise AssertionError(f"still {handle.state} after {ticks} TG ticks")  # type: ignore[attr-defined]


# ------------------------------------------------------------------------------ pure parts


def test_follow_is_exact_within_the_limits_and_arrives_without_overshoot_beyond() -> None:
    v = [0.0, 0.0, 0.0]
    assert follow([0.001, 0.0, 0.0], [0.1, 0.0, 0.0], v, 0.5, 20.0, DT)
    assert v == pytest.approx([0.1, 0.0, 0.0])
    # a 10 cm jump from rest: speed and acceleration held, no overshoot, arrives exactly
    v, x, target, ticks = [0.0], 0.0, 0.1, 0
    while True:
        e = [target - x]
        before = v[0]
        if follow(e, [0.0], v, 0.25, 1.0, DT):
            break
        assert abs(v[0]) <= 0.25 + 1e-12 and abs(v[0] - before) <= 1.0 * DT + 1e-12
        x += v[0] * DT
        assert x <= target + 1e-12
        ticks += 1
    # at 1 m/s² and 0.25 m/s, 0.1 m takes 2·√(0.1/1) = 0.63 s (it never reaches 0.25 m/s)
    assert 0.6 <= ticks * DT <= 0.8


def test_rotation_vectors_round_trip() -> None:
    rng = np.random.default_rng(3)
    out = np.empty((3, 3))
    for w in [*rng.normal(size=(20, 3)), np.array([0.0, 0.0, 3.1]), np.zeros(3)]:
        w = w / max(1.0, np.linalg.norm(w) / 3.0)  # angles up to 3 rad
        rotation(list(w), out)
        assert np.allclose(out.T @ out, np.eye(3), atol=1e-12)
        assert np.allclose(rotvec(out), w, atol=1e-9)


# ------------------------------------------------------------------------------ end to end


def test_a_shared_transform_is_followed_exactly_and_a_jump_is_rate_limited(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        target = ready_left(k)
        left = k.robot("left")
        grasp = np.eye(4)
        grasp[2, 3] = -0.05  # the tool 5 cm below the frame: a loop of two
        frame_pose = target @ np.linalg.inv(grasp)
        frame = k.shared_transform("part", frame_pose, lifetime=0.05)
        h = left.track([frame, grasp], speed=0.25, accel=20.0)
        tg_tick(k)
        assert h.state == RequestState.RUNNING
        for _ in range(40):  # 1 mm per TG tick (0.1 m/s): followed exactly, tick by tick
            frame_pose[1, 3] += 0.001
            frame.set(frame_pose)
            tg_tick(k)
            assert np.allclose(setpoint_pose(k, "left"), frame_pose @ grasp, atol=1e-9)
        assert h.limited == 0
        # a 10 cm jump: approached at 0.25 m/s at most, counted, then followed exactly
        frame_pose[2, 3] += 0.1
        frame.set(frame_pose)
        last = setpoint_pose(k, "left")[:3, 3]
        for _ in range(120):
            frame.set(frame_pose)  # written on, as a program does (else it goes stale)
            tg_tick(k)
            now = setpoint_pose(k, "left")[:3, 3]
            assert np.linalg.norm(now - last) <= 0.25 * DT * (1 + 1e-6)
            last = now
        assert np.allclose(last, (frame_pose @ grasp)[:3, 3], atol=1e-9)
        assert 30 <= h.limited <= 120
        left.stop()
        wait_over(k, h)
        assert h.state == RequestState.STOPPED
        assert "stopped on request" in h.message


def test_nan_and_a_stale_transform_stop_the_arm_on_its_path(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        frame = k.shared_transform("hand", start, lifetime=0.05)
        h = left.track([frame], speed=0.25, accel=2.0)
        p = start.copy()
        for _ in range(30):  # moving at 0.1 m/s, reached within the limits
            p[0, 3] += 0.001
            frame.set(p)
            tg_tick(k)
        before = setpoint_pose(k, "left")[:3, 3]
        nan = p.copy()
        nan[0, 3] = math.nan
        write_raw(k, frame.index, nan)  # a program the client's checks did not stop
        steps = []
        for _ in range(20):
            tg_tick(k)
            now = setpoint_pose(k, "left")[:3, 3]
            steps.append(now - before)
            before = now
            if h.done:
                break
        assert h.state == RequestState.STOPPED
        assert re.search(r"stopped on its path: shared transform 'hand' is not finite", h.message)
        # it decelerated along +x at 2 m/s² (0.02 m/s a tick), from 0.1 m/s down to rest
        speeds = [float(s[0]) / DT for s in steps if np.linalg.norm(s) > 0]
        assert speeds[0] == pytest.approx(0.08, abs=1e-6)
        assert all(b < a for a, b in itertools.pairwise(speeds))
        assert all(abs(float(s[1])) < 1e-9 and abs(float(s[2])) < 1e-9 for s in steps)
        # stale: written no more while it moves: stops once older than its lifetime
        frame.set(setpoint_pose(k, "left"))
        h = left.track([frame], speed=0.25, accel=2.0)
        tg_tick(k)
        wait_over(k, h)
        m = re.search(r"was not written for ([0-9.]+) s \(its lifetime is 0.05 s\)", h.message)
        assert h.state == RequestState.STOPPED and m, h.message
        assert 0.05 < float(m.group(1)) <= 0.05 + DT + 1e-9


def test_a_loop_that_does_not_close_and_garbage_are_refused_and_nothing_else_moves(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        k.ready(["right"])
        left, right = k.robot("left"), k.robot("right")
        far = start.copy()
        far[0, 3] += 3.0
        frame = k.shared_transform("far", far)
        h = left.track([frame])
        wait_over(k, h)
        assert h.state == RequestState.REFUSED
        assert re.search(r"the loop does not close: .* out of robot 'left''s reach", h.message)
        frame.close()
        frame2 = k.shared_transform("far", start)  # the name is free again
        frame2.close()
        with pytest.raises(MotionError, match=r"'far' is closed"):
            left.track([frame2])
        # one a program holds but has not written yet is not found: a follower finding it
        # would track nothing (the teleop example met it: "has never been written")
        unwritten = k.shared_transform("unwritten")
        with pytest.raises(
            MotionError, match=r"'unwritten': pid \d+ holds it but has not written it yet"
        ):
            k.find_transform("unwritten")
        unwritten.set(start)
        assert k.find_transform("unwritten").index == unwritten.index
        unwritten.close()
        held = k.shared_transform("held", start)
        with pytest.raises(MotionError, match=r"'held' is held by pid"):
            k.shared_transform("held")
        with pytest.raises(MotionError, match=r"not a rigid pose"):
            held.set(np.diag([2.0, 1.0, 1.0, 1.0]))
        with pytest.raises(MotionError, match=r"accel is 0.0 m/s²"):
            left.track([held], accel=0.0)
        # the right arm moves on, while the left one's tracking meets a non-rigid transform
        move = right.move_joints(right.read_joints() + turn(right, 5), wait=False)
        h = left.track([held])
        tg_tick(k, 3)
        skew = start.copy()
        skew[:3, :3] = skew[:3, :3] * 1.01
        write_raw(k, held.index, skew)
        wait_over(k, h)
        assert h.state == RequestState.STOPPED and "is not a rigid motion" in h.message
        move.wait(timeout=60)
        assert k.inst.fault_text() is None


def test_pose_and_joint_streams_follow_and_stop_when_their_program_stops(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        with left.stream(lifetime=0.1, accel=5.0) as s:
            p = start.copy()
            for _ in range(30):  # sent every other TG tick, a 2 mm stair: followed closely
                p[2, 3] += 0.002
                s.send(p)
                tg_tick(k, 2)
                assert np.linalg.norm(setpoint_pose(k, "left")[:3, 3] - p[:3, 3]) < 0.003
            assert s.handle.limited > 0  # a stair is faster than 5 m/s² allows
            for _ in range(8):  # held still: it settles on it exactly
                s.send(p)
                tg_tick(k)
            assert np.allclose(setpoint_pose(k, "left"), p, atol=1e-9)
            assert s.handle.state == RequestState.RUNNING
            # the program stops sending: within its lifetime the arm comes to rest
            wait_over(k, s.handle)
            assert s.handle.state == RequestState.STOPPED
            assert "not written for" in s.handle.message
        with pytest.raises(MotionFailedError):
            s.handle.wait()
        # joint targets
        js = left.stream_joints(lifetime=0.1, speed=0.5)
        q = k.start_point(left.index)
        for i in range(1, 40):  # up to 0.2 rad/s at 1 rad/s² (half the limits: 1.05)
            q[0] += min(0.2, 0.01 * i) * DT
            js.send(q)
            tg_tick(k)
            assert np.allclose(k.tg_robots["setpoint"][left.index, : left.n_joints], q, atol=1e-12)
        assert js.handle.limited == 0
        bad = q.copy()
        bad[1] = 10.0
        js.send(bad)
        wait_over(k, js.handle)
        assert js.handle.state == RequestState.STOPPED
        assert "joint 2 target 10 rad is outside its range" in js.handle.message
        js.close()


FAULTY_FN = Path(__file__).parent / "system" / "faulty_tg_function.py"
WITH_FAULTY_FN = {r"^tg_functions: \[(.*)\]$": rf"tg_functions: [\1, {FAULTY_FN}]"}


def test_a_tg_function_bends_the_target_every_tick_and_takes_parameters_on_line(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        wave = k.tg_function("sine", "wave", amplitude=0.01, frequency_hz=1.0, axis=2)
        assert wave.params()["phase_rad"] == 0.0  # the rest at their defaults
        with pytest.raises(MotionError, match=r"amplitude.*5.*1"):
            wave.set(amplitude=5.0)
        assert wave.params()["amplitude"] == 0.01  # nothing changed
        h = left.track([start, wave], accel=10.0)  # its start, 0.063 m/s at once: 6.3 m/s²
        for _ in range(60):
            tg_tick(k)
            tick = int(k.tg_robots["tick"][left.index])
            t = (tick - int(k.functions["start_tick"][wave.index])) * 1e-3
            want = start.copy()
            want[:3, 3] += start[:3, 2] * 0.01 * math.sin(2 * math.pi * t)  # along its z
            assert np.allclose(setpoint_pose(k, "left"), want, atol=1e-9)
        assert h.limited == 0
        wave.set(amplitude=0.0)  # on line: the offset goes, within the limits
        for _ in range(80):
            tg_tick(k)
        assert np.allclose(setpoint_pose(k, "left"), start, atol=1e-9)
        assert wave.worst_s > 0
        left.stop()
        wait_over(k, h)


def test_a_tg_function_that_raises_holds_its_motion_system_only_and_a_slow_one_nothing(
    kali: Callable[..., str],
) -> None:
    """A function that raises holds its motion system (ABORTED, naming it); one that takes
    50 ms, far beyond its 2 ms budget, is counted over budget but holds nothing in lockstep
    (wall time decides nothing there: tests/system/test_trust_round2.py has the real-time
    hold).  The other arm moves on and nothing halts."""
    name = kali(lockstep=True, edits=WITH_FAULTY_FN)
    with Kali(name) as k:
        start = ready_left(k)
        k.ready(["right"])
        left, right = k.robot("left"), k.robot("right")
        move = right.move_joints(right.read_joints() + turn(right, 8), wait=False)
        bad = k.tg_function("faulty", "bad")
        h = left.track([start, bad])
        tg_tick(k, 3)
        held = k.tg_robots["setpoint"][left.index, : left.n_joints].copy()
        bad.set(mode=1)
        wait_over(k, h)
        assert h.state == RequestState.ABORTED
        assert "tg function 'bad' (faulty) raised RuntimeError: asked to fail" in h.message
        assert "held at its last set-point" in h.message
        assert np.array_equal(k.tg_robots["setpoint"][left.index, : left.n_joints], held)
        assert bad.status.name == "RAISED"
        bad.set(mode=2)  # sleeps 50 ms an evaluation
        h = left.track([start, bad])
        tg_tick(k, 3)
        assert h.state == RequestState.RUNNING
        assert bad.over_budget >= 3 and bad.worst_s > 0.05
        assert bad.status.name == "RUNNING"
        left.stop()
        wait_over(k, h)
        assert h.state == RequestState.STOPPED
        move.wait(timeout=60)  # the other arm moved on, and nothing halted
        assert k.inst.fault_text() is None
        with pytest.raises(MotionError, match=r"none called 'nope'; known: conveyor, line"):
            k.tg_function("nope")


def test_motion_systems_started_together_start_on_one_tg_tick(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left, right = k.robot("left"), k.robot("right")
        # right unpowered: the TG refuses its move, and the left one with it; nothing moves
        with k.together() as group:
            line = left.move_line(start @ _shift(0.0, 0.0, 0.1), speed=0.05)  # no wait here
            joints = right.move_joints(right.read_joints() + 0.1)
            assert line.state == RequestState.QUEUED and "not sent yet" in line.message
        group_wait_fails = pytest.raises(MotionFailedError, match=r"not powered")
        with group_wait_fails:
            group.wait(timeout=30)
        assert joints.state == RequestState.REFUSED
        assert line.state == RequestState.REFUSED
        assert re.search(
            r"cancelled: request \d+ of its group .*refused: robot 'right'", line.message
        )
        k.ready(["right"])
        # a checked 2 s line (checked over several ticks first) and a joint move
        with k.together() as group:
            line = left.move_line(start @ _shift(0.0, 0.0, 0.1), speed=0.05)
            joints = right.move_joints(right.read_joints() + turn(right, 10))
        started: dict[str, int] = {}
        for _ in range(40):
            tg_tick(k)
            tick = int(k.tg_robots["tick"][0])
            for label, h in (("line", line), ("joints", joints)):
                if h.state == RequestState.RUNNING and label not in started:
                    started[label] = tick
            if len(started) == 2:
                break
        assert started["line"] == started["joints"], started
        assert started["line"] > int(k.tg_robots["tick"][0]) - 40 + 2 * TG_TICKS  # it waited
        first = group.wait(any=True, timeout=60)
        assert first is joints  # 10° at half speed is over before a 2 s line
        group.wait(timeout=60)
        assert line.state == joints.state == RequestState.DONE
        # the functional form: the moves as functions, held back and sent as one group
        group = k.together(
            lambda: left.move_line(start, speed=0.05),
            lambda: right.move_joints(right.read_joints() - turn(right, 10)),
        )
        group.wait(timeout=60)
        assert [h.state for h in group.handles] == [RequestState.DONE] * 2
        with pytest.raises(MotionError, match=r"moves\[0\] is .*give functions"):
            k.together(left.read_joints())


def _shift(x: float, y: float, z: float) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = (x, y, z)
    return t


def test_the_tool_tracks_a_part_on_the_conveyor_within_2_mm_and_picks_it_up(
    kali: Callable[..., str],
) -> None:
    """Plant truth: the true flange against the true grasp site of the bar the belt carries
    (``plant.conveyor_m_s``), every TG tick of a second in steady state; then the gripper
    closes on the moving bar and it comes off the belt with the arm."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        left.feedforward("full")
        cfg = k.inst.config
        vx, vy = cfg.plant.conveyor_m_s
        assert math.hypot(vx, vy) > 0.01
        grasp = k.scene.grasp_for("bar", cfg.robots[left.index])
        site = k.scene.object("bar").pose @ grasp
        kin = left.type.kinematics
        above = np.linalg.inv(left.base) @ site @ _shift(0, 0, 0.05)
        left.move_joints(kin.ikine(above, "run", left.read_joints()), speed=0.5, timeout=30)
        approach = k.shared_transform("approach", _shift(0, 0, 0.05), lifetime=0)
        belt = k.tg_function("conveyor", "belt", vx=vx, vy=vy)
        k.run_conveyor(True)
        h = left.track([belt, site, approach], speed=0.1, accel=0.5)
        for i in range(1, 51):
            approach.set(_shift(0, 0, 0.05 * (1 - i / 50)))
            tg_tick(k, 2)
        tg_tick(k, 100)  # steady state
        truth = k.inst.arena.existing(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, cfg.joints.total)
        bar_pose = k.inst.arena.existing(layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, 1)["pose"]
        span = cfg.joints.span(left.index)
        worst, limited = 0.0, h.limited
        for _ in range(100):
            tg_tick(k)
            flange = (left.base @ kin.fkine(truth["q"][span].copy()))[:3, 3]
            bar = _pose7(bar_pose[0])
            worst = max(worst, float(np.linalg.norm(flange - (bar @ grasp)[:3, 3])))
        assert worst < 0.002, f"the tool was {worst * 1000:.2f} mm from the moving grasp site"
        assert h.limited == limited > 0  # the descent was, the steady state is not limited
        left.grip(True)
        tg_tick(k, 5)
        armtruth = k.inst.arena.existing(layout.KEY_TRUTHS, layout.ARM_TRUTH, len(cfg.robots))
        assert int(armtruth["grasped"][left.index]) == 1
        left.stop()
        wait_over(k, h)
        z0 = float(bar_pose[0][2])
        up = left.base @ kin.fkine(k.start_point(left.index)) @ _shift(0, 0, -0.03)
        left.move_line(up, speed=0.03, timeout=30)  # the tool's z points down: up by 3 cm
        assert float(bar_pose[0][2]) == pytest.approx(z0 + 0.03, abs=0.003)
        k.run_conveyor(False)


def _pose7(p: np.ndarray) -> np.ndarray:
    """A 4×4 pose from MuJoCo's position and quaternion (w, x, y, z)."""
    w, x, y, z = (float(v) for v in p[3:7])
    t = np.eye(4)
    t[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    t[:3, 3] = p[:3]
    return t


def test_a_twist_stream_moves_the_target_at_its_velocity(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        with left.stream(lifetime=0.1, accel=5.0) as s:
            for _ in range(50):  # 2 cm/s along world y, sent every TG tick
                s.send_twist([0.0, 0.02, 0.0, 0.0, 0.0, 0.0])
                tg_tick(k)
            target = s.frame.value  # 49 TG ticks from the first send to the last
            assert target[1, 3] - start[1, 3] == pytest.approx(0.02 * 49 * DT, abs=1e-9)
            assert np.allclose(target[:3, :3], start[:3, :3])
            for _ in range(5):
                s.send_twist([0.0] * 6)  # held still: it settles on the target
                tg_tick(k)
            assert np.allclose(setpoint_pose(k, "left"), target, atol=1e-9)
            with pytest.raises(MotionError, match=r"twist has shape \(3,\)"):
                s.send_twist([0.0, 0.0, 1.0])


def test_a_segment_given_a_duration_takes_it_to_the_tick(kali: Callable[..., str]) -> None:
    """Thesis 2.2.1: a motion given by "the time for the movement": 1.5 s is 150 TG ticks,
    the target reached at the 150th set-point and not before; a duration that would beat
    the speed limits is refused naming the segment."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        target = start @ _shift(0.0, 0.03, 0.0)
        h = left.move_line(target, duration=1.5, wait=False)
        moved = [setpoint_pose(k, "left")]  # before it
        while not h.done:
            tg_tick(k)
            p = setpoint_pose(k, "left")
            if not np.array_equal(p, moved[-1]):
                moved.append(p)
        assert h.state == RequestState.DONE
        rec = k.status[records.find(k.status, h.seq)]
        assert float(rec["duration_s"]) == 1.5
        # τ = 0.01 .. 1.5 s: 150 set-points, the first tick pushing LEAD of them (one seen)
        assert len(moved) - 1 == 150 - (LEAD - 1)
        assert np.allclose(moved[-1], target, atol=1e-9)
        assert not np.allclose(moved[-2][:3, 3], target[:3, 3], atol=1e-5)
        with pytest.raises(MotionError, match=r"segment 1 .* in 0.001 s would go 30 m/s"):
            left.move_line(start, duration=0.001)
        with pytest.raises(MotionError, match=r"durations\[0\] is -1"):
            left.move_line(start, duration=-1)


def setpoints_until_done(
    k: Kali, handles: list, name: str = "left", ticks: int = 2000
) -> list[np.ndarray]:
    """The robot's TG set-point (joints) after every TG tick until every handle is over."""
    r = k.robot(name)
    out = []
    for _ in range(ticks):
        tg_tick(k)
        out.append(k.tg_robots["setpoint"][r.index, : r.n_joints].copy())
        if all(h.done for h in handles):
            return out
    raise AssertionError(f"still moving after {ticks} TG ticks")


def test_two_queued_lines_blend_into_paul_transition_without_a_stop(
    kali: Callable[..., str],
) -> None:
    """Thesis 3.1: two queued path requests of one motion system continue without a stop:
    the transition between the first's last segment and the second's first is Paul's, so
    the set-points are those of one two-segment path, to rounding; with blend=False the
    arm stops between them."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        a = start @ _shift(0.04, 0.0, 0.0)
        b = a @ _shift(0.0, 0.04, 0.0)
        kin = left.type.kinematics
        one = left.move_path([a, b], speed=0.05, transition_s=0.2, wait=False)
        whole = setpoints_until_done(k, [one])
        back = left.move_path([start], speed=0.1, transition_s=0.2)  # noqa: F841
        first = left.move_path([a], speed=0.05, transition_s=0.2, wait=False)
        second = left.move_path([b], speed=0.05, transition_s=0.2, wait=False)
        blended = setpoints_until_done(k, [first, second])
        assert first.state == second.state == RequestState.DONE
        poses = [left.base @ kin.fkine(q) for q in blended]
        speeds = [
            np.linalg.norm(q1[:3, 3] - q0[:3, 3]) / DT for q0, q1 in itertools.pairwise(poses)
        ]
        moving = [i for i, v in enumerate(speeds) if v > 1e-6]
        assert all(speeds[i] > 0.01 for i in range(moving[0] + 5, moving[-1] - 5))  # no stop
        ref = [left.base @ kin.fkine(q) for q in whole]

        def moving_part(ps: list[np.ndarray]) -> list[np.ndarray]:
            """From the first set-point off the start (before it: the start, or no set-point
            yet while the path is checked)."""
            i = next(i for i, x in enumerate(ps) if 1e-12 < np.abs(x - start).max() < 0.1)
            return ps[i:]

        ref, poses = moving_part(ref), moving_part(poses)
        assert len(ref) == len(poses)
        dev = [np.abs(p - r).max() for p, r in zip(poses, ref, strict=True)]
        assert max(dev) < 1e-9
        # blend=False: at rest between them
        left.move_path([start], speed=0.1, transition_s=0.2)
        first = left.move_path([a], speed=0.05, transition_s=0.2, wait=False)
        second = left.move_path([b], speed=0.05, transition_s=0.2, wait=False, blend=False)
        stopped = setpoints_until_done(k, [first, second])
        steps = [np.abs(q1 - q0).max() for q0, q1 in itertools.pairwise(stopped)]
        middle = steps[len(steps) // 4 : 3 * len(steps) // 4]
        assert min(middle) < 1e-9  # a tick without motion between the two lines


def test_two_queued_joint_moves_continue_without_a_stop(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        ready_left(k)
        left = k.robot("left")
        q0 = left.read_joints()
        mid, end = q0 + turn(left, -10), q0 + turn(left, -20) + turn(left, 5, joint=2)
        first = left.move_joints(mid, speed=0.5, wait=False)
        second = left.move_joints(end, speed=0.5, wait=False)
        points = setpoints_until_done(k, [first, second])
        assert first.state == second.state == RequestState.DONE
        assert np.allclose(points[-1], end, atol=1e-12)
        v = [np.abs(q1 - q0)[0] / DT for q0, q1 in itertools.pairwise(points)]
        moving = [i for i, x in enumerate(v) if x > 1e-9]
        assert all(v[i] > 1e-3 for i in range(moving[0] + 3, moving[-1] - 3))  # no stop
        limit = float(left.type.qd_max[0]) * 0.5
        assert max(v) <= limit * (1 + 1e-6)  # the sum within joint 1's (halved) limit


def test_a_200_segment_path_runs_through_the_queue_without_a_stop(
    kali: Callable[..., str],
) -> None:
    """No 16-segment cap: 200 segments (a 5 mm zigzag) go as 13 requests through the
    queue, each continuing the one before; the arm never stops on the way and ends on the
    last target."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        targets = [start @ _shift(0.005 * ((i + 1) % 2), 0.0005 * (i + 1), 0.0) for i in range(200)]
        h = left.move_path(targets, speed=0.05, transition_s=0.05, wait=False)
        points = setpoints_until_done(k, [h], ticks=3000)
        assert h.state == RequestState.DONE
        kin = left.type.kinematics
        end = left.base @ kin.fkine(points[-1])
        assert np.allclose(end, targets[-1], atol=1e-9)
        poses = [left.base @ kin.fkine(q) for q in points]
        speeds = [np.linalg.norm(b[:3, 3] - a[:3, 3]) / DT for a, b in itertools.pairwise(poses)]
        moving = [i for i, v in enumerate(speeds) if v > 1e-6]
        assert min(speeds[moving[0] + 3 : moving[-1] - 3]) > 0.005  # never at rest on the way


def test_a_stop_during_a_blend_stops_both_on_their_paths(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        ready_left(k)
        left = k.robot("left")
        q0 = left.read_joints()
        # a stop before the second began: it is cancelled, the first stops on its path
        first = left.move_joints(q0 + turn(left, -10), speed=0.5, wait=False)
        second = left.move_joints(q0 + turn(left, -20), speed=0.5, wait=False)
        tg_tick(k, 10)
        left.stop()
        setpoints_until_done(k, [first, second])
        assert first.state == second.state == RequestState.STOPPED
        assert "cancelled before it started" in second.message
        # a stop while they are summed: both decelerate together, no jump, at rest after
        q1 = k.start_point(left.index)
        first = left.move_joints(q1 + turn(left, -10), speed=0.5, wait=False)
        second = left.move_joints(q1 + turn(left, -20), speed=0.5, wait=False)
        for _ in range(400):
            tg_tick(k)
            if second.state == RequestState.RUNNING:
                break
        assert first.state == RequestState.RUNNING  # in the blend
        left.stop()
        points = setpoints_until_done(k, [first, second])
        assert first.state == second.state == RequestState.STOPPED
        steps = [float(np.abs(b - a)[0]) for a, b in itertools.pairwise(points)]
        assert all(b <= a + 1e-6 for a, b in itertools.pairwise(steps))  # slowing down
        assert steps[-1] < 1e-12


def test_a_circular_arc_keeps_to_its_circle_and_blends_with_lines(
    kali: Callable[..., str],
) -> None:
    """An arc segment (through a given point) runs on its circle at its speed; in a path with
    lines it is entered and left without a stop; a point on the chord is refused, naming the
    segment."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        kin = left.type.kinematics
        r = 0.03
        p0 = start[:3, 3]
        centre = p0 + np.array([0.0, r, 0.0])
        via = centre + r * np.array([math.sin(math.pi / 4), -math.cos(math.pi / 4), 0.0])
        end = start.copy()
        end[:3, 3] = centre + np.array([r, 0.0, 0.0])  # a quarter circle in the x-y plane
        h = left.move_arc(via, end, speed=0.02, wait=False)
        points = setpoints_until_done(k, [h])
        assert h.state == RequestState.DONE
        xyz = [(left.base @ kin.fkine(q))[:3, 3] for q in points]
        xyz = [p for p in xyz if np.abs(p - p0).max() < 0.1]  # not the record before any motion
        on = [abs(np.linalg.norm(p - centre) - r) for p in xyz]
        assert max(on) < 1e-9
        assert np.allclose(xyz[-1], end[:3, 3], atol=1e-9)
        speeds = [np.linalg.norm(b - a) / DT for a, b in itertools.pairwise(xyz)]
        assert max(speeds) == pytest.approx(0.02, rel=1e-3)  # the speed along the arc
        # a line, the arc back, a line: no stop on the way
        back = start @ _shift(0.0, 0.0, 0.0)
        line_end = end @ _shift(0.0, 0.0, 0.0)
        line_end[:3, 3] += np.array([0.0, 0.02, 0.0])
        far = centre + np.array([0.0, 2 * r, 0.0])  # the arc back bulges out past it
        h = left.move_path(
            [line_end, back], speed=0.02, transition_s=0.2, arcs=[None, far], wait=False
        )
        points = setpoints_until_done(k, [h])
        assert h.state == RequestState.DONE
        xyz = [(left.base @ kin.fkine(q))[:3, 3] for q in points]
        speeds = [np.linalg.norm(b - a) / DT for a, b in itertools.pairwise(xyz)]
        moving = [i for i, v in enumerate(speeds) if v > 1e-6]
        ramp = round(0.2 / DT)  # the start and end windows
        assert min(speeds[moving[0] + ramp : moving[-1] - ramp]) > 0.005  # never at rest
        with pytest.raises(MotionError, match=r"segment 1 .* is an arc through .* on the line"):
            left.move_arc((p0 + end[:3, 3]) / 2, end)


def test_a_stream_driven_into_the_wrist_singularity_slows_and_holds_before_it(
    kali: Callable[..., str],
) -> None:
    """Lockstep: the left tool streamed to the pose of its joints with joint 5 at 0 (the
    PUMA's wrist singularity) turns ever slower as joint 5 nears the type's 5° limit and
    holds there, the stream running on with no fault (MoveIt Servo's rule: before, it ended
    the motion at the limit); streamed back, it follows at speed; begun inside the limit,
    streamed out of it, it follows."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        start = ready_left(k)
        left = k.robot("left")
        q0 = k.start_point(left.index)
        q_singular = q0.copy()
        q_singular[4] = 0.0
        target = left.base @ left.type.kinematics.fkine(q_singular) @ left.tool
        limit = math.radians(5.0)  # puma560.kinematics.WRIST_MIN_DEG
        with left.stream(lifetime=0.5, speed=0.2) as s:
            wrist = []
            for _ in range(300):  # 6 s
                s.send(target)
                step_kali_clock(k.inst, 20)
                wrist.append(abs(float(k.servo.level.joints["demand"][left.span][4])))
            assert s.handle.state == RequestState.RUNNING, s.handle.message
            assert k.inst.fault_text() is None
            assert limit <= wrist[-1] < limit + math.radians(0.5), math.degrees(wrist[-1])
            assert min(wrist) >= limit
            rates = -np.diff(wrist) / 0.02
            far = [r for r, w in zip(rates, wrist[1:], strict=True) if w > 3 * limit]
            near = [r for r, w in zip(rates, wrist[1:], strict=True) if w < 1.25 * limit]
            assert max(near) < 0.5 * max(far), (max(near), max(far))
            assert abs(rates[-10:]).max() < 1e-6  # held at the end
            for _ in range(100):  # and back, at the stream's speed
                s.send(start)
                step_kali_clock(k.inst, 20)
            assert abs(float(k.servo.level.joints["demand"][left.span][4])) > 2 * limit
            assert s.handle.state == RequestState.RUNNING
        inside = q0.copy()  # a stream begun inside the limit is let out of it
        inside[4] = math.copysign(math.radians(3.0), q0[4])
        left.move_joints(inside, speed=0.3)
        with left.stream(lifetime=0.5, speed=0.2) as s:
            for _ in range(100):
                s.send(start)
                step_kali_clock(k.inst, 20)
            assert abs(float(k.servo.level.joints["demand"][left.span][4])) > 2 * limit
            assert s.handle.state == RequestState.RUNNING
