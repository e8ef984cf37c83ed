"""Panda kinematics: forward kinematics and a numerical inverse on Pinocchio, joint 3 held.

All of it is ``kali_daemons.robots.numik.NumericalKinematics``; this module only chooses its
parameters.  The redundancy parameter of the 7 joints is **joint 3's angle** (index 2),
libfranka's "elbow": ``ikine`` holds it at ``redundancy`` or, when that is None, at
``q_ref``'s value, so a Cartesian path keeps its elbow.  Joint 3 rather than joint 7 because
the other six are then an anthropomorphic arm, better conditioned.  There are no discrete
branches: ``configs`` is one ``NEAREST``.  ``singular`` refuses a configuration whose 6×7
Jacobian, or 6×6 without joint 3, has a singular value below ``SIGMA_MIN`` (what the PUMA's
thresholds amount to).  The flange is frame 8 of Franka's modified-DH table (no hand), the
``flange`` link of ``robots/panda/panda.urdf``.  The conditioning figures behind these choices:
docs/internals/robots-hardware-plant.md.
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
