"""The servo level's functional checks for every robot type (issue 25 item 5), in lockstep.

Each test runs on a cell of two arms of one type (config/default.yaml with both robots'
``model`` set to it), powered through the boards with the clock stepped tick by tick:
calibration and a hold within ±1 encoder count, a step and a ramp that arrive and track, a
bumpless switch of servo algorithm on a moving joint, and the range, runaway and current
faults halting with the robot, joint, value and limit named.  tests/test_servo_level.py
checks the same on the PUMAs in more detail; the bounds here are that file's, one for every
type: a type that misses them has its drive or gains wrong (its ``facts.py``), not the test.

Each type's figures are printed (``-s`` not needed): hold error, step overshoot and final
error, ramp tracking error.
"""

from __future__ import annotations

import math
import os
import re
import signal
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from kali_daemons.core.errors import KaliError
from kali_daemons.core.layout import CalibState, FaultCode, PowerState
from kali_daemons.core.spinlock import pid_alive
from kali_daemons.hardware import hardware_kind
from kali_daemons.hardware.mcgill.registers import CSR_NO_DISABLE
from kali_daemons.robots import RobotType, known_types, robot_type
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo.client import ServoClient
from kali_daemons.wallclock import step_kali_clock

from .conftest import ByArm, boards_of, wait_for
from .test_servo_level import switch_jumps

TYPES = ("puma560", "ur5", "panda")
SETTLE_TICKS = 3500  # as tests/test_servo_level.py: the integrals take up gravity sag
ONE_COUNT = 1.0 + 1e-6  # one encoder count, as radians over rad_per_count compute it
STEP_RAD = 0.02  # the step on every joint
STEP_OVERSHOOT_MAX = 0.35  # of the step
STEP_FINAL_MAX = 0.05  # of the step, 0.6 s after it
RAMP_RAD, RAMP_POINTS = 0.1, 100  # 0.1 rad over 1 s (TG-rate set-points)
RAMP_TRACKING_MAX_RAD = 0.02
RAMP_ARRIVED_COUNTS = 2.0  # off the ramp's end 0.5 s after it
SWITCH_EXTRA_NM = 1.0  # a switch moves the torque no more than the usual tick change + this
TG_POINT_RAD = 0.01  # a range ramp's set-point spacing: 1 rad/s at the TG's 10 ms


def test_every_shipped_type_the_boards_drive_is_covered() -> None:
    """Every type the simulated McGill boards can drive (an FR3 runs on libfranka alone:
    tests/test_franka.py)."""
    mcgill = hardware_kind("mcgill")
    assert sorted(TYPES) == [t for t in known_types() if not mcgill.refuses(robot_type(t), 1e-3)]


def cell(
    kali: Callable[..., str], model: str, separate: bool = False, raised: bool = False
) -> str:
    """A lockstep instance of two arms of type ``model``, facing each other (``separate``:
    a process per daemon, to kill one; ``raised``: on 0.5 m plinths, so a joint folded to its
    limit clears the floor)."""
    edits = {r"model: puma560": f"model: {model}"}
    if raised:
        edits[r"(base_xyz: \[-?0\.6, 0\.0, )0\.0\]"] = r"\g<1>0.5]"
    return kali(lockstep=True, edits=edits, separate=separate)


@contextmanager
def servoing(name: str) -> Iterator[tuple[Instance, ServoClient, RobotType]]:
    """Attach, power both arms and let them settle at rest (not calibrated)."""
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            step_kali_clock(inst, 30)  # SIO reads the pots first
            for robot in client.names:
                client.power(robot, True)
            step_kali_clock(inst, 100)
            assert [client.power_state(r) for r in client.names] == [PowerState.ON] * 2, (
                inst.fault_text()
            )
            step_kali_clock(inst, SETTLE_TICKS)
            yield inst, client, inst.config.robots[0].type
        finally:
            client.close()


def calibrate(inst: Instance, client: ServoClient) -> None:
    """Calibrate both arms, stepping the clock until both are done."""
    for robot in client.names:
        client.calibrate(robot)
    for _ in range(80):
        step_kali_clock(inst, 50)
        if all(
            client.calibration(r)[0] in (CalibState.DONE, CalibState.FAILED) for r in client.names
        ):
            break
    states = [client.calibration(r) for r in client.names]
    assert all(s == CalibState.DONE for s, _, _ in states), states


def error_counts(client: ServoClient, rtype: RobotType) -> np.ndarray:
    """Every joint's tracking error in encoder counts, (robots, joints)."""
    r = ByArm(client.level)
    return (r["demand"] - r["q"]) / np.asarray(rtype.drive.rad_per_count)


