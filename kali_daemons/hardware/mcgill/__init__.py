"""The McGill I/O board (thesis appendix C): one board and one DAC board per arm, simulated
by the plant.  Its registers (``registers``), what SIO drives through them (``boards``) and
the counts-to-radians driver (``driver``) are this package's alone (docs/decisions/0015).
"""

from __future__ import annotations

import numpy as np

from ...core.kernels import COUNTER_HALF
from ...robots import RobotType
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


def refuses(rtype: RobotType, period_s: float) -> str:
    """Why the boards cannot drive an arm of ``rtype``: a counter that moves half its range
    (``COUNTER_HALF``) within a servo period at the type's planned speed is read ambiguously
    (figure C.3), and calibration needs each joint's index pulse (3.5.1)."""
    d = rtype.drive
    counts = np.abs(d.gear) * d.counts_per_rev / (2 * np.pi) * rtype.qd_max * period_s
    if (counts >= COUNTER_HALF).any():
        j = int(np.argmax(counts))
        return (
            f"its joint {j + 1} moves {counts[j]:.0f} encoder counts in a servo period at "
            f"{rtype.qd_max[j]:g} rad/s; the board's counters must be read within "
            f"{COUNTER_HALF} (thesis figure C.3)"
        )
    if rtype.absolute_encoders or len(rtype.index_phases) != rtype.n_joints:
        return "it has no index pulses to calibrate against (thesis 3.5.1)"
    return ""


KIND = HardwareKind(
    name="mcgill",
    description="the McGill I/O board of thesis appendix C (counters, DACs, power switch, "
    "watchdog), simulated by the plant",
    channels=registers.BOARD_CHANNELS,
    operations=McGillOps,
    drive=McGillBoards.attach,
    records=registers.RECORDS,
    refuses=refuses,
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
