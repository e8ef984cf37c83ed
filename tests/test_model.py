"""Tests for the arm models: the PUMA 560 facts, the generated URDF, Pinocchio and the MuJoCo
cell (also a mixed one with a 7-joint Panda).

robotics-toolbox-python's ``Puma560`` (the source puma560.md transcribes) is the independent
oracle: its recursive Newton-Euler and forward kinematics are computed straight from the DH
table, with no URDF in between.  Given the same d1 and the same two inertia fixes, it,
Pinocchio and MuJoCo must agree to rounding error.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path
from typing import Any

import mujoco
import numpy as np
import pinocchio as pin
import pytest

from kali_daemons.core.errors import ConfigError, ModelError
from kali_daemons.robots import puma560, robot_type
from kali_daemons.robots.model import (
    ARMS_CONTACT,
    FLANGE_FRAME,
    PASSED_CONTACT,
    TOOL_CONTACT,
    World,
    _attach_arm,
    build_world,
    load_pinocchio,
)
from kali_daemons.runtime.config import FtConfig, RobotConfig, load_config

ROOT = Path(__file__).resolve().parents[1]
GEN_SCRIPT = ROOT / "scripts" / "gen_puma560_urdf.py"
N_POSES = 60
# What the three achieve here: torques within 7e-14 N·m (5e-15 relative) of the toolbox's,
# poses within 7e-16 m / rad.  The bounds leave room for other BLAS and compilers, not for
# a modelling difference (the smallest, link 1's 1 g, is exactly invisible to joint torques).
TORQUE_RTOL = 1e-9
TORQUE_ATOL = 1e-9  # N·m
POSE_TOL = 1e-9  # m and rad


# --------------------------------------------------------------------------------------------
# Fixtures


@pytest.fixture(scope="module")
def rtb_raw() -> Any:
    """robotics-toolbox-python's Puma560 exactly as shipped."""
    rtb = pytest.importorskip("roboticstoolbox", reason="the oracle; pip install '.[test]'")
    return rtb.models.DH.Puma560()


@pytest.fixture(scope="module")
def rtb_puma(rtb_raw: Any) -> Any:
    """The toolbox model made to describe the same robot: our d1, our inertia fixes, no
    friction.  Its ``rne`` keeps ``Jm·G²·qdd`` (the armature), as MuJoCo and Pinocchio do."""
    robot = rtb_raw.nofriction(coulomb=True, viscous=True)
    robot.links[0].d = float(puma560.D[0])
    for i, link in enumerate(robot.links):
        link.m = float(puma560.MASS[i])
        link.I = np.diag(puma560.INERTIA[i])
    return robot


@pytest.fixture(scope="module")
def pin_model() -> pin.Model:
    return load_pinocchio(puma560.ROBOT)


@pytest.fixture(scope="module")
def arm_world() -> World:
    """One arm at the origin, no yaw: its frames are the toolbox's base frame; a massless
    tool, as the toolbox's and Pinocchio's arms have none; no contacts."""
    bare = FtConfig(tool_mass_kg=0.0, tool_com_m=(0.0, 0.0, 0.0))
    world = build_world([RobotConfig("arm", "puma560", (0.0, 0.0, 0.0), 0.0, ft=bare)])
    # the arm alone: its tool's pad, at random poses, must not land on the cell's table
    world.model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return world


@pytest.fixture(scope="module")
def default_robots() -> tuple[RobotConfig, ...]:
    return load_config(ROOT / "config" / "default.yaml").robots


@pytest.fixture(scope="module")
def cell(default_robots: tuple[RobotConfig, ...]) -> World:
    return build_world(default_robots)


def random_states(n: int, seed: int = 560) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``n`` seeded (q, qd, qdd): q uniform within the joint limits, qd and qdd up to 3 / 10."""
    rng = np.random.default_rng(seed)
    return [
        (rng.uniform(puma560.Q_MIN, puma560.Q_MAX), rng.uniform(-3, 3, 6), rng.uniform(-10, 10, 6))
        for _ in range(n)
    ]


def yaw_transform(robot: RobotConfig) -> pin.SE3:
    """The robot's base in the world frame, as the config places it."""
    return pin.SE3(
        pin.utils.rpyToMatrix(0.0, 0.0, np.radians(robot.base_yaw_deg)), np.array(robot.base_xyz)
    )


