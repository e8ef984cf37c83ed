"""hardware/franka/wrench.py: the wrench an FR3's link publishes as its wrist's, from a state's
fields (libfranka's RobotState has no constructor: a plain record of the fields it reads).
Both sources recover a known flange wrench exactly: Kali's estimate from torques made by the
model (``joint-torques``), and the robot's own estimate given about its K frame in base axes
(``robot``), moved to the flange with the tool's weight added back."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pinocchio as pin

from kali_daemons.hardware.franka.wrench import FlangeWrench
from kali_daemons.hardware.ftsensor import gravity_wrench
from kali_daemons.robots.cell import FLANGE_FRAME, load_pinocchio
from kali_daemons.runtime.config import parse_config

TOOL = "tool_mass_kg: 0.73, tool_com_m: [-0.01, 0.0, 0.03], tool_tip_m: 0.1034"


def robot(sensor: str) -> object:
    cfg = parse_config(
        "version: 1\ninstance: x\nrobots:\n  - name: a\n    model: fr3\n"
        f"    ft: {{sensor: {sensor}, {TOOL}}}\n"
        "    hardware: {kind: franka, address: 127.0.0.1}\n"
    )
    return cfg.robots[0]


def flange_model(arm: object) -> tuple[pin.Model, pin.Data, int]:
    """Kali's model of ``arm``'s type, its data and its flange frame: what the test builds
    the wrenches with."""
    model = load_pinocchio(arm.type)  # type: ignore[attr-defined]
    return model, model.createData(), model.getFrameId(FLANGE_FRAME)


def test_kalis_estimate_recovers_the_flange_wrench_the_torques_were_made_with() -> None:
    arm = robot("joint-torques")
    est = FlangeWrench(arm)
    model, data, flange = flange_model(arm)
    rng = np.random.default_rng(5)
    for _ in range(20):
        q = rng.uniform(arm.type.q_min, arm.type.q_max)  # type: ignore[attr-defined]
        w = rng.normal(0.0, 10.0, 6)
        g = pin.computeGeneralizedGravity(model, data, q)
        jac = pin.computeFrameJacobian(model, data, q, flange, pin.LOCAL)
        est.update(SimpleNamespace(), q, g - jac.T @ w)
        np.testing.assert_allclose(est.out, w, rtol=0, atol=1e-8)


def test_the_robots_estimate_is_moved_to_the_flange_with_the_tools_weight() -> None:
    arm = robot("robot")
    est = FlangeWrench(arm)
    model, data, flange = flange_model(arm)
    ft = arm.ft  # type: ignore[attr-defined]
    rng = np.random.default_rng(6)
    for _ in range(20):
        q = rng.uniform(arm.type.q_min, arm.type.q_max)  # type: ignore[attr-defined]
        pin.framesForwardKinematics(model, data, q)
        o_t_f = data.oMf[flange].homogeneous
        f_t_ee = np.eye(4)
        f_t_ee[:3, :3] = pin.rpy.rpyToMatrix(0.0, 0.0, -np.pi / 4)
        f_t_ee[2, 3] = 0.1034
        ee_t_k = np.eye(4)
        ee_t_k[:3, 3] = rng.normal(0.0, 0.05, 3)
        contact = rng.normal(0.0, 10.0, 6)  # at the flange, flange axes: what should come out
        rot, p_f = o_t_f[:3, :3], o_t_f[:3, 3]
        p_k = (o_t_f @ f_t_ee @ ee_t_k)[:3, 3]
        force = rot @ contact[:3]
        torque_k = rot @ contact[3:] - np.cross(p_k - p_f, force)  # about K, base axes
        state = SimpleNamespace(
            O_T_EE=list((o_t_f @ f_t_ee).flatten(order="F")),
            EE_T_K=list(ee_t_k.flatten(order="F")),
            O_F_ext_hat_K=[*force, *torque_k],
        )
        est.update(state, q, np.zeros(7))
        weight = gravity_wrench(
            ft.tool_mass_kg, np.array(ft.tool_com_m), rot.T @ np.array([0.0, 0.0, -9.81])
        )
        np.testing.assert_allclose(est.out, contact + weight, rtol=0, atol=1e-9)
