"""Universal Robots UR5 (CB3), 6 joints: the robot type ``ur5``.

Kinematics and link masses and centres of mass are UR's published ones; inertia tensors are
an approximation (uniform cylinders), joint and speed limits as Kali uses them; all with
their sources in ``facts``.  The inverse kinematics is closed form with 8 branches
(``kinematics``), ``config/ur5.urdf`` is generated from the facts by
``scripts/gen_robot_urdf.py``.

The drives are plausible equivalents wired to McGill-style boards, NOT Universal Robots'.
The real UR5 has integrated joint modules (brushless motors, harmonic drives, absolute
encoders, their own current loops on a 48 V bus).  Kali's plant simulates a brushed DC motor,
a PWM current amplifier and an incremental encoder with one index pulse per motor turn behind
a 101:1 gearbox per joint, read and written through a McGill I/O board, so the numbers here
are chosen to behave like the arm, not measured on it:

- joints 1-3: Kt 0.1 N·m/A, 15 A peak, 0.3 Ω, rotor 4e-5 kg·m² → 151.5 N·m peak at the
  joint (UR: 150 N·m), 4.75 rad/s = 272°/s at the 48 V bus with no load;
- joints 4-6: Kt 0.035 N·m/A, 8 A peak, 1 Ω, rotor 6e-6 kg·m² → 28.3 N·m (UR: 28 N·m),
  13.6 rad/s = 779°/s;
- both well above the 90°/s the trajectory generator plans with (the data sheet's 180°/s
  halved); reflected rotor inertia 101² · Jm = 0.41 and 0.061 kg·m²;
- encoders 1000 counts per motor turn (250 lines, quadrature): 16 075 counts per joint
  radian, 62 µrad a count, as fine as the PUMA's (10 000-17 000 counts/rad), so ±1 count
  is the same hold test;
- the amplifier and DAC are the PUMA's (2.5 A/V, ±10 V, 12 bits, 500 Hz current loop): the
  25 A command range covers the 15 A peak;
- friction (Coulomb 6 and 1.2 N·m, viscous 2 and 0.4 N·m·s/rad, symmetric) and brakes (the
  joint's peak torque) are plausible choices for harmonic-drive joints of this size.
"""

from __future__ import annotations

from ..profile import RobotType, drive_from_facts, read_only
from . import facts
from .kinematics import KINEMATICS

DRIVE = drive_from_facts(facts)

ROBOT = RobotType(
    name="ur5",
    description=(
        "Universal Robots UR5 (CB3): UR's DH table, masses and centres of mass; cylinder "
        "inertias; plausible McGill-style drives (101:1)"
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