def site_pose(world: World, data: mujoco.MjData, site: int) -> pin.SE3:
    return pin.SE3(data.site_xmat[site].reshape(3, 3).copy(), data.site_xpos[site].copy())


# --------------------------------------------------------------------------------------------
# The facts


def test_facts_match_the_toolbox(rtb_raw: Any) -> None:
    """puma560.py transcribes the same table the toolbox ships (d1 to within 0.03 mm)."""
    links = rtb_raw.links
    # The toolbox's d1 is 26.45 in = 0.67183 m; puma560.md (and we) round it to 0.6718.
    assert links[0].d == pytest.approx(puma560.D[0], abs=5e-5)
    np.testing.assert_array_equal([lk.d for lk in links[1:]], puma560.D[1:])
    np.testing.assert_array_equal([lk.a for lk in links], puma560.A)
    np.testing.assert_allclose([lk.alpha for lk in links], puma560.ALPHA, rtol=0, atol=1e-15)
    np.testing.assert_allclose(
        np.array(rtb_raw.qlim).T, np.c_[puma560.Q_MIN, puma560.Q_MAX], atol=1e-15
    )
    for name in ("qz", "qr", "qs", "qn"):
        np.testing.assert_allclose(
            getattr(rtb_raw, name), getattr(puma560, name.upper()), atol=1e-15
        )
    np.testing.assert_array_equal([lk.m for lk in links], puma560.MASS_RAW)
    np.testing.assert_array_equal([lk.r for lk in links], puma560.COM)
    np.testing.assert_array_equal([np.diag(lk.I) for lk in links], puma560.INERTIA_RAW)
    for lk in links:
        assert not np.any(lk.I - np.diag(np.diag(lk.I))), "the table has no products of inertia"
    np.testing.assert_array_equal([lk.Jm for lk in links], puma560.JM)
    np.testing.assert_array_equal([lk.G for lk in links], puma560.G)
    np.testing.assert_array_equal([lk.B for lk in links], puma560.B_MOTOR)
    np.testing.assert_array_equal([lk.Tc[0] for lk in links], puma560.TC_POS)
    np.testing.assert_array_equal([lk.Tc[1] for lk in links], puma560.TC_NEG)


def test_derived_drive_train_values() -> None:
    np.testing.assert_allclose(puma560.ARMATURE, puma560.JM * puma560.G**2)
    np.testing.assert_allclose(puma560.VISCOUS, puma560.G**2 * puma560.B_MOTOR)
    np.testing.assert_allclose(puma560.COULOMB_POS, np.abs(puma560.G) * puma560.TC_POS)
    np.testing.assert_allclose(puma560.COULOMB_NEG, np.abs(puma560.G) * puma560.TC_NEG)
    assert np.all(puma560.COULOMB_POS > 0) and np.all(puma560.COULOMB_NEG < 0)
    # large motors where the rotor inertia is large; KT·I_peak is the peak torque to 2 %
    assert np.all((puma560.JM == 200e-6) == (puma560.PEAK_TORQUE == 2.12))
    np.testing.assert_allclose(puma560.KT * puma560.MAX_CURRENT, puma560.PEAK_TORQUE, rtol=0.02)
    assert not puma560.ARMATURE.flags.writeable


def test_inertia_fixes_are_minimal_and_physical() -> None:
    """Only the two documented entries change, and every link is a physical rigid body."""
    changed = np.argwhere(puma560.INERTIA != puma560.INERTIA_RAW).tolist()
    assert changed == [[0, 0], [0, 2], [2, 0]]
    assert np.argwhere(puma560.MASS != puma560.MASS_RAW).tolist() == [[0]]
    assert puma560.INERTIA[0, 1] == 0.35  # about joint 1's axis (DH y1), the only one that matters
    assert (
        puma560.INERTIA[0, 0] + puma560.INERTIA[0, 2] == puma560.INERTIA[0, 1]
    )  # triangle, with equality
    assert puma560.INERTIA[2, 0] + puma560.INERTIA[2, 2] == puma560.INERTIA[2, 1]
    assert puma560.MASS[0] <= 1e-3
    for ixx, iyy, izz in puma560.INERTIA:
        assert ixx + iyy >= izz and iyy + izz >= ixx and izz + ixx >= iyy
    assert np.all(puma560.MASS > 0) and np.all(puma560.INERTIA > 0)


