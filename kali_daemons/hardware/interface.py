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


class Operations(Protocol):
    """A hardware kind's operations, all outside any cycle: from any process, without a lock, on
    the arena alone (no config parsed), so a halt never waits on the process that may have
    caused it (docs/decisions/0015).  ``k`` is a robot's index in the cell."""

    def cut(self) -> None:
        """Every arm's drive off at once (a halt); nothing if the hardware is not there yet."""

    def reset(self) -> None:
        """A halt cleared (kalictl reset): what the hardware needs to run again (its error
        recovery); power stays off until enabled."""

    def amplifiers_cut(self) -> list[bool]:
        """Each arm's drive off or being cut, whatever SIO has seen yet."""

    def press_estop(self, k: int, pressed: bool) -> None:
        """Press (or release) arm ``k``'s emergency stop."""

    def estops_pressed(self) -> list[bool]:
        """Each arm's emergency stop: True while pressed."""

    def grip(self, k: int, close: bool) -> int:
        """Close (or open) arm ``k``'s gripper; a ticket for ``grip_result``, or 0 where the
        hardware reports no outcome (a line set at once)."""

    def grip_result(self, k: int, ticket: int) -> bool | None:
        """Whether arm ``k``'s gripper command ``ticket`` succeeded; None while it runs."""

    def run_conveyor(self, run: bool) -> None:
        """Start (or stop) the cell's conveyor belt."""

    def link_status(self, k: int) -> str:
        """Arm ``k``'s link as ``kalictl status`` shows it ('' without links): its
        connection and what it has counted; never in a cycle."""

    def link_text(self, k: int) -> str:
        """What arm ``k``'s link process is waiting for, for a fault that names it ('' for
        hardware without links); it builds a string: never in a cycle."""


class Driver(Protocol):
    """A kind's driver (thesis 3.5's table): joint angles in, joint torques out, the arms'
    limits; what SIO asks of it beside the tick's kernels."""

    q_min: np.ndarray  # rad, flat
    q_max: np.ndarray
    gkt: np.ndarray  # joint N·m per unit of SIO's "current" (a motor's A; an FR3's N·m)
    current_limit: np.ndarray
    current_unit: tuple[str, str]  # what SIO's "current" is, for messages: (name, unit)
    acc: np.ndarray  # its state a restarted SIO resumes (the joint records' acc, prev, offset)
    prev: np.ndarray
    offset: np.ndarray

    def load(self, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray) -> None:
        """Outside the cycle: resume from the joint records' state."""

    def angles(self, q: np.ndarray) -> None:
        """Outside the cycle: the joint angles (rad) it holds now into ``q``."""

    def bind(
        self, q: np.ndarray, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray
    ) -> None:
        """Outside the cycle: bind its kernels to SIO's arrays."""

    def zero(self) -> None:
        """No torque on any joint (a halt)."""

    def set_angle(self, i: int, angle: float) -> None:
        """Outside the common tick: make joint ``i`` read ``angle`` (calibration)."""


class IndexedDriver(Driver, Protocol):
    """A driver of incremental encoders with index pulses and potentiometers: what
    calibration (thesis 3.5.1, ``sio.calibration``) steps through."""

    index_spacing: np.ndarray  # rad between a joint's index pulses, flat
    rad_per_count: np.ndarray

    def nearest_index(self, i: int, angle: float) -> float:
        """Joint ``i``'s index pulse nearest ``angle`` (rad)."""

    def pot_angle(self, i: int, code: int) -> float:
        """Joint ``i``'s angle as its pot's reading ``code`` tells it."""


