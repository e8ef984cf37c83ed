"""The hardware boundary (DESIGN 6, thesis 3.5 and appendix C; docs/decisions/0015).

SIO is generic: hardware read → FIFO → checks → feed slots → wait → feed-forward → hardware
write.  It reaches the hardware behind each arm only through ``Hardware`` (in its cycle, the
analogue of ros2_control's ``SystemInterface``), and every other process only through
``Operations`` (out of any cycle, lock-free).  Each kind of hardware is a package here
declaring a ``KIND`` (``registry``), with all its facts: today the McGill I/O board
(``mcgill``); a wrist sensor's data sheets are ``ftsensor``'s.
"""

from __future__ import annotations

from .interface import Hardware, Operations
from .registry import DEFAULT_KIND, HardwareKind, hardware_kind, known_kinds

__all__ = [
    "DEFAULT_KIND",
    "Hardware",
    "HardwareKind",
    "Operations",
    "hardware_kind",
    "known_kinds",
]
