"""Franka Research 3 (FR3), 7 joints: the robot type ``fr3``.

Franka's modified-DH table and the FR3 datasheet's limits, ``franka_description``'s link
inertials (vendored as ``robots/fr3/fr3.urdf``, Apache-2.0, ``NOTICE`` beside it) and MuJoCo
Menagerie's joint friction and armature, with their sources in ``facts``; the inverse
kinematics is numerical on Pinocchio with joint 3 as the redundancy parameter
(``kinematics``), as for the Panda.

The arm is driven through libfranka's joint torque interface, so its drive is a 1:1 torque
source (``facts``' docstring), and its joints are absolute: nothing to calibrate.
"""

from __future__ import annotations

from ..profile import RobotType, drive_from_facts, read_only
from . import facts
from .kinematics import KINEMATICS

DRIVE = drive_from_facts(facts)

ROBOT = RobotType(
    name="fr3",
    description=(
        "Franka Research 3: Franka's modified-DH table, datasheet limits, franka_description "
        "inertials, Menagerie friction; libfranka torque interface (1:1), absolute encoders"
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
    absolute_encoders=True,
    gravity=facts.GRAVITY,
)

__all__ = ["DRIVE", "ROBOT"]