class Hardware(Protocol):
    """The hardware as SIO drives it.  ros2_control's lifecycle, in Kali's words: configure is
    the kind's ``drive`` (attach, wait for the hardware to answer), activate ``start``, read
    and write ``read``/``write``, deactivate ``zero``.  Each method says where it runs: *in the
    cycle* (SIO's tick: no allocation, no blocking, no I/O) or *outside it*."""

    @property
    def driver(self) -> Driver:
        """Angles in, torques out, the arms' limits (thesis 3.5)."""

    def start(self) -> None:
        """Outside the cycle, at SIO's first start (not a restart): registers at rest, the
        counters' readings as the reference."""

    def read(self, q: np.ndarray) -> None:
        """In the cycle: joint angles (rad) into ``q``."""

    def write(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        """In the cycle: joint torques (N·m) out; motor currents (A) and where they were
        clamped back."""

    def zero(self) -> None:
        """In the cycle or outside it: no torque on any joint (a halt)."""

    def amps_on(self, k: int) -> bool:
        """In the cycle: whether arm ``k``'s amplifiers are on."""

    def amps_register(self) -> tuple[np.ndarray, int]:
        """Outside the cycle (once, at configure): the register (uint8, one per arm, a 1-D
        view) and the bit of it that ``amps_on`` reads: SIO's compiled common path
        (``kali_sio_robots``) tests it in place."""

    def powered(self, k: int) -> bool:
        """In the cycle: whether arm ``k`` can servo (amplifiers on, brakes released)."""

    def power_text(self, k: int) -> str:
        """Outside the cycle (it builds a string): arm ``k``'s power status for a fault
        message."""

    def control(self, k: int, power: int, enable_ticks: int, capture: bool, halted: bool) -> None:
        """In the cycle: arm ``k``'s power switch (``power`` a ``PowerState``), index capture
        and indicators for this tick."""

    def end_tick(self) -> bool:
        """In the cycle, after every arm's ``control``: the tick's keep-alive; True when it
        reached the hardware (the watchdog was retriggered)."""

    def tick_kernels(
        self,
        power: np.ndarray,
        enable_ticks: np.ndarray,
        capture: np.ndarray,
        fault_active: np.ndarray,
    ) -> tuple[Kernel, Kernel, Kernel]:
        """Outside the cycle (once, at configure), after ``driver.bind``: ``read``, ``write``
        and every arm's ``control`` then ``end_tick`` as bound kernels, for SIO's compiled
        tick (``kali_sio_front``, ``kali_sio_back``), which calls them through their
        addresses; ``power`` and ``enable_ticks`` are the robots' records' fields,
        ``capture`` SIO's flags (uint8 per arm: index capture on), ``fault_active`` the fault
        word.  The control kernel returns 1 where ``end_tick`` returns True."""

    def close(self) -> None:
        """Outside the cycle, at SIO's end: give back what ``tick_kernels`` opened."""

    def gauges(self, k: int) -> np.ndarray:
        """Outside the cycle (once, at configure): arm ``k``'s wrist sensor's gauge ADC
        registers, which SIO's cycle then reads (0-d record: ``ft_gauge``, ``ft_control``,
        ``ft_status``; ``ftsensor``)."""

    def gauge_cycles(self, k: int) -> np.ndarray | None:
        """Outside the cycle (once, at configure): where the hardware behind arm ``k``'s gauges
        can stall while SIO runs (a simulated board: its plant's CPU taken by the machine, or
        the plant stopped), the count of the cycles it ran (0-d uint32), so that a tick it
        did not run is not counted as the sensor's silence; None where every tick is one."""

    def wrench(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Outside the cycle (once, at configure), for a kind whose arms have no gauges
        (``HardwareKind.wrist``): arm ``k``'s wrist wrench as its hardware gives it, at the
        flange in flange axes (6 float64, the wrench the tool side exerts on the arm), and
        its count (0-d uint64, one more for each new wrench), which SIO's cycle then reads."""

    def pots(self, k: int) -> PotReader:
        """Outside the common tick (calibration's steps): arm ``k``'s absolute joint sensors,
        read one joint per step."""

    def absolute_angles(self, k: int) -> str | None:
        """Outside the common tick, at start, once per tick until done: one step of reading arm
        ``k``'s absolute joint sensors into the driver; once its angles are in, what they came
        from (a status message), else None."""

    def index_hits(self, k: int) -> int:
        """In the cycle, while calibrating: arm ``k``'s index pulses seen since capture went
        on, bit j for joint j."""

    def at_index(self, k: int, j: int, i: int, angle: float) -> None:
        """In the cycle, while calibrating: arm ``k``'s joint ``j`` (flat ``i``) is at its index
        pulse and reads ``angle``."""
