"""A held object's mass and inertia in the controller's model (issue 56 item 1): what a
program says an arm holds (``robot.set_load``, a grip on a scene object, a motion system
holding one) reaches the dynamics process's feed-forward and the robot-level servos' model."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pinocchio as pin
import pytest

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.errors import MotionError, ServoError
from kali_daemons.robots import puma560
from kali_daemons.robots.cell import FLANGE_FRAME, load_pinocchio
from kali_daemons.robots.inverse import InverseDynamics
from kali_daemons.robots.model import build_world
from kali_daemons.robots.payload import HeldLoad, write_load
from kali_daemons.robots.scene import DEFAULT_SCENE, load_scene, parse_scene
from kali_daemons.wallclock import step_kali_clock
from tests.conftest import make_config

SHAPES = """version: 1
objects:
  - {name: b, shape: box, size: [0.1, 0.2, 0.3], at: [0, 0, 1], mass: 1.3}
  - {name: c, shape: cylinder, size: [0.05, 0.2], at: [1, 0, 1], mass: 0.7}
  - {name: k, shape: capsule, size: [0.04, 0.15], at: [2, 0, 1], mass: 0.9}
  - {name: s, shape: sphere, size: [0.06], at: [3, 0, 1], mass: 0.4}
"""
TOOL = (0.3, (0.0, 0.0, 0.02))


def test_an_objects_inertia_is_the_simulators() -> None:
    """Every shape's mass and rotational inertia as the controller computes them from the
    scene equal what MuJoCo builds from the same file."""
    scene = parse_scene(SHAPES, "shapes.yaml")
    world = build_world(make_config("payload-shapes").robots, scene=scene)
    for obj, body in zip(scene.free, world.object_body, strict=True):
        assert world.model.body_mass[body] == pytest.approx(obj.mass, rel=1e-12)
        np.testing.assert_allclose(np.diag(obj.inertia), world.model.body_inertia[body], rtol=1e-9)


def test_a_load_set_on_the_model_equals_a_body_appended_to_its_flange() -> None:
    """``HeldLoad.set`` gives the inverse dynamics of the arm with the load appended as a
    body at the flange (Pinocchio's appendBodyToJoint on a fresh model), at random states;
    a load of 0 kg gives back the bare model's torques exactly."""
    rng = np.random.default_rng(56)
    inverse = InverseDynamics(puma560.ROBOT, TOOL)
    held = HeldLoad(inverse.model)
    mass, com = 1.7, np.array([0.05, -0.02, 0.09])
    a = rng.normal(size=(3, 3))
    inertia = a @ a.T * 0.01
    held.set(mass, com, inertia)
    reference = load_pinocchio(puma560.ROBOT, TOOL)
    flange = reference.frames[reference.getFrameId(FLANGE_FRAME)]
    body = pin.Inertia(mass, com, inertia)
    reference.appendBodyToJoint(flange.parentJoint, body, flange.placement)
    data = reference.createData()
    bare = InverseDynamics(puma560.ROBOT, TOOL)
    for _ in range(20):
        q, qd, qdd = rng.uniform(-2, 2, (3, 6))
        want = pin.rnea(reference, data, q, qd, qdd)
        got = pin.rnea(inverse.model, inverse.data, q, qd, qdd)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-10)
    held.set(0.0, np.zeros(3), np.zeros((3, 3)))
    q, qd, qdd = rng.uniform(-2, 2, (3, 6))
    np.testing.assert_array_equal(
        pin.rnea(inverse.model, inverse.data, q, qd, qdd),
        pin.rnea(bare.model, bare.data, q, qd, qdd),
    )


def test_a_load_record_is_followed_whole_once_and_bad_values_are_refused() -> None:
    record = np.zeros((), layout.LOAD)
    inverse = InverseDynamics(puma560.ROBOT)
    held = HeldLoad(inverse.model)
    assert not held.follow(record)  # never written
    write_load(record, 2.0, np.array([0.0, 0.0, 0.1]), np.eye(3) * 1e-3, "test")
    assert held.follow(record) and not held.follow(record)  # applied once
    assert inverse.model.inertias[held.joint].mass == pytest.approx(held.bare.mass + 2.0)
    record["seq"] += 1  # a writer mid-write: odd
    record["mass"] = 5.0
    assert not held.follow(record)
    for mass, com, inertia, rule in (
        (-1.0, [0, 0, 0], np.zeros((3, 3)), "mass = -1.0: within 0..50 kg"),
        (1.0, [0, 0, 3.0], np.zeros((3, 3)), "within 2 m of the flange"),
        (1.0, [0, 0, 0], np.array([[0, 1, 0], [0, 0, 0], [0, 0, 0]]), "symmetric positive"),
        (1.0, [0, 0, 0], -np.eye(3), "symmetric positive"),
    ):
        with pytest.raises(ServoError, match=rule):
            write_load(record, mass, np.array(com, float), np.asarray(inertia, float), "test")


def test_the_load_of_an_object_held_at_a_grasp() -> None:
    """The bar held at its -x end (the left arm's grasp): its centre 16 cm along the flange's
    -x and 6.5 cm along its z (down), its inertia turned into flange axes; a half share for
    each of two arms."""
    scene = load_scene(DEFAULT_SCENE)
    bar = scene.object("bar")
    left = make_config("payload-grasp").robots[0]
    mass, com, inertia = bar.load_on(scene.grasp_for("bar", left), share=0.5)
    assert mass == 0.75
    np.testing.assert_allclose(com, [-0.16, 0.0, 0.065], atol=1e-15)
    np.testing.assert_allclose(inertia, 0.5 * bar.inertia, atol=1e-15)  # axes flipped in pairs


