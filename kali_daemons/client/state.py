"""An arm's state, read publicly: one servo tick's consistent snapshot (``Robot.read_state``,
``MotionSystem.read_state``).

SIO writes a row of every servo tick into the flight recorder's ring (``flightrec``): the
measured joints and their velocities, the demand and its velocity, the servo, feed-forward
and sent torques, the motor currents and each arm's wrench, all of one tick.  A reader takes
the last whole row (the ring's count is published after each row) and adds what changes only
on request (power, calibration, which servo runs each joint) as it stands when read.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..core import layout
from ..core.errors import ServoError
from ..core.layout import PowerState

if TYPE_CHECKING:
    from .motion import Kali

ARRAYS = (
    "q", "qd", "q_d", "qd_d", "servo_torque", "ff_torque", "torque", "current",
)  # fmt: skip
# each array's column of the flight row
ROW_FIELDS = dict(
    zip(ARRAYS, ("q", "qd", "demand", "demand_qd", *layout.FLIGHT_FIELDS[4:8]), strict=True)
)
RETRIES = 100  # a row overwritten while read is read again (the writer laps the ring first)


@dataclass(frozen=True, eq=False)
class ArmState:
    """One arm at one servo tick, as SIO served it (arrays: one value per joint).

    ``tick`` and ``time_s`` (the clock's running time of that tick); measured ``q`` (rad) and
    ``qd`` (rad/s); the demand ``q_d`` and its velocity ``qd_d``; the torques the servo asked
    for, the feed-forward added and the torque sent (N·m); the motor currents (A); the
    contact ``wrench`` at the tool point in tool axes (N, N·m; None without a wrist sensor).
    As read: ``power``, ``calibrated`` and ``servos`` (each joint's active servo, or the
    robot-level servo's name on every joint while one runs the arm)."""

    robot: str
    tick: int
    time_s: float
    q: np.ndarray
    qd: np.ndarray
    q_d: np.ndarray
    qd_d: np.ndarray
    servo_torque: np.ndarray
    ff_torque: np.ndarray
    torque: np.ndarray
    current: np.ndarray
    wrench: np.ndarray | None
    power: PowerState
    calibrated: bool
    servos: tuple[str, ...]

    def __post_init__(self) -> None:
        """Arrays as float arrays and ``servos`` as a tuple, however they came (a remote
        program's copy crosses the bridge as lists)."""
        for name in ARRAYS:
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        if self.wrench is not None:
            object.__setattr__(self, "wrench", np.asarray(self.wrench, dtype=np.float64))
        object.__setattr__(self, "servos", tuple(self.servos))
        object.__setattr__(self, "power", PowerState(self.power))

    def same(self, other: ArmState) -> bool:
        """Whether ``other`` holds the same values (arrays compared exactly)."""
        for f in dataclasses.fields(self):
            a, b = getattr(self, f.name), getattr(other, f.name)
            if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
                if a is None or b is None or not np.array_equal(a, b, equal_nan=True):
                    return False
            elif a != b:
                return False
        return True


@dataclass(frozen=True, eq=False)
class ObjectState:
    """A motion system (arms holding one object) at one servo tick: the object's ``pose``
    in the world from the first arm's measured joints, ``pose_d`` from its demand (4×4), and
    every arm's ``ArmState`` of that same tick."""

    robots: tuple[str, ...]
    tick: int
    time_s: float
    pose: np.ndarray
    pose_d: np.ndarray
    arms: tuple[ArmState, ...]

    def __post_init__(self) -> None:
        object.__setattr__(self, "robots", tuple(self.robots))
        object.__setattr__(self, "pose", np.asarray(self.pose, dtype=np.float64))
        object.__setattr__(self, "pose_d", np.asarray(self.pose_d, dtype=np.float64))
        object.__setattr__(self, "arms", tuple(self.arms))

    def same(self, other: ObjectState) -> bool:
        """Whether ``other`` holds the same values (arrays compared exactly)."""
        return (
            self.robots == other.robots
            and (self.tick, self.time_s) == (other.tick, other.time_s)
            and np.array_equal(self.pose, other.pose)
            and np.array_equal(self.pose_d, other.pose_d)
            and len(self.arms) == len(other.arms)
            and all(a.same(b) for a, b in zip(self.arms, other.arms, strict=True))
        )


class StateReader:
    """Reads the arms' states from an instance's flight-recorder ring (one per ``Kali``)."""

    def __init__(self, kali: Kali) -> None:
        inst = kali.inst
        self._kali = kali
        self._header = inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
        h = self._header
        if int(h["rows"]) == 0:
            raise ServoError("read_state: SIO has not laid out its flight recorder yet")
        row = layout.flight_row(int(h["n_joints"]), int(h["n_robots"]))
        self._ring = inst.arena.existing(layout.KEY_FLIGHT_RING, row, int(h["rows"]))
        self._clock = inst.clock
        self._has_sensor = [r.ft.sheet is not None for r in inst.config.robots]

    def read(self, indices: Sequence[int]) -> list[ArmState]:
        """Arms ``indices``' states at the last servo tick SIO finished, all of that tick."""
        h, ring = self._header, self._ring
        rows = int(h["rows"])
        for _ in range(RETRIES):
            count = int(h["count"])
            if count == 0:
                raise ServoError("read_state: SIO has not served a tick yet")
            row = ring[(count - 1) % rows].copy()
            if int(h["count"]) - count < rows - 1:  # not lapped while copied: whole
                break
        else:
            raise ServoError("read_state: the flight recorder's ring turned over every read")
        tick = int(row["tick"])
        c = self._clock
        time_s = float(c["time_offset_ms"]) / 1e3 + tick * int(c["base_tick_ns"]) / 1e9
        return [self._arm(row, k, tick, time_s) for k in indices]

    def _arm(self, row: np.ndarray, index: int, tick: int, time_s: float) -> ArmState:
        kali = self._kali
        span = kali.inst.config.joints.span(index)
        name = kali.names[index]
        servo = kali.servo
        arm = servo.arm_active(name)
        n = span.stop - span.start
        if arm is not None:
            servos = (arm,) * n
        else:
            servos = tuple(servo.active(name, j + 1) for j in range(n))
        return ArmState(
            robot=name,
            tick=tick,
            time_s=time_s,
            **{a: row[f][span] for a, f in ROW_FIELDS.items()},
            wrench=row["wrench"][index].copy() if self._has_sensor[index] else None,
            power=servo.power_state(name),
            calibrated=servo.calibrated(name),
            servos=servos,
        )