def ramp(client: ServoClient, robot: int, joint: int, delta: float, points: int) -> None:
    """Push TG-rate set-points moving one joint (index) by ``delta`` rad in ``points`` steps."""
    fifo = client.level.fifo(robot)
    start = ByArm(client.level)["demand"][robot].copy()
    for m in range(1, points + 1):
        target = start.copy()
        target[joint] += delta * m / points
        fifo.push(target)


def halt(inst: Instance) -> tuple[FaultCode, str]:
    """The fault's code and text."""
    return FaultCode[inst.read_fault().code], inst.fault_text() or ""


@pytest.mark.parametrize("model", TYPES)
def test_calibrated_arms_hold_step_ramp_and_switch_servo_bumplessly(
    kali: Callable[..., str], model: str, capsys: pytest.CaptureFixture[str]
) -> None:
    with servoing(cell(kali, model)) as (inst, client, rtype):
        n = rtype.n_joints
        calibrate(inst, client)
        step_kali_clock(inst, 1000)
        hold = np.zeros((2, n))
        for _ in range(10):  # at rest, over 200 ms
            step_kali_clock(inst, 20)
            hold = np.maximum(hold, np.abs(error_counts(client, rtype)))
        assert (hold <= ONE_COUNT).all(), f"{model}: hold error after calibration (counts) {hold}"

        r = ByArm(client.level)
        counts = 1.0 / np.asarray(rtype.drive.rad_per_count)
        peaks, finals = [], []
        for j in range(n):  # a step of every joint of the first arm
            q0 = float(r["q"][0, j])
            ramp(client, 0, j, STEP_RAD, 1)
            peak = 0.0
            for _ in range(60):  # 600 ms
                step_kali_clock(inst, 10)
                peak = max(peak, (float(r["q"][0, j]) - q0) / STEP_RAD)
            final = (float(r["q"][0, j]) - q0) / STEP_RAD
            peaks.append(peak - 1.0)
            finals.append(abs(final - 1.0) * STEP_RAD * counts[j])
            assert peak - 1.0 < STEP_OVERSHOOT_MAX, (
                f"{model} joint {j + 1}: overshoot {peak - 1:.0%}"
            )
            assert abs(final - 1.0) < STEP_FINAL_MAX, (
                f"{model} joint {j + 1}: at {final:.3f} of the step after 0.6 s"
            )
        tracking = []
        for j in (0, 1):  # a ramp of the base joint and of the shoulder (gravity-loaded)
            ramp(client, 0, j, RAMP_RAD, RAMP_POINTS)
            worst = 0.0
            for _ in range(RAMP_POINTS):
                step_kali_clock(inst, 10)
                worst = max(worst, abs(float(r["demand"][0, j] - r["q"][0, j])))
            tracking.append(worst)
            assert worst < RAMP_TRACKING_MAX_RAD, f"{model} joint {j + 1}: ramp error {worst:.4f}"
            step_kali_clock(inst, 500)  # the integral turns the friction it pushed through
            arrived = abs(float(r["demand"][0, j] - r["q"][0, j])) * counts[j]
            assert arrived <= RAMP_ARRIVED_COUNTS, (
                f"{model} joint {j + 1}: {arrived:.1f} counts off"
            )

        # a switch of algorithm on the shoulder while it moves under gravity: bumpless
        ramp(client, 0, 1, 0.15, 150)
        step_kali_clock(inst, 300)
        jumps, usual = switch_jumps(inst, client)
        for jump, change in zip(jumps, usual, strict=True):
            assert jump <= change + SWITCH_EXTRA_NM, f"{model}: torque jumps {jumps}, usual {usual}"
        assert inst.fault_text() is None
        with capsys.disabled():
            print(
                f"\n{model}: hold {hold.max():.0f} count(s); step overshoot up to "
                f"{max(peaks):.1%}, {max(finals):.1f} counts off after 0.6 s; ramp tracking "
                f"{max(tracking) * 1000:.2f} mrad; servo switch jumps up to {max(jumps):.2f} N·m "
                f"(the torque's own tick-to-tick change up to {max(usual):.2f} N·m)"
            )
        del r


@pytest.mark.parametrize("model", TYPES)
def test_a_joint_driven_past_its_limit_halts_naming_it(
    kali: Callable[..., str], model: str
) -> None:
    with servoing(cell(kali, model, raised=True)) as (inst, client, rtype):
        assert inst.config.robots[0].base_xyz[2] == 0.5  # the UR5's elbow folds to the floor
        q = ByArm(client.level)["q"][0]
        j = int(np.argmin(rtype.q_max - q))  # the joint nearest its upper limit
        limit = float(rtype.q_max[j])
        beyond = limit + 0.05 - float(q[j])
        points = math.ceil(beyond / TG_POINT_RAD)
        ramp(client, 0, j, beyond, points)
        step_kali_clock(inst, 10 * points + 300)
        code, text = halt(inst)
        assert code == FaultCode.RANGE, text
        m = re.search(rf"robot 'left' joint {j + 1} at (-?[\d.]+)° is beyond its limit ", text)
        assert m and float(m.group(1)) >= round(math.degrees(limit), 2), text  # 0.01° printed
        assert f"beyond its limit {math.degrees(limit):.2f}°" in text, text
        del q