# --------------------------------------------------------------------------------------------
# The generated URDF


def test_committed_urdf_is_what_the_script_generates() -> None:
    result = subprocess.run(
        [sys.executable, str(GEN_SCRIPT), "--check"], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stdout + result.stderr


def test_check_mode_notices_a_stale_file(tmp_path: Path) -> None:
    stale = tmp_path / "puma560.urdf"
    stale.write_text(puma560.URDF_PATH.read_text().replace('effort="', 'effort="1'))
    result = subprocess.run(
        [sys.executable, str(GEN_SCRIPT), "--check", "--output", str(stale)],
        capture_output=True,
        text=True,
        check=False,
    )
    assert result.returncode == 1
    assert "stale" in result.stderr


def test_pinocchio_model(pin_model: pin.Model) -> None:
    assert pin_model.nq == pin_model.nv == 6
    assert [pin_model.names[i] for i in range(1, 7)] == [f"j{i}" for i in range(1, 7)]
    np.testing.assert_array_equal(pin_model.armature, puma560.ARMATURE)
    np.testing.assert_array_equal(pin_model.lowerPositionLimit, puma560.Q_MIN)
    np.testing.assert_array_equal(pin_model.upperPositionLimit, puma560.Q_MAX)
    np.testing.assert_array_equal(pin_model.gravity.linear, [0.0, 0.0, -9.81])
    masses = [pin_model.inertias[i].mass for i in range(1, 7)]
    np.testing.assert_allclose(masses, puma560.MASS, rtol=1e-15)
    assert pin_model.existFrame(FLANGE_FRAME)


def test_a_robot_type_without_its_urdf_is_refused_naming_the_whole_path(tmp_path: Path) -> None:
    """However deep the file, the message names it whole: its name ends the path."""
    deep = tmp_path / ("d" * 90)
    with pytest.raises(ConfigError, match=r"robot type 'puma560': urdf = '.*d{90}/nope\.urdf'"):
        dataclasses.replace(puma560.ROBOT, urdf=deep / "nope.urdf")


# --------------------------------------------------------------------------------------------
# Three-way agreement: toolbox, Pinocchio, MuJoCo


def test_inverse_dynamics_agree(rtb_puma: Any, pin_model: pin.Model, arm_world: World) -> None:
    """rne (toolbox) == rnea (Pinocchio) == mj_inverse (MuJoCo), armature included in all."""
    pdata = pin_model.createData()
    no_arm = pin_model.copy()
    no_arm.armature = np.zeros(6)
    no_arm_data = no_arm.createData()
    m = arm_world.model
    mdata = mujoco.MjData(m)
    dofs = arm_world.dof_adr[0]
    qadr = arm_world.qpos_adr[0]
    worst_pin = worst_mj = 0.0
    for q, qd, qdd in random_states(N_POSES):
        tau_rtb = np.asarray(rtb_puma.rne(q, qd, qdd), dtype=float)
        tau_pin = pin.rnea(pin_model, pdata, q, qd, qdd).copy()
        # Pinocchio's rnea adds armature·qdd itself (a version that did not would fail here)
        tau_bare = pin.rnea(no_arm, no_arm_data, q, qd, qdd)
        np.testing.assert_allclose(
            tau_pin - tau_bare, puma560.ARMATURE * qdd, rtol=1e-12, atol=1e-12
        )
        mdata.qpos[qadr], mdata.qvel[dofs], mdata.qacc[dofs] = q, qd, qdd
        mujoco.mj_inverse(m, mdata)
        tau_mj = mdata.qfrc_inverse[dofs].copy()
        np.testing.assert_allclose(tau_pin, tau_rtb, rtol=TORQUE_RTOL, atol=TORQUE_ATOL)
        np.testing.assert_allclose(tau_mj, tau_rtb, rtol=TORQUE_RTOL, atol=TORQUE_ATOL)
        worst_pin = max(worst_pin, float(np.max(np.abs(tau_pin - tau_rtb))))
        worst_mj = max(worst_mj, float(np.max(np.abs(tau_mj - tau_rtb))))
    print(f"max |τ - τ_rtb|: Pinocchio {worst_pin:.1e} N·m, MuJoCo {worst_mj:.1e} N·m")


def test_forward_kinematics_agree(rtb_puma: Any, pin_model: pin.Model, arm_world: World) -> None:
    """fkine (toolbox) == flange frame (Pinocchio) == flange site (MuJoCo)."""
    pdata = pin_model.createData()
    fid = pin_model.getFrameId(FLANGE_FRAME)
    m = arm_world.model
    mdata = mujoco.MjData(m)
    site = arm_world.flange_site[0]
    poses = [puma560.QZ, puma560.QR, puma560.QS, puma560.QN] + [
        q for q, _, _ in random_states(N_POSES)
    ]
    for q in poses:
        t_rtb = rtb_puma.fkine(q).A
        pin.framesForwardKinematics(pin_model, pdata, q)
        mdata.qpos[arm_world.qpos_adr[0]] = q
        mujoco.mj_kinematics(m, mdata)
        for pose in (pdata.oMf[fid], site_pose(arm_world, mdata, site)):
            np.testing.assert_allclose(pose.translation, t_rtb[:3, 3], rtol=0, atol=POSE_TOL)
            np.testing.assert_allclose(pose.rotation, t_rtb[:3, :3], rtol=0, atol=POSE_TOL)


def test_flange_at_qn(pin_model: pin.Model) -> None:
    """puma560.md's (0.596, −0.150, 0.658) at qn; it really is z = 0.65745 (see FLANGE_QN)."""
    pdata = pin_model.createData()
    pin.framesForwardKinematics(pin_model, pdata, puma560.QN)
    p = pdata.oMf[pin_model.getFrameId(FLANGE_FRAME)].translation
    np.testing.assert_allclose(p, puma560.FLANGE_QN, atol=1e-3)


@pytest.mark.parametrize(
    ("q", "expected", "decimals"),
    [
        (puma560.QZ, puma560.GRAVITY_QZ, [3, 2, 3, 3, 3, 3]),
        (puma560.QN, puma560.GRAVITY_QN, [3, 2, 2, 3, 3, 3]),
    ],
    ids=["qz", "qn"],
)
def test_gravity_torques_match_puma560_md(
    q: np.ndarray,
    expected: np.ndarray,
    decimals: list[int],
    pin_model: pin.Model,
    arm_world: World,
) -> None:
    """The holding torques puma560.md prints, to the digits it prints them."""
    tau_pin = pin.computeGeneralizedGravity(pin_model, pin_model.createData(), q)
    m = arm_world.model
    mdata = mujoco.MjData(m)
    mdata.qpos[arm_world.qpos_adr[0]] = q
    mujoco.mj_forward(m, mdata)
    tau_mj = mdata.qfrc_bias[arm_world.dof_adr[0]]
    for tau in (tau_pin, tau_mj):
        got = [round(float(t), d) + 0.0 for t, d in zip(tau, decimals, strict=True)]
        assert got == pytest.approx(list(expected), abs=1e-12), f"{tau} vs {expected}"


# --------------------------------------------------------------------------------------------
# The cell


def test_cell_layout(
    cell: World, default_robots: tuple[RobotConfig, ...], pin_model: pin.Model
) -> None:
    """Bases where the config puts them; armature, no damping or friction; welds off."""
    m = cell.model
    assert cell.robots == ("left", "right")
    assert m.opt.timestep == 0.0005
    assert m.opt.integrator == mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    np.testing.assert_array_equal(m.opt.gravity, [0.0, 0.0, -9.81])
    data = mujoco.MjData(m)
    pdata = pin_model.createData()
    pin.framesForwardKinematics(pin_model, pdata, puma560.QZ)
    flange_in_base = pdata.oMf[pin_model.getFrameId(FLANGE_FRAME)]
    mujoco.mj_kinematics(m, data)  # qpos0: arms at QZ, bar on the stand
    flanges = {}
    for k, robot in enumerate(default_robots):
        assert cell.index(robot.name) == k
        dofs = cell.dof_adr[k]
        np.testing.assert_array_equal(m.dof_armature[dofs], puma560.ARMATURE)
        assert not np.any(m.dof_damping[dofs]) and not np.any(m.dof_frictionloss[dofs])
        np.testing.assert_array_equal(data.qpos[cell.qpos_adr[k]], puma560.QZ)
        flange = site_pose(cell, data, cell.flange_site[k])
        expected = yaw_transform(robot) * flange_in_base
        np.testing.assert_allclose(flange.translation, expected.translation, atol=1e-12)
        np.testing.assert_allclose(flange.rotation, expected.rotation, atol=1e-12)
        flanges[robot.name] = flange.translation
        (weld,) = cell.weld[k]  # one graspable object, the bar
        assert m.eq_type[weld] == mujoco.mjtEq.mjEQ_WELD
        assert not m.eq_active0[weld] and not data.eq_active[weld]
        assert m.eq_obj2id[weld] == cell.object_body[0]
    # facing each other across the origin: a half turn about z maps one flange onto the other
    np.testing.assert_allclose(flanges["right"], [-1, -1, 1] * flanges["left"], atol=1e-12)
    # of the arms, the tools' pads touch the fixtures only (issue 27), the collision shapes
    # (group 3) the world and the other arm (issue 56: tests/test_collisions.py), the
    # visuals nothing
    arm_geoms = [
        g
        for g in range(m.ngeom)
        if m.body_rootid[m.geom_bodyid[g]] not in cell.object_body and m.geom_bodyid[g] != 0
    ]
    pads = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, f"{r.name}/pad") for r in default_robots]
    assert all(m.geom_contype[g] == TOOL_CONTACT == m.geom_conaffinity[g] for g in pads)
    for g in arm_geoms:
        if g not in pads and m.geom_group[g] != 3:
            assert m.geom_contype[g] == 0 == m.geom_conaffinity[g]
        elif g not in pads:
            assert m.geom_contype[g] & ARMS_CONTACT and m.geom_conaffinity[g] & 1
    # the shipped scene's fixtures: the arms pass through them (arms_touch: false), the tools
    # touch the table, not the stand (tools_touch: false)
    table = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "table")
    assert m.geom_conaffinity[table] == PASSED_CONTACT | TOOL_CONTACT == m.geom_contype[table]
    stand = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "stand")
    assert m.geom_conaffinity[stand] == PASSED_CONTACT == m.geom_contype[stand]


