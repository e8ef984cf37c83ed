"""Plant (thesis 3.7, appendix C): the simulated PUMA 560 arms, motors, amplifiers, I/O and DAC
boards in MuJoCo.
"""

from __future__ import annotations

from ..daemon import Daemon


class Plant(Daemon):
    """Issue: plant fills this in.  It keeps its own real-time clock (it is the outside world and
    runs on when Kali halts); in lockstep mode the wall clock steps it one tick at a time, first
    in every tick.
    """

    kind = "plant"
    self_timed_in_realtime = True

    def cycle(self, tick: int) -> None:
        """Inside the cycle: nothing yet beyond the base class's acknowledgement."""
