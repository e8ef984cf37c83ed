"""Universal Robots UR5 (CB3), 6 joints: the robot type ``ur5``.

Kinematics and link masses and centres of mass are UR's published ones, inertia tensors an
approximation (uniform cylinders), all with their sources in ``facts``; the inverse
kinematics is closed form with 8 branches (``kinematics``); ``robots/ur5/ur5.urdf`` is generated
from the facts by ``scripts/gen_robot_urdf.py``.

The drives are plausible equivalents wired to McGill-style boards, NOT Universal Robots'
integrated joint modules: a brushed DC motor, a PWM current amplifier and an incremental
encoder behind a 101:1 gearbox per joint, chosen to behave like the arm (UR's peak torques),
not measured on it.  The numbers and what they give at the joint:
docs/internals/robots-hardware-plant.md.
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