def solve_ik(model: pin.Model, target: pin.SE3, q0: np.ndarray) -> np.ndarray:
    """Damped least squares on the flange frame, kept inside the joint limits."""
    data = model.createData()
    fid = model.getFrameId(FLANGE_FRAME)
    q = q0.copy()
    for _ in range(100):
        pin.framesForwardKinematics(model, data, q)
        err = pin.log6(data.oMf[fid].actInv(target)).vector
        if np.linalg.norm(err) < 1e-13:
            break
        jac = pin.computeFrameJacobian(model, data, q, fid, pin.LOCAL)
        step = jac.T @ np.linalg.solve(jac @ jac.T + 1e-10 * np.eye(6), err)
        q = np.clip(q + step, model.lowerPositionLimit, model.upperPositionLimit)
    return q


def test_grasp_sites_are_reachable(
    cell: World, default_robots: tuple[RobotConfig, ...], pin_model: pin.Model
) -> None:
    """Each flange reaches its grasp site, wrist down, inside the limits and away from any
    singularity (wrist, elbow, shoulder), by IK from a rough guess."""
    m = cell.model
    data = mujoco.MjData(m)
    mujoco.mj_kinematics(m, data)
    guess = np.radians([20.0, 60.0, -210.0, 0.0, -30.0, 20.0])
    solutions = {}
    for k, robot in enumerate(default_robots):
        grasp = site_pose(cell, data, cell.grasp_site[k])  # left: the -x end, right: the +x
        q = solve_ik(pin_model, yaw_transform(robot).actInv(grasp), guess)
        assert np.all(q > puma560.Q_MIN) and np.all(q < puma560.Q_MAX)
        assert abs(np.sin(q[4])) > np.sin(np.radians(20))  # wrist: well away from θ5 = 0
        pdata = pin_model.createData()
        jac = pin.computeFrameJacobian(pin_model, pdata, q, pin_model.getFrameId(FLANGE_FRAME))
        assert np.linalg.svd(jac, compute_uv=False).min() > 0.2
        check = mujoco.MjData(m)
        check.qpos[:] = data.qpos
        check.qpos[cell.qpos_adr[k]] = q
        mujoco.mj_kinematics(m, check)
        flange = site_pose(cell, check, cell.flange_site[k])
        grasp_now = site_pose(cell, check, cell.grasp_site[k])
        np.testing.assert_allclose(flange.translation, grasp_now.translation, atol=1e-9)
        np.testing.assert_allclose(flange.rotation, grasp_now.rotation, atol=1e-9)
        solutions[robot.name] = q
        print(robot.name, np.degrees(q).round(3).tolist())
    np.testing.assert_allclose(solutions["left"], solutions["right"], atol=1e-9)  # symmetric


