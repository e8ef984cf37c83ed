"""Admittance and hand guiding (issue 27 item 3, ``servo/admittance.py``), end to end in
lockstep on the PUMA, whose joints stick too much to be pushed by hand: the wrist sensor
moves the arm.  Guiding: a push moves the tool along itself by (|F| − band) / d per second
and it stays there; meanwhile the demand follows the arm, the TG refuses to move it and stops
a motion it was running, and another servo selected afterwards holds it where it was left.
Admittance: a steady push displaces the tool by the compliance R K⁻¹ Rᵀ of the push less the
dead band; released, it returns.  Bad parameters are refused and change nothing."""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core.errors import MotionError, ServoError
from kali_daemons.core.layout import RequestState
from kali_daemons.servo.algorithms.admittance import ADMITTANCE_PARAMS
from kali_daemons.tools import top
from kali_daemons.tools.introspect import Introspector
from kali_daemons.wallclock import step_kali_clock
from tests.test_armservo import LEFT_ROBOT_SERVOS, tool_point
from tests.test_introspect import render
from tests.test_launcher import kalictl

DEFAULT = {p.name: p.default for p in ADMITTANCE_PARAMS}
PUSH_S = 0.3


def guided_arm(k: Kali, servo: str) -> np.ndarray:
    """Ready the left arm, tare its sensor at rest and hand it to ``servo``; the tool point
    then (it must not have moved)."""
    k.ready(["left"])
    left = k.robot("left")
    step_kali_clock(k.inst, 300)
    left.tare()
    x0, _ = tool_point(k, 0)
    left.select_servo(servo)
    step_kali_clock(k.inst, 300)
    assert k.servo.arm_active("left") == servo
    x1, _ = tool_point(k, 0)
    assert np.linalg.norm(x1 - x0) < 1e-4, "a bumpless switch at rest moves nothing"
    return x1


def moves_from_where_it_is(k: Kali, degrees: list[float]) -> None:
    """A joint move of the left arm by ``degrees`` from where it is ends there."""
    left = k.robot("left")
    there = left.read_joints() + np.radians(degrees)
    handle = left.move_joints(there, wait=False)
    step_kali_clock(k.inst, 2000)
    assert handle.state == RequestState.DONE, handle.message
    assert np.abs(left.read_joints() - there).max() < np.radians(0.05)


def test_a_guided_arm_goes_where_it_is_pushed_stays_and_the_tg_keeps_off(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True, edits=LEFT_ROBOT_SERVOS)
    with Kali(name) as k:
        left = k.robot("left")
        k.ready(["left"])
        step_kali_clock(k.inst, 300)
        left.tare()
        # a motion running when guiding is selected stops, saying why
        q0 = left.read_joints()
        handle = left.move_joints(q0 - np.radians([20, 0, 0, 0, 0, 0]), speed=0.1, wait=False)
        step_kali_clock(k.inst, 500)
        left.select_servo("guiding")
        step_kali_clock(k.inst, 300)
        assert handle.state == RequestState.ABORTED
        assert "robot 'left' is guided by hand" in handle.message
        x1, _ = tool_point(k, 0)
        for push in (np.array([20.0, 0.0, 0.0]), np.array([0.0, -12.0, 16.0])):
            k.inst.push(0, push, PUSH_S)
            step_kali_clock(k.inst, int(PUSH_S * 1000) + 300)  # pushed, then let go
            x2, _ = tool_point(k, 0)
            step_kali_clock(k.inst, 1000)
            x3, _ = tool_point(k, 0)
            assert np.linalg.norm(x3 - x2) < 5e-4, "let go, it stays where it was pushed"
            moved = x3 - x1
            size = np.linalg.norm(push)
            # the reference's speed is (|F| − band) / d; its whole travel that times the push
            want = push / size * (size - DEFAULT["band"]) / DEFAULT["dx"] * PUSH_S
            assert np.linalg.norm(moved - want) < 0.05 * np.linalg.norm(want), (moved, want)
            # the demand followed the arm: nothing pulls it back
            err = np.abs(left.read_joints() - k.servo.level.arm("demand", 0))
            assert err.max() < 1e-3, err
            x1 = x3
        spy = Introspector(k.inst)  # top says so in the TG's column
        try:
            frame = top.frame(top.take(spy), top.take(spy), 0.1, 120)
        finally:
            spy.close()
        assert re.search(r"left\s.*\sguided", render(frame, 120)), render(frame, 120)
        with pytest.raises(MotionError, match=r"robot .left. is guided by hand .* servo select"):
            left.move_joints(left.read_joints() + 0.05)
        # another servo holds it where it was left, and moves start from there
        left.select_servo("joints")
        step_kali_clock(k.inst, 500)
        x4, _ = tool_point(k, 0)
        assert np.linalg.norm(x4 - x1) < 5e-4, (x4, x1)
        moves_from_where_it_is(k, [0, 5, 0, 0, 0, 0])
        assert k.inst.fault_text() is None


