"""Viewer (thesis 3.3.7): reads the arena without locking and logs the live dashboard to rerun at
25 Hz.
"""

from __future__ import annotations

from ..daemon import Daemon


class Viewer(Daemon):
    """Issue: dashboard fills this in; for now it registers (non-serious) and acknowledges."""

    kind = "viewer"

    def cycle(self, tick: int) -> None:
        """Inside the cycle: nothing yet beyond the base class's acknowledgement."""
