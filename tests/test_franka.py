"""An FR3 through libfranka, against franky-sim (a MuJoCo FR3 serving libfranka's protocol,
written elsewhere): config/fr3.yaml's cell in real time, every byte over the real protocol on
loopback.  Motions end where the simulator's truth says; a halt, a dead simulator, a dead or
stopped link each stop the cell naming why; nothing is left behind (the ``kali`` fixture)."""

from __future__ import annotations

import os
import random
import re
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

import numpy as np
import pytest

from kali_daemons.client import Kali, pose
from kali_daemons.client.common import MotionFailedError
from kali_daemons.core import layout
from kali_daemons.core.errors import ConfigError, KaliError
from kali_daemons.core.layout import FaultCode, PowerState
from kali_daemons.hardware.franka import registers
from kali_daemons.hardware.franka.arms import records
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher
from kali_daemons.wallclock import start_kali_clock

from .conftest import ROOT, leftovers, make_config, unique_name, wait_for
from .test_examples import run_example
from .test_launcher import kalictl

pytestmark = pytest.mark.serial  # real-time cells: alone on the machine (scripts/test.sh)

STEADY_RAD = 2e-3  # a joint move's end, on the simulator's truth
LINE_M = 1e-3  # a line's end, the flange by the truth's angles
HAND_CLOSED_M, HAND_OPEN_M = 0.005, 0.075  # the Franka Hand's fingers: 0 .. 0.08 m apart
PUSH_READ_N = 4.0  # a push on the hand, read from the joint torques: friction and model mismatch


def fr3_cell(kali: Callable[..., str]) -> str:
    """config/fr3.yaml's cell in real time, its FR3 on an address of its own (franky-sim
    binds it: two test runs side by side must not meet)."""
    address = f"127.{os.getpid() % 250 + 1}.{random.randrange(1, 255)}.{random.randrange(1, 255)}"
    return kali(lockstep=False, base="fr3.yaml", edits={r"127\.0\.0\.1": address})


def arm_record(inst: Instance) -> np.ndarray:
    return records(inst.arena, inst.cell.n_robots)[0]


def truth_q(inst: Instance) -> np.ndarray:
    return inst.arena.record(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, 7)["q"].copy()


def test_an_fr3_moves_through_libfranka_and_ends_where_the_simulator_says(
    kali: Callable[..., str],
) -> None:
    name = fr3_cell(kali)
    with Kali(name) as k:
        k.ready(["arm"])  # power on; nothing to calibrate (absolute encoders)
        assert k.servo.calibrated("arm")
        arm = k.robot("arm")
        q0 = arm.read_joints()
        target = q0 + np.radians([20, 10, -15, 15, 20, -20, 30])
        arm.move_joints(target, speed=0.5)
        arm.settle()
        assert np.abs(truth_q(k.inst) - target).max() < STEADY_RAD
        here = arm.read_pose(demand=True)
        goal = here[:3, 3] + np.array([0.0, 0.08, -0.04])
        arm.move_line(pose(goal, here), speed=0.1)
        arm.settle()
        flange = arm.base @ arm.type.kinematics.fkine(truth_q(k.inst)) @ arm.tool
        assert np.linalg.norm(flange[:3, 3] - goal) < LINE_M
        rec = arm_record(k.inst)
        assert int(rec["status"]) & registers.LINK_CONTROL
        assert int(rec["answered"]) > 1000  # every tick of the motions went out as torques
        shown = kalictl("-i", name, "status").stdout
        assert "link.arm: 0x3 (connected, torque control on), robot mode Move;" in shown, shown
        # the Franka Hand, through libfranka's gripper connection in its own process
        arm.grip(True)  # waits for the Hand's outcome
        assert float(rec["grip_width"]) < HAND_CLOSED_M
        arm.grip(False)
        assert float(rec["grip_width"]) > HAND_OPEN_M
        # the robot's packets pace the clock: one tick per state
        assert int(k.inst.clock["tick"]) <= int(rec["seq"])


