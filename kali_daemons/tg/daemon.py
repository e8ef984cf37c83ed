"""Trajectory generator (thesis 3.3.1): one process computes set-points for every motion system
each TG tick.
"""

from __future__ import annotations

from ..daemon import Daemon


class TrajectoryGenerator(Daemon):
    """Issue: trajectory generator fills this in; for now the TG registers with the wall clock at
    the TG period and acknowledges every tick.
    """

    kind = "tg"

    def cycle(self, tick: int) -> None:
        """Inside the cycle: nothing yet beyond the base class's acknowledgement."""
