"""What a robot type declares, in one place (thesis 3.1, 3.5: the driver "a set of functions
entered in a table" per robot type; issue 25).

A robot type is data plus a few functions, the way Drake and ros2_control describe robots:
a URDF, a joint count, limits, a drive, kinematics, default servo gains and a calibration
sheet.  Each type is one package under ``kali_daemons/robots/`` exposing ``ROBOT``, a
``RobotType``; ``kali_daemons.robots.robot_type(name)`` finds it by the ``robots[].model``
name of the config.  Nothing outside the type's package knows which arm it drives.

Conventions every type keeps:

- Arrays are indexed by joint, ``0 .. n_joints - 1``; every per-joint array has
  ``n_joints`` entries and is read-only.
- The URDF's revolute joints are named ``j1 .. jN`` from base to tip, and its last link is
  named ``flange`` (the mounting flange, where tools and the bar grasp attach).  The base
  link is at the robot's base frame (``robots[].base_xyz`` / ``base_yaw_deg`` place it).
- ``G`` is the signed gear ratio: motor angle = G · joint angle.  Motor-side quantities
  (rotor inertia, motor friction) are converted to the joint side through it.
- Angles in rad, lengths in m, torques in N·m at the joint unless named motor-side.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

MAX_JOINTS = 8  # one McGill board: 8 counter and 8 DAC channels (thesis appendix C)


def read_only(values: object, dtype: type = np.float64) -> npt.NDArray:
    """A read-only copy: a robot type's facts, nobody changes them in place."""
    arr = np.array(values, dtype=dtype)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Drive:
    """The drive train of every joint: motor, amplifier, gearbox and encoder.

    Per-joint arrays have ``n_joints`` entries; scalars hold for every joint (one amplifier
    and DAC model per board).
    """

    gear: FloatArray  # signed gear ratio G: motor angle = G · joint angle
    counts_per_rev: IntArray  # encoder counts per motor revolution (one index pulse per rev)
    kt: FloatArray  # N·m/A, motor torque constant (= back-EMF V/(rad/s))
    r_armature: FloatArray  # Ω, motor armature resistance
    max_current: FloatArray  # A, motor peak current (the amplifier clips at it)
    rotor_inertia: FloatArray  # kg·m², motor side (reflected: G² · it)
    viscous: FloatArray  # N·m·s/rad, joint side viscous friction
    coulomb_pos: FloatArray  # N·m, joint side Coulomb friction for qd > 0 (>= 0)
    coulomb_neg: FloatArray  # N·m, joint side Coulomb friction for qd < 0 (<= 0)
    brake_torque: FloatArray  # N·m, joint side holding torque of the brake
    amp_gain_a_per_v: float  # A of motor current per V of DAC output
    amp_bandwidth_hz: float  # current loop bandwidth
    bus_voltage: float  # V: R·i + Kt·ω_m must stay within ± this
    dac_volts: float  # the DAC's full scale is ± this

    @property
    def armature(self) -> FloatArray:
        """Reflected rotor inertia at the joint, kg·m² (MuJoCo armature, Pinocchio armature)."""
        return read_only(self.rotor_inertia * self.gear**2)

    @property
    def peak_joint_torque(self) -> FloatArray:
        """N·m at the joint at the motor's peak current."""
        return read_only(self.max_current * self.kt * np.abs(self.gear))


class Kinematics(Protocol):
    """A robot type's forward and inverse kinematics of the flange in its base frame.

    ``configs`` lists the type's inverse-kinematics branches (the PUMA's and the UR5's eight:
    arm, elbow, wrist); a type without branches has one.  A branch's index in ``configs``
    is how requests carry it through the arena.  Each branch prints as a short string and
    ``parse_config`` reads it back.

    ``fkine`` and ``ikine`` with ``out`` given, ``config_of`` and ``singular`` run inside the
    trajectory generator's cycle: no numpy allocation on the success path.
    """

    configs: tuple[object, ...]

    def fkine(self, q: FloatArray, out: FloatArray | None = None) -> FloatArray:
        """The flange pose (4×4) in the base frame for joint angles ``q``."""
        ...

    def ikine(
        self,
        t6: FloatArray,
        config: object,
        q_ref: FloatArray | None = None,
        out: FloatArray | None = None,
        redundancy: float | None = None,
    ) -> FloatArray:
        """Joint angles within the limits that put the flange at ``t6`` in branch ``config``,
        nearest ``q_ref``.  ``redundancy``: for a redundant arm, the value of the type's
        redundancy parameter (None: keep ``q_ref``'s).  ``KinematicsError`` if none."""
        ...

    def config_of(self, q: FloatArray) -> object:
        """The branch joint angles ``q`` are in (one of ``configs``)."""
        ...

    def parse_config(self, text: str) -> object:
        """A branch from its string; ``KinematicsError`` naming the accepted forms."""
        ...

    def singular(self, q: FloatArray) -> str | None:
        """Why ``q`` is too near a singularity for a Cartesian path, or None if it is not."""
        ...


@dataclass(frozen=True)
class RobotType:
    """One robot type: everything Kali knows about an arm model, found by ``name``."""

    name: str  # the config's robots[].model
    description: str  # one line: maker, model and where the numbers come from
    urdf: Path  # joints j1..jN, a 'flange' link
    n_joints: int  # 1 .. MAX_JOINTS
    q_min: FloatArray  # rad
    q_max: FloatArray  # rad
    qd_max: FloatArray  # rad/s, what the trajectory generator plans with
    qdd_max: FloatArray  # rad/s², likewise
    q_home: FloatArray  # rad: the pose the simulated arm starts in, and a reference pose
    drive: Drive
    kinematics: Kinematics
    pid_defaults: tuple[dict[str, float], ...]  # per joint: the built-in PID's init data
    pd_defaults: tuple[dict[str, float], ...]  # per joint: the built-in PD's
    # The calibration sheet (thesis 3.5.1, C.3): each joint's index-pulse motor angle, rad in
    # [0, 2π), measured once per arm; a robot's config may name its own.
    index_phases: FloatArray = field(default_factory=lambda: read_only([]))
    gravity: float = 9.81  # m/s²
