"""The servo level in the arena (DESIGN 4, thesis 3.3.3 - 3.4, figure 3.3), as SIO, the SVs
and clients see it.

- ``robots``: one ``ROBOT_STATE`` per robot (SIO's measurements, power, calibration).
- ``slots``: one ``SERVO_SLOT`` per joint (robot k joint j is slot ``6 k + j``).  SIO feeds
  them and clears ``busy``; an SV claims a slot by test-and-set of ``busy`` (3.3.5).
- Private data: one record per (slot, algorithm) of that algorithm's dtype, so a joint keeps
  the state of every algorithm it may switch to, and any SV can run any joint (3.3.4).
- The put/get mailbox (3.4): a client never touches a running servo's data.  It writes the
  staging bytes and the operation, and the SV carries it out at the slot's next run, before
  the step.  So a servo is never skipped for an update and never sees half-written data.

``ServoLevel`` is the view; ``ServoClient`` adds the operations users call (put/get/select,
gains, enable, range checking, ``safe``, power, calibration).
"""

from __future__ import annotations

import ctypes
import math
import time
from collections.abc import Mapping
from fractions import Fraction
from pathlib import Path

import numpy as np

from . import atomic, layout, puma560
from .channels import InterpolatingFifo
from .config import ms_to_ns
from .errors import KaliError, ServoError
from .instance import Instance, decode
from .layout import CalibState, FfMode, FfState, PowerCmd, PowerState, SlotOp
from .servo import Handover, Registry, ServoAlgorithm, registry_for, struct_view
from .spinlock import SpinLock

FIFO_CAPACITY = 256  # TG set-points the TG → SIO FIFO holds (2.56 s at 10 ms)
OP_TIMEOUT_S = 2.0  # how long a client waits for the SV to carry out a mailbox operation
SlotStruct = np.ctypeslib.as_ctypes_type(layout.SERVO_SLOT)


def init_data_for(model: str, algo: ServoAlgorithm, joint: int) -> dict[str, float]:
    """The parameters a joint's private data starts with: the robot model's tuned gains for
    the built-ins, the algorithm's own defaults for plugins."""
    tables = {"pid": puma560.PID_DEFAULTS, "pd": puma560.PD_DEFAULTS}
    if model == "puma560" and algo.name in tables:
        return dict(tables[algo.name][joint])
    return {}


