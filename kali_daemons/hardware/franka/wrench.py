"""An FR3's wrist wrench without a wrist sensor: from its joint torque sensors.

The link gives SIO the wrench a wrist sensor on the flange would read (``ftsensor``'s
convention: what the tool side exerts on the flange, flange axes, about its origin; an idle
tool reads its own weight), so SIO's sensor pipeline (tare, tool gravity, filter, contact
limit, guards) runs unchanged.  Two sources (the config's ``ft.sensor``):

- ``joint-torques`` (source ``model``): Kali's estimate.  At rest the motors hold the arm and
  whatever pushes on it, ``tau_J = g(q) - J(q)^T w``, so ``w`` is the least-squares solution of
  ``J^T w = g(q) - tau_J`` with ``g`` and ``J`` (the flange's, in its own axes) of the arm
  alone on Kali's model (Pinocchio): the hand then reads as the tool it is.  Quasi-static:
  joint friction and accelerations read as force (docs/guide/hardware.md has how good it is
  against franky-sim's truth).  franky-sim gives no estimate of its own.
- ``robot``: a real FR3's own estimate, ``O_F_ext_hat_K`` (base axes, about its K frame),
  moved to the flange and the tool's weight added back (the robot has taken its load out).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ...robots.cell import FLANGE_FRAME, load_pinocchio
from ..ftsensor import GAUGES, gravity_wrench


class FlangeWrench:
    """One FR3's flange wrench from each state packet (``update``; outside SIO's cycle, in
    its link's process), for a robot of config ``robot`` (its ``ft`` section names the
    source and the tool)."""

    def __init__(self, robot: Any) -> None:
        import pinocchio as pin  # only a link whose arm has the estimate loads it

        self._pin = pin
        sheet = robot.ft.sheet
        self.source = "" if sheet is None or sheet.source == "gauges" else sheet.source
        self.model = load_pinocchio(robot.type)  # the arm alone, with gravity
        self.data = self.model.createData()
        self.flange = self.model.getFrameId(FLANGE_FRAME)
        self.n = self.model.nv
        self.mass = robot.ft.tool_mass_kg
        self.com = np.asarray(robot.ft.tool_com_m, dtype=np.float64)
        self.g_base = np.array([0.0, 0.0, -robot.type.gravity])  # the robot's base is level
        self.out = np.zeros(GAUGES)  # the newest wrench
        self._r = np.zeros(self.n)  # g - tau_J: the torques something else exerts
        self._jjt, self._jr = np.zeros((GAUGES, GAUGES)), np.zeros(GAUGES)

    def update(self, state: Any, q: np.ndarray, tau_j: np.ndarray) -> None:
        """``out`` from one state packet (libfranka's RobotState), its angles ``q`` and
        measured torques ``tau_j`` already read out of it (float64 arrays)."""
        pin, model, data = self._pin, self.model, self.data
        if self.source == "model":
            g = pin.computeGeneralizedGravity(model, data, q)
            jac = pin.computeFrameJacobian(model, data, q, self.flange, pin.LOCAL)
            np.subtract(g, tau_j, out=self._r)
            np.matmul(jac, jac.T, out=self._jjt)  # J J^T w = J r: w = pinv(J^T) r
            np.matmul(jac, self._r, out=self._jr)
            try:
                self.out[:] = np.linalg.solve(self._jjt, self._jr)
            except np.linalg.LinAlgError:  # at a singularity: the least-squares one
                self.out[:] = np.linalg.lstsq(jac.T, self._r, rcond=None)[0]
        elif self.source == "robot":
            pin.framesForwardKinematics(model, data, q)
            flange = data.oMf[self.flange]
            rot_t = flange.rotation.T
            o_t_ee = np.asarray(state.O_T_EE, dtype=np.float64).reshape(4, 4, order="F")
            ee_t_k = np.asarray(state.EE_T_K, dtype=np.float64).reshape(4, 4, order="F")
            k_point = (o_t_ee @ ee_t_k)[:3, 3]
            wrench = np.asarray(state.O_F_ext_hat_K, dtype=np.float64)
            force = wrench[:3]
            torque = wrench[3:] + np.cross(k_point - flange.translation, force)
            self.out[:3], self.out[3:] = rot_t @ force, rot_t @ torque
            self.out += gravity_wrench(self.mass, self.com, rot_t @ self.g_base)


__all__ = ["FlangeWrench"]