def hold_arms(world: World, data: mujoco.MjData, qpos: np.ndarray) -> None:
    """Clamp every arm to ``qpos`` (a test stand-in for the plant's brakes)."""
    for qadr, dofs in zip(world.qpos_adr, world.dof_adr, strict=True):
        data.qpos[qadr] = qpos[qadr]
        data.qvel[dofs] = 0.0


def test_bar_rests_on_the_stand(cell: World) -> None:
    m = cell.model
    data = mujoco.MjData(m)
    mujoco.mj_forward(m, data)
    start = data.qpos.copy()
    for _ in range(round(1.0 / m.opt.timestep)):
        hold_arms(cell, data, start)
        mujoco.mj_step(m, data)
    (adr,), (dof,) = cell.object_qpos_adr, cell.object_dof_adr
    bar = slice(adr, adr + 7)
    np.testing.assert_allclose(data.qpos[bar][:3], start[bar][:3], atol=2e-3)  # settles < 2 mm
    np.testing.assert_allclose(np.abs(data.qpos[bar][3:]), [1, 0, 0, 0], atol=1e-4)
    assert np.all(np.abs(data.qvel[dof : dof + 6]) < 1e-3)


def test_weld_holds_the_pose_it_was_activated_at(cell: World) -> None:
    """Activating at an arbitrary relative pose starts with zero error and holds the bar."""
    m = cell.model
    data = mujoco.MjData(m)
    rng = np.random.default_rng(7)
    data.qpos[cell.qpos_adr[0]] = rng.uniform(puma560.Q_MIN, puma560.Q_MAX) * 0.3
    (bar,) = cell.object_qpos_adr
    data.qpos[bar : bar + 3] = [0.0, 0.4, 1.0]  # in the air, away from the stand
    data.qpos[bar + 3 : bar + 7] = np.array([0.9, 0.1, -0.3, 0.2]) / np.linalg.norm(
        [0.9, 0.1, -0.3, 0.2]
    )
    mujoco.mj_kinematics(m, data)
    saved = m.eq_data.copy()
    try:
        cell.activate_weld(data, "left", "bar")
        assert data.eq_active[cell.weld[0][0]] and not data.eq_active[cell.weld[1][0]]
        mujoco.mj_forward(m, data)
        eq_rows = data.efc_type == mujoco.mjtConstraint.mjCNSTR_EQUALITY
        assert np.count_nonzero(eq_rows) == 6
        assert np.max(np.abs(data.efc_pos[eq_rows])) < 1e-12
        start = data.qpos.copy()
        for _ in range(400):
            hold_arms(cell, data, start)
            mujoco.mj_step(m, data)
        # held against gravity by a soft constraint: about 1 mm of sag this far (0.7 m) out
        assert np.linalg.norm(data.qpos[bar : bar + 3] - start[bar : bar + 3]) < 2e-3
    finally:
        m.eq_data[:] = saved  # the module-scoped cell is shared


