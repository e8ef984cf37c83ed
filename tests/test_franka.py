"""An FR3 through libfranka, against franky-sim (a MuJoCo FR3 serving libfranka's protocol,
written elsewhere): config/fr3.yaml's cell in real time, every byte over the real protocol on
loopback.  Motions end where the simulator's truth says; a halt, a dead simulator, a dead or
stopped link each stop the cell naming why; nothing is left behind (the ``kali`` fixture)."""

from __future__ import annotations

import os
import random
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
from kali_daemons.core.errors import KaliError
from kali_daemons.core.layout import FaultCode, PowerState
from kali_daemons.hardware.franka import registers
from kali_daemons.hardware.franka.arms import records
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher
from kali_daemons.wallclock import start_kali_clock

from .conftest import ROOT, leftovers, make_config, unique_name, wait_for
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
        # in torque control at its configured priority (libfranka's Robot() sets SCHED_FIFO 99)
        link = int(k.inst.procs[k.inst.slot_of("link.arm")]["pid"])
        assert os.sched_getparam(link).sched_priority == k.inst.config.process("link.arm").priority
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
        assert not inst.fault["active"], inst.fault_text()


def ft_world(inst: Instance) -> np.ndarray:
    return inst.arena.record(layout.KEY_FT, layout.FT_STATE, inst.cell.n_robots)["world"][0].copy()


def test_programs_busy_on_the_simulators_cpu_leave_the_fr3_running(
    kali: Callable[..., str],
) -> None:
    """franky-sim runs at normal scheduling (below every Kali process) on CPU 1, where four
    busy programs, each in a session of its own as another cell's processes are, take their
    share for three seconds: the robot's states still come within the 20 ms the link waits."""
    name = fr3_cell(kali)
    with Kali(name) as k:
        k.ready(["arm"])
        busy = "import os, time\nos.sched_setaffinity(0, {1})\nt = time.monotonic() + 3\n" \
            "while time.monotonic() < t: pass\n"  # fmt: skip
        hogs = [
            subprocess.Popen([sys.executable, "-c", busy], start_new_session=True)
            for _ in range(4)
        ]
        try:
            for h in hogs:
                h.wait(timeout=30)
        finally:
            for h in hogs:
                h.kill()
        assert not k.inst.fault["active"], k.inst.fault_text()
