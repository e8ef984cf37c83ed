"""The example robot programs in scripts/ run as a newcomer runs them, ``kalictl run
PROGRAM``, here against a lockstep instance (a waiting program steps its clock)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from collections.abc import Callable

import pytest

from kali_daemons.client import Kali
from kali_daemons.core.errors import MotionError
from kali_daemons.core.layout import ProcState
from kali_daemons.robots.puma560 import PID_DEFAULTS
from kali_daemons.robots.scene import DEFAULT_SCENE, load_scene
from kali_daemons.wallclock import step_kali_clock

from .conftest import ROOT, wait_for
from .test_launcher import kalictl


def run_example(
    kali: Callable[..., str], script: str, base: str = "default.yaml", name: str = ""
) -> str:
    """Run ``scripts/SCRIPT`` with ``kalictl run`` against instance ``name`` or a new
    lockstep instance (of the config ``config/BASE``); its output, once it exited 0."""
    name = name or kali(lockstep=True, base=base)
    r = kalictl("-i", name, "run", f"scripts/{script}")
    assert r.returncode == 0, r.stdout + r.stderr
    return r.stdout


def force_report(what: str, out: str) -> tuple[float, float, float]:
    """The mean, least and most force of an example's ``WHAT M N mean, L .. H N`` line."""
    m = re.search(rf"{what} ([\d.]+) N mean, ([\d.]+) \.\. ([\d.]+) N", out)
    assert m, out
    mean, low, high = (float(v) for v in m.groups())
    return mean, low, high


def assert_bar_put_back(out: str) -> None:
    """An example's ``put back at (x, y, z) m`` line: the bar where it started, on the stand."""
    m = re.search(r"put back at \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m", out)
    assert m, out
    assert [float(v) for v in m.groups()] == pytest.approx([0.0, 0.0, 0.585], abs=0.003)


def test_square_example_draws_its_square(kali: Callable[..., str]) -> None:
    out = run_example(kali, "example_square.py")
    m = re.search(r"square of 10 cm done; the tool is ([\d.]+) mm from its start", out)
    assert m and float(m.group(1)) < 3.0, out  # the servo still settling


def test_carry_example_puts_the_bar_back(kali: Callable[..., str]) -> None:
    assert_bar_put_back(run_example(kali, "example_carry.py"))


def test_pid_tuning_example_prints_its_table(kali: Callable[..., str]) -> None:
    """It tunes the joint it swings (joint 2, the shoulder: index 1 of a joint vector, once
    mixed up with joint 1's gain), each gain over the same swing, so the error falls as kp
    rises; a joint with no kp is named with the command that gives it one."""
    name = kali(lockstep=True)
    r = kalictl("-i", name, "run", "scripts/example_tune_pid.py")
    assert r.returncode == 0, r.stdout + r.stderr
    kp0 = PID_DEFAULTS[1]["kp"]  # joint 2's configured kp
    assert f"left joint 2: pid, kp {kp0:g} at start" in r.stdout, r.stdout
    rows = re.findall(r"^\s*([\d.]+)\s+([\d.]+)\s+([\d.]+)$", r.stdout, re.M)
    assert [float(row[0]) for row in rows] == [kp0 / 2, kp0, 2 * kp0], r.stdout
    rms = [float(row[1]) for row in rows]
    assert rms[0] > 1.5 * rms[1] > 0 and rms[1] > 1.5 * rms[2] > 0, r.stdout  # stiffer, closer
    assert f"kp back to {kp0:g}; the arm is where it started" in r.stdout, r.stdout

    assert kalictl("-i", name, "servo", "select", "left", "2", "bwpd").returncode == 0
    kalictl("-i", name, "clock", "step", "5")  # the SV applies the selection at its tick
    r = kalictl("-i", name, "run", "scripts/example_tune_pid.py")
    assert r.returncode != 0
    assert "left joint 2 runs 'bwpd', which has no kp to tune: kalictl servo select left 2 pid" in (
        r.stderr
    ), r.stderr


def test_run_says_when_the_instance_or_program_is_missing(kali: Callable[..., str]) -> None:
    r = kalictl("-i", "nosuchinstance", "run", "scripts/example_square.py")
    assert r.returncode != 0 and "nosuchinstance" in r.stderr
    r = kalictl("-i", "nosuchinstance", "run", str(ROOT / "scripts" / "nothere.py"))
    assert r.returncode != 0 and "nothere.py" in r.stderr


def test_guarded_example_finds_the_table(kali: Callable[..., str]) -> None:
    out = run_example(kali, "example_guarded.py")
    m = re.search(r"contact at \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m: the table is", out)
    assert m, out
    table = load_scene(DEFAULT_SCENE).object("table")
    top = table.xyz[2] + table.size[2] / 2
    assert float(m.group(3)) == pytest.approx(top, abs=0.002), out


