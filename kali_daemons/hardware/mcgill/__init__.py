"""The McGill I/O board (thesis appendix C): one board and one DAC board per arm, simulated
by the plant.  Its registers (``registers``), what SIO drives through them (``boards``) and
the counts-to-radians driver (``driver``) are this package's alone (docs/decisions/0015).
"""

from __future__ import annotations

from ..registry import HardwareKind
from . import registers
from .boards import (
    McGillBoards,
    McGillOps,
    PotReader,
    amplifiers_cut,
    cut_all,
    estops_pressed,
    grip,
    press_estop,
    run_conveyor,
)
from .driver import JointDriver

KIND = HardwareKind(
    name="mcgill",
    description="the McGill I/O board of thesis appendix C (counters, DACs, power switch, "
    "watchdog), simulated by the plant",
    channels=registers.BOARD_CHANNELS,
    operations=McGillOps,
    drive=McGillBoards.attach,
    records=registers.RECORDS,
)

__all__ = [
    "KIND",
    "JointDriver",
    "McGillBoards",
    "McGillOps",
    "PotReader",
    "amplifiers_cut",
    "cut_all",
    "estops_pressed",
    "grip",
    "press_estop",
    "registers",
    "run_conveyor",
]
