"""Feed-forward dynamics (thesis 3.3.6): gravity and inverse-dynamics torques with Pinocchio, at
about the TG rate.
"""

from __future__ import annotations

from ..daemon import Daemon


class Dynamics(Daemon):
    """Issue: dynamics fills this in; for now it registers (non-serious) and acknowledges."""

    kind = "dynamics"

    def cycle(self, tick: int) -> None:
        """Inside the cycle: nothing yet beyond the base class's acknowledgement."""
