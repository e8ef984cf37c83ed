"""A link's side of lockstep over libfranka's protocol (decision 0015): the plant and each
FR3's link take turns on every state packet, so every byte still crosses the real protocol
on loopback and a run is the same bit for bit.

The plant begins each tick by letting the link go (``go``): the tick before has run whole,
so the link answers the state it took then and chooses its next libfranka call on
everything that tick did, and says what the plant must find on its sockets before it steps
(``ready``: its answer, or what the call sends first).  Once every link is ready the plant
lets the call go (``call``), which takes the tick's state (``took``).  So a link enters
libfranka only when the state it waits for is coming: never while the clock stands, nor
while the plant still waits for another link (libfranka's receive gives up after 1 s).
The plant writes in ``ls_go`` and ``ls_call`` the number of the state it sends next, which
the link waits for: one whose turn a halt cut short takes it up where it stopped.
"""

from __future__ import annotations

import numpy as np

from ..core import futex, rt
from ..runtime.daemon import Daemon

SLICE_S = 0.05  # a wait looks at the instance's shutdown this often


class LinkTurns:
    """The turns of one link (``daemon``) on its arm's record ``arm``."""

    def __init__(self, daemon: Daemon, arm: np.ndarray) -> None:
        self._daemon, self._arm = daemon, arm
        self._header = daemon.inst.arena.header
        self._futex = futex.Waiter(SLICE_S)
        self._heart = daemon.inst.procs["heartbeat_ns"][daemon.slot : daemon.slot + 1]
        self.n = int(arm["ls_taken"])  # the state the link's last call took

    def go(self) -> bool:
        """Wait until the plant begins the tick whose state the next call takes (it has
        run the last one whole); False if the link is to end.  The link's heartbeat says
        when it last took a turn (``kalictl status``)."""
        self._heart[0] = rt.monotonic_ns()
        return self._wait("ls_go")

    def call(self) -> bool:
        """Wait until every link is ready and the plant lets this one's call take its
        state; False if the link is to end."""
        return self._wait("ls_call")

    def _wait(self, field: str) -> bool:
        arm, want = self._arm, self.n + 1
        addr = arm[field].ctypes.data
        while (now := int(arm[field])) != want:
            if self._daemon._leave or self._header["shutdown"]:
                return False
            self._futex.wait(addr, now)
        return True

    def ask(self) -> None:
        """While the cell starts: the link's next call takes state ``n + 1``, which the plant
        sends at once (the physics stands until the first tick)."""
        self._set("ls_ready", self.n + 1)

    def ready(self, expect: int) -> None:
        """The link has answered state ``n`` and chosen its next call, which takes state
        ``n + 1``; ``expect`` (``LS_*``) is what the plant finds on its sockets first."""
        self._arm["ls_expect"] = expect
        self._set("ls_ready", self.n + 1)

    def took(self) -> None:
        """The call took state ``n + 1``: the plant may let the tick go on."""
        self.n += 1
        self._set("ls_taken", self.n)

    def leave(self) -> None:
        """Out of the turns (libfranka failed): the plant waits for this link no more."""
        self._arm["ls_off"] = 1
        for field in ("ls_ready", "ls_taken"):
            futex.wake(self._arm[field].ctypes.data)

    def _set(self, field: str, value: int) -> None:
        self._arm[field] = value
        futex.wake(self._arm[field].ctypes.data)
