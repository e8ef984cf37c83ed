"""Servo executor with dynamic loading (thesis 3.3.4, 3.3.5); N of them claim servo slots by test-
and-set.
"""

from __future__ import annotations

from ..daemon import Daemon


class ServoWorker(Daemon):
    """Issue: servo level fills this in; for now each SV registers at the servo period and
    acknowledges every tick.
    """

    kind = "sv"

    def cycle(self, tick: int) -> None:
        """Inside the cycle: nothing yet beyond the base class's acknowledgement."""
