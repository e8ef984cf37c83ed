"""The Panda robot type against robotics-toolbox-python's Panda, Pinocchio and MuJoCo."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from kali_daemons.core.errors import KinematicsError
from kali_daemons.robots import robot_type
from kali_daemons.robots.numik import DlsIk, _log3
from kali_daemons.robots.panda import ROBOT, facts
from kali_daemons.robots.panda import kinematics as kin
from kali_daemons.robots.profile import INTEGRATION_BAND_RAD, MAX_JOINTS, RobotType

from . import mj_model_of, mj_qpos_of, numpy_data_allocations, pin_model_of

ROOT = Path(__file__).resolve().parents[2]
N_POSES = 200
N_IK = 500
POSE_TOL = 1e-6  # m, and rotation matrix entries
TORQUE_TOL = 1e-6  # N·m
IK_TOL = 1e-9  # m and rad


def random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(facts.Q_MIN, facts.Q_MAX, size=(n, facts.NJOINTS))


@pytest.fixture(scope="module")
def rtb_raw() -> Any:
    rtb = pytest.importorskip("roboticstoolbox", reason="the oracle; pip install '.[test]'")
    return rtb.models.DH.Panda()


@pytest.fixture(scope="module")
def rtb_panda() -> Any:
    """The toolbox's Panda at the flange (no tool, no hand), with our rotors, no friction."""
    rtb = pytest.importorskip("roboticstoolbox", reason="the oracle; pip install '.[test]'")
    from spatialmath import SE3

    robot = rtb.models.DH.Panda()
    robot.tool = SE3()
    for j, link in enumerate(robot.links):
        link.Jm = float(facts.JM[j])
        link.G = float(facts.G[j])
        link.B = 0.0
        link.Tc = [0.0, 0.0]
    robot.gravity = [0.0, 0.0, -facts.GRAVITY]
    return robot


@pytest.fixture(scope="module")
def pin_model() -> pin.Model:
    return pin_model_of(facts)


@pytest.fixture(scope="module")
def mj_model() -> mujoco.MjModel:
    return mj_model_of(facts)


def mj_qpos(model: mujoco.MjModel) -> np.ndarray:
    return mj_qpos_of(model, facts.NJOINTS)


# --------------------------------------------------------------------------------------------
# Facts


