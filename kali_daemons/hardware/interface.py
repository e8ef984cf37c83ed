"""The hardware boundary's two interfaces (docs/decisions/0015): ``Hardware``, what SIO drives
inside its cycle, and ``Operations``, what any process may do outside any cycle.

Joint arrays are flat over the cell's joints (``joints.JointMap``); ``k`` is an arm's index in
config order, ``j`` a joint of it (0-based), ``i`` a flat joint index.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol

import numpy as np

from ..core.kernels import Kernel

if TYPE_CHECKING:
    from .mcgill.boards import PotReader
    from .mcgill.driver import JointDriver


class Operations(Protocol):
    """A hardware kind's operations outside any cycle: from any process, without a lock, on
    the arena alone (no config parsed), so a halt never waits on the process that may have
    caused it (docs/decisions/0015).  ``k`` is a robot's index in the cell."""

    def cut(self) -> None:
        """Every arm's drive off at once (a halt); nothing if the hardware is not there yet."""

    def amplifiers_cut(self) -> list[bool]:
        """Each arm's drive off or being cut, whatever SIO has seen yet."""

    def press_estop(self, k: int, pressed: bool) -> None:
        """Press (or release) arm ``k``'s emergency stop."""

    def estops_pressed(self) -> list[bool]:
        """Each arm's emergency stop: True while pressed."""

    def grip(self, k: int, close: bool) -> None:
        """Close (or open) arm ``k``'s gripper."""

    def run_conveyor(self, run: bool) -> None:
        """Start (or stop) the cell's conveyor belt."""


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

    def control(self, k: int, power: int, enable_ticks: int, capture: bool, halted: bool) -> None:
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

    def gauges(self, k: int) -> np.ndarray:
        """Arm ``k``'s wrist sensor's gauge ADC registers (0-d record: ``ft_gauge``,
        ``ft_control``, ``ft_status``; ``ftsensor``)."""

    def pots(self, k: int) -> PotReader:
        """Arm ``k``'s absolute joint sensors, read one joint per step."""

    def index_hits(self, k: int) -> int:
        """Arm ``k``'s index pulses seen since capture went on: bit j for joint j."""

    def at_index(self, k: int, j: int, i: int, angle: float) -> None:
        """Arm ``k``'s joint ``j`` (flat ``i``) is at its index pulse: it reads ``angle``."""
