"""Servo I/O's process (thesis 3.3.3): the daemon shell around SIO's cycle logic,
``cycle.SioCycle``, which the lockstep executive and a test drive the same way.
"""

from __future__ import annotations

from ..runtime.daemon import Daemon
from .cycle import SioCycle


class ServoIO(Daemon):
    """The SIO process: lays a ``SioCycle`` over the instance at configure and runs its
    ``cycle`` as its own."""

    kind = "sio"

    def on_configure(self) -> None:
        """Outside the cycle: SIO's cycle over the arena's records, the boards attached.  Its
        ``cycle`` is bound as this daemon's, so each tick calls it directly, with no call in
        between."""
        self.io = SioCycle(self.inst, self.name, self.slot, self.acknowledge)
        self.cycle = self.io.cycle  # type: ignore[method-assign]

    def on_activate(self) -> None:
        """The compiled tick acknowledges early where ``acknowledge`` does (real time)."""
        self.io.activate(self._ack_early)

    def on_shutdown(self) -> None:
        """Outside the cycle: release what on_configure took (if it got that far)."""
        io = getattr(self, "io", None)
        if io is not None:
            io.close()