def _lift(k: Kali, site: np.ndarray, lifted: np.ndarray) -> tuple[float, np.ndarray]:
    """The left arm, holding the bar at ``site``, up to ``lifted`` at 5 cm/s and 0.3 s
    there: the tracking error's RMS on the way (rad, the norm over its joints), and the
    feed-forward torques at the end."""
    left = k.robot("left")
    h = left.move_line(lifted, speed=0.05, wait=False)
    errors, after = [], 0
    while after < 300:  # the lift, then 0.3 s there
        step_kali_clock(k.inst, 1)
        state = left.read_state()
        errors.append(state.q - state.q_d)
        after += h.done
    h.wait(0)
    ff = left.read_state().ff_torque
    left.move_line(site, speed=0.05, timeout=30)  # and back down, the bar on the stand
    step_kali_clock(k.inst, 500)
    return float(np.linalg.norm(np.sqrt(np.mean(np.square(errors), axis=0)))), ff


def test_a_held_bar_reaches_the_feed_forward(kali: Callable[..., str]) -> None:
    """Lockstep: the left arm alone lifts the bar by its end, 5 cm, twice.  Told what it
    holds (``grip(holding="bar")``), its feed-forward carries the bar's weight (the gravity
    torques of the bar on the flange, from an independent model of the arm with the bar
    appended) and the lift tracks closer than with the load unknown (``set_load(0)``: the
    servos' integrals must take the weight up on the way: an RMS error of 0.85 against
    1.12 mrad here, bit for bit).  Opening lets go of the load; a
    motion system holding the bar gives each arm half of it."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left", "right"])
        left = k.robot("left")
        left.feedforward("full")
        robot = k.inst.config.robots[0]
        site = k.scene.object("bar").pose @ k.scene.grasp_for("bar", robot)
        lifted = site.copy()
        lifted[2, 3] += 0.05
        left.move_joints(left.joints_at(lifted, "run"), speed=0.5, timeout=30)
        left.move_line(site, speed=0.05, timeout=30)
        step_kali_clock(k.inst, 500)
        left.grip(True, holding="bar")
        loads = k.inst.arena.existing(layout.KEY_LOADS, layout.LOAD, 2)
        assert float(loads["mass"][0]) == 1.5
        step_kali_clock(k.inst, 300)
        known, ff_known = _lift(k, site, lifted)
        left.set_load(0.0)  # still gripping: the load unknown
        unknown, ff_unknown = _lift(k, site, lifted)
        assert known < 0.85 * unknown, (known, unknown)
        # the bar's gravity torques at the lifted pose, from the arm with the bar appended
        mass, com, inertia = k.scene.object("bar").load_on(k.scene.grasp_for("bar", robot))
        tool = (robot.ft.tool_mass_kg, robot.ft.tool_com_m)
        bare = load_pinocchio(robot.type, tool)
        carrying = load_pinocchio(robot.type, tool)
        flange = carrying.frames[carrying.getFrameId(FLANGE_FRAME)]
        body = pin.Inertia(mass, com, inertia)
        carrying.appendBodyToJoint(flange.parentJoint, body, flange.placement)
        q = left.joints_at(lifted, "run")
        weight = pin.computeGeneralizedGravity(
            carrying, carrying.createData(), q
        ) - pin.computeGeneralizedGravity(bare, bare.createData(), q)
        assert abs(weight[1]) > 5.0  # the shoulder lifts 1.5 kg 0.6 m out
        np.testing.assert_allclose(ff_known - ff_unknown, weight, atol=0.02 * abs(weight[1]))
        left.grip(False)
        assert float(loads["mass"][0]) == 0.0
        with pytest.raises(MotionError, match=r"holding 'anvil': .*no object 'anvil'"):
            left.grip(True, holding="anvil")
        k.motion_system(["left", "right"], holding="bar")
        assert [float(m) for m in loads["mass"]] == [0.75, 0.75]
        assert k.inst.fault_text() is None
        del loads


def test_a_robot_level_servos_model_carries_the_load() -> None:
    """An SV's arm model (``ArmModel``) follows its robot's load record: its gravity and mass
    matrix are the arm's with the load appended at the flange from the next update."""
    from kali_daemons.servo.algorithms.arm import ArmInput
    from kali_daemons.servo.sv.armmodel import ArmModel

    robot = make_config("payload-sv").robots[0]
    record = np.zeros((), layout.LOAD)
    inp = ArmInput(robot.n_joints, 0.001, robot.name)
    model = ArmModel(robot, inp, record)
    inp.q[:] = robot.type.q_home
    model.update()
    bare = inp.g.copy()
    com, inertia = np.array([0.0, 0.0, 0.08]), np.eye(3) * 2e-3
    write_load(record, 1.5, com, inertia, "test")
    model.update()
    reference = load_pinocchio(robot.type, (robot.ft.tool_mass_kg, robot.ft.tool_com_m))
    flange = reference.frames[reference.getFrameId(FLANGE_FRAME)]
    reference.appendBodyToJoint(
        flange.parentJoint, pin.Inertia(1.5, com, inertia), flange.placement
    )
    data = reference.createData()
    np.testing.assert_allclose(
        inp.g, pin.computeGeneralizedGravity(reference, data, inp.q), atol=1e-10
    )
    np.testing.assert_allclose(inp.M, pin.crba(reference, data, inp.q), atol=1e-10)
    assert np.abs(inp.g - bare).max() > 1.0
