"""The model a robot-level servo sees, refreshed every tick it runs: the arm's mass matrix,
nonlinear effects and gravity (Pinocchio, on the model the dynamics process's feed-forward
uses: rotor inertias, the configured tool and the load the program says it holds included,
``cell.load_pinocchio``, ``payload.HeldLoad``), the tool point's Jacobian, and the tool
point's pose at the measured and the demanded angles (``kernels.chain_pose``, the compiled
chain the wrist sensor uses too, with the base pose and the tool tip folded into its ends),
all in world axes through the robot's base pose.

The tool point is ``ft.tool_tip_m`` along the flange's z axis: where SIO expresses the contact
wrench (``sio/wrench.py``), so a stiffness and a sensed force are about the same point.

Pinocchio's results are bound once as views of its data (``M``, ``nle``, ``g``) and copied in
place; the frame Jacobian is the one vector its bindings return new each call (6 × n
floats), accepted inside the SV's cycle as the dynamics process accepts its own.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pinocchio as pin

from ...core.kernels import chain_pose
from ...robots.cell import FLANGE_FRAME, load_pinocchio
from ...robots.chain import base_pose, chain_of
from ...robots.inverse import DriveFriction
from ...robots.payload import HeldLoad
from ...runtime.config import RobotConfig
from ..algorithms.arm import ArmInput

TOOL_FRAME = "kali_tool_point"


class ArmModel:
    """Robot ``robot``'s model, bound to ``inp``: ``update()`` refills its model fields from
    the ``q``, ``qd`` and ``q_d`` in it.  Built outside the cycle."""

    def __init__(self, robot: RobotConfig, inp: ArmInput, load: np.ndarray) -> None:
        rtype = robot.type
        ft = robot.ft
        tool = (ft.tool_mass_kg, ft.tool_com_m)
        self.model = load_pinocchio(rtype, tool, gravity=not robot.holds_gravity)
        flange = self.model.frames[self.model.getFrameId(FLANGE_FRAME)]
        tip = pin.SE3(np.eye(3), np.array([0.0, 0.0, ft.tool_tip_m]))
        self.frame = self.model.addFrame(
            pin.Frame(TOOL_FRAME, flange.parentJoint, flange.placement * tip, pin.OP_FRAME)
        )
        self.data = self.model.createData()
        self.held, self.load = HeldLoad(self.model), load  # what the program says it holds
        self.inp = inp
        inp.friction = DriveFriction(rtype)
        base = base_pose(robot.base_xyz, robot.base_yaw_deg)
        self._rot = np.zeros((6, 6))  # the base's rotation for both halves of a twist
        self._rot[:3, :3] = self._rot[3:, 3:] = base[:3, :3]
        tip = np.eye(4)
        tip[2, 3] = ft.tool_tip_m
        # the tool point in the world is base · flange · tip: the chain with the base folded
        # into its first transform and the tip into its last, so one kernel call gives it
        chain = chain_of(rtype)
        origins = chain.origins.copy()
        origins[0] = base @ origins[0]
        origins[-1] = origins[-1] @ tip
        origins.setflags(write=False)
        self.tool_chain = replace(chain, origins=origins)
        self._pose = chain_pose(self.tool_chain, inp.q, inp.pose)
        self._pose_d = chain_pose(self.tool_chain, inp.q_d, inp.pose_d)
        self.update()  # a first computation now: Pinocchio's first use faults its pages in

    def update(self) -> None:
        """The model at this tick's ``inp.q``, ``inp.qd``, ``inp.q_d`` (inside the cycle)."""
        inp, model, data = self.inp, self.model, self.data
        self.held.follow(self.load)
        q, qd = inp.q, inp.qd
        np.copyto(inp.M, pin.crba(model, data, q))
        np.copyto(inp.h, pin.nonLinearEffects(model, data, q, qd))
        np.copyto(inp.g, pin.computeGeneralizedGravity(model, data, q))
        jac = pin.computeFrameJacobian(model, data, q, self.frame, pin.LOCAL_WORLD_ALIGNED)
        np.matmul(self._rot, jac, out=inp.J)
        self._pose()  # the tool point at q and at q_d (kali_chain_pose on tool_chain)
        self._pose_d()
