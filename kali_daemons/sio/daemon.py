"""Servo I/O (thesis 3.3.3): encoders to angles, checks, set-point interpolation, feeds the servos,
torques to the DAC.
"""

from __future__ import annotations

from ..daemon import Daemon


class ServoIO(Daemon):
    """Issue: servo level fills this in; for now SIO registers at the servo period and acknowledges
    every tick.
    """

    kind = "sio"

    def cycle(self, tick: int) -> None:
        """Inside the cycle: nothing yet beyond the base class's acknowledgement."""
