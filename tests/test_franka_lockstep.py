"""An FR3 through libfranka in lockstep (issue 54 item 8): franky-sim stepped once a tick by
the cell's plant, each FR3's link in its own process taking its turn on every state packet,
so every byte still crosses libfranka's real protocol on loopback and a run is the same bit
for bit (``kali_daemons.plant.turns``, ``kali_daemons.link.turns``)."""

from __future__ import annotations

import os
import random
import re
import signal
import time
from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.client import Kali, pose
from kali_daemons.core import layout
from kali_daemons.core.errors import ConfigError
from kali_daemons.core.layout import FaultCode, PowerState, RequestState
from kali_daemons.hardware.franka import registers
from kali_daemons.hardware.franka.arms import records
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo.algorithms.admittance import ADMITTANCE_PARAMS
from kali_daemons.tools import launcher
from kali_daemons.wallclock import step_kali_clock

from .conftest import leftovers, make_config, unique_name
from .test_examples import run_example
from .test_executive import first_difference, flight_rows
from .test_franka import PUSH_READ_N, ft_world
from .test_launcher import kalictl

STEADY_RAD = 2e-3  # a joint move's end, on the simulator's truth
LINE_M = 1e-3  # a line's end, the flange by the truth's angles
HAND_CLOSED_M, HAND_OPEN_M = 0.005, 0.075  # the Franka Hand's fingers: 0 .. 0.08 m apart
ADMITTANCE_BAND_N = next(p.default for p in ADMITTANCE_PARAMS if p.name == "band")


def address() -> str:
    """A loopback address of this test's own (franky-sim binds it: runs side by side)."""
    return f"127.{os.getpid() % 250 + 1}.{random.randrange(1, 255)}.{random.randrange(1, 255)}"


def fr3_lockstep(kali: Callable[..., str], separate: bool = False) -> str:
    return kali(base="fr3.yaml", edits={r"127\.0\.0\.1": address()}, separate=separate)


def truth_q(inst: Instance, n: int = 7) -> np.ndarray:
    return inst.arena.record(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, n)["q"].copy()


