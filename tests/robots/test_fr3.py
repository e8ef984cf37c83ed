"""The FR3 robot type against Franka's DH table, franka_description and franky-sim's model.

franky-sim (the FR3 cell's plant) simulates MuJoCo Menagerie's ``fr3.xml`` with a Franka Hand
and adds gravity from Pinocchio on ``franka_description``'s ``fr3_clean.urdf`` plus a 0.73 kg
hand; Kali's type is the arm alone, so each comparison takes the hand out or puts it back.
"""

from __future__ import annotations

import copy
import math
import xml.etree.ElementTree as ET
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from kali_daemons.core.errors import KinematicsError
from kali_daemons.robots import known_types, robot_type
from kali_daemons.robots.chain import chain_of, flange_pose
from kali_daemons.robots.fr3 import ROBOT, facts
from kali_daemons.robots.fr3 import kinematics as kin
from kali_daemons.robots.profile import INTEGRATION_BAND_RAD, RobotType

from . import mj_model_of, mj_qpos_of, numpy_data_allocations, pin_model_of

franky_sim = pytest.importorskip("franky_sim", reason="the FR3 cell's plant, a dependency")
ASSETS = Path(franky_sim.__file__).parent / "assets"

N_POSES = 20
DH_TOL = 1e-9  # m, and rotation matrix entries: the URDF against the table
POSE_TOL = 1e-6  # m, and rotation matrix entries: against MuJoCo
EXACT_TOL = 1e-9  # N·m: the same Pinocchio model of the same inertials
# N·m: Menagerie's fr3.xml rounds franka_description's inertials to 6 digits; measured 2.7e-5
# (joint 2) over 200 random poses
MENAGERIE_TOL = 1e-4
HAND_BODIES = ("hand", "left_finger", "right_finger")  # Menagerie's Franka Hand in fr3.xml


def random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(facts.Q_MIN, facts.Q_MAX, size=(n, facts.NJOINTS))


def dh_flange(q: np.ndarray) -> np.ndarray:
    """The flange by Franka's modified-DH table, written out independently of the URDF."""
    t = np.eye(4)
    for a, d, alpha, theta in zip(
        [*facts.A, 0.0], [*facts.D, facts.D_FLANGE], [*facts.ALPHA, 0.0], [*q, 0.0], strict=True
    ):
        ca, sa, ct, st = math.cos(alpha), math.sin(alpha), math.cos(theta), math.sin(theta)
        t = t @ np.array(
            [
                [ct, -st, 0.0, a],
                [st * ca, ct * ca, -sa, -d * sa],
                [st * sa, ct * sa, ca, d * ca],
                [0.0, 0.0, 0.0, 1.0],
            ]
        )
    return t


def rot_z(angle: float) -> np.ndarray:
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def pin_model() -> pin.Model:
    return pin_model_of(facts)


@pytest.fixture(scope="module")
def clean_model() -> pin.Model:
    """Pinocchio on franky-sim's ``fr3_clean.urdf`` (franka_description), no hand."""
    return pin.buildModelFromUrdf(str(ASSETS / "fr3_clean.urdf"))


@pytest.fixture(scope="module")
def franky() -> Iterator[tuple[Any, Any]]:
    """franky-sim's MuJoCo world with one FR3 at the origin (headless, never stepped), and
    that robot; ~0.7 s to build."""
    from franky_sim.mujoco_simulator import MujocoSimulator

    sim = MujocoSimulator(enable_visualization=False)
    sim.init()
    robot = sim.add_robot()
    sim.start()
    yield sim, robot
    sim.cleanup()


def arm_joints(model: mujoco.MjModel) -> list[Any]:
    return [model.joint(f"robot0_fr3_joint{j + 1}") for j in range(facts.NJOINTS)]


# --------------------------------------------------------------------------------------------
# The type


def test_robot_type_is_complete() -> None:
    robot = robot_type("fr3")
    assert robot is ROBOT and isinstance(robot, RobotType)
    assert "fr3" in known_types()
    n = robot.n_joints
    assert n == facts.NJOINTS == 7
    d = robot.drive
    arrays = [robot.q_min, robot.q_max, robot.qd_max, robot.qdd_max, robot.q_home]
    arrays += [d.gear, d.counts_per_rev, d.kt, d.r_armature, d.max_current, d.rotor_inertia]
    arrays += [d.viscous, d.coulomb_pos, d.coulomb_neg, d.brake_torque]
    for arr in arrays:
        assert arr.shape == (n,) and not arr.flags.writeable
    assert np.all(robot.q_min < robot.q_home) and np.all(robot.q_home < robot.q_max)
    assert np.all(d.coulomb_pos >= 0) and np.all(d.coulomb_neg <= 0)
    assert len(robot.pid_defaults) == len(robot.pd_defaults) == n
    assert robot.urdf.is_file() and (robot.urdf.parent / "NOTICE").is_file()
    assert robot.kinematics.singular(robot.q_home) is None


