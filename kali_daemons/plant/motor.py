"""Motors and PWM amplifiers of every joint (thesis table 3.1 and 3.7.2), from each arm's
robot type's drive (``kali_daemons.robots``).

Per joint, vectorised over all arms: DAC volts → commanded current (the amplifier's A/V,
clipped at the motor's peak current) → a first-order current loop whose output the bus
limits (R·i + Kt·ω_m within ± the bus) → joint torque G·Kt·i.  The loop itself runs inside
MuJoCo at every substep (``model.build_world``); once per plant cycle this model sets its
command and range, [0, 0] while the amplifier is off.  Friction: the symmetric Coulomb and
the viscous parts go to MuJoCo as constraints (stiction holds exactly), the asymmetric
remainder is a torque here; a brake raises the joint's frictionloss to its holding torque.
The plant runs a cycle compiled (``MotorBank.compiled``: ``csrc/plant.c``'s ``kali_motors``);
``drive_reference`` is what it equals.  In full: docs/internals/robots-hardware-plant.md.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from ..core.kernels import Kernel
from ..robots import RobotType
from ..robots.profile import FRICTION_SMOOTHING_RAD_S


class MotorBank:
    """The amplifiers and motors of the arms of ``types`` (one robot type per arm), as the
    plant's MuJoCo actuators see them (their activations are the motor currents).

    ``cycle`` runs inside the plant's cycle: every array is preallocated, no allocation.
    """

    def __init__(self, types: list[RobotType]) -> None:
        def tile(field: str) -> np.ndarray:
            return np.concatenate([np.asarray(getattr(t.drive, field), float) for t in types])

        self.n = sum(t.n_joints for t in types)
        self.gear = tile("gear")
        self.kt = tile("kt")
        self.r = tile("r_armature")
        self.i_max = tile("max_current")
        # motor side Coulomb levels, |G|·Tc at the joint
        tc_pos = tile("coulomb_pos") / np.abs(self.gear)
        tc_neg = np.abs(tile("coulomb_neg")) / np.abs(self.gear)
        sym = np.minimum(tc_pos, tc_neg)
        self.extra_pos = tc_pos - sym  # motor-side Coulomb beyond the symmetric part
        self.extra_neg = tc_neg - sym
        self.frictionloss = np.abs(self.gear) * sym  # joint side, for MuJoCo
        self.damping = tile("viscous")  # joint side, for MuJoCo
        self.brake = tile("brake_torque")
        self.gain = np.concatenate([[t.drive.amp_gain_a_per_v] * t.n_joints for t in types])
        self.v_bus = np.concatenate([[t.drive.bus_voltage] * t.n_joints for t in types])
        self.enabled = np.zeros(self.n)  # 1.0 where the joint's amplifier is on
        self.ctrl = np.zeros(self.n)  # A: the current the loop drives toward
        self.range = np.zeros((self.n, 2))  # A: [low, high] the current may take
        self.friction = np.zeros(self.n)  # N·m at the joint: the asymmetric Coulomb remainder
        # precomputed per-joint constants, so a cycle is a handful of array operations
        self._vbus_r = self.v_bus / self.r  # A
        self._kt_r = self.kt / self.r  # A per rad/s of motor speed (back-EMF)
        self.gkt = self.gear * self.kt  # joint torque per A
        self._w_scale = self.gear / FRICTION_SMOOTHING_RAD_S
        self._g_extra_pos = self.gear * self.extra_pos
        self._g_extra_neg = self.gear * self.extra_neg
        self._a = np.zeros(self.n)
        self._b = np.zeros(self.n)

    def cycle(self, volts: np.ndarray, qd: np.ndarray) -> None:
        """Once per plant cycle, for DAC ``volts`` at joint speeds ``qd``: fill ``ctrl``,
        ``range`` and ``friction``.  Inside the cycle: preallocated arrays only.
        """
        a, b = self._a, self._b
        lo, hi = self.range[:, 0], self.range[:, 1]
        np.multiply(qd, self.gear, out=a)  # motor speed ω_m
        np.multiply(a, self._kt_r, out=b)  # back-EMF / R
        # the bus voltage limits the current: (−Vbus − Kt ω)/R ≤ i ≤ (Vbus − Kt ω)/R,
        # and the motor's peak current bounds it too
        np.subtract(self._vbus_r, b, out=hi)
        np.minimum(hi, self.i_max, out=hi)
        np.add(self._vbus_r, b, out=lo)
        np.negative(lo, out=lo)
        np.maximum(lo, -self.i_max, out=lo)
        np.maximum(hi, lo, out=hi)
        np.multiply(lo, self.enabled, out=lo)  # an amplifier that is off: [0, 0]
        np.multiply(hi, self.enabled, out=hi)
        np.multiply(volts, self.gain, out=self.ctrl)
        np.maximum(self.ctrl, lo, out=self.ctrl)  # np.clip's wrapper costs 2 µs more
        np.minimum(self.ctrl, hi, out=self.ctrl)
        # asymmetric Coulomb remainder, opposing the motor's motion
        np.multiply(qd, self._w_scale, out=a)
        np.tanh(a, out=a)
        np.maximum(a, 0.0, out=b)
        np.minimum(a, 0.0, out=a)
        np.multiply(b, self._g_extra_pos, out=b)
        np.multiply(a, self._g_extra_neg, out=a)
        np.subtract(a, b, out=self.friction)

    def compiled(self, volts: np.ndarray, qd: np.ndarray, current: np.ndarray, mj: Drive) -> Kernel:
        """``drive_reference`` compiled (``csrc/plant.c``'s ``kali_motors``), bound to the DAC
        ``volts``, joint speeds ``qd`` and motor ``current`` (flat, float64, never moving) and
        to MuJoCo's arrays ``mj``: each call is one cycle of it.  Outside the cycle."""
        flat = {
            "volts": volts, "qd": qd, "enabled": self.enabled, "current": current,
            "gear": self.gear, "kt_r": self._kt_r, "vbus_r": self._vbus_r, "i_max": self.i_max,
            "gain": self.gain, "w_scale": self._w_scale, "g_extra_pos": self._g_extra_pos,
            "g_extra_neg": self._g_extra_neg, "ctrl": self.ctrl, "range": self.range,
            "friction": self.friction, "mj_actrange": mj.actrange, "mj_ctrl": mj.ctrl,
            "mj_act": mj.act, "mj_qfrc": mj.qfrc,
        }  # fmt: skip
        for name, a in flat.items():
            assert a.dtype == np.float64 and a.flags.c_contiguous, f"motors: {name} {a.dtype}"
        for name in ("volts", "qd", "enabled", "current", "ctrl", "friction"):
            assert flat[name].shape == (self.n,), f"motors: {name} {flat[name].shape}"
        index = {
            name: np.ascontiguousarray(getattr(mj, name), dtype=np.int64)
            for name in ("acts", "act_adr", "dofs")
        }
        assert mj.actrange.shape[1:] == (2,) and mj.act.ndim == mj.ctrl.ndim == mj.qfrc.ndim == 1
        assert int(index["acts"].max()) < len(mj.ctrl) == len(mj.actrange)
        assert int(index["act_adr"].max()) < len(mj.act) and int(index["dofs"].max()) < len(mj.qfrc)
        arrays = {**flat, **index}
        return Kernel(
            "kali_motors",
            tuple(arrays.values()),
            n=self.n,
            **{name: a.ctypes.data for name, a in arrays.items()},
        )

    def joint_frictionloss(self, braked: np.ndarray, out: np.ndarray) -> None:
        """MuJoCo frictionloss per joint: the brake's holding torque where ``braked`` (bool).

        Called when a brake changes state, not every step.
        """
        np.copyto(out, self.frictionloss)
        np.copyto(out, self.brake, where=braked)


class Drive(NamedTuple):
    """Where the motors' cycle goes in MuJoCo: each joint's actuator (``acts``), its
    activation (``act_adr``: the motor current) and its dof (``dofs``), flat; and the model's
    ``actuator_actrange`` and the data's ``ctrl``, ``act`` and ``qfrc_applied``."""

    acts: np.ndarray
    act_adr: np.ndarray
    dofs: np.ndarray
    actrange: np.ndarray
    ctrl: np.ndarray
    act: np.ndarray
    qfrc: np.ndarray


def drive_reference(
    bank: MotorBank, volts: np.ndarray, qd: np.ndarray, current: np.ndarray, mj: Drive
) -> None:
    """One plant cycle of the amplifiers and motors (``MotorBank.cycle``) and what MuJoCo
    gets from them: each actuator's current range and control, each activation (the motor
    current) cut into its range at once (a disabled amplifier cuts its current), each dof's
    asymmetric Coulomb remainder.  ``kali_motors``' reference (the tests'); it allocates."""
    bank.cycle(volts, qd)
    mj.actrange[mj.acts] = bank.range
    mj.ctrl[mj.acts] = bank.ctrl
    mj.act[mj.act_adr] = np.minimum(np.maximum(current, bank.range[:, 0]), bank.range[:, 1])
    mj.qfrc[mj.dofs] = bank.friction
