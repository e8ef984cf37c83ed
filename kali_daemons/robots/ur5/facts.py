"""The UR5's facts as typed constants: kinematics, link dynamics, limits, drives, servo gains.

Kinematics (standard DH) and link masses and centres of mass are Universal Robots' published
UR5 (CB3) table, where robotics-toolbox-python 1.5's ``UR5`` has three transcription slips
(``tests/robots/test_ur5.py`` checks they are the only differences).  UR publishes no inertia
tensors: each link is a uniform solid cylinder (``CYLINDERS``), an approximation that leaves
the gravity torques exact.  Joint limits ±2π (±π on the elbow, joint 3); speeds the data
sheet's, halved; drives plausible equivalents, not UR's (the package docstring).  Each
number's source: docs/internals/robots-hardware-plant.md.

Conventions: standard DH, ``A_i = Rz(θ_i)·Tz(d_i)·Tx(a_i)·Rx(α_i)``; centres of mass and
inertias in DH frame ``i``; arrays indexed by joint, 0..5; ``G`` the signed gear ratio.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Final

import numpy as np

from ..profile import FloatArray, IntArray, read_only, servo_gains

NJOINTS: Final = 6
GRAVITY: Final = 9.81  # m/s², as the PUMA's and the toolbox's
URDF_PATH: Final = Path(__file__).with_name("ur5.urdf")  # package data

# --------------------------------------------------------------------------------------------
# Kinematics: standard DH (UR's table, UR5)

D: Final[FloatArray] = read_only([0.089159, 0.0, 0.0, 0.10915, 0.09465, 0.0823])  # m
A: Final[FloatArray] = read_only([0.0, -0.425, -0.39225, 0.0, 0.0, 0.0])  # m
ALPHA: Final[FloatArray] = read_only([math.pi / 2, 0.0, 0.0, math.pi / 2, -math.pi / 2, 0.0])

Q_MIN: Final[FloatArray] = read_only([-2 * math.pi, -2 * math.pi, -math.pi] + [-2 * math.pi] * 3)
Q_MAX: Final[FloatArray] = read_only([2 * math.pi, 2 * math.pi, math.pi] + [2 * math.pi] * 3)
QD_MAX: Final[FloatArray] = read_only(np.radians([90.0] * NJOINTS))  # rad/s
QDD_MAX: Final[FloatArray] = read_only(np.radians([180.0] * NJOINTS))  # rad/s²

# Named poses (rad).  QZ is the stretched zero pose (elbow and wrist singular); Q_HOME is the
# usual UR home: upper arm up, forearm level, wrist down (shoulder 0.487 m, elbow 0.392 m and
# wrist 90° from their singularities; branch 'lun').
QZ: Final[FloatArray] = read_only([0.0] * NJOINTS)
Q_HOME: Final[FloatArray] = read_only(np.radians([0.0, -90.0, 90.0, -90.0, -90.0, 0.0]))

# --------------------------------------------------------------------------------------------
# Link dynamics: UR's masses and centres of mass (m, in DH frame i)

MASS: Final[FloatArray] = read_only([3.7, 8.393, 2.33, 1.219, 1.219, 0.1879])  # kg
COM: Final[FloatArray] = read_only(
    [
        [0.0, -0.02561, 0.00193],
        [0.2125, 0.0, 0.11336],
        [0.15, 0.0, 0.0265],
        [0.0, -0.0018, 0.01634],
        [0.0, 0.0018, 0.01634],
        [0.0, 0.0, -0.001159],
    ]
)

# The cylinder each link is approximated by: (axis of DH frame i it lies along, radius m,
# length m).  Link 1 is the shoulder housing around joint 2's axis, links 2 and 3 the upper
# arm and forearm tubes along their DH x axes (|a2|, |a3| long), links 4 and 5 the wrist
# housings around the next joint's axis, link 6 the flange disc.
CYLINDERS: Final = (
    ("z", 0.06, 0.15),
    ("x", 0.06, 0.425),
    ("x", 0.06, 0.39225),
    ("z", 0.06, 0.12),
    ("z", 0.06, 0.12),
    ("z", 0.0375, 0.0345),
)


def _cylinder_inertia(mass: float, axis: str, radius: float, length: float) -> list[float]:
    """Principal moments (Ixx, Iyy, Izz) of a uniform solid cylinder about its centre."""
    along = 0.5 * mass * radius**2
    across = mass * (3.0 * radius**2 + length**2) / 12.0
    return [along if axis == name else across for name in "xyz"]


INERTIA: Final[FloatArray] = read_only(  # kg·m², principal moments about the COM, DH frame i
    [_cylinder_inertia(float(m), *c) for m, c in zip(MASS, CYLINDERS, strict=True)]
)

# --------------------------------------------------------------------------------------------
# Drives (plausible equivalents on a McGill-style board, see the package docstring).  Joints
# 1-3 are the UR5's large joints (150 N·m), 4-6 the small ones (28 N·m).

_LARGE, _SMALL = 3, 3
G: Final[FloatArray] = read_only([101.0] * NJOINTS)  # harmonic drives, 101:1
KT: Final[FloatArray] = read_only([0.1] * _LARGE + [0.035] * _SMALL)  # N·m/A = V/(rad/s)
R_ARMATURE: Final[FloatArray] = read_only([0.3] * _LARGE + [1.0] * _SMALL)  # Ω
MAX_CURRENT: Final[FloatArray] = read_only([15.0] * _LARGE + [8.0] * _SMALL)  # A, peak
JM: Final[FloatArray] = read_only([4.0e-5] * _LARGE + [6.0e-6] * _SMALL)  # kg·m², rotor
COUNTS_PER_MOTOR_REV: Final[IntArray] = read_only([1000] * NJOINTS, np.int64)  # 250 lines × 4
# Joint side friction of the harmonic drive and motor, symmetric: about 4 % of the peak
# torque as Coulomb friction, viscous 2 and 0.4 N·m·s/rad.
VISCOUS: Final[FloatArray] = read_only([2.0] * _LARGE + [0.4] * _SMALL)  # N·m·s/rad
COULOMB_POS: Final[FloatArray] = read_only([6.0] * _LARGE + [1.2] * _SMALL)  # N·m
COULOMB_NEG: Final[FloatArray] = read_only(-COULOMB_POS)  # N·m
# Brake holding torque at the joint: the joint's peak torque, 2.7 times the largest gravity
# torque of joint 2 (GRAVITY_MAX) and far above the wrist's.
BRAKE_TORQUE: Final[FloatArray] = read_only([150.0] * _LARGE + [28.0] * _SMALL)  # N·m

AMP_GAIN_A_PER_V: Final = 2.5  # A per V of DAC output, the PUMA's amplifier scale
AMP_BANDWIDTH_HZ: Final = 500.0  # current loop, as the PUMA's
BUS_VOLTAGE: Final = 48.0  # V, the UR controller's DC bus
DAC_VOLTS: Final = 10.0  # ±10 V, 12 bits: 25 A of command range covers the 15 A peak

ARMATURE: Final[FloatArray] = read_only(JM * G**2)  # kg·m², reflected rotor inertia
PEAK_JOINT_TORQUE: Final[FloatArray] = read_only(MAX_CURRENT * KT * np.abs(G))  # N·m
MAX_JOINT_SPEED: Final[FloatArray] = read_only(BUS_VOLTAGE / KT / np.abs(G))  # rad/s
COUNTS_PER_JOINT_RAD: Final[FloatArray] = read_only(
    COUNTS_PER_MOTOR_REV * np.abs(G) / (2 * math.pi)
)

# --------------------------------------------------------------------------------------------
# Default servo gains, by the PUMA's rule (robots/puma560/facts.py) as robots/profile.py
# servo_gains writes it out: kp = J·ωn², kv = 2ζ·J·ωn − viscous, ki = 20 s⁻¹ · kp,
# integration_reset = 1.2 · (largest gravity + Coulomb) rounded up to a whole N·m,
# integration_band 0.01 rad, ωn raised where the band needs it; ζ = 0.7, ωn = 50 rad/s on
# joints 1-3 and 60 rad/s on 4-6 (the PUMA's values).  J is the joint-side inertia at Q_HOME
# with the armature (the diagonal of Pinocchio's crba on robots/ur5/ur5.urdf with ARMATURE set),
# GRAVITY_MAX the largest gravity torque over the joint ranges (joint 2 with the arm
# stretched level); tests/robots/test_ur5.py recomputes both.  The raised ωn:
# docs/internals/robots-hardware-plant.md.

J_HOME: Final[FloatArray] = read_only([1.282, 2.497, 1.118, 0.0805, 0.0654, 0.0613])  # kg·m²
GRAVITY_MAX: Final[FloatArray] = read_only([0.0, 55.25, 17.15, 1.52, 0.34, 0.0])  # N·m
WN: Final[FloatArray] = read_only([50.0] * _LARGE + [60.0] * _SMALL)  # rad/s
ZETA: Final = 0.7


PID_DEFAULTS, PD_DEFAULTS = servo_gains(
    J_HOME, WN, ZETA, VISCOUS, GRAVITY_MAX + np.maximum(COULOMB_POS, -COULOMB_NEG)
)

# The arm's calibration sheet: each joint's index-pulse motor angle, rad in [0, 2π), drawn
# once with numpy.random.default_rng(5).uniform(0, 2π, 6) and written down here.
INDEX_PHASES: Final[FloatArray] = read_only(
    [5.057983, 5.076442, 3.237886, 1.795743, 0.338857, 2.408778]
)
