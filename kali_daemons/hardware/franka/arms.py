"""The FR3s as SIO drives them (``hardware.Hardware``): the arms' records, which each arm's
link process (``kali_daemons.link.franka``) fills from libfranka and sends on.

An FR3 takes joint torques and compensates gravity itself: SIO's "current" of an FR3 joint is
the torque sent, its limit the FR3's torque limit, and each tick's change is held within the
FR3's torque rate (1000 N·m/s: a faster jump aborts a real FR3's motion; libfranka's
``limitRate``).  Power on is torque control running; a halt stops it (``FrankaOps.cut``).
"""

from __future__ import annotations

import ctypes
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np

from ...core import futex, rt
from ...core.arena import Arena
from ...core.errors import HardwareError
from ...core.joints import JointMap
from ...core.kernels import Kernel
from ...core.layout import PowerState
from ...robots import RobotType
from . import registers
from .registers import FRANKA_ARM, KEY_ARMS, LINK_CONNECTED, LINK_CONTROL

if TYPE_CHECKING:
    from ...runtime.config import KaliConfig as CellConfig

LINK_WAIT_S = 60.0  # how long SIO waits at start for every arm's link to publish a state
TAU_RATE_MAX = 1000.0  # N·m/s: the FR3's torque rate limit (Franka's FCI limits table)


def mode_name(mode: int) -> str:
    """libfranka's name of robot mode ``mode``."""
    return registers.ROBOT_MODES[mode] if 0 <= mode < len(registers.ROBOT_MODES) else str(mode)


def records(arena: Arena, n_robots: int) -> np.ndarray:
    """The FR3s' records, one per robot of the cell (laid out by ``kalictl start``)."""
    return arena.existing(KEY_ARMS, FRANKA_ARM, n_robots)


def offset(field: str) -> int:
    """Byte offset of ``field`` in an arm's record."""
    fields = FRANKA_ARM.fields
    assert fields is not None
    return int(fields[field][1])


def _offsets(arms: np.ndarray, field: str, m: JointMap) -> np.ndarray:
    """Byte offset of each flat joint's element of ``field`` from the first record."""
    row, at = arms.strides[0], offset(field)
    return np.array(
        [m.robot_of[i] * row + at + 8 * m.joint_of[i] for i in range(m.total)], dtype=np.int64
    )


