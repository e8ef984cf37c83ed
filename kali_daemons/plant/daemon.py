"""Plant (thesis 3.7, appendix C): the simulated arms (each of its robot type, PUMA 560 or
another), motors, amplifiers, I/O and DAC boards, behind their registers in the arena.
"""

from __future__ import annotations

from ..core import rt
from ..runtime.daemon import Daemon
from ..runtime.stalls import ClockWitness
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
        # SIO is not signalled while the machine holds the clock's CPU; if SIO shares that
        # CPU, it did not run either, and the boards' watchdogs do not count the time
        self.stalls = ClockWitness(self.inst)
        clock, sio = cfg.process("wallclock"), cfg.process("sio")
        self.stalls.enabled &= clock.cpu is not None and clock.cpu == sio.cpu

    def on_deactivate(self) -> None:
        self.stalls.close()

    def cycle(self, tick: int) -> None:
        """Inside the cycle: one plant period, not counted by the boards' watchdogs while the
        machine holds SIO's CPU (``stalls``)."""
        if self.stalls.held(rt.monotonic_ns()):
            self.sim.hold_watchdogs()
        self.sim.cycle()