def test_a_halt_stops_the_fr3_within_a_robot_cycle_and_reset_lets_it_run_again(
    kali: Callable[..., str],
) -> None:
    name = fr3_cell(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        rec = arm_record(k.inst)
        k.inst.raise_fault(FaultCode.OPERATOR, "test", "halt the FR3")
        wait_for(lambda: not int(rec["status"]) & registers.LINK_CONTROL, 2.0, "torque control off")
        wait_for(lambda: int(rec["mode"]) == 1, 2.0, "the robot Idle (its next state says so)")
        assert k.servo.power_state("arm") == PowerState.OFF
        assert k.inst.clear_fault()
        start_kali_clock(k.inst)
        k.ready(["arm"])
        arm = k.robot("arm")
        target = arm.read_joints() + np.radians([0, 0, 0, 10, 0, 0, 0])
        arm.move_joints(target, speed=0.5)
        arm.settle()
        assert np.abs(truth_q(k.inst) - target).max() < STEADY_RAD


def test_calibrating_an_fr3_says_there_is_nothing_to_calibrate(kali: Callable[..., str]) -> None:
    name = fr3_cell(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        k.servo.calibrate("arm")
        wait_for(lambda: k.servo.calibration("arm")[0] == layout.CalibState.FAILED, 2.0)
        assert "nothing to calibrate" in k.servo.calibration("arm")[2]
        assert "absolute encoders" in k.servo.calibration("arm")[2]
        assert k.servo.calibrated("arm")
        done = kalictl("-i", name, "calibrate")
        assert done.returncode == 0, done.stderr
        assert "arm (fr3): nothing to calibrate: its encoders are absolute" in done.stdout


@pytest.mark.parametrize(
    ("process", "sig", "code", "says"),
    [
        ("plant", signal.SIGKILL, "PROCESS_DIED", "process 'plant'"),
        ("link.arm", signal.SIGKILL, "PROCESS_DIED", "process 'link.arm'"),
        ("link.arm", signal.SIGSTOP, "DEADLINE", "'link.arm' (its last state packet from the FR3"),
    ],
    ids=["franky-sim-killed", "link-killed", "link-stopped"],
)
def test_losing_the_robot_halts_the_cell_naming_what_was_lost(
    kali: Callable[..., str], process: str, sig: signal.Signals, code: str, says: str
) -> None:
    name = fr3_cell(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        pid = int(k.inst.procs[k.inst.slot_of(process)]["pid"])
        os.kill(pid, sig)
        try:
            wait_for(lambda: bool(k.inst.fault["active"]), 5.0, f"a halt after {process} lost")
            fault = k.inst.read_fault()
            assert fault.code == code, fault
            assert says in fault.message, fault
            assert k.inst.hardware(0).amplifiers_cut() == [True]  # the link is told to stop
            with pytest.raises(MotionFailedError, match="the system is halted"):
                k.robot("arm").move_joints(k.robot("arm").read_joints(), speed=0.5)
        finally:
            if sig == signal.SIGSTOP:
                os.kill(pid, signal.SIGCONT)


def test_an_unreachable_robot_is_refused_at_start_naming_it() -> None:
    """No simulator and no robot at the address: the link gives up within start's wait,
    saying where it looked; start cleans up."""
    name = unique_name()
    edits = {
        r"127\.0\.0\.1": "127.254.254.254",
        r"^  plant: .*$": "  plant: {enabled: false}",
        r"^arena_kib: 6144$": "arena_kib: 6144\nstartup_timeout_s: 6",
    }
    t0 = time.monotonic()
    unreachable = r"at 127\.254\.254\.254\): no (robot or simulator|gripper)"
    with pytest.raises(KaliError, match=unreachable):
        launcher.start(make_config(name, edits, base="fr3.yaml"), lockstep=False)
    assert time.monotonic() - t0 < 6 + launcher.STOP_GRACE_S + launcher.KILL_GRACE_S + 5
    assert leftovers(name) == ([], [])


def test_lockstep_is_refused_for_an_fr3_cell() -> None:
    with pytest.raises(ConfigError, match="runs in real time"):
        launcher.start(make_config(unique_name(), base="fr3.yaml"), lockstep=True)


@contextmanager
def proxied_cell(kali: Callable[..., str]) -> Iterator[tuple[str, subprocess.Popen]]:
    """An FR3 cell whose link reaches franky-sim through scripts/franka_proxy.py (a relay of
    libfranka's protocol that drops or blacks out states on a signal); the proxy's counts
    printed when it stops."""
    net = f"127.{os.getpid() % 250 + 1}.{random.randrange(1, 255)}"
    listen, upstream = f"{net}.{random.randrange(1, 127)}", f"{net}.{random.randrange(128, 255)}"
    proxy = subprocess.Popen(
        [sys.executable, str(ROOT / "scripts" / "franka_proxy.py"), "--listen", listen,
         "--upstream", upstream, "--drop-p", "0.2"],
        stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert proxy.stdout is not None and proxy.stdout.readline().startswith("READY")
        # no hand: the proxy relays the robot's port alone, not the gripper's
        edits = {
            r"address: 127\.0\.0\.1, hand: true": (
                f"address: {listen}, simulator_address: {upstream}"
            )
        }
        yield kali(lockstep=False, base="fr3.yaml", edits=edits), proxy
    finally:
        proxy.terminate()
        proxy.wait(timeout=5)


def test_states_dropped_on_the_way_are_counted_and_the_arm_holds(
    kali: Callable[..., str],
) -> None:
    """A fifth of the robot's state packets lost for two seconds: the clock ticks on the
    ones that come, the link counts the lost ones, the arm holds where it was."""
    with proxied_cell(kali) as (name, proxy), Kali(name) as k:
        k.ready(["arm"])
        rec = arm_record(k.inst)
        held = k.robot("arm").read_joints()
        lost = int(rec["lost"])
        proxy.send_signal(signal.SIGUSR2)  # drop each state with probability 0.2
        time.sleep(2.0)
        proxy.send_signal(signal.SIGUSR2)
        assert not k.inst.fault["active"], k.inst.fault_text()
        assert int(rec["lost"]) - lost > 100  # ~400 of ~2000 states
        assert np.abs(truth_q(k.inst) - held).max() < STEADY_RAD


def test_states_blacked_out_halt_the_cell_naming_the_robot_link(
    kali: Callable[..., str],
) -> None:
    """No state packet at all: the link waits in libfranka's readOnce, the clock ticks no
    more and halts the cell on the link's silence, saying when the last state came."""
    with proxied_cell(kali) as (name, proxy), Kali(name) as k:
        k.ready(["arm"])
        proxy.send_signal(signal.SIGUSR1)  # black the states out
        wait_for(lambda: bool(k.inst.fault["active"]), 5.0, "a halt")
        fault = k.inst.read_fault()
        assert fault.code == "DEADLINE", fault
        assert "'link.arm' (its last state packet from the FR3 published" in fault.message


def test_two_fr3s_in_one_simulated_world_move_together_as_a_motion_system(
    kali: Callable[..., str],
) -> None:
    """config/fr3-two.yaml: two FR3s served by one franky-sim, one object frame fixed to both
    flanges; a path of the object ends with both tools where they were sent."""
    net = f"127.{os.getpid() % 250 + 1}.{random.randrange(1, 255)}"
    host = random.randrange(1, 250)
    edits = {r"127\.0\.0\.1": f"{net}.{host}", r"127\.0\.0\.2": f"{net}.{host + 1}"}
    name = kali(lockstep=False, base="fr3-two.yaml", edits=edits)
    with Kali(name) as k:
        k.ready(["left", "right"])
        both = k.motion_system(["left", "right"])
        obj = both.read_pose()
        both.move_path([pose(obj[:3, 3] + np.array([0.05, 0.0, 0.04]), obj), obj], speed=0.05)
        truth = k.inst.arena.record(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, 14)
        for i, n in enumerate(("left", "right")):
            arm = k.robot(n)
            arm.settle()
            tool = arm.base @ arm.type.kinematics.fkine(truth["q"][7 * i : 7 * i + 7]) @ arm.tool
            assert np.linalg.norm(tool[:3, 3] - arm.read_pose(demand=True)[:3, 3]) < LINE_M


def test_the_example_programs_run_unchanged_on_an_fr3(kali: Callable[..., str]) -> None:
    """The square, the PID tuning table and teleoperation (the examples that need no bar or
    wrist sensor), as a newcomer runs them, on config/fr3.yaml's FR3."""
    name = fr3_cell(kali)
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


def test_a_second_client_on_the_same_robot_is_refused_naming_it(kali: Callable[..., str]) -> None:
    """Another Kali's link to a robot this one holds waits for a connection the robot never
    gives (libfranka takes one client): its start gives up saying so (whether the link was
    still configuring or already waiting: a loaded host imports slower); this one runs on."""
    first = fr3_cell(kali)
    with Instance.attach(first) as inst:
        address = inst.config.robots[0].hardware.address
    edits = {
        r"127\.0\.0\.1, hand: true": address,
        r"^  plant: .*$": "  plant: {enabled: false}",
        r"^arena_kib: 6144$": "arena_kib: 6144\nstartup_timeout_s: 3",
    }
    second = unique_name()
    try:
        with pytest.raises(KaliError, match=r"link\.arm \((SPAWNED|INACTIVE): connecting to its "
                           r"FR3: nothing answers, or another client holds the robot"):  # fmt: skip
            launcher.start(make_config(second, edits, base="fr3.yaml"), lockstep=False)
    finally:
        launcher.stop(second)
    assert leftovers(second) == ([], [])
    with Instance.attach(first) as inst:
        assert not inst.fault["active"]


def ft_world(inst: Instance) -> np.ndarray:
    return inst.arena.record(layout.KEY_FT, layout.FT_STATE, inst.cell.n_robots)["world"][0].copy()


def test_a_push_reads_on_the_fr3s_wrench_from_its_joint_torques_and_trips_a_guarded_move(
    kali: Callable[..., str],
) -> None:
    """No wrist sensor: the link estimates the wrench at the flange from the FR3's joint
    torques (config/fr3.yaml's ``ft.sensor: joint-torques``; franky-sim gives no estimate of its
    own), and SIO's sensor pipeline takes it as a wrist sensor's.  Tared at rest, a 20 N push
    down on the hand (``kalictl push``, franky-sim's truth) reads within ``PUSH_READ_N``; a
    guarded move down stops on a push that meets its guard, as it would on a table."""
    name = fr3_cell(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        arm = k.robot("arm")
        arm.tare()
        assert np.linalg.norm(ft_world(k.inst)[:3]) < 1.0
        push = np.array([0.0, 0.0, -20.0])
        k.inst.push(0, push, 1.5)
        time.sleep(1.0)
        read = ft_world(k.inst)[:3]
        assert np.linalg.norm(read - push) < PUSH_READ_N, read
        time.sleep(1.0)
        arm.tare()
        here = arm.read_pose()
        down = pose(here[:3, 3] - np.array([0.0, 0.0, 0.05]), here)
        move = arm.move_line(down, speed=0.01, guard=10.0, wait=False)
        time.sleep(0.5)
        k.inst.push(0, np.array([0.0, 0.0, 25.0]), 1.0)  # what a table would do
        move.wait(timeout=10.0)
        assert move.state == layout.RequestState.CONTACT, move.message
        assert move.contact is not None and move.contact.force >= 10.0
        assert not k.inst.fault["active"], k.inst.fault_text()