def test_an_admittance_yields_to_a_push_by_its_compliance_and_returns(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True, edits=LEFT_ROBOT_SERVOS)
    with Kali(name) as k:
        x1 = guided_arm(k, "admittance")
        left = k.robot("left")
        stiffness = (1000.0, 2000.0, 500.0)
        left.set_servo(dict(zip(("kx", "ky", "kz"), stiffness, strict=True)))
        _, rot = tool_point(k, 0)
        compliance = rot @ np.diag([1 / s for s in stiffness]) @ rot.T
        for push in (np.array([20.0, 0.0, 0.0]), np.array([0.0, -20.0, 10.0])):
            k.inst.push(0, push, 1.0)
            step_kali_clock(k.inst, 900)
            moved = tool_point(k, 0)[0] - x1
            size = np.linalg.norm(push)
            want = compliance @ (push * (size - DEFAULT["band"]) / size)
            assert np.linalg.norm(moved - want) < 0.1 * np.linalg.norm(want), (moved, want)
            step_kali_clock(k.inst, 1500)  # released: back where it was
            assert np.linalg.norm(tool_point(k, 0)[0] - x1) < 1e-3
        # a TG motion runs under it as under any servo
        moves_from_where_it_is(k, [5, 0, 0, 0, 0, 0])
        assert k.inst.fault_text() is None


def test_bad_admittance_parameters_are_refused_and_change_nothing(
    kali: Callable[..., str],
) -> None:
    no_sensor = {r"^(  - \{name: right.*)\}$": r"\1, robot_servos: true, ft: {sensor: none}}"}
    name = kali(lockstep=True, edits={**LEFT_ROBOT_SERVOS, **no_sensor})
    with Kali(name) as k:
        left, right = k.robot("left"), k.robot("right")
        for servo in ("admittance", "guiding"):  # moved by a sensor: it must be there, tared
            with pytest.raises(ServoError, match="sensor was never tared, and its offsets"):
                left.select_servo(servo)
            with pytest.raises(ServoError, match=r"right' '.*': the arm has no wrist sensor"):
                right.select_servo(servo)
        assert k.servo.arm_active("left") is None
        for servo in ("admittance", "guiding"):
            before = left.servo_params(servo)
            for params, says in (
                ({"mass": 0.0}, "mass = 0 kg must be > 0"),
                ({"dx": float("nan")}, "must be finite"),
                ({"band": -1.0}, "band = -1 N must be >= 0"),
            ):
                with pytest.raises(ServoError, match=says):
                    left.set_servo(params, servo)
            assert left.servo_params(servo) == before
        with pytest.raises(ServoError, match="'guiding' has no parameter kx"):
            left.set_servo({"kx": 100.0}, "guiding")  # a guided arm has no spring
        r = kalictl("-i", name, "servo", "list")
        assert "admittance" in r.stdout and "guiding" in r.stdout, r.stdout
        r = kalictl("-i", name, "tare", "left", "nobody")
        assert r.returncode != 0 and "tare: no robot 'nobody'" in r.stderr, r.stderr
        r = kalictl("-i", name, "tare", "left")  # in lockstep it steps the clock
        assert r.returncode == 0 and "left: tared; the sensor reads 0." in r.stdout, r
        left.select_servo("guiding")  # tared now: taken (it runs once the arm is powered)
