"""The trajectory generator's process (thesis 3.3.1): the daemon shell around the TG's cycle
logic, ``planner.Planner``, which a test or the lockstep executive drives the same way.
"""

from __future__ import annotations

from ..runtime.daemon import Daemon
from .planner import Planner


class TrajectoryGenerator(Daemon):
    """The TG process: lays a ``Planner`` over the instance at configure and runs the
    planner's ``cycle`` as its own."""

    kind = "tg"

    def on_configure(self) -> None:
        """Outside the cycle: the planner over the arena's records.  Its ``cycle`` is bound as
        this daemon's, so each tick calls it directly, with no call in between."""
        self.planner = Planner(self.inst, self.name, self.slot)
        self.cycle = self.planner.cycle  # type: ignore[method-assign]
