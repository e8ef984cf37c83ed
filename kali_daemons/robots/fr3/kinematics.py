"""FR3 kinematics: forward kinematics and a numerical inverse on Pinocchio, joint 3 held.

The Panda's choices (``robots/panda/kinematics.py``), on the FR3's URDF and limits: all of it
is ``kali_daemons.robots.numik.NumericalKinematics``; the redundancy parameter is joint 3's
angle (index 2), libfranka's "elbow", held at ``redundancy`` or at ``q_ref``'s value; one
branch, ``NEAREST``; ``singular`` refuses a configuration whose 6×7 Jacobian, or 6×6 without
joint 3, has a singular value below ``SIGMA_MIN``.  The flange is the ``flange`` link of
``robots/fr3/fr3.urdf``, frame 8 of Franka's table (no hand).
"""

from __future__ import annotations

from typing import Final

from ..numik import FLANGE_FRAME, NEAREST, Nearest, NumericalKinematics
from . import facts

HELD_JOINT: Final = 2  # index of joint 3, the redundancy parameter
SIGMA_MIN: Final = 0.02  # smallest singular value allowed for a Cartesian path (the Panda's)

KINEMATICS: Final = NumericalKinematics(
    facts.URDF_PATH,
    facts.Q_MIN,
    facts.Q_MAX,
    facts.Q_HOME,
    name="fr3",
    label="FR3",
    redundant_joint=HELD_JOINT,
    sigma_min=SIGMA_MIN,
)

__all__ = ["FLANGE_FRAME", "HELD_JOINT", "KINEMATICS", "NEAREST", "SIGMA_MIN", "Nearest"]