def test_only_the_fr3_has_absolute_encoders() -> None:
    """Absolute: no calibration sheet; the other types calibrate on index pulses (3.5.1)."""
    for name in ("puma560", "panda", "ur5"):
        t = robot_type(name)
        assert t.absolute_encoders is False and len(t.index_phases) == t.n_joints
    assert ROBOT.absolute_encoders is True
    assert ROBOT.index_phases.shape == (0,)


def test_home_pose_and_planning_limits() -> None:
    np.testing.assert_allclose(
        facts.Q_HOME, [0, -math.pi / 4, 0, -3 * math.pi / 4, 0, math.pi / 2, math.pi / 4]
    )
    assert np.all(facts.QD_MAX == facts.QD_MAKER / 2)
    assert np.all(facts.QDD_MAX <= facts.QDD_MAKER)


def test_drive_is_a_one_to_one_torque_source() -> None:
    """One "ampere" is one N·m at the joint; the current limit is the FR3's torque limit,
    within the DAC's range; the voltage never limits; a count is far below a micro-radian and
    the int32 accumulated count holds the widest mechanical angle with room to spare."""
    d = ROBOT.drive
    assert np.all(d.gear == 1.0) and np.all(d.kt == 1.0)
    np.testing.assert_array_equal(d.peak_joint_torque, facts.TAU_MAKER)
    assert np.all(d.max_current <= d.amp_gain_a_per_v * d.dac_volts)
    np.testing.assert_array_equal(d.armature, facts.JM)
    assert np.all(facts.MAX_JOINT_SPEED > 10 * facts.QD_MAKER)
    assert np.all(d.r_armature * d.max_current + d.kt * facts.QD_MAKER < 0.1 * d.bus_voltage)
    assert np.all(d.rad_per_count < 1e-7)
    mechanical = np.array(
        [
            [float(lim.get("lower")), float(lim.get("upper"))]
            for lim in ET.parse(ASSETS / "fr3_clean.urdf").getroot().iter("limit")
        ]
    )
    assert np.all(np.abs(mechanical).max(axis=1) * facts.COUNTS_PER_JOINT_RAD < 2**31 / 10)
    assert np.all(d.brake_torque > 1.5 * facts.GRAVITY_MAX)


def test_gains_are_frankas_joint_impedance_with_an_integral_for_friction(
    pin_model: pin.Model,
) -> None:
    """GRAVITY_MAX as written is the model's (maximised; a sample comes within 1 % below
    it); the gains are libfranka's examples' stiffness and damping, the PID's integral sized
    for the joint's friction and banded wide enough to reach it."""
    data = pin_model.createData()
    gmax = np.zeros(facts.NJOINTS)
    for q in random_q(np.random.default_rng(0), 20000):
        gmax = np.maximum(gmax, np.abs(pin.computeGeneralizedGravity(pin_model, data, q)))
    assert np.all(gmax <= facts.GRAVITY_MAX + 0.01)
    np.testing.assert_allclose(gmax, facts.GRAVITY_MAX, rtol=0.01, atol=0.01)
    assert [g["kp"] for g in ROBOT.pd_defaults] == [600, 600, 600, 600, 250, 150, 50]
    assert [g["kv"] for g in ROBOT.pd_defaults] == [50, 50, 50, 50, 30, 25, 15]
    for j, g in enumerate(ROBOT.pid_defaults):
        friction = max(facts.COULOMB_POS[j], -facts.COULOMB_NEG[j])
        assert friction < g["integration_reset"] <= friction * 1.2 + 1
        assert g["integration_band"] >= INTEGRATION_BAND_RAD
        assert g["kp"] * g["integration_band"] >= 2.5 * g["integration_reset"] - 1e-9


# --------------------------------------------------------------------------------------------
# The URDF: franka_description's, converted


