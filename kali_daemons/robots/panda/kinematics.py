"""Panda kinematics: forward kinematics and a numerical inverse on Pinocchio, joint 3 held.

The Panda has 7 joints for a 6-dimensional pose, so a pose has a one-parameter family of
solutions.  The redundancy parameter is **joint 3's angle** (index 2), libfranka's "elbow"
(its Cartesian interfaces carry the elbow as joint 3's position): ``ikine`` holds joint 3 at
``redundancy`` or, when that is None, at ``q_ref``'s value, so a Cartesian path keeps its
elbow, and solves for the other six by damped least squares from ``q_ref``
(``kali_daemons.robots.numik``).  Joint 3 rather than joint 7 (He and Liu's parameter in their
analytic solution): with joint 3 held the remaining six joints are an anthropomorphic arm
(shoulder 1-2, elbow 4, wrist 5-6-7) and better conditioned than with joint 7 held: over
3000 random in-limit configurations the smallest singular value of the 6×6 Jacobian had a
median of 0.047 against 0.037, a 5th percentile of 3.5e-3 against 9.4e-4, and 0.21 against
0.077 at the ready pose ``Q_HOME``.

There are no discrete branches: ``configs`` is one ``NEAREST`` (the solution nearest
``q_ref``, reached continuously from it), which ``config_of`` returns and ``parse_config``
reads as "nearest".  All of it is ``kali_daemons.robots.numik.NumericalKinematics``, the
numerical kinematics any robot type may use; this module only chooses its parameters.

``singular`` refuses a configuration whose 6×7 Jacobian has a singular value below
``SIGMA_MIN`` (a true singularity: the flange cannot move in some direction), or whose 6×6
Jacobian without joint 3 has (the arm is not singular but holding joint 3 there makes the
other joints race).  ``SIGMA_MIN`` = 0.02 (m or rad per rad) is what the PUMA's thresholds
amount to: its Jacobian's smallest singular value is 0.020 at 5 cm from the elbow
singularity and 0.039 at 5° from the wrist one, at its nominal pose.

Conventions: the flange is frame 8 of Franka's modified-DH table (0.107 m past joint 7, no
hand), the ``flange`` link of ``config/panda.urdf``, the toolbox's ``fkine`` without its tool.
Everything here runs on the Pinocchio model of that URDF.
"""

from __future__ import annotations

from typing import Final

from ..numik import FLANGE_FRAME, NEAREST, Nearest, NumericalKinematics
from . import facts

HELD_JOINT: Final = 2  # index of joint 3, the redundancy parameter
SIGMA_MIN: Final = 0.02  # smallest singular value allowed for a Cartesian path

KINEMATICS: Final = NumericalKinematics(
    facts.URDF_PATH,
    facts.Q_MIN,
    facts.Q_MAX,
    facts.Q_HOME,
    name="panda",
    label="Panda",
    redundant_joint=HELD_JOINT,
    sigma_min=SIGMA_MIN,
)

__all__ = ["FLANGE_FRAME", "HELD_JOINT", "KINEMATICS", "NEAREST", "SIGMA_MIN", "Nearest"]
