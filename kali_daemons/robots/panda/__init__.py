"""Franka Emika Panda, 7 joints: the robot type ``panda``.

Kinematics, limits and link dynamics are published ones (Franka's documentation and Gaz et
al. 2019), with their sources in ``facts``; the inverse kinematics is numerical on Pinocchio
with joint 3 as the redundancy parameter (``kinematics``); ``robots/panda/panda.urdf`` is generated
from the facts by ``scripts/gen_robot_urdf.py``.

The drives are plausible equivalents wired to McGill-style boards, NOT Franka's integrated
joint modules: a brushed DC motor, a PWM current amplifier and an incremental encoder behind
a 100:1 gearbox per joint, chosen to behave like the arm (Franka's peak torques), not
measured on it.  The numbers and what they give at the joint:
docs/internals/robots-hardware-plant.md.
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
