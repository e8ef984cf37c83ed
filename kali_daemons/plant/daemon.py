"""Plant (thesis 3.7, appendix C): the simulated arms (each of its robot type, PUMA 560 or
another), motors, amplifiers, I/O and DAC boards, behind their registers in the arena.
"""

from __future__ import annotations

from ..daemon import Daemon
from .sim import PlantSim


class Plant(Daemon):
    """The outside world as a process.

    It keeps its own real-time clock (it is not scheduled by Kali's wall clock and keeps
    running, arms falling until the brakes bite, when Kali halts, DESIGN 6); in lockstep
    mode the wall clock steps it one period at a time, first in every tick.
    """

    kind = "plant"
    self_timed_in_realtime = True

    def on_configure(self) -> None:
        """Build the MuJoCo world and the register records (before going real-time)."""
        cfg = self.inst.config
        period_ms = self.period_ticks * cfg.clock.base_tick_ms
        self.sim = PlantSim(cfg, self.inst.arena, period_ms=period_ms)
        self.sim.cycle()  # first cycle outside real time: warms every code path

    def cycle(self, tick: int) -> None:
        """Inside the cycle: one plant period."""
        self.sim.cycle()