@pytest.mark.parametrize("model", TYPES)
def test_a_runaway_halts_naming_robot_joint_value_and_limit(
    kali: Callable[..., str], model: str
) -> None:
    with servoing(cell(kali, model)) as (inst, client, _):
        client.set_safe("right", 3, 0.01)
        ramp(client, 1, 2, 0.05, 1)
        step_kali_clock(inst, 20)
        code, text = halt(inst)
        assert code == FaultCode.RUNAWAY, text
        m = re.search(r"robot 'right' joint 3: tracking error ([+-][\d.]+) rad beyond safe ", text)
        assert m and abs(float(m.group(1))) >= 0.01, text  # 4 decimals printed
        assert "beyond safe 0.0100 rad (runaway)" in text, text


@pytest.mark.parametrize("model", TYPES)
def test_a_current_demand_beyond_the_motor_limit_halts_naming_it(
    kali: Callable[..., str], model: str
) -> None:
    with servoing(cell(kali, model)) as (inst, client, rtype):
        client.set_safe("left", 1, 1.0)  # let the current check, not the runaway, catch it
        kp = client.get_params("left", 1)["kp"]
        client.set_params("left", 1, {"kp": 50.0 * kp}, wait=False)  # a wildly high gain
        ramp(client, 0, 0, 0.3, 1)
        step_kali_clock(inst, 400)
        code, text = halt(inst)
        assert code == FaultCode.CURRENT, text
        limit = float(rtype.drive.max_current[0])
        m = re.search(r"robot 'left' joint 1: motor current demand ([+-][\d.]+) A beyond ", text)
        assert m and abs(float(m.group(1))) > limit, text
        assert f"beyond its limit {limit:.2f} A for 100 ms" in text, text


# The serious processes whose death halts the system (thesis 3.6.2), and the non-serious ones
# the system runs on without (DESIGN 7: degrade).  The wall clock's own death is found by the
# other processes' watch in real time, so it is tested there (tests/system/test_faults.py).
KILLED_SERIOUS = ("plant", "tg", "sio", "sv.0", "sv.1")
KILLED_OPTIONAL = ("dynamics", "viewer")


@pytest.mark.serial
@pytest.mark.parametrize("model", TYPES)
def test_kill_9_of_each_process_halts_or_degrades_with_the_arms_cut(
    kali: Callable[..., str], model: str
) -> None:
    """Per type, a cell of two such arms, powered and holding: kill -9 of a serious process
    halts (PROCESS_DIED naming it) with the amplifiers commanded off; of an optional one, the
    arms hold on.  A fresh cell per serious victim; the ``kali`` fixture then stops each and
    checks nothing is left behind."""
    for victim in (*KILLED_SERIOUS, "optional"):
        name = cell(kali, model, separate=True)
        with servoing_briefly(name) as (inst, client):
            victims = KILLED_OPTIONAL if victim == "optional" else (victim,)
            for v in victims:
                pid = int(inst.procs[inst.slot_of(v)]["pid"])
                os.kill(pid, signal.SIGKILL)
                wait_for(lambda pid=pid: not pid_alive(pid), 5.0, f"{v} gone")
            try:
                step_kali_clock(inst, 50)
            except KaliError:
                pass  # the clock refuses to step once halted
            if victim == "optional":  # the servo level runs on, and the arms settle to hold
                step_kali_clock(inst, SETTLE_TICKS)
                assert inst.fault_text() is None, f"{model}: {inst.fault_text()}"
                hold = np.abs(error_counts(client, inst.config.robots[0].type))
                assert (hold <= ONE_COUNT).all(), f"{model}: {hold} counts"
                continue
            info = inst.read_fault()
            assert info.code == FaultCode.PROCESS_DIED.name, f"{model}, {victim}: {info}"
            assert f"process '{victim}' (pid" in info.message and "died" in info.message
            if victim != "plant":  # the plant's death takes the boards' answers with it
                assert not (boards_of(inst)["csr"] & CSR_NO_DISABLE).any(), "amplifiers cut"


@contextmanager
def servoing_briefly(name: str) -> Iterator[tuple[Instance, ServoClient]]:
    """Attach and power both arms (holding, not settled: enough to be cut)."""
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            step_kali_clock(inst, 30)
            for robot in client.names:
                client.power(robot, True)
            step_kali_clock(inst, 400)
            assert [client.power_state(r) for r in client.names] == [PowerState.ON] * 2
            yield inst, client
        finally:
            client.close()