class FrankaDriver:
    """Joint angles from the arms' state packets, torques into their commands (thesis 3.5's
    driver table for an FR3: absolute angles, torques at the joint, nothing to convert)."""

    current_unit = ("joint torque", "N·m")  # SIO's "current": the torque sent

    def __init__(self, types: list[RobotType], arms: np.ndarray, period_s: float) -> None:
        self.map = m = JointMap(
            tuple(f"arm {k}" for k in range(len(types))), tuple(t.n_joints for t in types)
        )
        n = self.n = m.total

        def tile(values: Callable[[RobotType], object]) -> np.ndarray:
            return np.concatenate([np.asarray(values(t), dtype=np.float64) for t in types])

        self.types, self.arms = types, arms
        self.q_min, self.q_max = tile(lambda t: t.q_min), tile(lambda t: t.q_max)
        self.gkt = tile(lambda t: t.drive.gear * t.drive.kt)  # 1: a "current" is a torque
        self.current_limit = tile(lambda t: t.drive.max_current)
        self.torque_limit = self.current_limit * np.abs(self.gkt)
        self.step = np.full(n, TAU_RATE_MAX * period_s)
        self.last = np.zeros(n)  # the torques sent last tick (the rate limit's reference)
        self.seen = np.zeros(len(types), dtype=np.uint64)  # per arm: the state read this tick
        # no counters and no calibration offsets: the joint records' fields stay zero
        self.acc, self.prev = np.zeros(n, np.int32), np.zeros(n, np.int32)
        self.offset = np.zeros(n)
        self._q_off = _offsets(arms, "q", m)
        self._tau_off = _offsets(arms, "tau", m)
        self._seq_off = np.array(
            [k * arms.strides[0] + offset("seq") for k in range(len(types))],
            dtype=np.int64,
        )
        self._read: Kernel | None = None
        self._write: Kernel | None = None

    def load(self, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray) -> None:
        """A restarted SIO: nothing to resume, the angles are absolute."""

    def bind(
        self, q: np.ndarray, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray
    ) -> None:
        """Bind the read and write kernels to SIO's arrays (outside the cycle)."""
        assert clamped.dtype == np.bool_, f"clamped is bool, not {clamped.dtype}"
        arms = self.arms
        self._read = Kernel(
            "kali_franka_read",
            (arms,),
            n=self.n,
            n_arms=len(self.types),
            arms=arms.ctypes.data,
            q_off=self._q_off,
            seq_off=self._seq_off,
            q=q,
            seen=self.seen,
        )
        self._write = Kernel(
            "kali_franka_write",
            (arms,),
            n=self.n,
            torque=torque,
            torque_limit=self.torque_limit,
            step=self.step,
            last=self.last,
            current=current,
            clamped=clamped,
            arms=arms.ctypes.data,
            tau_off=self._tau_off,
        )

    def kernels(self) -> tuple[Kernel, Kernel]:
        """The read and write kernels ``bind`` bound."""
        assert self._read is not None and self._write is not None, "driver: bind first"
        return self._read, self._write

    def read(self, q: np.ndarray) -> None:
        """Joint angles (rad) of each arm's newest state into ``q`` (the bound kernel)."""
        assert self._read is not None, "driver: bind first"
        self._read()

    def angles(self, q: np.ndarray) -> None:
        """Joint angles (rad) of each arm's newest state, outside the cycle."""
        self.read_reference(q, self.seen)

    def read_reference(self, q: np.ndarray, seen: np.ndarray) -> None:
        """``kali_franka_read`` in numpy."""
        flat = self.arms.view(np.uint8).reshape(-1)
        seen[:] = [flat[o : o + 8].view(np.uint64)[0] for o in self._seq_off]
        q[:] = [flat[o : o + 8].view(np.float64)[0] for o in self._q_off]

    def write_reference(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        """``kali_franka_write`` in numpy."""
        clamped[:] = np.abs(torque) > self.torque_limit
        t = np.minimum(np.maximum(torque, self.last - self.step), self.last + self.step)
        t = np.minimum(np.maximum(t, -self.torque_limit), self.torque_limit)
        self.last[:] = t
        current[:] = t
        flat = self.arms.view(np.uint8).reshape(-1)
        for o, v in zip(self._tau_off, t, strict=True):
            flat[o : o + 8].view(np.float64)[0] = v

    def write(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        """Torques out, clamped and rate-limited (the bound kernel)."""
        assert self._write is not None, "driver: bind first"
        self._write()

    def zero(self) -> None:
        """No torque on any joint (a halt): every command zero."""
        self.arms["tau"] = 0.0
        self.last[:] = 0.0

    def set_angle(self, i: int, angle: float) -> None:
        """Absolute encoders: an angle cannot be set."""
        raise HardwareError("franka: an FR3's joint angles are absolute; none can be set")


class FrankaArms:
    """The cell's FR3s as SIO drives them, tick by tick (``hardware.Hardware``)."""

    def __init__(
        self, arms: np.ndarray, types: list[RobotType], links: list[Any], period_s: float
    ) -> None:
        self.driver = FrankaDriver(types, arms, period_s)
        self._arms, self._types, self._links = arms, types, links
        self._status = arms["status"]  # every arm's status (amps_register)
        self._stop = arms["stop"]
        self._control_kernel: Kernel | None = None
        self._sem_addresses: list[int] = []

    @classmethod
    def attach(
        cls,
        arena: Arena,
        cfg: CellConfig,
        servo_ticks: Callable[[float], int],
        semaphore: Callable[[str], Any],
    ) -> FrankaArms:
        """The cell's FR3s once every link publishes its arm's state (``LINK_WAIT_S``);
        ``semaphore(process)`` opens a process's wake-up semaphore (each link's)."""
        n = len(cfg.robots)
        arms = records(arena, n)
        deadline = time.monotonic() + LINK_WAIT_S
        while not (arms["status"] & LINK_CONNECTED).all() or not arms["seq"].all():
            if time.monotonic() > deadline:
                missing = [r.name for k, r in enumerate(cfg.robots) if not arms["seq"][k]]
                raise HardwareError(
                    f"franka: no state from robot {', '.join(map(repr, missing))} within "
                    f"{LINK_WAIT_S:g} s (is its link process running, its FR3 reachable?)"
                )
            time.sleep(0.005)
        # each answer wakes its link; in lockstep the link waits for its own stage instead
        lockstep = bool(arena.header["lockstep"])
        links = [] if lockstep else [semaphore(f"link.{r.name}") for r in cfg.robots]
        return cls(arms, [r.type for r in cfg.robots], links, cfg.clock.servo_period_ms / 1e3)

    def start(self) -> None:
        """First start: no torque commanded."""
        self.driver.zero()

    def read(self, q: np.ndarray) -> None:
        self.driver.read(q)

    def write(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        self.driver.write(torque, current, clamped)

    def zero(self) -> None:
        self.driver.zero()

    def amps_on(self, k: int) -> bool:
        """Whether arm ``k`` takes Kali's torques: its torque control runs, and began after
        the last halt (the link ends a session the halt cut, then clears ``stop``)."""
        return bool(int(self._status[k]) & LINK_CONTROL) and not int(self._stop[k])

    def amps_register(self) -> tuple[np.ndarray, int]:
        return self._status, LINK_CONTROL

    def powered(self, k: int) -> bool:
        return self.amps_on(k)

    def power_text(self, k: int) -> str:
        arm = self._arms[k]
        text = f"link status {registers.status_text(int(arm['status']))}"
        error = bytes(arm["error"]).decode(errors="replace")
        return f"{text}: {error}" if error else text

    def control(self, k: int, power: int, enable_ticks: int, capture: bool, halted: bool) -> None:
        """Arm ``k``'s wish for torque control this tick, its command stamped with the state
        it answers, its link woken (``kali_franka_control`` does every arm at once)."""
        arm = self._arms[k : k + 1].reshape(())
        want = not halted and power in (PowerState.ON, PowerState.ENABLING)
        arm["want"] = int(want)
        if not want:
            arm["tau"][: self._types[k].n_joints] = 0.0
            self.driver.last[self.driver.map.span(k)] = 0.0
        arm["cmd_seq"] = self.driver.seen[k]
        if self._links:
            self._links[k].release()

    def end_tick(self) -> bool:
        """Every arm's command went out with its ``control``."""
        return True

    def tick_kernels(
        self,
        power: np.ndarray,
        enable_ticks: np.ndarray,
        capture: np.ndarray,
        fault_active: np.ndarray,
    ) -> tuple[Kernel, Kernel, Kernel]:
        """``Hardware.tick_kernels``: the driver's read and write kernels and every arm's
        ``control`` compiled (``kali_franka_control``)."""
        arms = self._arms
        read, write = self.driver.kernels()
        for address in self._sem_addresses:
            rt.close_semaphore_address(address)
        self._sem_addresses = [rt.semaphore_address(s) for s in self._links]
        n = len(self._types)  # no semaphore (lockstep): the kernel posts none
        links = (ctypes.c_void_p * n)(*(self._sem_addresses or [0] * n))
        self._control_kernel = Kernel(
            "kali_franka_control",
            (arms, links, fault_active),
            n_arms=len(self._types),
            arms=arms.ctypes.data,
            row=arms.strides[0],
            want_off=offset("want"),
            cmd_seq_off=offset("cmd_seq"),
            tau_off=offset("tau"),
            power=power,
            n_joints=np.array([t.n_joints for t in self._types], dtype=np.int64),
            seen=self.driver.seen,
            last=self.driver.last,
            base=np.array(self.driver.map.base, dtype=np.int64),
            links=ctypes.addressof(links),
            fault_active=fault_active.ctypes.data,
            on=PowerState.ON,
            enabling=PowerState.ENABLING,
            ticks=0,
        )
        return read, write, self._control_kernel

    def close(self) -> None:
        """Give back the compiled control's opens of the links' semaphores."""
        for address in self._sem_addresses:
            rt.close_semaphore_address(address)
        self._sem_addresses = []

    def gauges(self, k: int) -> np.ndarray:
        raise HardwareError("franka: an FR3 has no gauge ADC (no wrist sensor is wired to it)")

    def gauge_cycles(self, k: int) -> np.ndarray | None:
        raise HardwareError("franka: an FR3 has no gauge ADC (no wrist sensor is wired to it)")

    def wrench(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """Arm ``k``'s wrist wrench as its link publishes it with each state (``wrench``, at
        the flange in flange axes), counted by the state's ``seq``."""
        arm = self._arms[k : k + 1].reshape(())
        return arm["wrench"], arm["seq"]

    def pots(self, k: int) -> Any:
        raise HardwareError("franka: an FR3 has no potentiometers (absolute encoders)")

    def absolute_angles(self, k: int) -> str | None:
        """Arm ``k``'s angles are its state's from the first packet (absolute encoders)."""
        return "joint angles from the FR3's absolute encoders" if self._arms["seq"][k] else None

    def index_hits(self, k: int) -> int:
        return 0

    def at_index(self, k: int, j: int, i: int, angle: float) -> None:
        raise HardwareError("franka: an FR3 has no index pulses (absolute encoders)")


class FrankaOps:
    """The FR3s' operations outside any cycle (``hardware.Operations``): on their records,
    which each arm's link carries out at its next state packet."""

    def __init__(self, arena: Arena, n_robots: int) -> None:
        self._arena, self._n = arena, n_robots
        self._arms: np.ndarray | None = None

    def _view(self) -> np.ndarray | None:
        if self._arms is None and self._arena.lookup(KEY_ARMS) is not None:
            self._arms = records(self._arena, self._n)
        return self._arms

    def cut(self) -> None:
        arms = self._view()
        if arms is not None:
            arms["stop"] = 1
            arms["want"] = 0

    def reset(self) -> None:
        """Ask each link to recover; it clears ``stop`` itself once the torque control the
        halt cut has ended, so no power-on takes that session for a new one."""
        arms = self._view()
        if arms is not None:
            arms["recover"] = 1

    def amplifiers_cut(self) -> list[bool]:
        arms = self._view()
        if arms is None:
            return [False] * self._n
        off = (arms["status"] & LINK_CONTROL) == 0
        return [bool(v) for v in off | (arms["stop"] != 0) | (arms["estop"] != 0)]

    def press_estop(self, k: int, pressed: bool) -> None:
        arms = self._view()
        if arms is not None:
            arms["estop"][k] = 1 if pressed else 0

    def estops_pressed(self) -> list[bool]:
        arms = self._view()
        return [False] * self._n if arms is None else [bool(b) for b in arms["estop"]]

    def grip(self, k: int, close: bool) -> int:
        """A command to arm ``k``'s hand process; its number is the ticket."""
        arms = records(self._arena, self._n)
        if not int(arms["hand_up"][k]):
            raise HardwareError(
                f"franka: robot {k} has no Franka Hand running (hardware.hand: true in its "
                "config, and its hand process up)"
            )
        arms["grip_close"][k] = 1 if close else 0
        ticket = int(arms["grip_cmd"][k]) + 1
        arms["grip_cmd"][k] = ticket
        futex.wake(arms["grip_cmd"][k : k + 1].ctypes.data)  # the hand waits on it
        return ticket

    def grip_result(self, k: int, ticket: int) -> bool | None:
        arms = records(self._arena, self._n)
        if int(arms["grip_done"][k]) != ticket:
            return None
        return int(arms["grip_state"][k]) == registers.GRIP_DONE

    def run_conveyor(self, run: bool) -> None:
        raise HardwareError("franka: an FR3 cell has no conveyor")

    def link_status(self, k: int) -> str:
        arms = self._view()
        if arms is None:
            return ""
        a = arms[k]
        error = bytes(a["error"]).decode(errors="replace")
        hand = f"; hand {float(a['grip_width']) * 1e3:.1f} mm open" if int(a["hand_up"]) else ""
        return (
            f"{registers.status_text(int(a['status']))}, robot mode {mode_name(int(a['mode']))}; "
            f"{int(a['seq'])} states, {int(a['answered'])} answered, {int(a['late'])} late, "
            f"{int(a['lost'])} lost; Kali's share of a cycle at most "
            f"{int(a['share_max_ns']) / 1e3:.0f} µs{hand}" + (f"; error: {error}" if error else "")
        )

    def link_text(self, k: int) -> str:
        """How long since arm ``k``'s link published its last state packet (a link stuck in
        libfranka's ``readOnce`` waits for the robot; a stopped one publishes none)."""
        arms = self._view()
        if arms is None or not int(arms["seq"][k]):
            return (
                "connecting to its FR3: nothing answers, or another client holds the robot "
                "(libfranka takes one)"
            )
        age_ms = (rt.monotonic_ns() - int(arms["state_ns"][k])) / 1e6
        return f"its last state packet from the FR3 published {age_ms:.0f} ms ago"
