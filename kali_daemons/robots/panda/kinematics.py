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
reads as "nearest".

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

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import pinocchio as pin

from ...errors import KinematicsError
from ..numik import DlsIk
from ..profile import FloatArray
from . import facts

HELD_JOINT: Final = 2  # index of joint 3, the redundancy parameter
SIGMA_MIN: Final = 0.02  # smallest singular value allowed for a Cartesian path
FLANGE_FRAME: Final = "flange"


@dataclass(frozen=True, slots=True)
class Nearest:
    """The Panda's only branch: the solution nearest ``q_ref``."""

    def __str__(self) -> str:
        return "nearest"


NEAREST: Final = Nearest()


class PandaKinematics:
    """The Panda's ``Kinematics`` (kali_daemons.robots.profile) on a Pinocchio model of
    ``urdf``.  The model is loaded on first use (so importing the type, or generating the
    URDF, needs no URDF): a process calls ``load`` while it configures, outside the cycle;
    the methods then run inside it.
    """

    configs: tuple[object, ...] = (NEAREST,)

    def __init__(self, urdf: Path = facts.URDF_PATH) -> None:
        self.urdf = Path(urdf)
        self._solver: DlsIk | None = None
        self._qv = [0.0] * facts.NJOINTS
        self._home = [float(v) for v in facts.Q_HOME]

    def load(self) -> DlsIk:
        """The solver on the URDF's Pinocchio model, loading it the first time (allocates)."""
        if self._solver is None:
            if not self.urdf.is_file():
                raise KinematicsError(f"panda: {self.urdf}: no such file")
            model = pin.buildModelFromUrdf(str(self.urdf))
            self._solver = DlsIk(
                model, FLANGE_FRAME, facts.Q_MIN, facts.Q_MAX, name="panda", held=HELD_JOINT
            )
        return self._solver

    @property
    def solver(self) -> DlsIk:
        """``load()``."""
        return self._solver if self._solver is not None else self.load()

    def fkine(self, q: FloatArray, out: FloatArray | None = None) -> FloatArray:
        """The flange pose (4×4) in the base frame; into ``out`` without allocating."""
        return self.solver.fkine(q, out)

    def ikine(
        self,
        t6: FloatArray,
        config: object = NEAREST,
        q_ref: FloatArray | None = None,
        out: FloatArray | None = None,
        redundancy: float | None = None,
    ) -> FloatArray:
        """Joint angles within the limits putting the flange at ``t6``, found from ``q_ref``
        (default ``Q_HOME``), joint 3 at ``redundancy`` (default: ``q_ref``'s joint 3).

        ``KinematicsError`` for a bad ``t6`` or branch, a pose beyond the arm's reach, or no
        convergence (out of reach or the limits with joint 3 there), with the numbers.
        """
        if config is not NEAREST and config != NEAREST:
            raise KinematicsError(f"panda ikine: {config!r} is not a Panda configuration")
        if not isinstance(t6, np.ndarray) or t6.shape != (4, 4):
            raise KinematicsError(
                f"panda ikine: T must be a 4×4 array, got {type(t6).__name__} "
                f"{getattr(t6, 'shape', '')}"
            )
        start = self._home if q_ref is None else q_ref
        if len(start) != facts.NJOINTS:
            raise KinematicsError(f"panda ikine: q_ref has {len(start)} angles, not 7")
        return self.solver.solve(t6, start, out, redundancy)

    def config_of(self, q: FloatArray) -> object:
        """Always ``NEAREST``: the Panda has no discrete branches."""
        return NEAREST

    def parse_config(self, text: str) -> object:
        """``NEAREST`` from "nearest" (case ignored)."""
        if isinstance(text, str) and text.lower() == "nearest":
            return NEAREST
        raise KinematicsError(
            f"panda: configuration {text!r}: the Panda has one, 'nearest' (the solution "
            f"nearest the present joints; the elbow is joint 3, the redundancy parameter)"
        )

    def singular(self, q: FloatArray) -> str | None:
        """Why ``q`` is too near a singularity for a Cartesian path, or None.  Inside the
        cycle on the None path (one Cholesky per Jacobian); a refusal computes the singular
        values for its message."""
        qv = self._qv
        for k in range(facts.NJOINTS):
            qv[k] = float(q[k])
        solver = self.solver
        solver.forward(qv, jacobian=True)
        if not solver.min_singular_above(SIGMA_MIN, None):
            sigma = float(solver.singular_values(qv, None)[-1])
            return (
                f"{sigma:.4f} from a singularity: the 6×7 Jacobian's smallest singular "
                f"value is below {SIGMA_MIN:g}"
            )
        if not solver.min_singular_above(SIGMA_MIN, HELD_JOINT):
            sigma = float(solver.singular_values(qv, HELD_JOINT)[-1])
            return (
                f"{sigma:.4f} from a singularity with joint 3 held (at "
                f"{math.degrees(qv[HELD_JOINT]):.2f}°): the 6×6 Jacobian of the other joints "
                f"has a singular value below {SIGMA_MIN:g}"
            )
        return None


KINEMATICS: Final = PandaKinematics()
