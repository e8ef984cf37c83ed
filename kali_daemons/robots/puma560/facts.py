"""The PUMA 560's facts as typed constants: kinematics, dynamics, motors, amplifiers, encoders.

Transcribed from ``shared/puma560.md``: kinematics and link and motor dynamics from
robotics-toolbox-python's ``Puma560`` (Corke & Armstrong-Hélouvry, ICRA 1994) with the
pedestal in d1 = 0.6718 m; joint limits from Wang & Chen 1991; motors, amplifiers and DAC from
the thesis, table 3.1 and section 3.7.2; encoders from its appendix C.  Standard DH; arrays
indexed by joint, 0..5; ``JM``, ``B_MOTOR``, ``TC_POS``/``TC_NEG`` are motor side, and
``ARMATURE``, ``VISCOUS``, ``COULOMB_*`` their joint-side equivalents through ``G``.

``MASS``/``INERTIA`` differ from the published ``MASS_RAW``/``INERTIA_RAW`` on links 1 and 3
only: the smallest changes that make them physical rigid bodies, which MuJoCo requires (why
these, in docs/internals/robots-hardware-plant.md).  This module only states facts;
``scripts/gen_puma560_urdf.py`` turns them into ``robots/puma560/puma560.urdf``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Final

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]

NJOINTS: Final = 6
GRAVITY: Final = 9.81  # m/s², as in robotics-toolbox-python, so the gravity torques compare

URDF_PATH: Final = Path(__file__).with_name("puma560.urdf")  # package data


def _ro(values: object, dtype: type = np.float64) -> npt.NDArray:
    """A read-only numpy array: these are facts, nobody should change them in place."""
    arr: npt.NDArray = np.array(values, dtype=dtype)
    arr.setflags(write=False)
    return arr


# --------------------------------------------------------------------------------------------
# Kinematics: standard DH (puma560.md "Kinematics")

D: Final[FloatArray] = _ro([0.6718, 0.0, 0.15005, 0.4318, 0.0, 0.0])  # m; d1 with pedestal
A: Final[FloatArray] = _ro([0.0, 0.4318, 0.0203, 0.0, 0.0, 0.0])  # m
ALPHA: Final[FloatArray] = _ro(np.radians([90.0, 0.0, -90.0, 90.0, -90.0, 0.0]))  # rad

Q_MIN: Final[FloatArray] = _ro(np.radians([-160.0, -45.0, -225.0, -110.0, -100.0, -266.0]))
Q_MAX: Final[FloatArray] = _ro(np.radians([160.0, 225.0, 45.0, 170.0, 100.0, 266.0]))

# Named poses (rad).  QZ, QR and QS are wrist-singular (θ5 = 0); QN is not.
# Joint speed and acceleration limits the trajectory generator plans with (not in puma560.md:
# chosen well inside what the motors can do at the 40 V bus, so the PID alone tracks them to
# a degree or so without feed-forward).
QD_MAX: Final[FloatArray] = _ro(np.radians([60.0, 60.0, 60.0, 120.0, 120.0, 120.0]))  # rad/s
QDD_MAX: Final[FloatArray] = _ro(np.radians([120.0, 120.0, 120.0, 240.0, 240.0, 240.0]))  # rad/s²

QZ: Final[FloatArray] = _ro([0.0, 0.0, 0.0, 0.0, 0.0, 0.0])  # zero: the 'L' shape
QR: Final[FloatArray] = _ro(np.radians([0.0, 90.0, -90.0, 0.0, 0.0, 0.0]))  # ready: arm vertical
QS: Final[FloatArray] = _ro(np.radians([0.0, 0.0, -90.0, 0.0, 0.0, 0.0]))  # stretched along x
QN: Final[FloatArray] = _ro(np.radians([0.0, 45.0, -180.0, 0.0, 45.0, 0.0]))  # nominal

# Flange position at QN as puma560.md prints it (m, base frame).  The DH table gives
# (0.59630, -0.15005, 0.65745): the printed z looks like the toolbox's 4-digit 0.6575
# (with its d1 = 0.67183) rounded a second time; it is good to 1 mm, not 0.5 mm.
FLANGE_QN: Final[FloatArray] = _ro([0.596, -0.150, 0.658])

# --------------------------------------------------------------------------------------------
# Link dynamics (puma560.md "Dynamics"): centre of mass r and inertia about it, in DH frame i

# The table as published.  Two rows are not physical rigid bodies (see below).
MASS_RAW: Final[FloatArray] = _ro([0.0, 17.4, 4.8, 0.82, 0.34, 0.09])  # kg
COM: Final[FloatArray] = _ro(  # m, in DH frame i
    [
        [0.0, 0.0, 0.0],
        [-0.3638, 0.006, 0.2275],
        [-0.0203, -0.0141, 0.070],
        [0.0, 0.019, 0.0],
        [0.0, 0.0, 0.0],
        [0.0, 0.0, 0.032],
    ]
)
INERTIA_RAW: Final[FloatArray] = _ro(  # kg·m², principal moments Ixx, Iyy, Izz about the COM
    [
        [0.0, 0.35, 0.0],
        [0.13, 0.524, 0.539],
        [0.066, 0.086, 0.0125],
        [1.8e-3, 1.3e-3, 1.8e-3],
        [0.3e-3, 0.4e-3, 0.3e-3],
        [0.15e-3, 0.15e-3, 0.04e-3],
    ]
)

# The two minimal fixes (docs/internals/robots-hardware-plant.md says why these).
LINK1_MASS: Final = 1e-3  # kg
LINK1_IXX_IZZ: Final = 0.175  # kg·m², = 0.35 / 2
LINK3_IXX: Final = 0.0735  # kg·m², = 0.086 - 0.0125

MASS: Final[FloatArray] = _ro([LINK1_MASS, *MASS_RAW[1:]])  # kg, used everywhere
INERTIA: Final[FloatArray] = _ro(  # kg·m², used everywhere
    [
        [LINK1_IXX_IZZ, INERTIA_RAW[0, 1], LINK1_IXX_IZZ],
        INERTIA_RAW[1],
        [LINK3_IXX, INERTIA_RAW[2, 1], INERTIA_RAW[2, 2]],
        *INERTIA_RAW[3:],
    ]
)

# --------------------------------------------------------------------------------------------
# Drive train (puma560.md "Dynamics"); motor side unless named otherwise

JM: Final[FloatArray] = _ro([200e-6, 200e-6, 200e-6, 33e-6, 33e-6, 33e-6])  # kg·m², rotor
G: Final[FloatArray] = _ro([-62.6111, 107.815, -53.7063, 76.0364, 71.923, 76.686])  # signed
B_MOTOR: Final[FloatArray] = _ro([1.48e-3, 0.817e-3, 1.38e-3, 71.2e-6, 82.6e-6, 36.7e-6])  # N·m·s
TC_POS: Final[FloatArray] = _ro([0.395, 0.126, 0.132, 11.2e-3, 9.26e-3, 3.96e-3])  # N·m, qd > 0
TC_NEG: Final[FloatArray] = _ro([-0.435, -0.071, -0.105, -16.9e-3, -14.5e-3, -10.5e-3])  # qd < 0

# Joint side: reflected rotor inertia, viscous and Coulomb friction.
ARMATURE: Final[FloatArray] = _ro(JM * G**2)  # kg·m²; MuJoCo dof_armature, Pinocchio armature
VISCOUS: Final[FloatArray] = _ro(G**2 * B_MOTOR)  # N·m·s/rad
COULOMB_POS: Final[FloatArray] = _ro(np.abs(G) * TC_POS)  # N·m, friction level for qd > 0
COULOMB_NEG: Final[FloatArray] = _ro(np.abs(G) * TC_NEG)  # N·m (negative), for qd < 0

# --------------------------------------------------------------------------------------------
# Motors (thesis table 3.1): large motors on joints 1-3, small on 4-6 (as the rotor
# inertias say: 200e-6 vs 33e-6 kg·m²)

_LARGE, _SMALL = 3, 3
PEAK_TORQUE: Final[FloatArray] = _ro([2.12] * _LARGE + [0.339] * _SMALL)  # N·m (300/48 oz-in)
CONT_TORQUE: Final[FloatArray] = _ro([1.06] * _LARGE + [0.170] * _SMALL)  # N·m (150/24 oz-in)
MAX_CURRENT: Final[FloatArray] = _ro([8.0] * _LARGE + [3.72] * _SMALL)  # A, at peak torque
KT: Final[FloatArray] = _ro([0.261] * _LARGE + [0.091] * _SMALL)  # N·m/A = V/(rad/s) back-EMF
R_ARMATURE: Final[FloatArray] = _ro([1.6] * _LARGE + [3.9] * _SMALL)  # Ω, ±12.5 %
L_ARMATURE: Final[FloatArray] = _ro([2.6e-3] * _LARGE + [2.3e-3] * _SMALL)  # H, ±30 %

# Holding torque of the brakes at the joint, N·m.  Not in puma560.md: chosen well above the
# largest gravity torque of each joint (37.5 N·m on joint 2) so an engaged brake holds the arm.
BRAKE_TORQUE: Final[FloatArray] = _ro([150.0, 150.0, 80.0, 20.0, 20.0, 20.0])

# Amplifiers (Contraves CSR NC600 PWM, thesis 3.7.2).
AMP_GAIN_A_PER_V: Final = 2.5  # A per volt of DAC output
AMP_BANDWIDTH_HZ: Final = 500.0  # current loop
AMP_PEAK_CURRENT: Final = 25.0  # A (±); ±12.5 A RMS continuous
AMP_INPUT_V: Final = 10.0  # V (±)
AMP_SWITCHING_HZ: Final = 5000.0
BUS_VOLTAGE: Final = 40.0  # V

# DAC board: 8 channels, 12 bits over ±10 V.
DAC_BITS: Final = 12
DAC_VOLTS: Final = 10.0  # full scale is ±DAC_VOLTS
DAC_CHANNELS: Final = 8

# Encoders (appendix C): on the motor shafts, one index pulse per motor revolution.
COUNTS_PER_MOTOR_REV: Final[IntArray] = _ro([1000, 800, 1000, 1000, 1000, 500], np.int64)

# Joint-side limits derived from the motors, used for the URDF's effort and velocity limits:
# peak motor torque through the gearbox, and the speed at which back-EMF eats the whole bus.
PEAK_JOINT_TORQUE: Final[FloatArray] = _ro(PEAK_TORQUE * np.abs(G))  # N·m
MAX_JOINT_SPEED: Final[FloatArray] = _ro(BUS_VOLTAGE / KT / np.abs(G))  # rad/s

# --------------------------------------------------------------------------------------------
# Reference values for tests (puma560.md, with d1 = 0.6718 and g = 9.81 m/s²): the joint
# torque that holds the arm still at QZ and QN, printed to the precision given here.

GRAVITY_QZ: Final[FloatArray] = _ro([0.0, 37.48, 0.249, 0.0, 0.0, 0.0])  # N·m
GRAVITY_QN: Final[FloatArray] = _ro([0.0, 31.64, 6.04, 0.0, 0.028, 0.0])  # N·m


# --------------------------------------------------------------------------------------------
# Default gains of the built-in servos (kali_daemons.servo, thesis 3.4 and figure 3.4): the
# init data the SV gives each joint's PID and PD.  Joint side: torque N·m at the joint, angle
# rad at the joint.  The rule robots/profile.py servo_gains writes out for the other types:
#
# - kp = J·ωn² and kv = 2ζ·J·ωn − (the joint's viscous friction), J the joint-side inertia at
#   QN with the armature G²·Jm, ωn = 50, 55, 60, 60, 60, 60 rad/s and ζ = 0.7: well inside
#   the 50 Hz error filter and the 25 Hz velocity filter;
# - ki = 20 s⁻¹ · kp: the integral pushes through Coulomb friction and holds gravity from
#   errors of a few encoder counts;
# - integration_band 0.01 rad: the integral winds up only near the set-point, yet the band is
#   2.5-3 times (gravity + friction) / kp of joints 1-3: a joint stuck on friction or sagging
#   outside the band would never integrate.  Halving kp needs a wider band;
# - integration_reset: the largest gravity plus friction torque the joint must hold, N·m.
#
# The inertias and what these gains measure in the simulated plant:
# docs/internals/robots-hardware-plant.md.

_PID_TABLE: Final = (  # per joint: kp, ki, kv, integration_band, integration_reset
    (9000.0, 180000.0, 250.0, 0.010, 50.0),
    (13000.0, 260000.0, 330.0, 0.010, 60.0),
    (3400.0, 68000.0, 75.0, 0.010, 30.0),
    (700.0, 14000.0, 16.0, 0.010, 5.0),
    (600.0, 12000.0, 14.0, 0.010, 5.0),
    (700.0, 14000.0, 16.0, 0.010, 5.0),
)
PID_DEFAULTS: Final[tuple[dict[str, float], ...]] = tuple(
    {
        "kp": kp,  # N·m/rad
        "ki": ki,  # N·m/(rad·s)
        "kv": kv,  # N·m·s/rad
        "fe": 50.0,  # Hz, error filter (figure 3.4)
        "fv": 25.0,  # Hz, velocity filter (figure 3.4)
        "integration_band": band,  # rad
        "integration_reset": reset,  # N·m
        "bias_tau": 0.5,  # s, hand-over bias
    }
    for kp, ki, kv, band, reset in _PID_TABLE
)

# The PD: the PID's kp and kv without the integral, so it cannot hold a load without an
# error (a sag of a few mrad on joint 2); the hand-over bias fades with bias_tau.
PD_DEFAULTS: Final[tuple[dict[str, float], ...]] = tuple(
    {"kp": g["kp"], "kv": g["kv"], "fv": g["fv"], "bias_tau": 0.5} for g in PID_DEFAULTS
)
