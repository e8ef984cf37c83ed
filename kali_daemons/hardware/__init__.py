"""The hardware boundary: what SIO asks of the I/O boards, and the one board
Kali has, the McGill I/O board (thesis appendix C).

SIO is generic: hardware read → FIFO → checks → feed slots → wait → feed-forward → hardware
write.  It reaches the boards only through ``Hardware``, the analogue of ros2_control's
``SystemInterface`` (``read``/``write``) with the power and calibration steps a robot with
relative encoders needs (thesis 3.5.1).  Every register bit lives in ``mcgill``; a different
board is a module that implements the same interface and the same out-of-cycle functions
(``cut_all``, ``press_estop``, ``estops_pressed``, ``amplifiers_cut``, ``grip``,
``run_conveyor``).

Joint arrays are flat over the cell's joints (``joints.JointMap``); ``k`` is an arm's index in
config order, ``j`` a joint of it (0-based), ``i`` a flat joint index.
"""

from __future__ import annotations

from typing import Protocol

import numpy as np

from ..core.kernels import Kernel
from .driver import JointDriver
from .mcgill import (
    McGillBoards,
    PotReader,
    amplifiers_cut,
    cut_all,
    estops_pressed,
    grip,
    press_estop,
    run_conveyor,
)


class Hardware(Protocol):
    """The boards as SIO drives them, once per servo tick, inside its cycle (no allocation)."""

    driver: JointDriver  # counts ↔ radians, torque → codes, calibration offsets (thesis 3.5)

    def start(self) -> None:
        """First start (not a restarted SIO): registers at rest, counters as the reference."""

    def read(self, q: np.ndarray) -> None:
        """Joint angles (rad) into ``q``."""

    def write(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        """Joint torques (N·m) out; motor currents (A) and where they were clamped back."""

    def zero(self) -> None:
        """No torque on any joint (a halt)."""

    def amps_on(self, k: int) -> bool:
        """Whether arm ``k``'s amplifiers are on."""

    def amps_register(self) -> tuple[np.ndarray, int]:
        """The register (uint8, one per arm, a 1-D view) and the bit of it that ``amps_on``
        reads: SIO's compiled common path (``kali_sio_robots``) tests it in place."""

    def powered(self, k: int) -> bool:
        """Whether arm ``k`` can servo: amplifiers on, brakes released."""

    def power_text(self, k: int) -> str:
        """Arm ``k``'s power status for a fault message (outside the common path)."""

    def control(
        self, k: int, power: int, enable_ticks: int, capture: bool, halted: bool
    ) -> None:
        """Arm ``k``'s power switch (``power`` a ``PowerState``), index capture and
        indicators for this tick."""

    def end_tick(self) -> bool:
        """After every arm's ``control``: the tick's keep-alive; True when it reached the
        board (the watchdog was retriggered)."""

    def tick_kernels(
        self,
        power: np.ndarray,
        enable_ticks: np.ndarray,
        capture: np.ndarray,
        fault_active: np.ndarray,
    ) -> tuple[Kernel, Kernel, Kernel]:
        """After ``driver.bind``: ``read``, ``write`` and every arm's ``control`` then
        ``end_tick`` as bound kernels, for SIO's compiled tick (``kali_sio_front``,
        ``kali_sio_back``), which calls them through their addresses; ``power`` and
        ``enable_ticks`` are the robots' records' fields, ``capture`` SIO's flags (uint8 per
        arm: index capture on), ``fault_active`` the fault word.  The control kernel returns
        1 where ``end_tick`` returns True."""

    def pots(self, k: int) -> PotReader:
        """Arm ``k``'s absolute joint sensors, read one joint per step."""

    def index_hits(self, k: int) -> int:
        """Arm ``k``'s index pulses seen since capture went on: bit j for joint j."""

    def at_index(self, k: int, j: int, i: int, angle: float) -> None:
        """Arm ``k``'s joint ``j`` (flat ``i``) is at its index pulse: it reads ``angle``."""


__all__ = [
    "Hardware",
    "JointDriver",
    "McGillBoards",
    "PotReader",
    "amplifiers_cut",
    "cut_all",
    "estops_pressed",
    "grip",
    "press_estop",
    "run_conveyor",
]