def program(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Power the FR3 (libfranka's torque control starts), move its joints, power it off and
    on again (control finished and started once more), move a line; the flight recorder's
    rows and the simulator's true angles."""
    with Kali(name) as k:
        step_kali_clock(k.inst, 30)
        k.servo.power("arm", True)
        step_kali_clock(k.inst, 300)
        assert k.servo.power_state("arm") == PowerState.ON, k.inst.fault_text()
        arm = k.robot("arm")
        target = arm.read_joints() + np.radians([15, 10, -10, 15, 15, -15, 20])
        move = arm.move_joints(target, speed=1.0, wait=False)
        step_kali_clock(k.inst, 1400)
        assert move.state == RequestState.DONE, move.message
        assert np.abs(truth_q(k.inst) - target).max() < STEADY_RAD
        k.servo.power("arm", False)
        step_kali_clock(k.inst, 50)
        assert not int(records(k.inst.arena, 1)[0]["status"]) & registers.LINK_CONTROL
        k.servo.power("arm", True)
        step_kali_clock(k.inst, 300)
        here = arm.read_pose(demand=True)
        goal = here[:3, 3] + np.array([0.0, 0.06, -0.03])
        line = arm.move_line(pose(goal, here), speed=0.1, wait=False)
        step_kali_clock(k.inst, 1500)
        assert line.state == RequestState.DONE, line.message
        flange = arm.base @ arm.type.kinematics.fkine(truth_q(k.inst)) @ arm.tool
        assert np.linalg.norm(flange[:3, 3] - goal) < LINE_M
        rec = records(k.inst.arena, 1)[0]
        assert int(rec["late"]) == int(rec["lost"]) == 0
        assert int(rec["answered"]) > 3000  # each tick in control answered by torques
        assert k.inst.fault_text() is None
        return flight_rows(k.inst), truth_q(k.inst)


def test_an_fr3_in_lockstep_moves_over_libfranka_and_runs_the_same_bytes_twice(
    kali: Callable[..., str],
) -> None:
    rows_one, truth_one = program(fr3_lockstep(kali))
    rows_two, truth_two = program(fr3_lockstep(kali))
    assert len(rows_one) == layout.flight_rows(1_000_000)
    assert rows_one.tobytes() == rows_two.tobytes(), first_difference(rows_one, rows_two)
    assert truth_one.tobytes() == truth_two.tobytes()


@pytest.mark.serial
def test_an_fr3_in_lockstep_runs_the_same_bytes_with_a_process_per_daemon(
    kali: Callable[..., str],
) -> None:
    rows_one, truth_one = program(fr3_lockstep(kali))
    rows_many, truth_many = program(fr3_lockstep(kali, separate=True))
    assert rows_one.tobytes() == rows_many.tobytes(), first_difference(rows_one, rows_many)
    assert truth_one.tobytes() == truth_many.tobytes()


def test_the_franka_hand_grips_in_lockstep(kali: Callable[..., str]) -> None:
    """A program's grip waits for the Hand's outcome, the clock stepped meanwhile.  The link
    in torque control runs SCHED_OTHER, as the executive it takes turns with (never above a
    real-time cell beside it)."""
    name = fr3_lockstep(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        link = int(k.inst.procs[k.inst.slot_of("link.arm")]["pid"])
        assert os.sched_getscheduler(link) == os.SCHED_OTHER
        arm, rec = k.robot("arm"), records(k.inst.arena, 1)[0]
        arm.grip(True)
        k.sleep(0.05)  # the width comes with the next gripper state
        assert float(rec["grip_width"]) < HAND_CLOSED_M
        arm.grip(False)
        k.sleep(0.05)
        assert float(rec["grip_width"]) > HAND_OPEN_M
        assert k.inst.fault_text() is None


def two_fr3s(kali: Callable[..., str]) -> str:
    """config/fr3-two.yaml in lockstep, its two FR3s on addresses of their own."""
    net = f"127.{os.getpid() % 250 + 1}.{random.randrange(1, 255)}"
    host = random.randrange(1, 250)
    edits = {r"127\.0\.0\.1": f"{net}.{host}", r"127\.0\.0\.2": f"{net}.{host + 1}"}
    return kali(base="fr3-two.yaml", edits=edits)


def test_two_fr3s_in_lockstep_move_together_as_a_motion_system(
    kali: Callable[..., str],
) -> None:
    """config/fr3-two.yaml in lockstep: two links take their turns with one franky-sim."""
    name = two_fr3s(kali)
    with Kali(name) as k:
        k.ready(["left", "right"])
        both = k.motion_system(["left", "right"])
        obj = both.read_pose()
        both.move_path([pose(obj[:3, 3] + np.array([0.05, 0.0, 0.04]), obj), obj], speed=0.05)
        truth = truth_q(k.inst, 14)
        for i, n in enumerate(("left", "right")):
            arm = k.robot(n)
            arm.settle()
            tool = arm.base @ arm.type.kinematics.fkine(truth[7 * i : 7 * i + 7]) @ arm.tool
            assert np.linalg.norm(tool[:3, 3] - arm.read_pose(demand=True)[:3, 3]) < LINE_M


def test_the_example_programs_run_unchanged_on_an_fr3_in_lockstep(
    kali: Callable[..., str],
) -> None:
    """The square, the PID tuning table and teleoperation (the examples that need no bar or
    wrist sensor), as a newcomer runs them, on config/fr3.yaml's FR3 in lockstep."""
    name = fr3_lockstep(kali)
    out = run_example(kali, "example_square.py", name=name)
    m = re.search(r"square of 10 cm done; the tool is ([\d.]+) mm from its start", out)
    assert m and float(m.group(1)) < 3.0, out
    out = run_example(kali, "example_tune_pid.py", name=name)
    rows = re.findall(r"^\s*([\d.]+)\s+([\d.]+)\s+([\d.]+)$", out, re.M)
    rms = [float(row[1]) for row in rows]
    assert len(rms) == 3 and rms[0] > rms[1] > rms[2] > 0, out  # stiffer, closer
    out = run_example(kali, "example_teleop.py", name=name)
    m = re.search(r"followed the hand up to ([\d.]+) mm from the start", out)
    assert m and 25.0 < float(m.group(1)) < 40.0, out
    assert "so did the arm: stopped on its path" in out, out


@pytest.mark.serial  # a process stopped for seconds, the others waiting on it
@pytest.mark.parametrize(
    ("sig", "code", "says"),
    [
        (signal.SIGKILL, "PROCESS_DIED", r"process 'link\.arm'"),
        (
            signal.SIGSTOP,
            "DEADLINE",
            "lockstep: link.arm (was not ready for|did not take the state of) tick",
        ),
    ],
    ids=["link-killed", "link-stopped"],
)
def test_losing_the_link_in_lockstep_halts_the_cell_naming_it(
    kali: Callable[..., str], sig: signal.Signals, code: str, says: str
) -> None:
    name = fr3_lockstep(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        pid = int(k.inst.procs[k.inst.slot_of("link.arm")]["pid"])
        os.kill(pid, sig)
        try:
            step_kali_clock(k.inst, 100)
            fault = k.inst.read_fault()
            assert fault.code == code, fault
            assert re.search(says, fault.message), fault
            assert k.inst.hardware(0).amplifiers_cut() == [True]
        finally:
            if sig == signal.SIGSTOP:
                os.kill(pid, signal.SIGCONT)


def test_ready_at_once_after_a_reset_waits_for_torque_control_begun_after_it(
    kali: Callable[..., str],
) -> None:
    """A halt cuts the FR3's torque control, which its link ends at its next turn (in
    lockstep, after the reset): power asked at once after the reset comes on a control
    session begun after that, not on the one the halt cut; and ``ready()`` does not take
    SIO's record, not written since the halt, for power on."""
    name = fr3_lockstep(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        rec = records(k.inst.arena, 1)[0]
        k.inst.raise_fault(FaultCode.OPERATOR, "test", "halt the FR3")
        assert k.inst.clear_fault()
        assert k.servo.power_state("arm") == PowerState.OFF  # SIO has not run since the halt
        k.servo.power("arm", True)
        control = []  # each tick: the link in torque control, the arm ON
        while k.servo.power_state("arm") != PowerState.ON and len(control) < 300:
            step_kali_clock(k.inst, 1)
            on = k.servo.power_state("arm") == PowerState.ON
            control.append((bool(int(rec["status"]) & registers.LINK_CONTROL), on))
        assert control[-1][1], k.inst.fault_text() or k.servo.calibration("arm")[2]
        assert (False, False) in control, "power came on the control session the halt cut"
        arm = k.robot("arm")
        target = arm.read_joints() + np.radians([0, 0, 0, 10, 0, 0, 0])
        move = arm.move_joints(target, speed=1.0, wait=False)
        step_kali_clock(k.inst, 1000)
        assert not k.inst.fault["active"], k.inst.fault_text()
        assert k.servo.power_state("arm") == PowerState.ON, k.servo.calibration("arm")[2]
        assert move.state == RequestState.DONE, move.message


def test_calibrating_an_fr3_says_there_is_nothing_to_calibrate(kali: Callable[..., str]) -> None:
    name = fr3_lockstep(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        k.servo.calibrate("arm")
        step_kali_clock(k.inst, 10)
        assert k.servo.calibration("arm")[0] == layout.CalibState.FAILED
        assert "nothing to calibrate" in k.servo.calibration("arm")[2]
        assert "absolute encoders" in k.servo.calibration("arm")[2]
        assert k.servo.calibrated("arm")
        done = kalictl("-i", name, "calibrate")
        assert done.returncode == 0, done.stderr
        assert "arm (fr3): nothing to calibrate: its encoders are absolute" in done.stdout


def test_a_push_reads_on_the_fr3s_wrench_from_its_joint_torques_and_trips_a_guarded_move(
    kali: Callable[..., str],
) -> None:
    """No wrist sensor: the link estimates the wrench at the flange from the FR3's joint
    torques (config/fr3.yaml's ``ft.sensor: joint-torques``; franky-sim gives no estimate of its
    own), and SIO's sensor pipeline takes it as a wrist sensor's.  Tared at rest, a 20 N push
    down on the hand (``kalictl push``, franky-sim's truth) reads within ``PUSH_READ_N``; a
    guarded move down stops on a push that meets its guard, as it would on a table."""
    name = fr3_lockstep(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        arm = k.robot("arm")
        arm.tare()
        assert np.linalg.norm(ft_world(k.inst)[:3]) < 1.0
        push = np.array([0.0, 0.0, -20.0])
        k.inst.push(0, push, 1.5)
        k.sleep(1.0)
        read = ft_world(k.inst)[:3]
        assert np.linalg.norm(read - push) < PUSH_READ_N, read
        k.sleep(1.0)
        arm.tare()
        here = arm.read_pose()
        down = pose(here[:3, 3] - np.array([0.0, 0.0, 0.05]), here)
        move = arm.move_line(down, speed=0.01, guard=10.0, wait=False)
        k.sleep(0.5)
        k.inst.push(0, np.array([0.0, 0.0, 25.0]), 1.0)  # what a table would do
        move.wait(timeout=30.0)
        assert move.state == layout.RequestState.CONTACT, move.message
        assert move.contact is not None and move.contact.force >= 10.0
        assert not k.inst.fault["active"], k.inst.fault_text()


def test_lockstep_is_refused_for_a_real_robot() -> None:
    """config/fr3-lab.yaml drives a real FR3 (no simulator): nothing can step it."""
    name = unique_name()
    with pytest.raises(ConfigError, match="lockstep steps the cell's simulated plant"):
        launcher.start(make_config(name, base="fr3-lab.yaml"), lockstep=True)
    assert leftovers(name) == ([], [])


def test_an_fr3_yields_to_a_push_under_the_admittance_servo(kali: Callable[..., str]) -> None:
    """A force servo on an FR3, its wrench Kali's estimate from the joint torques: under the
    admittance servo a steady push displaces the flange by about the push less the dead band
    over the stiffness, and released, it returns (the estimate is quasi-static: friction
    and the model's mismatch read as force, hence the tolerance)."""
    edits = {r"127\.0\.0\.1": address(), r"^    ff: full$": "    ff: full\n    robot_servos: true"}
    name = kali(base="fr3.yaml", edits=edits)
    with Kali(name) as k:
        k.ready(["arm"])
        arm = k.robot("arm")

        def flange() -> np.ndarray:
            return (arm.base @ arm.type.kinematics.fkine(truth_q(k.inst)))[:3, 3]

        k.sleep(0.3)
        arm.tare()
        x0 = flange()
        arm.select_servo("admittance")
        stiffness = 1000.0
        arm.set_servo({"kx": stiffness, "ky": stiffness, "kz": stiffness})
        k.sleep(0.3)
        x1 = flange()
        assert np.linalg.norm(x1 - x0) < 1e-3, "a bumpless switch at rest moves nothing"
        push = np.array([0.0, 20.0, 0.0])
        k.inst.push(0, push, 1.0)
        k.sleep(0.9)
        moved = flange() - x1
        want = push * (1.0 - ADMITTANCE_BAND_N / np.linalg.norm(push)) / stiffness
        assert np.linalg.norm(moved - want) < 0.3 * np.linalg.norm(want), (moved, want)
        k.sleep(1.5)  # released: back where it was
        assert np.linalg.norm(flange() - x1) < 3e-3
        assert k.inst.fault_text() is None


def test_a_servo_beyond_the_fr3s_torque_limit_halts_naming_joint_torque_and_limit(
    kali: Callable[..., str],
) -> None:
    """A joint servo demanding more than the FR3's joint torque limit halts the cell, the
    fault naming the robot, the joint, the torque demanded and the limit in N·m (an FR3's
    drive takes torques, not a motor's current), and torque control ends."""
    name = fr3_lockstep(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        k.servo.set_safe("arm", 1, 1.0)  # let the torque check, not runaway, catch it
        k.servo.set_params("arm", 1, {"kp": 1e6}, wait=False)  # wildly high gain
        arm = k.robot("arm")
        arm.move_joints(arm.read_joints() + np.radians([10, 0, 0, 0, 0, 0, 0]), wait=False)
        step_kali_clock(k.inst, 600)
        fault = k.inst.read_fault()
        assert fault.code == "CURRENT", fault
        limit = k.inst.config.robots[0].type.drive.max_current[0]
        assert re.search(
            rf"robot 'arm' joint 1: joint torque demand [+-][\d.]+ N·m beyond its limit "
            rf"{limit:.2f} N·m for \d+ ms",
            fault.message,
        ), fault
        assert k.inst.hardware(0).amplifiers_cut() == [True]


@pytest.mark.serial  # a process stopped for seconds, the others waiting on it
def test_a_late_link_halts_two_fr3s_and_the_other_link_keeps_its_turn(
    kali: Callable[..., str],
) -> None:
    """One of two FR3s' links stopped: the cell halts naming it, and the tick goes on for the
    other link, already let into libfranka (whose receive would give up after 1 s); once the
    stopped one continues and the halt is reset, both arms move on."""
    name = two_fr3s(kali)
    with Kali(name) as k:
        k.ready(["left", "right"])
        pid = int(k.inst.procs[k.inst.slot_of("link.left")]["pid"])
        os.kill(pid, signal.SIGSTOP)
        try:
            step_kali_clock(k.inst, 50)
            fault = k.inst.read_fault()
            assert fault.code == "DEADLINE" and fault.process == "link.left", fault
            time.sleep(1.5)  # halted, longer than libfranka waits in a receive
        finally:
            os.kill(pid, signal.SIGCONT)
        assert k.inst.clear_fault()
        k.ready(["left", "right"])
        rec = records(k.inst.arena, 2)
        assert rec["ls_off"].tolist() == [0, 0]  # neither link left its turns
        assert not (rec["status"] & registers.LINK_ERROR).any(), rec["error"]
        moves = [
            k.robot(n).move_joints(k.robot(n).read_joints() + np.radians(5), wait=False)
            for n in ("left", "right")
        ]
        step_kali_clock(k.inst, 1500)
        assert [m.state for m in moves] == [RequestState.DONE] * 2, [m.message for m in moves]