def test_urdf_is_franka_descriptions_arm(pin_model: pin.Model, clean_model: pin.Model) -> None:
    """Joints j1..j7 with the datasheet's limits; every moving link's inertial (and the
    facts') exactly fr3_clean.urdf's."""
    assert [pin_model.names[j] for j in range(1, pin_model.njoints)] == [
        f"j{j + 1}" for j in range(facts.NJOINTS)
    ]
    np.testing.assert_array_equal(pin_model.lowerPositionLimit, facts.Q_MIN)
    np.testing.assert_array_equal(pin_model.upperPositionLimit, facts.Q_MAX)
    np.testing.assert_array_equal(pin_model.effortLimit, facts.TAU_MAKER)
    for j in range(1, pin_model.njoints):
        ours, theirs = pin_model.inertias[j], clean_model.inertias[j]
        assert ours.mass == theirs.mass == facts.MASS[j - 1]
        np.testing.assert_allclose(ours.lever, theirs.lever, rtol=0, atol=1e-15)
        np.testing.assert_allclose(ours.lever, facts.COM[j - 1], rtol=0, atol=1e-15)
        np.testing.assert_array_equal(ours.inertia, theirs.inertia)
        ixx, iyy, izz, ixy, ixz, iyz = facts.INERTIA[j - 1]
        want = [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]
        np.testing.assert_allclose(ours.inertia, want, rtol=0, atol=1e-15)  # the last bit: parsing


def test_forward_kinematics_is_the_dh_table(pin_model: pin.Model) -> None:
    """fkine == Pinocchio's flange == MuJoCo's flange (on our URDF) == the SIO's chain ==
    Franka's modified-DH table, and fr3_clean.urdf's link8 too."""
    clean = pin.buildModelFromUrdf(str(ASSETS / "fr3_clean.urdf"))
    cdata, cid = clean.createData(), clean.getFrameId("link8")
    pdata, fid = pin_model.createData(), pin_model.getFrameId("flange")
    mj = mj_model_of(facts)
    mdata, adr, body = mujoco.MjData(mj), mj_qpos_of(mj, facts.NJOINTS), mj.body("flange").id
    chain = chain_of(ROBOT)
    for q in [facts.Q_HOME, *random_q(np.random.default_rng(1), N_POSES)]:
        want = dh_flange(q)
        pin.framesForwardKinematics(pin_model, pdata, q)
        pin.framesForwardKinematics(clean, cdata, q)
        mdata.qpos[adr] = q
        mujoco.mj_kinematics(mj, mdata)
        mj_pose = np.eye(4)
        mj_pose[:3, :3], mj_pose[:3, 3] = mdata.xmat[body].reshape(3, 3), mdata.xpos[body]
        for got in (
            ROBOT.kinematics.fkine(q),
            pdata.oMf[fid].homogeneous,
            cdata.oMf[cid].homogeneous,
            mj_pose,
            flange_pose(chain, q),
        ):
            np.testing.assert_allclose(got, want, rtol=0, atol=DH_TOL)


# --------------------------------------------------------------------------------------------
# Against franky-sim's own model


def test_flange_is_franky_sims(franky: tuple[Any, Any]) -> None:
    """The flange is MuJoCo's link 7 moved D_FLANGE along its z; franky-sim's hand sits on it
    turned −45° about z (Menagerie's hand quat; franky-sim's F_T_EE turns the same way)."""
    sim, _ = franky
    model, data = sim.model, sim.data
    adr = [j.qposadr[0] for j in arm_joints(model)]
    link7, hand = model.body("robot0_fr3_link7").id, model.body("robot0_hand").id
    for q in random_q(np.random.default_rng(2), N_POSES):
        data.qpos[adr] = q
        mujoco.mj_kinematics(model, data)
        t = ROBOT.kinematics.fkine(q)
        r7 = data.xmat[link7].reshape(3, 3)
        np.testing.assert_allclose(r7, t[:3, :3], rtol=0, atol=POSE_TOL)
        np.testing.assert_allclose(
            data.xpos[link7] + facts.D_FLANGE * r7[:, 2], t[:3, 3], rtol=0, atol=POSE_TOL
        )
        np.testing.assert_allclose(data.xpos[hand], t[:3, 3], rtol=0, atol=POSE_TOL)
        np.testing.assert_allclose(
            data.xmat[hand].reshape(3, 3), t[:3, :3] @ rot_z(-math.pi / 4), rtol=0, atol=POSE_TOL
        )


