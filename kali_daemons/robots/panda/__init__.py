"""Franka Emika Panda, 7 joints: the robot type ``panda``.

Kinematics, limits and link dynamics are published ones (Franka's documentation and Gaz et
al. 2019), with their sources in ``facts``; the inverse kinematics is numerical on Pinocchio
with joint 3 as the redundancy parameter (``kinematics``); ``config/panda.urdf`` is generated
from the facts by ``scripts/gen_robot_urdf.py``.

The drives are plausible equivalents wired to McGill-style boards, NOT Franka's.  The real
Panda has integrated joint modules (brushless motors, harmonic drives, joint torque sensors,
their own current loops).  Kali's plant simulates a brushed DC motor, a PWM current amplifier
and an incremental encoder with one index pulse per motor turn behind a 100:1 gearbox per
joint, read and written through a McGill I/O board, so these numbers are chosen to behave
like the arm, not measured on it:

- joints 1-4: Kt 0.07 N·m/A, 12.5 A peak, 0.4 Ω, rotor 3e-5 kg·m² → 87.5 N·m peak at the
  joint (Franka: 87 N·m), 6.9 rad/s at the 48 V bus with no load (Franka: 2.175 rad/s);
- joints 5-7: Kt 0.03 N·m/A, 4 A peak, 1.2 Ω, rotor 5e-6 kg·m² → 12 N·m (Franka: 12 N·m),
  16 rad/s (Franka: 2.61 rad/s);
- the trajectory generator plans with half Franka's speeds (1.09 and 1.31 rad/s); reflected
  rotor inertia 100² · Jm = 0.3 and 0.05 kg·m²;
- encoders 1000 counts per motor turn: 15 915 counts per joint radian, 63 µrad a count, as
  fine as the PUMA's, so ±1 count is the same hold test;
- amplifier and DAC as the PUMA's (2.5 A/V, ±10 V, 12 bits, 500 Hz current loop);
- friction: the Coulomb levels of the real Panda's identified joint friction (Gaz et al.),
  asymmetric, no viscous term; brakes hold the joint's torque limit.
"""

from __future__ import annotations

from ..profile import RobotType, drive_from_facts, read_only
from . import facts
from .kinematics import KINEMATICS

DRIVE = drive_from_facts(facts)

ROBOT = RobotType(
    name="panda",
    description=(
        "Franka Emika Panda: Franka's modified-DH table and limits, Gaz et al. 2019 dynamics; "
        "plausible McGill-style drives (100:1)"
    ),
    urdf=facts.URDF_PATH,
    n_joints=facts.NJOINTS,
    q_min=facts.Q_MIN,
    q_max=facts.Q_MAX,
    qd_max=facts.QD_MAX,
    qdd_max=facts.QDD_MAX,
    q_home=facts.Q_HOME,
    drive=DRIVE,
    kinematics=KINEMATICS,
    pid_defaults=facts.PID_DEFAULTS,
    pd_defaults=facts.PD_DEFAULTS,
    index_phases=read_only(facts.INDEX_PHASES),
    gravity=facts.GRAVITY,
)

__all__ = ["DRIVE", "ROBOT"]