def test_facts_match_the_toolbox(rtb_raw: Any) -> None:
    """Franka's table and limits as the toolbox has them; Gaz et al.'s dynamics as the toolbox
    has them, but link 7's centre of mass in the flange frame and link 1's z dropped."""
    links = rtb_raw.links
    np.testing.assert_array_equal([lk.a for lk in links], facts.A)
    np.testing.assert_array_equal([lk.alpha for lk in links], facts.ALPHA)
    np.testing.assert_array_equal([lk.d for lk in links][:6], facts.D[:6])
    assert links[6].d == facts.D[6] + facts.D_FLANGE
    np.testing.assert_array_equal(np.array(rtb_raw.qlim).T, np.c_[facts.Q_MIN, facts.Q_MAX])
    np.testing.assert_array_equal([lk.m for lk in links], facts.MASS)
    com = np.array([lk.r for lk in links])
    np.testing.assert_allclose(com[1:6], facts.COM[1:6], rtol=0, atol=1e-15)
    np.testing.assert_allclose(com[0], facts.COM[0] * [1, 1, 0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(com[6], facts.COM[6] - [0, 0, facts.D_FLANGE], atol=1e-15)
    for link, (ixx, iyy, izz, ixy, ixz, iyz) in zip(links, facts.INERTIA, strict=True):
        want = [[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]]
        np.testing.assert_allclose(link.I, want, rtol=0, atol=1e-15)


def test_inertias_are_physical() -> None:
    for ixx, iyy, izz, ixy, ixz, iyz in facts.INERTIA:
        eig = np.linalg.eigvalsh([[ixx, ixy, ixz], [ixy, iyy, iyz], [ixz, iyz, izz]])
        assert eig[0] > 0 and eig[0] + eig[1] >= eig[2]


def test_friction_is_gaz_at_speed() -> None:
    """The Coulomb levels are Gaz et al.'s friction model far from rest."""

    def tau_f(qd: float) -> np.ndarray:
        p1, p2, p3 = facts.FRICTION_PHI1, facts.FRICTION_PHI2, facts.FRICTION_PHI3
        return p1 / (1 + np.exp(-p2 * (qd + p3))) - p1 / (1 + np.exp(-p2 * p3))

    np.testing.assert_allclose(tau_f(10.0), facts.COULOMB_POS, rtol=0, atol=1e-6)
    np.testing.assert_allclose(tau_f(-10.0), facts.COULOMB_NEG, rtol=0, atol=1e-6)


def test_drive_matches_the_arm() -> None:
    np.testing.assert_allclose(ROBOT.drive.peak_joint_torque, facts.TAU_MAKER, rtol=0.02)
    assert np.all(facts.MAX_JOINT_SPEED > facts.QD_MAKER)
    assert np.all(facts.QD_MAX < facts.QD_MAKER)
    assert np.all(facts.MAX_CURRENT <= facts.AMP_GAIN_A_PER_V * facts.DAC_VOLTS)
    assert np.all(facts.BRAKE_TORQUE > 1.5 * facts.GRAVITY_MAX)
    assert np.all(1.0 / facts.COUNTS_PER_JOINT_RAD < 1e-4)


def test_robot_type_is_complete() -> None:
    robot = robot_type("panda")
    assert robot is ROBOT and isinstance(robot, RobotType)
    n = robot.n_joints
    assert 1 <= n <= MAX_JOINTS and n == 7
    d = robot.drive
    arrays = [robot.q_min, robot.q_max, robot.qd_max, robot.qdd_max, robot.q_home]
    arrays += [d.gear, d.counts_per_rev, d.kt, d.r_armature, d.max_current, d.rotor_inertia]
    arrays += [d.viscous, d.coulomb_pos, d.coulomb_neg, d.brake_torque, robot.index_phases]
    for arr in arrays:
        assert arr.shape == (n,) and not arr.flags.writeable
    assert np.all(robot.q_min < robot.q_home) and np.all(robot.q_home < robot.q_max)
    assert np.all((robot.index_phases >= 0) & (robot.index_phases < 2 * math.pi))
    assert np.all(d.coulomb_pos >= 0) and np.all(d.coulomb_neg <= 0)
    assert len(robot.pid_defaults) == len(robot.pd_defaults) == n
    assert robot.urdf.is_file()
    assert robot.kinematics.singular(robot.q_home) is None


def test_gains_follow_the_rule_on_the_model(pin_model: pin.Model) -> None:
    from kali_daemons.robots import puma560

    data = pin_model.createData()
    np.testing.assert_allclose(
        np.diag(pin.crba(pin_model, data, facts.Q_HOME)), facts.J_HOME, rtol=0.001
    )
    rng = np.random.default_rng(0)
    gmax = np.zeros(facts.NJOINTS)
    for q in random_q(rng, 20000):
        gmax = np.maximum(gmax, np.abs(pin.computeGeneralizedGravity(pin_model, data, q)))
    np.testing.assert_allclose(gmax, facts.GRAVITY_MAX, rtol=0.01, atol=0.01)
    assert {frozenset(g) for g in ROBOT.pid_defaults} == {frozenset(puma560.PID_DEFAULTS[0])}
    assert {frozenset(g) for g in ROBOT.pd_defaults} == {frozenset(puma560.PD_DEFAULTS[0])}
    for j, g in enumerate(ROBOT.pid_defaults):
        # ωn raised where the load needs it, so the band stays the PUMA's
        wn = max(facts.WN[j], math.sqrt(2.5 * g["integration_reset"] / (0.01 * facts.J_HOME[j])))
        assert g["kp"] == pytest.approx(facts.J_HOME[j] * wn**2)
        assert g["kp"] * 0.01 >= 2.5 * g["integration_reset"] - 1e-9
        assert g["integration_band"] == INTEGRATION_BAND_RAD == 0.01
        assert g["integration_reset"] >= facts.GRAVITY_MAX[j] + facts.COULOMB_POS[j]


# --------------------------------------------------------------------------------------------
# The URDF and forward kinematics


def test_committed_urdf_is_what_the_script_generates() -> None:
    script = ROOT / "scripts" / "gen_robot_urdf.py"
    done = subprocess.run(
        [sys.executable, str(script), "panda", "--check"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr


def test_urdf_names_and_limits(pin_model: pin.Model) -> None:
    assert pin_model.nq == facts.NJOINTS
    assert [pin_model.names[j] for j in range(1, pin_model.njoints)] == [
        f"j{j + 1}" for j in range(facts.NJOINTS)
    ]
    np.testing.assert_array_equal(pin_model.lowerPositionLimit, facts.Q_MIN)
    np.testing.assert_array_equal(pin_model.upperPositionLimit, facts.Q_MAX)
    np.testing.assert_allclose(pin_model.effortLimit, facts.PEAK_JOINT_TORQUE, atol=1e-3)


def test_forward_kinematics_agree(
    rtb_panda: Any, pin_model: pin.Model, mj_model: mujoco.MjModel
) -> None:
    """The toolbox's fkine without tool == Pinocchio's flange == MuJoCo's flange == fkine."""
    pdata = pin_model.createData()
    fid = pin_model.getFrameId("flange")
    mdata = mujoco.MjData(mj_model)
    adr = mj_qpos(mj_model)
    body = mj_model.body("flange").id
    k = ROBOT.kinematics
    for q in [facts.Q_HOME, *random_q(np.random.default_rng(1), N_POSES)]:
        t_rtb = rtb_panda.fkine(q).A
        pin.framesForwardKinematics(pin_model, pdata, q)
        mdata.qpos[adr] = q
        mujoco.mj_kinematics(mj_model, mdata)
        own = k.fkine(q)
        for pos, rot in (
            (pdata.oMf[fid].translation, pdata.oMf[fid].rotation),
            (mdata.xpos[body], mdata.xmat[body].reshape(3, 3)),
            (own[:3, 3], own[:3, :3]),
        ):
            np.testing.assert_allclose(pos, t_rtb[:3, 3], rtol=0, atol=POSE_TOL)
            np.testing.assert_allclose(rot, t_rtb[:3, :3], rtol=0, atol=POSE_TOL)


# --------------------------------------------------------------------------------------------
# Inverse kinematics


def pose_error(t_a: np.ndarray, t_b: np.ndarray) -> tuple[float, float]:
    """Position (m) and rotation (rad) between two poses."""
    r = t_a[:3, :3] @ t_b[:3, :3].T
    return float(np.linalg.norm(t_a[:3, 3] - t_b[:3, 3])), float(np.linalg.norm(_log3(*r.flat)))


def test_ikine_converges_from_near_and_keeps_joint_3() -> None:
    """From q_ref = q + a small perturbation, ikine finds T to 1e-9 with joint 3 held where
    asked, explicitly or by q_ref; a few iterations each."""
    rng = np.random.default_rng(2)
    k = ROBOT.kinematics
    out = np.empty(7)
    iterations = []
    for q in random_q(rng, N_IK):
        t6 = k.fkine(q)
        q_ref = np.clip(q + rng.normal(0.0, 0.01, 7), facts.Q_MIN, facts.Q_MAX)
        got = k.ikine(t6, kin.NEAREST, q_ref=q_ref, out=out, redundancy=float(q[2]))
        assert got is out and got[2] == q[2]
        assert max(pose_error(k.fkine(got), t6)) < IK_TOL
        assert np.all(got >= facts.Q_MIN) and np.all(got <= facts.Q_MAX)
        iterations.append(k.solver.iterations)
        q_ref[2] = q[2]  # redundancy None: joint 3 stays at q_ref's
        got = k.ikine(t6, kin.NEAREST, q_ref=q_ref)
        assert got[2] == q_ref[2] and max(pose_error(k.fkine(got), t6)) < IK_TOL
    assert np.percentile(iterations, 95) <= 5, np.bincount(iterations)


def test_ikine_follows_a_cartesian_path_in_two_or_three_iterations() -> None:
    """A 10 cm line at 0.25 m/s sampled every 10 ms, each sample from the last set-point."""
    k = ROBOT.kinematics
    q = facts.Q_HOME.copy()
    t6 = k.fkine(q)
    start = t6[:3, 3].copy()
    elbow = q[2]
    for s in np.linspace(0.0, 0.1, 41)[1:]:
        t6[:3, 3] = start + np.array([s, 0.0, -0.5 * s])
        k.ikine(t6, kin.NEAREST, q_ref=q, out=q)
        assert k.solver.iterations <= 3
        assert q[2] == elbow
        assert max(pose_error(k.fkine(q), t6)) < IK_TOL


def test_ikine_refusals() -> None:
    k = ROBOT.kinematics
    far = k.fkine(facts.Q_HOME)
    far[:3, 3] = [1.5, 0.0, 0.5]
    with pytest.raises(KinematicsError, match=r"out of reach: the flange at .* beyond the"):
        k.ikine(far, kin.NEAREST)
    edge = k.fkine(facts.Q_HOME)
    edge[:3, 3] = [0.95, 0.0, 0.333]  # inside the bound, outside the arm's true reach
    with pytest.raises(KinematicsError, match=r"no solution with joint 3 held .* left"):
        k.ikine(edge, kin.NEAREST, q_ref=facts.Q_HOME)
    with pytest.raises(KinematicsError, match="outside its limits"):
        k.ikine(k.fkine(facts.Q_HOME), kin.NEAREST, redundancy=3.0)
    with pytest.raises(KinematicsError, match="not a Panda configuration"):
        k.ikine(k.fkine(facts.Q_HOME), "run")
    with pytest.raises(KinematicsError, match="not finite"):
        k.ikine(np.full((4, 4), np.nan), kin.NEAREST)


def test_configs() -> None:
    k = ROBOT.kinematics
    assert k.configs == (kin.NEAREST,)
    assert k.config_of(facts.Q_HOME) is kin.NEAREST
    assert k.parse_config("Nearest") is kin.NEAREST
    with pytest.raises(KinematicsError, match="the Panda has one, 'nearest'"):
        k.parse_config("ruf")


def test_singular(rtb_panda: Any) -> None:
    """Refused where the toolbox's Jacobian (or the one without joint 3) has a singular value
    below SIGMA_MIN, accepted where not."""
    k = ROBOT.kinematics
    rng = np.random.default_rng(3)
    kinds: dict[str, int] = {"6×7": 0, "6×6": 0}
    for q in random_q(rng, 300):
        jac = rtb_panda.jacob0(q)
        full = np.linalg.svd(jac, compute_uv=False)[-1]
        held = np.linalg.svd(np.delete(jac, kin.HELD_JOINT, axis=1), compute_uv=False)[-1]
        if abs(full - kin.SIGMA_MIN) < 1e-6 or abs(held - kin.SIGMA_MIN) < 1e-6:
            continue
        why = k.singular(q)
        assert (why is not None) == (min(full, held) < kin.SIGMA_MIN), (q, full, held, why)
        if why is not None and full < kin.SIGMA_MIN:
            assert why.startswith(f"{full:.4f} from a singularity: the 6×7")
            kinds["6×7"] += 1
        elif why is not None:
            assert why.startswith(f"{held:.4f} from a singularity with joint 3 held")
            kinds["6×6"] += 1
    assert min(kinds.values()) > 10 and sum(kinds.values()) < 150, kinds


def test_log3_is_the_inverse_of_exp() -> None:
    rng = np.random.default_rng(4)
    for angle in [0.0, 1e-9, 1e-4, 0.5, 2.0, math.pi - 1e-4, math.pi - 1e-9]:
        axis = rng.normal(size=3)
        axis /= np.linalg.norm(axis)
        r = pin.exp3(angle * axis)
        np.testing.assert_allclose(_log3(*r.flat), angle * axis, rtol=0, atol=1e-8)


def test_dlsik_refuses_what_it_cannot_solve(pin_model: pin.Model) -> None:
    with pytest.raises(KinematicsError, match="no frame 'hand'"):
        DlsIk(pin_model, "hand", facts.Q_MIN, facts.Q_MAX, name="panda")
    with pytest.raises(KinematicsError, match="held joint index 7"):
        DlsIk(pin_model, "flange", facts.Q_MIN, facts.Q_MAX, name="panda", held=7)


# --------------------------------------------------------------------------------------------
# Dynamics


def test_inverse_dynamics_agree(
    rtb_panda: Any, pin_model: pin.Model, mj_model: mujoco.MjModel
) -> None:
    """rne (toolbox: Gaz et al.'s values, our rotors) == rnea (Pinocchio) == mj_inverse."""
    pdata = pin_model.createData()
    mdata = mujoco.MjData(mj_model)
    adr = mj_qpos(mj_model)
    rng = np.random.default_rng(5)
    for q in random_q(rng, N_POSES):
        qd, qdd = rng.uniform(-2, 2, 7), rng.uniform(-5, 5, 7)
        tau_pin = pin.rnea(pin_model, pdata, q, qd, qdd)
        mdata.qpos[adr], mdata.qvel[:], mdata.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(mj_model, mdata)
        tau_rtb = np.asarray(rtb_panda.rne(q, qd, qdd), dtype=float)
        np.testing.assert_allclose(tau_pin, mdata.qfrc_inverse, rtol=0, atol=TORQUE_TOL)
        np.testing.assert_allclose(tau_pin, tau_rtb, rtol=0, atol=TORQUE_TOL)


# --------------------------------------------------------------------------------------------
# In the cycle


def test_cycle_functions_allocate_no_numpy_data() -> None:
    k = ROBOT.kinematics
    q = facts.Q_HOME.copy()
    q_ref = q + 0.01
    t6, out = np.empty((4, 4)), np.empty(7)
    k.fkine(q, t6)
    assert numpy_data_allocations(lambda: k.fkine(q, t6)) == 0
    assert numpy_data_allocations(lambda: k.ikine(t6, kin.NEAREST, q_ref, out)) == 0
    assert numpy_data_allocations(lambda: k.config_of(q)) == 0
    assert numpy_data_allocations(lambda: k.singular(q)) == 0
