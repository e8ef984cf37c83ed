"""The UR5 robot type against robotics-toolbox-python's UR5, Pinocchio and MuJoCo."""

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
from kali_daemons.robots.profile import INTEGRATION_BAND_RAD, MAX_JOINTS, RobotType
from kali_daemons.robots.ur5 import ROBOT, facts
from kali_daemons.robots.ur5 import kinematics as kin

from . import mj_model_of, mj_qpos_of, numpy_data_allocations, pin_model_of

ROOT = Path(__file__).resolve().parents[2]
N_POSES = 200
N_PER_BRANCH = 500
POSE_TOL = 1e-6  # m, and rotation matrix entries
TORQUE_TOL = 1e-6  # N·m


def random_q(rng: np.random.Generator, n: int) -> np.ndarray:
    return rng.uniform(facts.Q_MIN, facts.Q_MAX, size=(n, facts.NJOINTS))


@pytest.fixture(scope="module")
def rtb_raw() -> Any:
    """The toolbox's UR5 as it ships."""
    rtb = pytest.importorskip("roboticstoolbox", reason="the oracle; pip install '.[test]'")
    return rtb.models.DH.UR5()


@pytest.fixture(scope="module")
def rtb_ur5(rtb_raw: Any) -> Any:
    """The toolbox's UR5 with UR's values where it slipped (see facts), our cylinder
    inertias (it has none) and our rotors, so its rne is the same model as ours."""
    robot = rtb_raw.copy() if hasattr(rtb_raw, "copy") else rtb_raw
    for j, link in enumerate(robot.links):
        link.d = float(facts.D[j])
        link.m = float(facts.MASS[j])
        link.r = facts.COM[j]
        link.I = facts.INERTIA[j]
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


def test_facts_match_the_toolbox_but_for_its_three_slips(rtb_raw: Any) -> None:
    """UR's table; the toolbox differs in d1, link 6's mass and link 5's COM y only."""
    links = rtb_raw.links
    np.testing.assert_array_equal([lk.a for lk in links], facts.A)
    np.testing.assert_array_equal([lk.alpha for lk in links], facts.ALPHA)
    np.testing.assert_array_equal([lk.d for lk in links][1:], facts.D[1:])
    assert (links[0].d, facts.D[0]) == (0.089459, 0.089159)
    np.testing.assert_array_equal([lk.m for lk in links][:5], facts.MASS[:5])
    assert (links[5].m, facts.MASS[5]) == (0.1897, 0.1879)
    for j in (0, 1, 2, 3, 5):
        np.testing.assert_array_equal(links[j].r, facts.COM[j])
    np.testing.assert_array_equal(links[4].r * [1, -1, 1], facts.COM[4])
    assert not np.any([lk.I for lk in links]), "the toolbox has inertias now: compare them"


def test_inertias_are_the_stated_cylinders() -> None:
    m, (axis, r, length) = facts.MASS[1], facts.CYLINDERS[1]
    assert axis == "x"
    for inertia in facts.INERTIA:  # physical: the triangle inequality
        ixx, iyy, izz = inertia
        assert ixx + iyy >= izz and iyy + izz >= ixx and izz + ixx >= iyy
    ixx, iyy, izz = facts.INERTIA[1]
    assert ixx == pytest.approx(m * r**2 / 2)
    assert iyy == izz == pytest.approx(m * (3 * r**2 + length**2) / 12)


def test_drive_matches_the_arm() -> None:
    """Peak joint torque within 2 % of UR's 150/28 N·m; speed above the plan and the data
    sheet's 180°/s at the bus; the amplifier's range covers the peak current."""
    np.testing.assert_allclose(ROBOT.drive.peak_joint_torque, [150.0] * 3 + [28.0] * 3, rtol=0.02)
    assert np.all(facts.MAX_JOINT_SPEED > facts.QD_MAX)
    assert np.all(math.radians(180.0) < facts.MAX_JOINT_SPEED)
    assert np.all(facts.MAX_CURRENT <= facts.AMP_GAIN_A_PER_V * facts.DAC_VOLTS)
    np.testing.assert_array_equal(ROBOT.drive.armature, facts.ARMATURE)
    assert np.all(facts.BRAKE_TORQUE > 2 * facts.GRAVITY_MAX)
    # ±1 count is a fine hold: one count under 0.1 mrad at the joint
    assert np.all(1.0 / facts.COUNTS_PER_JOINT_RAD < 1e-4)