def test_explicit_friction_is_stable_at_half_a_millisecond(arm_world: World) -> None:
    """The plant's way: viscous and asymmetric Coulomb friction as qfrc_applied, explicit.
    Spinning joints come to rest with no growth and only a tiny Coulomb chatter."""
    m = arm_world.model
    data = mujoco.MjData(m)
    dofs = arm_world.dof_adr[0]
    data.qpos[arm_world.qpos_adr[0]] = puma560.QN
    data.qvel[dofs] = [2.0, -1.5, 2.5, -5.0, 5.0, -5.0]
    gravity = m.opt.gravity.copy()
    m.opt.gravity[:] = 0.0
    try:
        energy = []
        for _ in range(2000):
            qd = data.qvel[dofs]
            coulomb = np.where(
                qd > 0, puma560.COULOMB_POS, np.where(qd < 0, puma560.COULOMB_NEG, 0.0)
            )
            data.qfrc_applied[dofs] = -puma560.VISCOUS * qd - coulomb
            mujoco.mj_step(m, data)
            mujoco.mj_energyVel(m, data)
            energy.append(float(data.energy[1]))
    finally:
        m.opt.gravity[:] = gravity
    assert np.all(np.isfinite(data.qvel))
    assert max(energy[1:]) <= energy[0]
    assert np.max(np.abs(data.qvel[dofs])) < 0.01