def test_polish_example_slides_pressing_15_n(kali: Callable[..., str]) -> None:
    """Its wrist sensor's (filtered) normal force along the 10 cm stroke: 15 N on average,
    within 15 ± 3 N throughout (tests/test_contact.py checks the plant's truth).  It leaves
    the arm's impedance servo as it found it: its parameters stay in the instance, and the
    squeeze example run next on the same cell, with polish's force feedback gain 5, saturated a
    wrist sensor (FORCE halt) while it squeezed the bar."""
    name = kali(lockstep=True, base="force.yaml")
    with Kali(name) as k:
        before = k.robot("left").servo_params("impedance")
    out = run_example(kali, "example_polish.py", name=name)
    mean, low, high = force_report("normal force", out)
    assert mean == pytest.approx(15.0, abs=0.5), out
    assert 12.0 <= low <= high <= 18.0, out
    with Kali(name) as k:
        step_kali_clock(k.inst, 2)  # its last select (back to the joint servos) is taken
        assert k.robot("left").servo_params("impedance") == before


def test_squeeze_example_carries_the_bar_squeezing_20_n(kali: Callable[..., str]) -> None:
    """Its wrist sensors' squeeze from the lift to the set-down: 20 N on average, within
    20 ± 6 N (tests/test_squeeze.py checks the plant's truth), and the bar back on the stand."""
    out = run_example(kali, "example_squeeze.py", base="force.yaml")
    mean, low, high = force_report("squeeze", out)
    assert mean == pytest.approx(20.0, abs=0.5), out
    assert 14.0 <= low <= high <= 26.0, out
    assert_bar_put_back(out)


def test_conveyor_example_catches_the_bar_on_the_move(kali: Callable[..., str]) -> None:
    """It tracks the bar's grasp site on the moving belt (its own measure, from the measured
    joints, within 2 mm; tests/test_tracking.py checks the plant's truth), picks the bar up
    and sets it down further along the belt."""
    out = run_example(kali, "example_conveyor.py")
    m = re.search(r"tracked the moving grasp site within ([\d.]+) mm", out)
    assert m and float(m.group(1)) < 2.0, out
    m = re.search(r"set down at \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m", out)
    assert m, out


def test_teleop_example_follows_the_hand_and_stops_with_it(kali: Callable[..., str]) -> None:
    """The hand controller (its own process, on the wall clock) streams a figure of eight of
    ±3 cm; the tool follows it; the device stops and the stale stream stops the arm."""
    out = run_example(kali, "example_teleop.py")
    m = re.search(r"followed the hand up to ([\d.]+) mm from the start", out)
    assert m and 25.0 < float(m.group(1)) < 40.0, out
    assert re.search(r"so did the arm: stopped on its path: shared transform 'hand' was not "
                     r"written for 0\.1[01]\d s \(its lifetime is 0\.1 s\)", out), out  # fmt: skip


@pytest.mark.parametrize("base", ["default.yaml", "force.yaml"])
def test_sensor_path_example_bends_its_line_and_follows_the_table(
    kali: Callable[..., str], base: str
) -> None:
    """A periodic function of the program reads the measured joints and the wrist sensor and
    writes the shared transform that bends the TG's line into a ±10 mm sine over the table
    and holds 10 N on it (on average: under the joint PIDs the 20 N/mm pad bounces)."""
    out = run_example(kali, "example_sensor_path.py", base=base)
    m = re.search(r"measured across it ([-\d.]+) \.\. ([-\d.]+) mm", out)
    assert m, out
    assert float(m.group(1)) == pytest.approx(-10.0, abs=2.0), out
    assert float(m.group(2)) == pytest.approx(10.0, abs=2.0), out
    mean, _, _ = force_report("normal force", out)
    assert mean == pytest.approx(10.0, abs=1.0), out


def test_the_hand_controller_s_transform_appears_only_once_it_streams(
    kali: Callable[..., str],
) -> None:
    """A program finds the hand controller's transform and follows it at once: found before
    the device's periodic function ran, the stream went stale while the device was still
    registering with the clock (in a loaded CI run: "followed the hand up to 0.2 mm", then
    the program waited for the device, which lockstep never signalled: a timeout).  In
    lockstep with the clock stopped the device has not run, so its transform is not there
    yet; two periods of steps and it is, and the device ends on time."""
    name = kali(lockstep=True)
    device = subprocess.Popen(
        [sys.executable, str(ROOT / "scripts" / "hand_controller.py"), "--seconds", "0.5"],
        env={**os.environ, "KALI_INSTANCE": name},
    )
    try:
        with Kali(name) as k:
            procs = k.inst.procs

            def registered() -> bool:
                return any(
                    bytes(p["name"]).startswith(b"hand.")
                    and int(p["periodic"])
                    and int(p["state"]) == ProcState.ACTIVE
                    for p in procs
                )

            wait_for(registered, 30.0, "the hand controller registers with the clock")
            with pytest.raises(MotionError, match="hand"):
                k.find_transform("hand")
            step_kali_clock(k.inst, 40)  # two periods of the device: it has run
            k.find_transform("hand")
            step_kali_clock(k.inst, 600)  # past its 0.5 s: it stops and exits
            assert device.wait(timeout=30) == 0
    finally:
        if device.poll() is None:
            device.kill()
            device.wait()
