"""The model a robot-level servo sees (issue 27 item 3), refreshed every tick it runs: the
arm's mass matrix, nonlinear effects and gravity (Pinocchio, on the model the dynamics
process's feed-forward uses: rotor inertias and the configured tool included,
``cell.load_pinocchio``), the tool point's Jacobian, and the tool point's pose at the
measured and the demanded angles (``kernels.chain_pose``, the compiled chain the wrist sensor
uses too), all in world axes through the robot's base pose.

The tool point is ``ft.tool_tip_m`` along the flange's z axis: where SIO expresses the contact
wrench (``sio/wrench.py``), so a stiffness and a sensed force are about the same point.

Pinocchio's results are bound once as views of its data (``M``, ``nle``, ``g``) and copied in
place; the frame Jacobian is the one vector its bindings return new each call (6 × n
floats), accepted inside the SV's cycle as the dynamics process accepts its own.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..cell import FLANGE_FRAME, load_pinocchio
from ..chain import base_pose, chain_of
from ..config import RobotConfig
from ..dynamics.inverse import DriveFriction
from ..kernels import chain_pose
from .arm import ArmInput

TOOL_FRAME = "kali_tool_point"


class ArmModel:
    """Robot ``robot``'s model, bound to ``inp``: ``update()`` refills its model fields from
    the ``q``, ``qd`` and ``q_d`` in it.  Built outside the cycle."""

    def __init__(self, robot: RobotConfig, inp: ArmInput) -> None:
        rtype = robot.type
        ft = robot.ft
        self.model = load_pinocchio(rtype, (ft.tool_mass_kg, ft.tool_com_m))
        flange = self.model.frames[self.model.getFrameId(FLANGE_FRAME)]
        tip = pin.SE3(np.eye(3), np.array([0.0, 0.0, ft.tool_tip_m]))
        self.frame = self.model.addFrame(
            pin.Frame(TOOL_FRAME, flange.parentJoint, flange.placement * tip, pin.OP_FRAME)
        )
        self.data = self.model.createData()
        self.inp = inp
        inp.friction = DriveFriction(rtype)
        base = base_pose(robot.base_xyz, robot.base_yaw_deg)
        self._base = base
        self._rot = np.zeros((6, 6))  # the base's rotation for both halves of a twist
        self._rot[:3, :3] = self._rot[3:, 3:] = base[:3, :3]
        self._tip = np.eye(4)
        self._tip[2, 3] = ft.tool_tip_m
        self._flange = np.zeros((4, 4))
        self._flange_d = np.zeros((4, 4))
        self._scratch = np.zeros((4, 4))
        self._q = np.zeros(inp.n)  # contiguous copies the kernels read
        self._q_d = np.zeros(inp.n)
        chain = chain_of(rtype)
        self._pose = chain_pose(chain, self._q, self._flange)
        self._pose_d = chain_pose(chain, self._q_d, self._flange_d)
        self.update()  # a first computation now: Pinocchio's first use faults its pages in

    def update(self) -> None:
        """The model at this tick's ``inp.q``, ``inp.qd``, ``inp.q_d`` (inside the cycle)."""
        inp, model, data = self.inp, self.model, self.data
        q, qd = inp.q, inp.qd
        np.copyto(inp.M, pin.crba(model, data, q))
        np.copyto(inp.h, pin.nonLinearEffects(model, data, q, qd))
        np.copyto(inp.g, pin.computeGeneralizedGravity(model, data, q))
        jac = pin.computeFrameJacobian(model, data, q, self.frame, pin.LOCAL_WORLD_ALIGNED)
        np.matmul(self._rot, jac, out=inp.J)
        np.copyto(self._q, q)
        np.copyto(self._q_d, inp.q_d)
        self._pose()
        self._pose_d()
        self._world(self._flange, inp.pose)
        self._world(self._flange_d, inp.pose_d)

    def _world(self, flange: np.ndarray, out: np.ndarray) -> None:
        """base · flange · tip into ``out``."""
        np.matmul(self._base, flange, out=self._scratch)
        np.matmul(self._scratch, self._tip, out=out)