def test_world_index(cell: World) -> None:
    assert cell.index("right") == 1 and cell.index(0) == 0
    with pytest.raises(ModelError, match="no robot 'middle'; robots: left, right"):
        cell.index("middle")
    with pytest.raises(ModelError, match="out of range"):
        cell.index(2)


def test_a_mixed_cell_sizes_each_robot_by_its_type() -> None:
    """A PUMA 560 and a 7-joint Panda in one cell: every per-robot index has the type's joint
    count, addresses never overlap, each dof has its drive's armature and motor, and the
    Panda's flange in MuJoCo is Pinocchio's on the same URDF."""
    robots = (
        RobotConfig("left", "puma560", (-0.6, 0.0, 0.0), 0.0),
        RobotConfig("right", "panda", (0.6, 0.0, 0.0), 180.0),
    )
    world = build_world(robots)
    m = world.model
    assert [r.n_joints for r in robots] == [6, 7]
    for field in ("qpos_adr", "dof_adr", "motor", "motor_act_adr"):
        sizes = [len(a) for a in getattr(world, field)]
        assert sizes == [6, 7], field
        flat = np.concatenate(getattr(world, field))
        assert len(set(flat.tolist())) == 13, f"{field}: every joint its own"
    assert m.nu == m.na == 13
    for k, r in enumerate(robots):
        t = r.type
        dofs, motors = world.dof_adr[k], world.motor[k]
        np.testing.assert_array_equal(m.dof_armature[dofs], t.drive.armature)
        np.testing.assert_allclose(m.actuator_gear[motors, 0], t.drive.gear * t.drive.kt)
        np.testing.assert_array_equal(m.actuator_trnid[motors, 0], m.dof_jntid[dofs])
        np.testing.assert_allclose(m.actuator_actrange[motors, 1], t.drive.max_current)
        assert m.jnt_qposadr[m.dof_jntid[dofs]].tolist() == world.qpos_adr[k].tolist()
    panda = robot_type("panda")
    pmodel = load_pinocchio(panda)
    pdata = pmodel.createData()
    fid = pmodel.getFrameId(FLANGE_FRAME)
    data = mujoco.MjData(m)
    rng = np.random.default_rng(7)
    for _ in range(10):
        q = rng.uniform(panda.q_min, panda.q_max)
        data.qpos[world.qpos_adr[1]] = q
        mujoco.mj_kinematics(m, data)
        pin.framesForwardKinematics(pmodel, pdata, q)
        expected = yaw_transform(robots[1]) * pdata.oMf[fid]
        flange = site_pose(world, data, world.flange_site[1])
        np.testing.assert_allclose(flange.translation, expected.translation, atol=1e-12)
        np.testing.assert_allclose(flange.rotation, expected.rotation, atol=1e-12)


def test_an_arm_file_with_another_joint_count_is_refused() -> None:
    """A type of 6 joints on the Panda's 7-joint file: one joint would move unactuated."""
    wrong = dataclasses.replace(puma560.ROBOT, urdf=robot_type("panda").urdf)
    robot = RobotConfig("a", "puma560", (0.0, 0.0, 0.0), 0.0)
    with pytest.raises(ModelError, match=r"expects 6 moving joints, the file has 7: j1, .*j7"):
        _attach_arm(mujoco.MjSpec(), robot, wrong, 0)


def test_build_world_refusals() -> None:
    with pytest.raises(ModelError, match="no robots"):
        build_world([])
    with pytest.raises(ConfigError, match="robot type 'kuka': no such type"):
        build_world([RobotConfig("a", "kuka", (0.0, 0.0, 0.0), 0.0)])
    with pytest.raises(ModelError, match="timestep"):
        build_world([RobotConfig("a", "puma560", (0.0, 0.0, 0.0), 0.0)], timestep=0.0)
