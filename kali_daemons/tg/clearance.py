"""A joint move's clearance, checked before it starts (issue 56 item 3): the move is straight
in joint space, so it is walked from its start in steps as long as the margin the last look
left allows (``robots.collision.ClearanceWalk``; at least ``STEP_M`` of the arms' motion, the
finest the check resolves), and refused at the first pose within the scene's clearance of
another arm or of an object the arm's links touch (arms starting within it may move away:
``ClearanceWalk.refused``).  A Cartesian path's poses are walked by
``CartesianMotion.check_some`` itself, sample by sample.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from ..robots.collision import STEP_M, ClearanceWalk
from .profiles import JointMotion, MotionError


class JointMoveCheck:
    """The clearance check of joint motion ``motion`` of robots named ``names`` (their joints
    ``widths`` long, one after another in the motion), walked by ``walk``."""

    def __init__(
        self, motion: JointMotion, walk: ClearanceWalk, names: Sequence[str], widths: Sequence[int]
    ) -> None:
        self.motion, self.walk, self.names = motion, walk, list(names)
        ends = np.cumsum(widths)
        self._rows = [slice(int(e) - w, int(e)) for w, e in zip(widths, ends, strict=True)]
        self._q = motion.start.copy()
        self._views = [self._q[r] for r in self._rows]
        self._delta = motion.target - motion.start
        self._rate = walk.rate([self._delta[r] for r in self._rows])  # m per unit of s
        self.s = 0.0  # how far along the move the next look is (0 .. 1)
        self.done = False

    @property
    def progress(self) -> float:
        return self.s

    def check_some(self, samples: int) -> bool:
        """Look at up to ``samples`` more poses; True once the whole move is checked.  Raises
        ``MotionError`` naming the two bodies, the distance and where at the first pose within
        the clearance."""
        m = self.motion
        for _ in range(samples):
            if self.done:
                break
            np.multiply(self._delta, self.s, out=self._q)
            self._q += m.start
            near = self.walk.refused(self._views)
            if near is not None:
                arm = near.near_a.partition("/")[0]
                k = self.names.index(arm) if arm in self.names else 0
                angles = ", ".join(f"{math.degrees(float(v)):.1f}" for v in self._views[k])
                raise MotionError(
                    f"joint move refused: {100 * self.s:.0f} % of the way, robot "
                    f"'{self.names[k]}' at ({angles})°: "
                    f"{near.within(self.walk.cell.clearance)}"
                )
            if self.s >= 1.0 or self._rate <= 0.0:
                self.done = True
                break
            self.s = min(1.0, self.s + max(self.walk.slack, STEP_M) / self._rate)
        return self.done
