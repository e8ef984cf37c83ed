"""The feed-forward torques themselves (thesis 2.2.3, 3.3.6), apart from the process that
schedules them, so they can be checked against an independent model.

``InverseDynamics.torque`` at a demanded (q, q̇, q̈):

    FfMode.GRAVITY:  g(q)
    FfMode.FULL:     M(q) q̈ + C(q, q̇) q̇ + g(q) + friction(q̇) + k_v q̇

with Pinocchio on the robot type's model both Kali and the plant load
(``model.load_pinocchio``: rotor inertias included), its drive's viscous and asymmetric
Coulomb friction (the Coulomb part smoothed by tanh(|G| q̇ / ω₀) as the plant smooths it), and
``k_v`` the servos' velocity gains (see ``dynamics/daemon.py``).

``central_differences`` gives q̇ and q̈ at a set-point from its neighbours over segments of
unequal length (the TG's period may change on line), exact for quadratics.
"""

from __future__ import annotations

import numpy as np
import pinocchio as pin

from ..core.layout import FfMode
from ..robots import RobotType
from ..robots.profile import FRICTION_SMOOTHING_RAD_S
from .cell import load_pinocchio


class InverseDynamics:
    """Feed-forward torques of one arm of type ``robot``; every array preallocated except the
    vectors Pinocchio's Python bindings return."""

    def __init__(
        self,
        robot: RobotType,
        tool: tuple[float, tuple[float, float, float]] | None = None,
        gravity: bool = True,
    ) -> None:
        """``tool``: the mass and centre of mass (flange frame) of the tool the arm carries;
        ``gravity`` False: its hardware holds it against gravity (``load_pinocchio``)."""
        self.model = load_pinocchio(robot, tool, gravity)
        self.data = self.model.createData()
        n = robot.n_joints
        self.tau = np.zeros(n)
        self._c = np.zeros(n)
        self.friction = DriveFriction(robot)
        # a first computation now: the first use of Pinocchio faults its pages in
        self.torque(FfMode.FULL, robot.q_home.copy(), np.ones(n), np.ones(n), np.zeros(n))

    def torque(
        self, mode: FfMode, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray, kv: np.ndarray
    ) -> np.ndarray:
        """Feed-forward joint torques (N·m) at (q, q̇, q̈) in ``mode``, into ``self.tau``;
        ``kv`` the servos' velocity gains (N·m·s/rad, FULL only)."""
        if mode == FfMode.GRAVITY:
            np.copyto(self.tau, pin.computeGeneralizedGravity(self.model, self.data, q))
            return self.tau
        np.copyto(self.tau, pin.rnea(self.model, self.data, q, qd, qdd))
        c = self._c
        self.friction(qd, c)
        np.add(self.tau, c, out=self.tau)
        np.multiply(qd, kv, out=c)  # velocity feed-forward: the servo damps q̇ − q̇_d
        np.add(self.tau, c, out=self.tau)
        return self.tau


class DriveFriction:
    """The drive's friction torque at joint velocity q̇ (N·m), as the plant models it:
    viscous plus asymmetric Coulomb smoothed by tanh(|G| q̇ / ω₀).  Preallocated; a call
    allocates nothing (the feed-forward and the robot-level servos' compensation)."""

    def __init__(self, robot: RobotType) -> None:
        n = robot.n_joints
        d = robot.drive
        self._s, self._c = np.zeros(n), np.zeros(n)
        self._gear_w = np.abs(d.gear) / FRICTION_SMOOTHING_RAD_S
        self._viscous, self._pos, self._neg = d.viscous, d.coulomb_pos, d.coulomb_neg

    def coefficients(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Per joint: viscous (N·m·s/rad), |gear| / ω₀ (s/rad), Coulomb up and down (N·m):
        what a compiled law needs to compute this friction (``kernels.arm_step``)."""
        return self._viscous, self._gear_w, self._pos, self._neg

    def __call__(self, qd: np.ndarray, out: np.ndarray) -> None:
        """The friction torque at ``qd`` into ``out``."""
        s, c = self._s, self._c
        np.multiply(qd, self._viscous, out=out)
        np.multiply(qd, self._gear_w, out=s)  # motor speed / ω₀
        np.tanh(s, out=s)
        np.maximum(s, 0.0, out=c)
        np.multiply(c, self._pos, out=c)
        np.add(out, c, out=out)
        np.minimum(s, 0.0, out=c)
        np.multiply(c, self._neg, out=c)  # both negative: a positive product
        np.subtract(out, c, out=out)


def central_differences(
    q_prev: np.ndarray,
    q: np.ndarray,
    q_next: np.ndarray,
    t_in: float,
    t_out: float,
    qd: np.ndarray,
    qdd: np.ndarray,
    scratch: np.ndarray,
) -> None:
    """q̇ and q̈ at ``q`` from its neighbours ``t_in`` s before and ``t_out`` s after, into
    ``qd`` and ``qdd`` (``scratch`` as long as ``q``: one entry per joint); no allocation."""
    np.subtract(q, q_prev, out=scratch)
    np.divide(scratch, t_in, out=scratch)  # mean speed over the segment ending at q
    np.subtract(q_next, q, out=qd)
    np.divide(qd, t_out, out=qd)  # mean speed over the one leaving it
    np.subtract(qd, scratch, out=qdd)
    np.divide(qdd, 0.5 * (t_in + t_out), out=qdd)
    # the speed at q: the two mean speeds weighted by the other segment's length
    np.multiply(qd, t_in, out=qd)
    np.multiply(scratch, t_out, out=scratch)
    np.add(qd, scratch, out=qd)
    np.divide(qd, t_in + t_out, out=qd)
