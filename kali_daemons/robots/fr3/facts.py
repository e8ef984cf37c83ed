"""The Franka Research 3's facts as typed constants: kinematics, dynamics, limits, drive, gains.

Kinematics is Franka's modified-DH table, the Panda's (``franka_description``'s FR3 joint
origins give the same, the flange frame 8 0.107 m past joint 7, without the hand).  Limits are
the FR3 datasheet's (FCI documentation, "Limits for Franka Research 3"; MuJoCo Menagerie's
``fr3.xml`` ranges too); link inertials are ``franka_description``'s, as ``fr3.urdf`` carries
them (what libfranka's model and franky-sim's gravity use); joint friction and armature are
Menagerie's ``fr3.xml``, the physics franky-sim simulates.  The trajectory generator plans
with half the maker's speeds, as for the Panda.

The drive is the FR3's torque interface, not a motor: libfranka takes joint torques, and the
joints report absolute angles.  So the drive is a 1:1 torque source (G = 1, Kt = 1 N·m/A):
Kali's motor "current" of a joint is its commanded joint torque in N·m, its current limit the
FR3's torque limit, its rotor inertia the joint's armature, its encoder the arm's own angle.

Conventions: modified DH (Craig), ``T_i = Rx(α_{i−1})·Tx(a_{i−1})·Rz(θ_i)·Tz(d_i)``, row i of
``A``/``ALPHA`` holding a_{i−1}/α_{i−1}; arrays indexed by joint, 0..6; inertia tensors about
the centre of mass in link i's frame, (Ixx, Iyy, Izz, Ixy, Ixz, Iyz).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Final

import numpy as np

from ..profile import INTEGRATION_BAND_RAD, FloatArray, IntArray, read_only

NJOINTS: Final = 7
GRAVITY: Final = 9.81  # m/s²
URDF_PATH: Final = Path(__file__).with_name("fr3.urdf")  # package data, NOTICE beside it

# --------------------------------------------------------------------------------------------
# Kinematics: modified DH (Franka; the Panda's table)

A: Final[FloatArray] = read_only([0.0, 0.0, 0.0, 0.0825, -0.0825, 0.0, 0.088])  # m, a_{i-1}
D: Final[FloatArray] = read_only([0.333, 0.0, 0.316, 0.0, 0.384, 0.0, 0.0])  # m
_H = math.pi / 2
ALPHA: Final[FloatArray] = read_only([0.0, -_H, _H, _H, -_H, _H, _H])  # rad, α_{i-1}
D_FLANGE: Final = 0.107  # m, frame 8 (the flange) along z7

# Datasheet ranges (franka_description's are the wider mechanical ones)
Q_MIN: Final[FloatArray] = read_only([-2.7437, -1.7837, -2.9007, -3.0421, -2.8065, 0.5445, -3.0159])
Q_MAX: Final[FloatArray] = read_only([2.7437, 1.7837, 2.9007, -0.1518, 2.8065, 4.5169, 3.0159])
QD_MAKER: Final[FloatArray] = read_only([2.62] * 4 + [5.26, 4.18, 5.26])  # rad/s, datasheet
QDD_MAKER: Final[FloatArray] = read_only([10.0] * NJOINTS)  # rad/s², libfranka 0.21
TAU_MAKER: Final[FloatArray] = read_only([87.0] * 4 + [12.0] * 3)  # N·m, datasheet
QD_MAX: Final[FloatArray] = read_only(QD_MAKER / 2.0)  # rad/s: 75°/s, 151°/s, 120°/s
QDD_MAX: Final[FloatArray] = read_only(2.0 * QD_MAX)  # rad/s², the Panda's rule (< QDD_MAKER)

# Q_HOME: libfranka's and franka_ros's "ready" pose, flange down in front of the base
Q_HOME: Final[FloatArray] = read_only(
    [0.0, -math.pi / 4, 0.0, -3 * math.pi / 4, 0.0, math.pi / 2, math.pi / 4]
)

# --------------------------------------------------------------------------------------------
# Link dynamics (franka_description, as fr3.urdf has them): kg, m, kg·m² about the COM.
# The base (link 0, 2.3966 kg, fixed) is in the URDF and moves nothing.

MASS: Final[FloatArray] = read_only(
    [2.9274653454, 2.9355370338, 2.2449013699, 2.6155955791, 2.3271207594, 1.8170376524,
     0.6271432862]
)  # fmt: skip
COM: Final[FloatArray] = read_only(
    [
        [0.0000004128, -0.0181251324, -0.0386035970],
        [0.0031828864, -0.0743221644, 0.0088146084],
        [0.0407015686, -0.0048200565, -0.0289730823],
        [-0.0459100965, 0.0630492960, -0.0085187868],
        [-0.0016039605, 0.0292536262, -0.0972965990],
        [0.0597131221, -0.0410294666, -0.0101692726],
        [0.0045225817, 0.0086261921, -0.0161633251],
    ]
)
INERTIA: Final[FloatArray] = read_only(  # Ixx, Iyy, Izz, Ixy, Ixz, Iyz
    [
        [0.023927316485107913, 0.0224821613275756, 0.006350098258530016,
         1.3317903455714081e-05, -0.00011404774918616684, -0.0019950320628240115],
        [0.041938946257609425, 0.02514514885014724, 0.06170214472888839,
         0.00020257331521090626, 0.004077784227179924, -0.0042252158006570156],
        [0.02410142547240885, 0.01974053266708178, 0.019044494482244823,
         0.002404694559042109, -0.002856269270114313, -0.002104212683891874],
        [0.03452998321913202, 0.028881621933049058, 0.04125471171146641,
         0.01322552265982813, 0.01015142998484113, -0.0009762833870704552],
        [0.051610278463662895, 0.04787729713371481, 0.016423625579357254,
         -0.005715173387783472, -0.0035673167625872135, 0.010673985108535986],
        [0.005412333594383447, 0.014058329545509979, 0.016080817924212554,
         0.006193456360285834, 0.0014219289306117652, -0.0013140753741120031],
        [0.00021092389150104718, 0.00017718568002411474, 5.993190599659971e-05,
         -2.433299114461931e-05, 4.564480393778983e-05, 8.744070223226438e-05],
    ]
)  # fmt: skip

# Joint friction and armature: MuJoCo Menagerie's fr3.xml (frictionloss, damping, armature)
FRICTIONLOSS: Final[FloatArray] = read_only([1.137] * 4 + [0.763, 0.44, 0.248])  # N·m
COULOMB_POS: Final[FloatArray] = read_only(FRICTIONLOSS)  # N·m
COULOMB_NEG: Final[FloatArray] = read_only(-FRICTIONLOSS)  # N·m
VISCOUS: Final[FloatArray] = read_only([0.21] * NJOINTS)  # N·m·s/rad

# --------------------------------------------------------------------------------------------
# Drive: the torque interface as a 1:1 torque source (the module docstring)

G: Final[FloatArray] = read_only([1.0] * NJOINTS)  # the command is the joint's torque
KT: Final[FloatArray] = read_only([1.0] * NJOINTS)  # N·m per "A": one A is one N·m
R_ARMATURE: Final[FloatArray] = read_only([0.01] * NJOINTS)  # Ω: small, no voltage limit
MAX_CURRENT: Final[FloatArray] = read_only(TAU_MAKER)  # "A" = N·m: the torque limits
JM: Final[FloatArray] = read_only([0.195] * 4 + [0.074] * 3)  # kg·m², Menagerie's armature
# Absolute angles, 2²⁸ counts per turn: 23 nrad a count (the arm sends float32 angles, 0.5 µrad
# apart near 4 rad), and the int32 accumulator holds ±8 turns, 11 times the widest mechanical
# angle (4.62 rad).  Not a McGill board's counter: the arm reports its angles itself.
COUNTS_PER_MOTOR_REV: Final[IntArray] = read_only([2**28] * NJOINTS, np.int64)
BRAKE_TORQUE: Final[FloatArray] = read_only(TAU_MAKER)  # N·m

# ±10 V spans ±100 "A": every joint's torque limit, 0.05 N·m a 12-bit DAC code
AMP_GAIN_A_PER_V: Final = 10.0
AMP_BANDWIDTH_HZ: Final = 1000.0  # the arm's 1 kHz torque loop
BUS_VOLTAGE: Final = 100.0  # V: never limits (100 rad/s of "back-EMF", 19 times QD_MAKER)
DAC_VOLTS: Final = 10.0

ARMATURE: Final[FloatArray] = read_only(JM * G**2)  # kg·m²
PEAK_JOINT_TORQUE: Final[FloatArray] = read_only(MAX_CURRENT * KT * np.abs(G))  # N·m
MAX_JOINT_SPEED: Final[FloatArray] = read_only(BUS_VOLTAGE / KT / np.abs(G))  # rad/s
COUNTS_PER_JOINT_RAD: Final[FloatArray] = read_only(
    COUNTS_PER_MOTOR_REV * np.abs(G) / (2 * math.pi)
)

# --------------------------------------------------------------------------------------------
# Default servo gains: Franka's own joint impedance, the stiffness and damping libfranka's
# examples servo an FR3 with (joint_impedance_control.cpp, motion_with_control.cpp).  The FR3
# holds itself against gravity, so the PID's integral takes up friction alone: its reset is
# 1.2 x the joint's Coulomb friction rounded up to a whole N·m, ki = 20 s⁻¹ x kp as the PUMA's,
# and its band is wide enough (2.5 x reset / kp, at least the PUMA's 0.01 rad) that a joint
# stuck on its friction outside it still integrates.  Kali's rule for McGill-style drives
# (robots/profile.py servo_gains, ωn = 50 rad/s) would be ten to thirty times stiffer than an
# FR3 is driven, more than its 1 N·m-per-millisecond torque rate lets a servo use.

GRAVITY_MAX: Final[FloatArray] = read_only(  # N·m, over the joint ranges (the FR3 holds it)
    [0.0, 52.17, 26.92, 20.04, 2.01, 1.78, 0.06]
)
KP: Final[FloatArray] = read_only([600.0, 600.0, 600.0, 600.0, 250.0, 150.0, 50.0])  # N·m/rad
KV: Final[FloatArray] = read_only([50.0, 50.0, 50.0, 50.0, 30.0, 25.0, 15.0])  # N·m·s/rad


def _gains() -> tuple[tuple[dict[str, float], ...], tuple[dict[str, float], ...]]:
    pid = []
    for j in range(NJOINTS):
        reset = float(max(1.0, math.ceil(1.2 * max(COULOMB_POS[j], -COULOMB_NEG[j]))))
        pid.append(
            {
                "kp": float(KP[j]),
                "ki": 20.0 * float(KP[j]),
                "kv": float(KV[j]),
                "fe": 50.0,  # Hz, error filter (thesis figure 3.4)
                "fv": 25.0,  # Hz, velocity filter
                "integration_band": max(INTEGRATION_BAND_RAD, 2.5 * reset / float(KP[j])),
                "integration_reset": reset,
                "bias_tau": 0.5,  # s, hand-over bias
            }
        )
    pd = [{"kp": g["kp"], "kv": g["kv"], "fv": g["fv"], "bias_tau": 0.5} for g in pid]
    return tuple(pid), tuple(pd)


PID_DEFAULTS, PD_DEFAULTS = _gains()

# No calibration sheet: the joints' encoders are absolute (RobotType.absolute_encoders)
INDEX_PHASES: Final[FloatArray] = read_only([])