class ServoLevel:
    """Views of the servo level; ``create=True`` (SIO) allocates what is missing."""

    def __init__(self, inst: Instance, create: bool = False) -> None:
        self.inst = inst
        cfg = inst.config
        self.cfg = cfg
        self.names = [r.name for r in cfg.robots]
        self.n_robots = len(self.names)
        n = self.n = 6 * self.n_robots
        self.registry: Registry = registry_for(cfg.plugins, Path(cfg.base_dir))
        a = inst.arena
        get = a.record if create else a.existing
        self.robots = get(layout.KEY_ROBOTS, layout.ROBOT_STATE, self.n_robots)
        self.slots = get(layout.KEY_SLOTS, layout.SERVO_SLOT, n)
        self.ctrl = get(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
        width = layout.SERVO_STAGING_BYTES
        self.staging = get(layout.KEY_STAGING, np.dtype("u1"), n * width).reshape(n, width)
        self.data: list[list[np.ndarray]] = []
        for i in range(n):
            row = []
            for k in range(len(self.registry)):
                key = layout.KEY_SERVO_DATA.format(slot=i, algo=k)
                row.append(get(key, self.registry[k].dtype))
            self.data.append(row)
        self.structs = [[struct_view(rec) for rec in row] for row in self.data]
        self.slot_structs = (SlotStruct * n).from_buffer(self.slots)
        off = a.lookup(layout.KEY_SLOTS)[0]  # type: ignore[index]
        self.busy_addr = [a.address_of_field(off, layout.SERVO_SLOT, "busy", i) for i in range(n)]
        self.lock_addr = [
            a.address_of_field(off, layout.SERVO_SLOT, "op_lock", i) for i in range(n)
        ]
        self.op_addr = [a.address_of_field(off, layout.SERVO_SLOT, "op", i) for i in range(n)]
        coff = a.lookup(layout.KEY_SERVO_CTRL)[0]  # type: ignore[index]
        self.done_addr = a.address_of_field(coff, layout.SERVO_CTRL, "done")
        self.servo_period_s = cfg.clock.servo_period_ms / 1000.0
        self.fifo_ratio = Fraction(
            ms_to_ns(cfg.clock.tg_period_ms), ms_to_ns(cfg.clock.servo_period_ms)
        )  # exact: periods are whole ns

    def fifo(self, robot: int) -> InterpolatingFifo:
        """The TG → SIO set-point FIFO of robot index ``robot`` (Type 2, 2.2.2)."""
        key = layout.KEY_FIFO.format(robot=self.names[robot])
        return InterpolatingFifo(self.inst.arena, key, 6, FIFO_CAPACITY, self.fifo_ratio)

    def initialise(self) -> None:
        """First start (SIO): every joint's servo, data, tolerances and checks from the config."""
        for k, robot in enumerate(self.cfg.robots):
            r = self.robots[k]
            r["safe"] = robot.safe_rad
            r["range_check"] = 1
            r["power"] = PowerState.OFF
            r["calib_state"] = CalibState.IDLE
            first = self.registry.index(robot.servo)
            for j in range(6):
                i = 6 * k + j
                s = self.slot_structs[i]
                s.busy = layout.SLOT_NOT_FED
                s.algo = first
                s.enabled = 1
                for a, alg in enumerate(self.registry):
                    init = init_data_for(robot.model, alg, j)
                    alg.init(self.structs[i][a], init, self.servo_period_s)

    def close(self) -> None:
        """Drop the ctypes views (they pin the arena's buffer)."""
        self.structs = []
        self.slot_structs = None  # type: ignore[assignment]


class ServoClient:
    """What users, kalictl and robot programs do to the servo level (thesis 3.4)."""

    def __init__(self, inst: Instance) -> None:
        self.inst = inst
        self.level = ServoLevel(inst)
        self.names = self.level.names

    def close(self) -> None:
        """Release the views."""
        self.level.close()

    # ------------------------------------------------------------------ addressing

    def robot_index(self, robot: str | int) -> int:
        """Index of a robot given by name or index; ServoError naming the robots."""
        if isinstance(robot, int) and not isinstance(robot, bool):
            if 0 <= robot < len(self.names):
                return robot
        elif isinstance(robot, str) and robot in self.names:
            return self.names.index(robot)
        raise ServoError(f"no robot {robot!r}; robots: {', '.join(self.names)}")

    def slot(self, robot: str | int, joint: int) -> int:
        """Slot index of ``joint`` (1..6, as the thesis and the PUMA number them)."""
        k = self.robot_index(robot)
        if (
            isinstance(joint, bool)
            or not isinstance(joint, int | np.integer)
            or not 1 <= joint <= 6
        ):
            raise ServoError(f"joint {joint!r} of robot '{self.names[k]}', must be 1..6")
        return 6 * k + int(joint) - 1

    def algorithm(self, name: str) -> tuple[int, ServoAlgorithm]:
        """(index, algorithm) of a registered servo algorithm; ServoError naming them."""
        registry = self.level.registry
        if name not in registry.names():
            raise ServoError(f"no algorithm {name!r}; known: {', '.join(registry.names())}")
        idx = registry.index(name)
        return idx, registry[idx]

    def _where(self, i: int) -> str:
        return f"robot '{self.names[i // 6]}' joint {i % 6 + 1}"

    # ------------------------------------------------------------------ the mailbox

    def _clock_running(self) -> bool:
        return int(self.inst.clock["mode"]) != layout.RunMode.STOPPED

    def _op(self, i: int, op: SlotOp, algo: int, payload: bytes | None, wait: bool) -> None:
        """Post a mailbox operation on slot ``i`` for the SV.  With the clock stopped no SV
        runs, so put/get/params are carried out here; a select waits for the next tick (the
        hand-over needs that tick's measurement to be bumpless)."""
        lv = self.level
        lock = SpinLock(lv.lock_addr[i], f"servo slot {self._where(i)}")
        lock.acquire(OP_TIMEOUT_S)
        try:
            self._wait_op_clear(i)
            if payload is not None:
                lv.staging[i, : len(payload)] = np.frombuffer(payload, np.uint8)
            s = lv.slot_structs[i]
            s.op_algo = algo
            if not self._clock_running() and op != SlotOp.SELECT:
                apply_op(lv, i, int(op))  # no SV runs while the clock is stopped
                return
            done = int(s.ops_done)
            atomic.store32(lv.op_addr[i], int(op))  # published last: the SV acts on it
            if wait and self._clock_running():
                self._wait_done(i, done)
        finally:
            lock.release()

    def _wait_op_clear(self, i: int) -> None:
        deadline = time.monotonic() + OP_TIMEOUT_S
        while atomic.load32(self.level.op_addr[i]) != SlotOp.NONE:
            if not self._clock_running():
                apply_op(self.level, i, atomic.load32(self.level.op_addr[i]))
                atomic.store32(self.level.op_addr[i], SlotOp.NONE)
                return
            if time.monotonic() > deadline:
                raise ServoError(
                    f"{self._where(i)}: the previous update was not taken within "
                    f"{OP_TIMEOUT_S:g} s (are the SVs running?)"
                )
            time.sleep(0.0005)

    def _wait_done(self, i: int, before: int) -> None:
        deadline = time.monotonic() + OP_TIMEOUT_S
        s = self.level.slot_structs[i]
        while int(s.ops_done) == before:
            if time.monotonic() > deadline:
                raise ServoError(
                    f"{self._where(i)}: the SV did not carry out the update within "
                    f"{OP_TIMEOUT_S:g} s (is the clock running and the robot enabled?)"
                )
            if not self._clock_running():
                return  # halted meanwhile: it applies when the clock runs again
            time.sleep(0.0005)

    def put_servo(
        self, robot: str | int, joint: int, servo: str, data: np.ndarray, wait: bool = True
    ) -> None:
        """Replace the private data of algorithm ``servo`` on a joint (thesis 3.4 put_servo).

        ``data`` is one record of the algorithm's dtype (from ``get_servo``).  It takes effect
        at the joint's next servo tick; the servo is not skipped.
        """
        i = self.slot(robot, joint)
        idx, alg = self.algorithm(servo)
        rec = np.asarray(data)
        if rec.dtype != alg.dtype or rec.size != 1:
            raise ServoError(
                f"put_servo {self._where(i)} '{servo}': data of dtype {rec.dtype} and "
                f"size {rec.size}, expected one record of {alg.dtype}"
            )
        self._op(i, SlotOp.PUT, idx, rec.tobytes(), wait)

    def get_servo(self, robot: str | int, joint: int, servo: str) -> np.ndarray:
        """A consistent copy of the private data of algorithm ``servo`` on a joint (3.4)."""
        i = self.slot(robot, joint)
        idx, alg = self.algorithm(servo)
        self._op(i, SlotOp.GET, idx, None, wait=True)
        raw = self.level.staging[i, : alg.dtype.itemsize].copy()
        return raw.view(alg.dtype).reshape(())

    def select(self, robot: str | int, joint: int, servo: str, wait: bool = True) -> None:
        """Make ``servo`` the joint's algorithm, handing over bumplessly at the next tick."""
        i = self.slot(robot, joint)
        idx, _ = self.algorithm(servo)
        self._op(i, SlotOp.SELECT, idx, None, wait)

    def set_params(
        self,
        robot: str | int,
        joint: int,
        params: Mapping[str, float],
        servo: str | None = None,
        wait: bool = True,
    ) -> None:
        """Change parameters (gains) of ``servo`` (default: the joint's active one) on line.

        Validated here first, on a copy, so a bad value changes nothing.
        """
        i = self.slot(robot, joint)
        name = servo or self.active(robot, joint)
        idx, alg = self.algorithm(name)
        unknown = sorted(set(params) - set(alg.params))
        if unknown:
            raise ServoError(
                f"'{name}' has no parameter {', '.join(unknown)}; "
                f"parameters: {', '.join(alg.params)}"
            )
        trial = self.level.data[i][idx].copy()
        try:
            alg.set_params(struct_view(trial), dict(params))
        except KaliError as exc:
            raise ServoError(f"{self._where(i)} '{name}': {exc}") from None
        values = np.full(len(alg.params), math.nan)
        for key, value in params.items():
            values[alg.params.index(key)] = float(value)
        self._op(i, SlotOp.PARAMS, idx, values.tobytes(), wait)

    def get_params(
        self, robot: str | int, joint: int, servo: str | None = None
    ) -> dict[str, float]:
        """The parameters of ``servo`` (default: the active one) on a joint."""
        name = servo or self.active(robot, joint)
        _, alg = self.algorithm(name)
        rec = self.get_servo(robot, joint, name)
        return alg.get_params(struct_view(rec.copy()))

    def active(self, robot: str | int, joint: int) -> str:
        """Name of the joint's active servo algorithm."""
        i = self.slot(robot, joint)
        return self.level.registry[int(self.level.slot_structs[i].algo)].name

    # ------------------------------------------------------------------ single words

    def enable_servo(self, robot: str | int, joint: int, on: bool = True) -> None:
        """Run (or stop: zero torque) one joint's servo."""
        self.level.slot_structs[self.slot(robot, joint)].enabled = int(bool(on))

    def range_check(self, robot: str | int, joint: int, on: bool = True) -> None:
        """Turn SIO's joint-range check for one joint on or off."""
        i = self.slot(robot, joint)
        self.level.robots["range_check"][i // 6, i % 6] = int(bool(on))

    def set_safe(self, robot: str | int, joint: int, safe_rad: float) -> None:
        """Set a joint's tracking-error tolerance (rad) before a runaway halt."""
        i = self.slot(robot, joint)
        value = float(safe_rad)
        if not 0.0 < value <= math.pi:
            raise ServoError(f"safe {safe_rad!r} rad for {self._where(i)}, must be in (0, π]")
        self.level.robots["safe"][i // 6, i % 6] = value

    # ------------------------------------------------------------------ power

    def power(self, robot: str | int, on: bool) -> None:
        """Ask SIO to enable (or disable) a robot's amplifiers; see ``wait_power``."""
        k = self.robot_index(robot)
        if on and self.inst.fault["active"]:
            raise ServoError(
                f"cannot enable '{self.names[k]}' while a fault is active "
                f"({self.inst.fault_text()}); kalictl reset first"
            )
        self.level.robots["power_cmd"][k] = PowerCmd.ENABLE if on else PowerCmd.DISABLE

    def power_state(self, robot: str | int) -> PowerState:
        """The robot's amplifier power as SIO drives it."""
        return PowerState(int(self.level.robots["power"][self.robot_index(robot)]))

    # ------------------------------------------------------------------ feed-forward (3.3.6)

    def feedforward(self, robot: str | int, mode: str) -> None:
        """Switch a robot's feed-forward on line: ``off``, ``gravity``, or ``full`` (``on``):
        the inverse dynamics of the demanded motion.  SIO fades it in or out (no torque
        step); the dynamics process computes it."""
        k = self.robot_index(robot)
        modes = {"off": FfMode.OFF, "gravity": FfMode.GRAVITY, "full": FfMode.FULL}
        modes["on"] = FfMode.FULL
        if mode not in modes:
            raise ServoError(
                f"feed-forward of robot '{self.names[k]}': mode {mode!r}, must be one of "
                f"{', '.join(modes)}"
            )
        self._ff_records()["mode"][k] = modes[mode]

    def feedforward_state(self, robot: str | int) -> tuple[FfMode, FfState]:
        """(mode asked for, what SIO does with it) of a robot's feed-forward."""
        rec = self._ff_records()[self.robot_index(robot)]
        return FfMode(int(rec["mode"])), FfState(int(rec["state"]))

    def _ff_records(self) -> np.ndarray:
        if self.inst.arena.lookup(layout.KEY_FEEDFORWARD) is None:
            raise ServoError("feed-forward: SIO has not laid out its records yet")
        return self.inst.arena.existing(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, len(self.names))

    # ------------------------------------------------------------------ calibration (3.5.1)

    def calibrate(self, robot: str | int) -> None:
        """Ask SIO to calibrate a powered robot against its index pulses; see ``calibration``."""
        k = self.robot_index(robot)
        if self.inst.fault["active"]:
            raise ServoError(
                f"calibrate: robot '{self.names[k]}' cannot calibrate while a fault is active "
                f"({self.inst.fault_text()}); kalictl reset first"
            )
        self.level.robots["calib_cmd"][k] = 1

    def calibration(self, robot: str | int) -> tuple[CalibState, int, str]:
        """The robot's calibration: state, bit mask of index pulses found, SIO's message."""
        r = self.level.robots[self.robot_index(robot)]
        return CalibState(int(r["calib_state"])), int(r["calib_found"]), decode(r["message"])

    def calibrated(self, robot: str | int) -> bool:
        """True once the robot's angles are exact (calibrated against the index pulses)."""
        return bool(self.level.robots["calibrated"][self.robot_index(robot)])

    def require_calibrated(self, robot: str | int, what: str) -> None:
        """ServoError unless the robot is calibrated: Cartesian motion needs exact angles."""
        if not self.calibrated(robot):
            name = self.names[self.robot_index(robot)]
            raise ServoError(
                f"{what}: robot '{name}' is not calibrated; its angles come from the "
                f"potentiometers (about 1° off), too coarse for Cartesian motion. "
                f"Run: kalictl calibrate {name}"
            )


def apply_op(level: ServoLevel, i: int, op: int) -> None:
    """Carry out mailbox operation ``op`` on slot ``i`` (the SV, or a client while the clock
    is stopped and no SV runs).  Only PARAMS allocates, and only when asked for."""
    s = level.slot_structs[i]
    a = int(s.op_algo)
    if a >= len(level.registry):
        s.status = -1
        return
    alg = level.registry[a]
    size = alg.dtype.itemsize
    if op == SlotOp.PUT:
        ctypes.memmove(ctypes.addressof(level.structs[i][a]), level.staging[i].ctypes.data, size)
    elif op == SlotOp.GET:
        ctypes.memmove(level.staging[i].ctypes.data, ctypes.addressof(level.structs[i][a]), size)
    elif op == SlotOp.SELECT:
        handover(level, i, a)
    elif op == SlotOp.PARAMS:
        values = level.staging[i, : 8 * len(alg.params)].view(np.float64)
        alg.set_params(
            level.structs[i][a],
            {p: float(v) for p, v in zip(alg.params, values, strict=True) if not math.isnan(v)},
        )
    s.ops_done += 1


def handover(level: ServoLevel, i: int, a: int) -> None:
    """Switch slot ``i`` to algorithm ``a``, initialising its state from the running servo so
    the torque does not jump (bumpless transfer)."""
    s = level.slot_structs[i]
    level.registry[a].handover(
        level.structs[i][a],
        Handover(s.position, s.velocity, s.demand, s.error, s.torque),
    )
    s.algo = a
