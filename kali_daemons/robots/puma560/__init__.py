"""The PUMA 560 robot type: Unimation's six-joint arm with a spherical wrist, as at McGill.

Its facts (kinematics, dynamics, motors, amplifiers, encoders, gains) are in ``facts`` with
their sources, its closed-form kinematics in ``kinematics``; ``ROBOT`` declares them to Kali
(``kali_daemons.robots.profile``).  The facts are re-exported here, so ``puma560.G`` reads as
before.
"""

from __future__ import annotations

import math
from typing import Final

from ..profile import RobotType, drive_from_facts, read_only
from . import facts
from .facts import *  # noqa: F403 - the type's facts, by their published names
from .kinematics import KINEMATICS

# The calibration sheet of an arm built to the type's drawing, used when a robot's config
# names none: each joint's index-pulse motor angle (deg).  Kali's two arms have their own
# sheets in config/default.yaml.
INDEX_PHASES_DEG: Final = (229.3062, 97.1232, 14.7505, 5.9499, 292.7773, 328.592)

ROBOT: Final = RobotType(
    name="puma560",
    description="Unimation PUMA 560 (Corke & Armstrong-Hélouvry 1994; thesis table 3.1, app. C)",
    urdf=facts.URDF_PATH,
    n_joints=facts.NJOINTS,
    q_min=facts.Q_MIN,
    q_max=facts.Q_MAX,
    qd_max=facts.QD_MAX,
    qdd_max=facts.QDD_MAX,
    q_home=facts.QN,
    drive=drive_from_facts(facts),
    kinematics=KINEMATICS,
    pid_defaults=facts.PID_DEFAULTS,
    pd_defaults=facts.PD_DEFAULTS,
    index_phases=read_only([math.radians(v) for v in INDEX_PHASES_DEG]),
    gravity=facts.GRAVITY,
)
