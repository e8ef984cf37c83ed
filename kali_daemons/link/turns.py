"""A link's side of lockstep over libfranka's protocol (decision 0015): the plant and each
FR3's link take turns on every state packet, so every byte still crosses the real protocol
on loopback and a run is the same bit for bit.

Each tick the link's libfranka call takes exactly one state: it calls only once the plant has
begun the tick (``go``: never blocking inside libfranka while the clock stands, where its
receive times out), tells the plant it took the state (``took``), and answers it and chooses
its next call only on its own lockstep signal (``signalled``, its stage after SIO's), so each
choice sees the tick whole; ``ready`` says what the plant must find on its sockets before it
steps (the answer, or what the next call sends first) and acknowledges the tick.
"""

from __future__ import annotations

import numpy as np

from ..core import futex, rt
from ..core.kernels import WAIT_SHUTDOWN, WAIT_SIGNAL
from ..runtime.daemon import ClockWait, Daemon, _CycleStats

SLICE_S = 0.05  # a wait looks at the instance's shutdown this often


class LinkTurns:
    """The turns of one link (``daemon``) on its arm's record ``arm``."""

    def __init__(self, daemon: Daemon, arm: np.ndarray) -> None:
        inst, slot = daemon.inst, daemon.slot
        self._daemon, self._arm, self._header = daemon, arm, inst.arena.header
        self._futex = futex.Waiter(SLICE_S)
        self._go = int(arm["ls_go"])
        self._after = np.zeros(1, np.int64)
        self._stats = _CycleStats(inst.procs, slot)
        self._clock = ClockWait(
            inst, slot, daemon.period_ticks, 0, SLICE_S, self._after, self._stats,
            inst.ack_semaphore(),
        )  # fmt: skip
        self.n = int(arm["ls_taken"])  # the state the link's last call took

    def _running(self) -> bool:
        return not self._daemon._leave and not self._header["shutdown"]

    def go(self) -> bool:
        """Wait until the plant begins the next tick; False if the link is to end."""
        arm, addr = self._arm, self._arm["ls_go"].ctypes.data
        while int(arm["ls_go"]) == self._go:
            if not self._running():
                return False
            self._futex.wait(addr, self._go)
        self._go = int(arm["ls_go"])
        return True

    def ask(self) -> None:
        """While the cell starts: the link's next call takes state ``n + 1``, which the plant
        sends at once (the physics stands until the first tick)."""
        self._arm["ls_ready"] = self.n + 1
        futex.wake(self._arm["ls_ready"].ctypes.data)

    def took(self) -> None:
        """The call took state ``n + 1``: the plant may let the tick go on."""
        self.n += 1
        self._arm["ls_taken"] = self.n
        futex.wake(self._arm["ls_taken"].ctypes.data)

    def signalled(self) -> bool:
        """Wait for this tick's lockstep signal (the tick has run up to the link's stage);
        False if the link is to end.  Through a halt the clock stands and the link waits on:
        the tick's rest runs once the halt is reset."""
        while True:
            event = self._clock.wait()
            if event == WAIT_SIGNAL:
                return self._running()
            if event == WAIT_SHUTDOWN or not self._running():
                return False
            self._daemon.inst.procs[self._daemon.slot]["heartbeat_ns"] = rt.monotonic_ns()

    def ready(self, expect: int) -> None:
        """The link has answered state ``n`` and chosen its next call, which takes state
        ``n + 1``; ``expect`` (``LS_*``) is what the plant finds on its sockets first.
        Acknowledges the tick."""
        arm = self._arm
        arm["ls_expect"] = expect
        arm["ls_ready"] = self.n + 1
        futex.wake(arm["ls_ready"].ctypes.data)
        self._clock.settle()

    def leave(self) -> None:
        """Out of the turns (libfranka failed): the plant waits for this link no more, and the
        clock signals it no more."""
        self._arm["ls_off"] = 1
        futex.wake(self._arm["ls_ready"].ctypes.data)
        futex.wake(self._arm["ls_taken"].ctypes.data)
        procs = self._daemon.inst.procs
        procs[self._daemon.slot]["periodic"] = 0
        self._daemon.inst.bump_registry()

    def close(self) -> None:
        self._clock.close()