def test_robot_type_is_complete() -> None:
    robot = robot_type("ur5")
    assert robot is ROBOT and isinstance(robot, RobotType)
    n = robot.n_joints
    assert 1 <= n <= MAX_JOINTS and n == 6
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
    """J at home (crba with armature) and the gravity maxima are what the model gives; the
    gains are the PUMA's rule on them, with the PUMA's keys."""
    from kali_daemons.robots import puma560

    data = pin_model.createData()
    np.testing.assert_allclose(
        np.diag(pin.crba(pin_model, data, facts.Q_HOME)), facts.J_HOME, rtol=0.005
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
        assert g["ki"] == pytest.approx(20 * g["kp"])
        assert g["integration_reset"] >= facts.GRAVITY_MAX[j] + facts.COULOMB_POS[j]


# --------------------------------------------------------------------------------------------
# The URDF


def test_committed_urdf_is_what_the_script_generates(tmp_path: Path) -> None:
    script = ROOT / "scripts" / "gen_robot_urdf.py"
    done = subprocess.run(
        [sys.executable, str(script), "ur5", "--check"], capture_output=True, text=True
    )
    assert done.returncode == 0, done.stderr
    (tmp_path / "ur5.urdf").write_text("stale\n")
    done = subprocess.run(
        [sys.executable, str(script), "ur5", "--check", "--output-dir", str(tmp_path)],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 1 and "stale" in done.stderr


def test_urdf_names_and_limits(pin_model: pin.Model) -> None:
    assert pin_model.nq == facts.NJOINTS
    assert [pin_model.names[j] for j in range(1, pin_model.njoints)] == [
        f"j{j + 1}" for j in range(facts.NJOINTS)
    ]
    assert pin_model.existFrame("flange")
    np.testing.assert_array_equal(pin_model.lowerPositionLimit, facts.Q_MIN)
    np.testing.assert_array_equal(pin_model.upperPositionLimit, facts.Q_MAX)
    np.testing.assert_allclose(pin_model.effortLimit, facts.PEAK_JOINT_TORQUE, atol=1e-3)
    np.testing.assert_allclose(pin_model.velocityLimit, facts.MAX_JOINT_SPEED, atol=1e-3)


def test_forward_kinematics_agree(
    rtb_ur5: Any, pin_model: pin.Model, mj_model: mujoco.MjModel
) -> None:
    """The toolbox's fkine == Pinocchio's flange frame == MuJoCo's flange body == fkine."""
    pdata = pin_model.createData()
    fid = pin_model.getFrameId("flange")
    mdata = mujoco.MjData(mj_model)
    adr = mj_qpos(mj_model)
    body = mj_model.body("flange").id
    poses = [facts.QZ, facts.Q_HOME, *random_q(np.random.default_rng(1), N_POSES)]
    for q in poses:
        t_rtb = rtb_ur5.fkine(q).A
        pin.framesForwardKinematics(pin_model, pdata, q)
        mdata.qpos[adr] = q
        mujoco.mj_kinematics(mj_model, mdata)
        own = kin.fkine(q)
        for pos, rot in (
            (pdata.oMf[fid].translation, pdata.oMf[fid].rotation),
            (mdata.xpos[body], mdata.xmat[body].reshape(3, 3)),
            (own[:3, 3], own[:3, :3]),
        ):
            np.testing.assert_allclose(pos, t_rtb[:3, 3], rtol=0, atol=POSE_TOL)
            np.testing.assert_allclose(rot, t_rtb[:3, :3], rtol=0, atol=POSE_TOL)
        np.testing.assert_array_equal(own[3], [0, 0, 0, 1])


# --------------------------------------------------------------------------------------------
# Inverse kinematics


def _samples_per_branch(rng: np.random.Generator) -> dict[kin.Branch, list[np.ndarray]]:
    """N_PER_BRANCH random in-limit q in each branch, none within 1e-3 of a singularity
    (where the branch flags are ties)."""
    found: dict[kin.Branch, list[np.ndarray]] = {b: [] for b in kin.BRANCHES}
    while min(map(len, found.values())) < N_PER_BRANCH:
        for q in random_q(rng, 2000):
            s = kin._reach(q[1], q[2], q[1] + q[2] + q[3])
            if min(abs(s), abs(math.sin(q[2])), abs(math.sin(q[4]))) < 1e-3:
                continue
            bucket = found[kin.branch_of(q)]
            if len(bucket) < N_PER_BRANCH:
                bucket.append(q)
    return found


def test_ikine_round_trip_in_every_branch() -> None:
    """ikine(fkine(q), branch_of(q), q_ref near q) gives q back; every other branch gives
    the same pose where it is reachable within the limits, in that branch."""
    rng = np.random.default_rng(2)
    out = np.empty(6)
    worst = 0.0
    others = 0
    for branch, qs in _samples_per_branch(rng).items():
        for q in qs:
            t6 = kin.fkine(q)
            got = kin.ikine(t6, branch, q_ref=q + rng.normal(0.0, 0.1, 6), out=out)
            assert got is out
            worst = max(worst, float(np.max(np.abs(got - q))))
            for other in kin.BRANCHES:
                if other == branch:
                    continue
                try:
                    q2 = kin.ikine(t6, other, q_ref=q)
                except KinematicsError as exc:
                    assert "out of joint limits" in str(exc) or "out of reach" in str(exc)
                    continue
                others += 1
                np.testing.assert_allclose(kin.fkine(q2), t6, rtol=0, atol=1e-9)
                assert kin.branch_of(q2) == other
    assert worst < 1e-9, worst
    assert others > 7 * 8 * N_PER_BRANCH // 2  # most poses are reachable in most branches


def test_ikine_keeps_each_joint_near_q_ref() -> None:
    """With ±2π limits a joint has two equivalents: the one nearer q_ref is taken."""
    q = np.radians([-10.0, -80.0, 70.0, -100.0, -60.0, 30.0])
    t6 = kin.fkine(q)
    turned = q + 2 * math.pi * np.array([1.0, 0.0, 0.0, 1.0, 0.0, -1.0])
    got = kin.ikine(t6, kin.branch_of(q), q_ref=turned)
    np.testing.assert_allclose(got, turned, atol=1e-9)


def test_home_branch_and_parse() -> None:
    assert str(kin.branch_of(facts.Q_HOME)) == "lun"
    k = ROBOT.kinematics
    assert k.parse_config("LUN") == kin.branch_of(facts.Q_HOME)
    assert {str(b) for b in k.configs} == {a + b + c for a in "rl" for b in "ud" for c in "fn"}
    with pytest.raises(KinematicsError, match=r"three letters .* shoulder \(l/r\)"):
        k.parse_config("up")


def test_ikine_refusals() -> None:
    k = ROBOT.kinematics
    far = kin.fkine(facts.Q_HOME)
    far[:3, 3] = [2.0, 0.0, 0.5]
    with pytest.raises(KinematicsError, match=r"out of reach: joint 4's axis is .* m from"):
        k.ikine(far, kin.BRANCHES[0])
    near_axis = kin.fkine(facts.Q_HOME)
    near_axis[:3, 3] = [0.0, 0.0, 0.5]
    near_axis[:3, :3] = np.diag([1.0, -1.0, -1.0])
    with pytest.raises(KinematicsError, match=r"closer than the shoulder offset d4"):
        k.ikine(near_axis, kin.BRANCHES[0])
    bent = kin.fkine(facts.Q_HOME)
    bent[0, 0] = 2.0
    with pytest.raises(KinematicsError, match="not orthonormal"):
        k.ikine(bent, kin.BRANCHES[0])
    with pytest.raises(KinematicsError, match="not redundant"):
        k.ikine(kin.fkine(facts.Q_HOME), kin.BRANCHES[0], redundancy=0.3)


def test_determinant_and_singular(rtb_ur5: Any) -> None:
    """det J = a2·a3·sin θ3·sin θ5·s (the toolbox's Jacobian), and the three refusals."""
    rng = np.random.default_rng(3)
    for q in random_q(rng, 50):
        s = kin._reach(q[1], q[2], q[1] + q[2] + q[3])
        expect = facts.A[1] * facts.A[2] * math.sin(q[2]) * math.sin(q[4]) * s
        assert np.linalg.det(rtb_ur5.jacob0(q)) == pytest.approx(expect, abs=1e-12)
    k = ROBOT.kinematics
    assert "elbow singularity" in (k.singular(facts.QZ) or "")
    wrist = facts.Q_HOME.copy()
    wrist[4] = math.radians(3.0)
    assert "wrist singularity" in (k.singular(wrist) or "")
    # Home with joint 2 turned: s = −a2·c2 + (d5 − a3)·s2, 0 where tan θ2 = −a2 / (d5 − a3)
    shoulder = facts.Q_HOME.copy()
    shoulder[1] = math.atan2(-facts.A[1], facts.D[4] - facts.A[2]) + 0.02
    s = kin._reach(shoulder[1], shoulder[2], shoulder[1] + shoulder[2] + shoulder[3])
    assert 0.005 < abs(s) < 0.05
    assert "shoulder singularity" in (k.singular(shoulder) or "")


# --------------------------------------------------------------------------------------------
# Dynamics


def test_inverse_dynamics_agree(
    rtb_ur5: Any, pin_model: pin.Model, mj_model: mujoco.MjModel
) -> None:
    """rne (toolbox, with our inertias and rotors) == rnea (Pinocchio) == mj_inverse (MuJoCo)."""
    pdata = pin_model.createData()
    mdata = mujoco.MjData(mj_model)
    adr = mj_qpos(mj_model)
    rng = np.random.default_rng(4)
    for q in random_q(rng, N_POSES):
        qd, qdd = rng.uniform(-2, 2, 6), rng.uniform(-5, 5, 6)
        tau_pin = pin.rnea(pin_model, pdata, q, qd, qdd)
        mdata.qpos[adr], mdata.qvel[:], mdata.qacc[:] = q, qd, qdd
        mujoco.mj_inverse(mj_model, mdata)
        tau_rtb = np.asarray(rtb_ur5.rne(q, qd, qdd), dtype=float)
        np.testing.assert_allclose(tau_pin, mdata.qfrc_inverse, rtol=0, atol=TORQUE_TOL)
        np.testing.assert_allclose(tau_pin, tau_rtb, rtol=0, atol=TORQUE_TOL)


def test_gravity_matches_the_toolbox_as_shipped(rtb_raw: Any, pin_model: pin.Model) -> None:
    """Gravity load with the toolbox's own masses and centres of mass (no inertias needed),
    within what its slips move it: link 6's 1.8 g at up to 0.95 m and link 5's 1.219 kg
    shifted 3.6 mm, 0.06 N·m at most."""
    data = pin_model.createData()
    slips = 9.81 * (0.0018 * 0.95 + 1.219 * 0.0036)
    for q in random_q(np.random.default_rng(5), 50):
        tau = pin.computeGeneralizedGravity(pin_model, data, q)
        np.testing.assert_allclose(tau, rtb_raw.gravload(q), rtol=0, atol=slips)


# --------------------------------------------------------------------------------------------
# In the cycle


def test_the_counter_sees_a_temporary() -> None:
    """The allocation oracle itself: a 6-vector temporary per call counts, in place does not."""
    a, b = np.ones(6), np.empty(6)
    assert numpy_data_allocations(lambda: a + a, 10) == 10
    assert numpy_data_allocations(lambda: np.add(a, a, out=b), 10) == 0


def test_cycle_functions_allocate_no_numpy_data() -> None:
    k = ROBOT.kinematics
    q = facts.Q_HOME.copy()
    t6, out = np.empty((4, 4)), np.empty(6)
    k.fkine(q, t6)
    branch = k.config_of(q)
    assert numpy_data_allocations(lambda: k.fkine(q, t6)) == 0
    assert numpy_data_allocations(lambda: k.ikine(t6, branch, q, out)) == 0
    assert numpy_data_allocations(lambda: k.config_of(q)) == 0
    assert numpy_data_allocations(lambda: k.singular(q)) == 0
