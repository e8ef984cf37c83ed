"""The Franka Emika Panda's facts as typed constants: kinematics, dynamics, limits, drives, gains.

Kinematics, joint limits and the maker's speed and torque limits are Franka's published ones
(its modified-DH table, as robotics-toolbox-python 1.5 and ``franka_description`` carry it;
the flange is frame 8, 0.107 m past joint 7, without the hand).  Link masses, centres of mass,
inertias and joint friction are Gaz et al.'s identification (IEEE RA-L 4(4), 2019), whose
friction model has no viscous term.  The trajectory generator plans with half the maker's
speeds; the drives are plausible equivalents, not Franka's (the package docstring).  Each
number's source: docs/internals/robots-hardware-plant.md.

Conventions: modified DH (Craig), ``T_i = Rx(α_{i−1})·Tx(a_{i−1})·Rz(θ_i)·Tz(d_i)``, row i of
``A``/``ALPHA`` holding a_{i−1}/α_{i−1} as Franka prints them; arrays indexed by joint, 0..6;
inertia tensors about the centre of mass in link i's frame, (Ixx, Iyy, Izz, Ixy, Ixz, Iyz).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Final

import numpy as np

from ..profile import FloatArray, IntArray, read_only, servo_gains

NJOINTS: Final = 7
GRAVITY: Final = 9.81  # m/s²
URDF_PATH: Final = Path(__file__).with_name("panda.urdf")  # package data

# --------------------------------------------------------------------------------------------
# Kinematics: modified DH (Franka)

A: Final[FloatArray] = read_only([0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088])  # m, a_{i-1}
D: Final[FloatArray] = read_only([0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0])  # m
_H = math.pi / 2
ALPHA: Final[FloatArray] = read_only([0.0, -_H, _H, _H, -_H, _H, _H])  # rad, α_{i-1}
D_FLANGE: Final = 0.107  # m, frame 8 (the flange) along z7

Q_MIN: Final[FloatArray] = read_only(
    [-2.8973, -1.7628, -2.8973, -3.0718, -2.8973, -0.0175, -2.8973]
)
Q_MAX: Final[FloatArray] = read_only([2.8973, 1.7628, 2.8973, -0.0698, 2.8973, 3.7525, 2.8973])
QD_MAKER: Final[FloatArray] = read_only([2.175] * 4 + [2.61] * 3)  # rad/s, Franka's limits
TAU_MAKER: Final[FloatArray] = read_only([87.0] * 4 + [12.0] * 3)  # N·m, Franka's limits
QD_MAX: Final[FloatArray] = read_only(QD_MAKER / 2.0)  # rad/s: 62°/s and 75°/s
QDD_MAX: Final[FloatArray] = read_only(2.0 * QD_MAX)  # rad/s²

# Named poses (rad): QZ all zero (joint 4 is outside its limits there); Q_HOME the toolbox's
# 'qr' ready pose, flange down in front of the base (smallest singular value of the 6×7
# Jacobian 0.21, of the 6×6 with joint 3 held 0.21).
QZ: Final[FloatArray] = read_only([0.0] * NJOINTS)
Q_HOME: Final[FloatArray] = read_only([0.0, -0.3, 0.0, -2.2, 0.0, 2.0, math.pi / 4])

# --------------------------------------------------------------------------------------------
# Link dynamics (Gaz et al. 2019): mass kg, centre of mass m, inertia kg·m² about the COM

MASS: Final[FloatArray] = read_only(
    [4.970684, 0.646926, 3.228604, 3.587895, 1.225946, 1.666555, 0.735522]
)
COM: Final[FloatArray] = read_only(
    [
        [0.003875, 0.002081, -0.04762],
        [-0.003141, -0.02872, 0.003495],
        [0.027518, 0.039252, -0.066502],
        [-0.05317, 0.104419, 0.027454],
        [-0.011953, 0.041065, -0.038437],
        [0.060149, -0.014117, -0.010517],
        [0.010517, -0.004252, 0.061597],
    ]
)
INERTIA: Final[FloatArray] = read_only(  # Ixx, Iyy, Izz, Ixy, Ixz, Iyz
    [
        [0.70337, 0.70661, 0.009117, -0.000139, 0.006772, 0.019169],
        [0.007962, 0.02811, 0.025995, -0.003925, 0.010254, 0.000704],
        [0.037242, 0.036155, 0.01083, -0.004761, -0.011396, -0.012805],
        [0.025853, 0.019552, 0.028323, 0.007796, -0.001332, 0.008641],
        [0.035549, 0.029474, 0.008627, -0.002117, -0.004037, 0.000229],
        [0.001964, 0.004354, 0.005433, 0.000109, -0.001158, 0.000341],
        [0.012516, 0.010027, 0.004815, -0.000428, -0.001196, -0.000741],
    ]
)

# Gaz et al.'s friction parameters per joint: φ1 (N·m), φ2 (s/rad), φ3 (rad/s).
FRICTION_PHI1: Final[FloatArray] = read_only(
    [0.54615, 0.87224, 0.64068, 1.2794, 0.83904, 0.30301, 0.56489]
)
FRICTION_PHI2: Final[FloatArray] = read_only(
    [5.1181, 9.0657, 10.136, 5.5903, 8.3469, 17.133, 10.336]
)
FRICTION_PHI3: Final[FloatArray] = read_only(
    [0.039533, 0.025882, -0.04607, 0.036194, 0.026226, -0.021047, 0.0035526]
)
_AT_REST: Final = FRICTION_PHI1 / (1.0 + np.exp(-FRICTION_PHI2 * FRICTION_PHI3))
COULOMB_POS: Final[FloatArray] = read_only(FRICTION_PHI1 - _AT_REST)  # N·m, τ_f(+∞)
COULOMB_NEG: Final[FloatArray] = read_only(-_AT_REST)  # N·m, τ_f(−∞)
VISCOUS: Final[FloatArray] = read_only([0.0] * NJOINTS)  # N·m·s/rad: none in Gaz's model

# --------------------------------------------------------------------------------------------
# Drives (plausible equivalents on a McGill-style board, see the package docstring).

_LARGE, _SMALL = 4, 3
G: Final[FloatArray] = read_only([100.0] * NJOINTS)  # harmonic drives, 100:1
KT: Final[FloatArray] = read_only([0.07] * _LARGE + [0.03] * _SMALL)  # N·m/A = V/(rad/s)
R_ARMATURE: Final[FloatArray] = read_only([0.4] * _LARGE + [1.2] * _SMALL)  # Ω
MAX_CURRENT: Final[FloatArray] = read_only([12.5] * _LARGE + [4.0] * _SMALL)  # A, peak
JM: Final[FloatArray] = read_only([3.0e-5] * _LARGE + [5.0e-6] * _SMALL)  # kg·m², rotor
COUNTS_PER_MOTOR_REV: Final[IntArray] = read_only([1000] * NJOINTS, np.int64)  # 250 lines × 4
# Brakes hold the joint's torque limit: 1.7 times the largest gravity torque (joint 2).
BRAKE_TORQUE: Final[FloatArray] = read_only(TAU_MAKER)  # N·m

AMP_GAIN_A_PER_V: Final = 2.5  # A per V, the PUMA's amplifier scale
AMP_BANDWIDTH_HZ: Final = 500.0
BUS_VOLTAGE: Final = 48.0  # V
DAC_VOLTS: Final = 10.0

ARMATURE: Final[FloatArray] = read_only(JM * G**2)  # kg·m²
PEAK_JOINT_TORQUE: Final[FloatArray] = read_only(MAX_CURRENT * KT * np.abs(G))  # N·m
MAX_JOINT_SPEED: Final[FloatArray] = read_only(BUS_VOLTAGE / KT / np.abs(G))  # rad/s
COUNTS_PER_JOINT_RAD: Final[FloatArray] = read_only(
    COUNTS_PER_MOTOR_REV * np.abs(G) / (2 * math.pi)
)

# --------------------------------------------------------------------------------------------
# Default servo gains, by the PUMA's rule as robots/profile.py servo_gains writes it out:
# kp = J·ωn², kv = 2ζ·J·ωn − viscous, ki = 20 s⁻¹ · kp, integration_reset = 1.2 · (largest
# gravity + Coulomb) rounded up to a whole N·m, integration_band 0.01 rad; ζ = 0.7, ωn = 50
# rad/s on joints 1-4 and 60 rad/s on 5-7, raised where kp · 0.01 rad < 2.5 · reset until it
# is not (the raised values: docs/internals/robots-hardware-plant.md).  J is the diagonal of
# Pinocchio's crba at Q_HOME on robots/panda/panda.urdf with ARMATURE set, GRAVITY_MAX the largest
# gravity torque over the joint ranges; tests/robots/test_panda.py recomputes both.

J_HOME: Final[FloatArray] = read_only(  # kg·m²
    [1.099, 2.005, 1.357, 1.112, 0.07404, 0.08256, 0.05491]
)
GRAVITY_MAX: Final[FloatArray] = read_only(  # N·m
    [0.0, 50.56, 25.98, 19.43, 2.07, 1.82, 0.08]
)
WN: Final[FloatArray] = read_only([50.0] * _LARGE + [60.0] * _SMALL)  # rad/s
ZETA: Final = 0.7


PID_DEFAULTS, PD_DEFAULTS = servo_gains(
    J_HOME, WN, ZETA, VISCOUS, GRAVITY_MAX + np.maximum(COULOMB_POS, -COULOMB_NEG)
)

# The arm's calibration sheet: each joint's index-pulse motor angle, rad in [0, 2π), drawn
# once with numpy.random.default_rng(7).uniform(0, 2π, 7) and written down here.
INDEX_PHASES: Final[FloatArray] = read_only(
    [3.927591, 5.637361, 4.873777, 1.415019, 1.886, 5.488698, 0.033083]
)