def test_gravity_is_franky_sims(
    franky: tuple[Any, Any], pin_model: pin.Model, clean_model: pin.Model
) -> None:
    """Our gravity (rnea at rest) is Pinocchio's on fr3_clean.urdf exactly; with franky-sim's
    hand added at the flange, exactly what franky-sim adds to a zero torque command; and
    MuJoCo's (Menagerie's fr3.xml, hand bodies made massless) to MENAGERIE_TOL."""
    from franky_sim.base_simulator import RobotParameters

    sim, robot = franky
    model, data = sim.model, sim.data
    dofs = [j.dofadr[0] for j in arm_joints(model)]
    adr = [j.qposadr[0] for j in arm_joints(model)]
    armless = copy.copy(model)  # a deep copy: franky-sim's own model keeps its hand
    for name in HAND_BODIES:
        armless.body_mass[armless.body(f"robot0_{name}").id] = 0.0
        armless.body_inertia[armless.body(f"robot0_{name}").id] = 0.0
    adata = mujoco.MjData(armless)

    hand = RobotParameters()  # franky-sim's defaults, the hand its gravity carries
    with_hand = pin_model_of(facts)
    flange = with_hand.frames[with_hand.getFrameId("flange")]
    with_hand.inertias[flange.parentJoint] += flange.placement.act(
        pin.Inertia(
            hand.ee_mass, np.array(hand.ee_com), np.array(hand.ee_inertia).reshape(3, 3, order="F")
        )
    )
    np.testing.assert_array_equal(clean_model.gravity.linear, [0.0, 0.0, -facts.GRAVITY])
    pdata, cdata, hdata = pin_model.createData(), clean_model.createData(), with_hand.createData()
    zero = np.zeros(facts.NJOINTS)
    worst = np.zeros(facts.NJOINTS)
    for q in random_q(np.random.default_rng(3), N_POSES):
        ours = pin.rnea(pin_model, pdata, q, zero, zero).copy()
        clean = pin.computeGeneralizedGravity(clean_model, cdata, q)
        np.testing.assert_allclose(ours, clean, rtol=0, atol=EXACT_TOL)
        data.qpos[adr] = q
        robot.torque_control([0.0] * facts.NJOINTS)  # what franky-sim applies: its gravity
        franky_g = np.array(robot.inner_state.tau_j)
        ours_with_hand = pin.computeGeneralizedGravity(with_hand, hdata, q)
        np.testing.assert_allclose(ours_with_hand, franky_g, rtol=0, atol=EXACT_TOL)
        adata.qpos[:] = data.qpos
        adata.qvel[:] = 0.0
        mujoco.mj_forward(armless, adata)
        worst = np.maximum(worst, np.abs(adata.qfrc_bias[dofs] - ours))
    assert np.all(worst < MENAGERIE_TOL), worst


def test_limits_and_joint_friction_are_menageries(franky: tuple[Any, Any]) -> None:
    """Our ranges are MuJoCo's hard stops (so within them); friction, damping and armature
    are the MuJoCo joints'."""
    model = franky[0].model
    joints = arm_joints(model)
    ranges = np.array([j.range for j in joints])
    assert np.all(ranges[:, 0] <= facts.Q_MIN) and np.all(ranges[:, 1] >= facts.Q_MAX)
    np.testing.assert_allclose(ranges, np.c_[facts.Q_MIN, facts.Q_MAX], rtol=0, atol=1e-12)
    dofs = [j.dofadr[0] for j in joints]
    d = ROBOT.drive
    np.testing.assert_allclose(model.dof_frictionloss[dofs], d.coulomb_pos, rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.dof_frictionloss[dofs], -d.coulomb_neg, rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.dof_damping[dofs], d.viscous, rtol=0, atol=1e-12)
    np.testing.assert_allclose(model.dof_armature[dofs], d.armature, rtol=0, atol=1e-12)


# --------------------------------------------------------------------------------------------
# Inverse kinematics (the Panda's, tests/robots/test_panda.py: here only that it works)


def test_ikine_round_trips_with_joint_3_held() -> None:
    rng = np.random.default_rng(4)
    k = ROBOT.kinematics
    out = np.empty(facts.NJOINTS)
    for q in random_q(rng, 50):
        t6 = k.fkine(q)
        q_ref = np.clip(q + rng.normal(0.0, 0.01, 7), facts.Q_MIN, facts.Q_MAX)
        got = k.ikine(t6, kin.NEAREST, q_ref=q_ref, out=out, redundancy=float(q[2]))
        assert got is out and got[2] == q[2]
        np.testing.assert_allclose(k.fkine(got), t6, rtol=0, atol=1e-9)
        assert np.all(got >= facts.Q_MIN) and np.all(got <= facts.Q_MAX)
    with pytest.raises(KinematicsError, match="the FR3 has one, 'nearest'"):
        k.parse_config("ruf")


def test_cycle_functions_allocate_no_numpy_data() -> None:
    k = ROBOT.kinematics
    q = facts.Q_HOME.copy()
    q_ref = q + 0.01
    t6, out = np.empty((4, 4)), np.empty(7)
    k.fkine(q, t6)
    assert numpy_data_allocations(lambda: k.fkine(q, t6)) == 0
    assert numpy_data_allocations(lambda: k.ikine(t6, kin.NEAREST, q_ref, out)) == 0
    assert numpy_data_allocations(lambda: k.singular(q)) == 0
