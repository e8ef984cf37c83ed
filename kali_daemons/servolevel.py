"""The servo level in the arena (DESIGN 4, thesis 3.3.3 - 3.4, figure 3.3), as SIO, the SVs
and clients see it.

- ``robots``: one ``ROBOT_STATE`` per robot (power, calibration).
- ``joints``: one ``JOINT_STATE`` per joint of the cell (SIO's measurements, the clients'
  tolerances and checks), flat: robot k joint j is ``cfg.joints.base[k] + j``.
- ``slots``: one ``SERVO_SLOT`` per joint, flat in the same order.  SIO feeds
  them and clears ``busy``; an SV claims a slot by test-and-set of ``busy`` (3.3.5).
- Private data: one record per (slot, algorithm) of that algorithm's dtype, so a joint keeps
  the state of every algorithm it may switch to, and any SV can run any joint (3.3.4).  An
  algorithm's records for all joints are one block (``blocks[k]``, slot order), so an SV can
  run a built-in over a robot's joints in one call; ``data[i][k]`` views slot i's record.
- The put/get mailbox (3.4): a client never touches a running servo's data.  It writes the
  staging bytes and the operation, and the SV carries it out at the slot's next run, before
  the step.  So a servo is never skipped for an update and never sees half-written data.
  The SV trusts none of it (DESIGN 7): an undefined operation, an algorithm index outside the
  registry, a PUT record with a non-finite field or a parameter out of range, a PARAMS value
  out of range are refused (``apply_op``), the servo's data unchanged; the slot's
  ``op_status`` says so and the staging bytes then hold the reason, which ``ServoClient``
  raises as a ServoError.

``ServoLevel`` is the view; ``ServoClient`` adds the operations users call (put/get/select,
gains, enable, range checking, ``safe``, power, calibration).
"""

from __future__ import annotations

import ctypes
import math
import time
from collections.abc import Callable, Mapping, Sequence
from fractions import Fraction
from pathlib import Path
from typing import Protocol

import numpy as np

from . import atomic, layout, shadow
from .channels import InterpolatingFifo
from .config import ms_to_ns
from .errors import InstanceError, KaliError, ServoError
from .instance import Instance, decode
from .layout import CalibState, FfMode, FfState, PowerState, ShadowState, SlotOp
from .robots import robot_type
from .servo import (
    ArmServoAlgorithm,
    Handover,
    Registry,
    ServoAlgorithm,
    registry_for,
    struct_view,
)
from .shadow import Trial
from .spinlock import SpinLock

FIFO_CAPACITY = layout.FIFO_CAPACITY  # TG set-points a TG → SIO FIFO holds (the layout sizes it)
# SIO refuses a set-point beyond ±this (rad) as garbage, holding instead: two full turns either
# way is no joint angle (joint range itself is SIO's range check, which halts)
SETPOINT_BOUND_RAD = 4.0 * math.pi
OP_TIMEOUT_S = 2.0  # how long a client waits for the SV to carry out a mailbox operation
# numpy's stubs type a structured dtype's ctypes class as a scalar's (dtype[void] matches no
# overload); it is a Structure
SlotStruct: type[ctypes.Structure] = np.ctypeslib.as_ctypes_type(layout.SERVO_SLOT)  # type: ignore[arg-type, assignment]
JOINT_SERVOS = "joints"  # what ``select_arm`` takes for "back to the joint servos"
FORCE_SETPOINTS = ("fx", "fy", "fz")  # robot-level parameters the wrist sensor must measure
SQUEEZE_SETPOINT = "fi"  # and a squeeze, along any line: within the smallest force range
SQUEEZE_PARTNER = "partner"  # the arm sharing the squeeze: its config index + 1


class ArmHands(Protocol):
    """What carrying out a robot's SELECT or SHADOW needs: this tick's inputs, which only
    the SV that claimed the robot has (``sv.arm.ArmRunner``)."""

    def select(self, a: int) -> None:
        """Switch the robot to robot-level servo ``a`` (ARM_NONE: its joint servos)."""

    def trial(self, a: int) -> str:
        """Start a shadow trial of robot-level servo ``a``; '' or why it was refused."""


class _NoHands:
    """A client's: it carries out neither (``_arm_op`` leaves both to the SV)."""

    def select(self, a: int) -> None:
        raise ServoError("a select is carried out by the SV at the robot's next tick")

    def trial(self, a: int) -> str:
        raise ServoError("a shadow trial is started by the SV at the robot's next tick")


def flag(what: str, value: object) -> bool:
    """``value`` as an on/off flag: a bool, or the integers 0 and 1 (numpy's too); ServoError
    naming ``what`` for anything else (an array's truth is ambiguous, a string's meaningless)."""
    if isinstance(value, bool | np.bool_) or (
        isinstance(value, int | np.integer) and int(value) in (0, 1)
    ):
        return bool(value)
    raise ServoError(f"{what}: {value!r:.60} is not a flag (True/False, 1/0)")


def check_names(where: str, name: str, known: tuple[str, ...], params: Mapping[str, float]) -> None:
    """ServoError unless ``params`` is a mapping of algorithm ``name``'s parameters."""
    if not isinstance(params, Mapping):
        raise ServoError(
            f"{where}: parameters {params!r:.60} are not a mapping of names to values "
            f"(e.g. {{'{known[0] if known else 'kp'}': 1.0}})"
        )
    unknown = sorted(str(p) for p in set(params) - set(known))
    if unknown:
        raise ServoError(
            f"'{name}' has no parameter {', '.join(unknown)}; parameters: {', '.join(known)}"
        )


def init_data_for(model: str, algo: ServoAlgorithm, joint: int) -> dict[str, float]:
    """The parameters a joint's private data starts with: the robot type's tuned gains for
    the built-ins, the algorithm's own defaults for plugins."""
    rtype = robot_type(model)
    tables = {"pid": rtype.pid_defaults, "pd": rtype.pd_defaults}
    if algo.name in tables:
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
        self.map = cfg.joints  # the flat joint numbering
        n = self.n = self.map.total
        self.registry: Registry = registry_for(cfg.plugins, Path(cfg.base_dir), cfg.files)
        a = inst.arena
        get = a.record if create else a.existing
        self.robots = get(layout.KEY_ROBOTS, layout.ROBOT_STATE, self.n_robots)
        self.joints = get(layout.KEY_JOINTS, layout.JOINT_STATE, n)
        self.slots = get(layout.KEY_SLOTS, layout.SERVO_SLOT, n)
        self.ctrl = get(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
        self.servo_names = get(
            layout.KEY_SERVO_NAMES,
            layout.SERVO_NAME,
            len(self.registry) + len(self.registry.arms),
        )
        width = layout.SERVO_STAGING_BYTES
        self.staging = get(layout.KEY_STAGING, np.dtype("u1"), n * width).reshape(n, width)
        # algorithm k's private data for every joint, one record per slot (servo.vector runs
        # a built-in over a robot's joints in one call); data[i][k] is slot i's record of it
        self.blocks: list[np.ndarray] = [
            get(layout.KEY_SERVO_DATA.format(algo=k), alg.dtype, n)
            for k, alg in enumerate(self.registry)
        ]
        self.data: list[list[np.ndarray]] = [
            [block[i : i + 1].reshape(()) for block in self.blocks] for i in range(n)
        ]
        self.structs = [[struct_view(rec) for rec in row] for row in self.data]
        # numpy's stubs give an ndarray the buffer protocol only from Python 3.12 on
        self.slot_structs = (SlotStruct * n).from_buffer(self.slots)  # type: ignore[arg-type]
        # robot-level servos: algorithm a's record for every robot is one block,
        # arm_data[k][a] robot k's record (0-d); each robot's mailbox staging bytes
        nr = self.n_robots
        self.arm_blocks: list[np.ndarray] = [
            get(layout.KEY_ARM_DATA.format(arm=k), alg.dtype, nr)
            for k, alg in enumerate(self.registry.arms)
        ]
        self.arm_data: list[list[np.ndarray]] = [
            [block[k : k + 1].reshape(()) for block in self.arm_blocks] for k in range(nr)
        ]
        self.arm_staging = get(layout.KEY_ARM_STAGING, np.dtype("u1"), nr * width).reshape(
            nr, width
        )
        roff = a.lookup(layout.KEY_ROBOTS)[0]  # type: ignore[index]
        rs = layout.ROBOT_STATE
        self.arm_op_addr = [a.address_of_field(roff, rs, "arm_op", k) for k in range(nr)]
        self.arm_lock_addr = [a.address_of_field(roff, rs, "arm_op_lock", k) for k in range(nr)]
        off = a.lookup(layout.KEY_SLOTS)[0]  # type: ignore[index]
        self.busy_addr = [a.address_of_field(off, layout.SERVO_SLOT, "busy", i) for i in range(n)]
        self.lock_addr = [
            a.address_of_field(off, layout.SERVO_SLOT, "op_lock", i) for i in range(n)
        ]
        self.op_addr = [a.address_of_field(off, layout.SERVO_SLOT, "op", i) for i in range(n)]
        self.shadows_addr = [a.address_of_field(roff, rs, "shadows", k) for k in range(nr)]
        coff = a.lookup(layout.KEY_SERVO_CTRL)[0]  # type: ignore[index]
        self.done_addr = a.address_of_field(coff, layout.SERVO_CTRL, "done")
        self.servo_period_s = cfg.clock.servo_period_ms / 1000.0
        self.fifo_ratio = Fraction(
            ms_to_ns(cfg.clock.tg_period_ms), ms_to_ns(cfg.clock.servo_period_ms)
        )  # exact: periods are whole ns

    def arm(self, field: str, robot: int) -> np.ndarray:
        """Robot index ``robot``'s joints of a ``JOINT_STATE`` field: a live view into the
        arena (``arm("q", 0)`` is the first arm's measured angles); outside the cycle."""
        return self.joints[field][self.map.span(robot)]

    def fifo(self, robot: int) -> InterpolatingFifo:
        """The TG → SIO set-point FIFO of robot index ``robot`` (Type 2, 2.2.2); as SIO
        consumes it, a set-point beyond ``SETPOINT_BOUND_RAD`` or not finite is refused."""
        key = layout.KEY_FIFO.format(robot=self.names[robot])
        width = self.map.counts[robot]
        return InterpolatingFifo(
            self.inst.arena, key, width, FIFO_CAPACITY, self.fifo_ratio, bound=SETPOINT_BOUND_RAD
        )

    def initialise(self) -> None:
        """First start (SIO): every joint's servo, data, tolerances and checks from the config."""
        named = [(n, 0) for n in self.registry.names()]
        named += [(n, 1) for n in self.registry.arm_names()]
        for rec, (name, robot_level) in zip(self.servo_names, named, strict=True):
            rec["name"], rec["robot_level"] = name.encode()[:31], robot_level
        for k, robot in enumerate(self.cfg.robots):
            r = self.robots[k]
            span = self.map.span(k)
            r["first_joint"] = span.start
            r["n_joints"] = robot.n_joints
            self.joints["safe"][span] = robot.safe_rad
            self.joints["range_check"][span] = 1
            r["power"] = PowerState.OFF
            r["calib_state"] = CalibState.IDLE
            r["arm_algo"] = layout.ARM_NONE
            r["arm_shadow"] = layout.NO_SHADOW
            r["guided"] = 0
            for a, arm in enumerate(self.registry.arms):
                arm.init(self.arm_data[k][a], {}, self.servo_period_s)
            first = self.registry.index(robot.servo)
            for j in range(robot.n_joints):
                i = self.map.index(k, j)
                s = self.slot_structs[i]
                s.busy = layout.SLOT_NOT_FED
                s.algo = first
                s.shadow = layout.NO_SHADOW
                s.shadow_torque = math.nan  # no trial (the flight recorder's column)
                s.enabled = 1
                for a, alg in enumerate(self.registry):
                    init = init_data_for(robot.model, alg, j)
                    alg.init(self.structs[i][a], init, self.servo_period_s)

    def close(self) -> None:
        """Drop the ctypes views (they pin the arena's buffer)."""
        self.structs = []
        self.arm_data = []
        self.slot_structs = None  # type: ignore[assignment]


class ServoClient:
    """What users, kalictl and robot programs do to the servo level (thesis 3.4)."""

    def __init__(self, inst: Instance, pause: Callable[[], None] | None = None) -> None:
        """``pause``: how its user lets time pass (a program's ``Kali.pause``, which steps a
        lockstep instance's stopped clock): given, a call that needs a servo tick (a
        robot-level select or shadow, or one behind it) waits for it as ``wait()`` does;
        without it (kalictl) such a call says the clock must be stepped."""
        self.inst = inst
        self.level = ServoLevel(inst)
        self.names = self.level.names
        self._pause = pause

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
        raise ServoError(f"no robot {robot!r:.60}; robots: {', '.join(self.names)}")

    def slot(self, robot: str | int, joint: int) -> int:
        """Slot index of ``joint`` (1..n, as the thesis numbers the PUMA's)."""
        k = self.robot_index(robot)
        n = self.level.map.counts[k]
        if (
            isinstance(joint, bool)
            or not isinstance(joint, int | np.integer)
            or not 1 <= joint <= n
        ):
            raise ServoError(f"joint {joint!r:.60} of robot '{self.names[k]}', must be 1..{n}")
        return self.level.map.index(k, int(joint) - 1)

    def algorithm(self, name: str) -> tuple[int, ServoAlgorithm]:
        """(index, algorithm) of a registered servo algorithm; ServoError naming them."""
        registry = self.level.registry
        if not isinstance(name, str) or name not in registry.names():
            raise ServoError(f"no algorithm {name!r:.60}; known: {', '.join(registry.names())}")
        idx = registry.index(name)
        return idx, registry[idx]

    def _where(self, i: int) -> str:
        return self.level.map.label(i)

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
                if not apply_op(lv, i, int(op)):  # no SV runs while the clock is stopped
                    self._check_refused(i)
                return
            done = int(s.ops_done)
            atomic.store32(lv.op_addr[i], int(op))  # published last: the SV acts on it
            if wait and self._clock_running():
                self._wait_done(i, done)
                if int(s.ops_done) != done:
                    self._check_refused(i)
        finally:
            lock.release()

    def _check_refused(self, i: int) -> None:
        """ServoError with the SV's reason if slot ``i``'s last mailbox operation was refused."""
        if int(self.level.slot_structs[i].op_status) == layout.OP_REFUSED:
            raise ServoError(f"{self._where(i)}: {refusal_text(self.level, i)}")

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
        rec = _one_record(f"put_servo {self._where(i)} '{servo}'", data, alg.dtype)
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
        name = self.active(robot, joint) if servo is None else servo
        idx, alg = self._check_params(i, name, params)
        values = np.full(len(alg.params), math.nan)
        for key, value in params.items():
            values[alg.params.index(key)] = float(value)
        self._op(i, SlotOp.PARAMS, idx, values.tobytes(), wait)

    def select_joints(
        self,
        robot: str | int,
        servo: str,
        params: Sequence[Mapping[str, float]] | Mapping[str, float] | None = None,
    ) -> None:
        """Every joint of ``robot`` onto joint servo ``servo``, each with its parameters
        (``params[j]`` for joint j + 1; one mapping: the same for every joint), selected
        together so they hand over on one servo tick.  Every joint's parameters are checked
        before any is changed: a bad one is a ServoError naming the joint, nothing changed."""
        k = self.robot_index(robot)
        n = self.level.map.counts[k]
        if params is None or isinstance(params, Mapping):
            per_joint: list[Mapping[str, float]] = [dict(params or {})] * n
        else:
            per_joint = list(params)
            if len(per_joint) != n:
                raise ServoError(
                    f"select_joints: robot '{self.names[k]}' has {n} joints, "
                    f"{len(per_joint)} sets of parameters given"
                )
        for j, values in enumerate(per_joint, start=1):  # all checked, then all changed
            self._check_params(self.slot(k, j), servo, values)
        for j, values in enumerate(per_joint, start=1):
            if values:
                self.set_params(k, j, values, servo)
        for j in range(1, n + 1):  # posted back to back: taken on one tick
            self.select(k, j, servo, wait=False)
        deadline = time.monotonic() + OP_TIMEOUT_S
        while any(atomic.load32(self.level.op_addr[self.slot(k, j)]) for j in range(1, n + 1)):
            if time.monotonic() > deadline:
                raise ServoError(
                    f"select_joints: robot '{self.names[k]}': the SVs did not take '{servo}' "
                    f"within {OP_TIMEOUT_S:g} s (is the clock running?)"
                )
            self._servo_tick(f"robot '{self.names[k]}': select_joints waits for the next tick")
        for j in range(1, n + 1):
            self._check_refused(self.slot(k, j))

    def _check_params(
        self, i: int, name: str, params: Mapping[str, float]
    ) -> tuple[int, ServoAlgorithm]:
        """Servo ``name``'s index and algorithm, once ``params`` are known to be valid for
        slot ``i`` (set on a copy of its record); ServoError naming the slot otherwise."""
        idx, alg = self.algorithm(name)
        check_names(f"{self._where(i)} '{name}'", name, alg.params, params)
        trial = self.level.data[i][idx].copy()
        try:
            alg.set_params(struct_view(trial), dict(params))
        except KaliError as exc:
            raise ServoError(f"{self._where(i)} '{name}': {exc}") from None
        return idx, alg

    def get_params(
        self, robot: str | int, joint: int, servo: str | None = None
    ) -> dict[str, float]:
        """The parameters of ``servo`` (default: the active one) on a joint."""
        name = self.active(robot, joint) if servo is None else servo
        _, alg = self.algorithm(name)
        rec = self.get_servo(robot, joint, name)
        return alg.get_params(struct_view(rec.copy()))

    def shadow(self, robot: str | int, joint: int, servo: str | None, wait: bool = True) -> None:
        """Run joint servo ``servo`` in shadow beside the joint's active servo (None: end the
        trial running): stepped every tick on the same inputs from the running servo's
        state, its torque compared, never applied (``kali_daemons.shadow``; ``trials``
        reads the figures).  Selecting it afterwards goes on from its own state."""
        i = self.slot(robot, joint)
        idx = layout.SHADOW_OFF if servo is None else self.algorithm(servo)[0]
        self._op(i, SlotOp.SHADOW, idx, None, wait)

    def shadow_arm(self, robot: str | int, servo: str | None, wait: bool = True) -> None:
        """Run robot-level servo ``servo`` in shadow beside the robot's active servos (None:
        end the trial running), as ``shadow`` for a joint; it needs the robot's model
        (``robot_servos: true``) and, if it moves by the wrist sensor, a tared one."""
        k = self.robot_index(robot)
        if servo is None:
            self._arm_op(k, SlotOp.SHADOW, layout.ARM_NONE, None, wait)
            return
        idx, alg = self.arm_algorithm(servo)
        if isinstance(alg, ArmServoAlgorithm) and alg.senses:
            self._check_tared(k, alg.name)
        self._arm_op(k, SlotOp.SHADOW, idx, None, wait)

    def trials(self, robot: str | int | None = None) -> list[Trial]:
        """Every joint's figures from its last shadow trial (of ``robot``, or all)."""
        k = None if robot is None else self.robot_index(robot)
        return shadow.trials(self.level, k)

    def active(self, robot: str | int, joint: int) -> str:
        """Name of the joint's active servo algorithm; ServoError if the slot holds an index
        outside the registry (written by something other than an SV, which restores it)."""
        i = self.slot(robot, joint)
        a = int(self.level.slot_structs[i].algo)
        registry = self.level.registry
        if not 0 <= a < len(registry):
            raise ServoError(
                f"{self._where(i)}: algorithm index {a} in the arena, registered 0.."
                f"{len(registry) - 1}; the SV restores the robot's configured servo at its next run"
            )
        return registry[a].name

    # ------------------------------------------------------------------ robot-level servos

    def arm_algorithm(self, name: str) -> tuple[int, ServoAlgorithm | ArmServoAlgorithm]:
        """(index, algorithm) of a robot-level servo; ServoError naming them (and saying so
        when ``name`` is a joint servo)."""
        registry = self.level.registry
        if isinstance(name, str) and name in registry.arm_names():
            idx = registry.arm_index(name)
            return idx, registry.arms[idx]
        if isinstance(name, str) and name in registry.names():
            raise ServoError(
                f"'{name}' is a joint servo: select it per joint (kalictl servo select ROBOT "
                f"JOINT {name}); robot-level servos: {', '.join(registry.arm_names())}"
            )
        raise ServoError(
            f"no robot-level algorithm {name!r:.60}; known: {', '.join(registry.arm_names())}"
            f" (or '{JOINT_SERVOS}' for the joint servos)"
        )

    def arm_active(self, robot: str | int) -> str | None:
        """The robot-level servo robot ``robot`` runs, or None while it runs joint servos."""
        k = self.robot_index(robot)
        a = int(self.level.robots["arm_algo"][k])
        arms = self.level.registry.arms
        return arms[a].name if 0 <= a < len(arms) else None

    def select_arm(self, robot: str | int, servo: str | None, wait: bool = True) -> None:
        """Make robot-level servo ``servo`` run the whole robot (None or ``'joints'``: back to
        its joint servos), handed over bumplessly at the next tick (thesis 3.3.4)."""
        k = self.robot_index(robot)
        if servo is None or servo == JOINT_SERVOS:
            idx = layout.ARM_NONE
        else:
            idx, alg = self.arm_algorithm(servo)
            if isinstance(alg, ArmServoAlgorithm) and alg.senses:
                self._check_tared(k, alg.name)
            if not self.inst.config.robots[k].robot_servos:
                raise ServoError(
                    f"robot '{self.names[k]}' runs no robot-level servo: its config has "
                    f"robot_servos: false (set robots[].robot_servos: true; the SVs then "
                    f"load its model, Pinocchio, ~20 MB each)"
                )
        self._arm_op(k, SlotOp.SELECT, idx, None, wait)

    def set_arm_params(
        self,
        robot: str | int,
        params: Mapping[str, float],
        servo: str | None = None,
        wait: bool = True,
    ) -> None:
        """Change parameters of robot-level servo ``servo`` (default: the active one) on line;
        validated here first, on a copy, so a bad value changes nothing.  A force set-point
        (``fx``, ``fy``, ``fz``) needs a wrist sensor and must lie within its rated range."""
        k = self.robot_index(robot)
        name = self._arm_name(k, servo)
        idx, alg = self.arm_algorithm(name)
        where = f"robot '{self.names[k]}' '{name}'"
        check_names(where, name, alg.params, params)
        trial = self.level.arm_data[k][idx].copy()
        try:
            alg.set_params(trial, dict(params))
        except KaliError as exc:
            raise ServoError(f"{where}: {exc}") from None
        self._check_force_setpoint(k, where, params)
        self._check_partner(k, where, params)
        values = np.full(len(alg.params), math.nan)
        for key, value in params.items():
            values[alg.params.index(key)] = float(value)
        self._arm_op(k, SlotOp.PARAMS, idx, values.tobytes(), wait)

    def _check_tared(self, k: int, servo: str) -> None:
        """ServoError unless robot ``k`` has a wrist sensor that has been tared: servo
        ``servo`` moves the arm by it, so a sensor's offsets would move the arm."""
        name = self.names[k]
        if self.inst.config.robots[k].ft.sheet is None:
            raise ServoError(
                f"robot '{name}' '{servo}': the arm has no wrist sensor to be moved by "
                f"(robots[].ft.sensor)"
            )
        ft = self.inst.arena.existing(layout.KEY_FT, layout.FT_STATE, len(self.names))
        if int(ft["tare_count"][k]) == 0:
            raise ServoError(
                f"robot '{name}' '{servo}': its wrist sensor was never tared, and its offsets "
                f"would move the arm: tare it at rest, touching nothing (Robot.tare)"
            )

    def _check_partner(self, k: int, where: str, params: Mapping[str, float]) -> None:
        """ServoError for a squeeze partner that is not another robot of the cell with a
        wrist sensor: the servo reads the partner's wrench by that index every tick."""
        partner = int(params.get(SQUEEZE_PARTNER, 0))
        if not partner:
            return
        other = partner - 1
        if other == k or other >= len(self.names):
            raise ServoError(
                f"{where}: {SQUEEZE_PARTNER} = {partner}: not another robot of the cell "
                f"(1..{len(self.names)}, not robot '{self.names[k]}' itself, {k + 1})"
            )
        if self.inst.config.robots[other].ft.sheet is None:
            raise ServoError(
                f"{where}: {SQUEEZE_PARTNER} = {partner}: robot '{self.names[other]}' has no "
                f"wrist sensor to share a squeeze with (robots[].ft.sensor)"
            )

    def _check_force_setpoint(self, k: int, where: str, params: Mapping[str, float]) -> None:
        """ServoError for a force set-point the robot's wrist sensor could not measure."""
        sheet = self.inst.config.robots[k].ft.sheet
        for axis, key in enumerate((*FORCE_SETPOINTS, SQUEEZE_SETPOINT)):
            if key not in params or float(params[key]) == 0.0:
                continue
            value = float(params[key])
            if sheet is None:
                raise ServoError(
                    f"{where}: {key} = {value:g} N: robot '{self.names[k]}' has no wrist "
                    f"sensor to hold a force with (robots[].ft.sensor)"
                )
            rated = min(sheet.rated[:3]) if key == SQUEEZE_SETPOINT else sheet.rated[axis]
            if abs(value) > rated:
                raise ServoError(
                    f"{where}: {key} = {value:g} N beyond the {sheet.name} sensor's rated "
                    f"range ±{rated:g} N on that axis"
                )

    def get_arm_params(self, robot: str | int, servo: str | None = None) -> dict[str, float]:
        """The parameters of robot-level servo ``servo`` (default: the active one)."""
        k = self.robot_index(robot)
        name = self._arm_name(k, servo)
        _, alg = self.arm_algorithm(name)
        return alg.get_params(self.get_arm(robot, name).copy())

    def get_arm(self, robot: str | int, servo: str) -> np.ndarray:
        """A consistent copy of robot ``robot``'s record of robot-level servo ``servo``:
        through the mailbox while the clock runs, read in place while it is stopped (no SV
        writes it then, and an operation still pending in the mailbox is left to its tick)."""
        k = self.robot_index(robot)
        idx, alg = self.arm_algorithm(servo)
        if not self._clock_running():
            return self.level.arm_data[k][idx].copy()
        self._arm_op(k, SlotOp.GET, idx, None, wait=True)
        raw = self.level.arm_staging[k, : alg.dtype.itemsize].copy()
        return raw.view(alg.dtype).reshape(())

    def put_arm(self, robot: str | int, servo: str, data: np.ndarray, wait: bool = True) -> None:
        """Replace robot ``robot``'s record of robot-level servo ``servo`` (from ``get_arm``)."""
        k = self.robot_index(robot)
        idx, alg = self.arm_algorithm(servo)
        rec = _one_record(f"put_arm robot '{self.names[k]}' '{servo}'", data, alg.dtype)
        self._arm_op(k, SlotOp.PUT, idx, rec.tobytes(), wait)

    def _arm_name(self, k: int, servo: str | None) -> str:
        if servo is not None:
            return servo
        active = self.arm_active(k)
        if active is None:
            raise ServoError(
                f"robot '{self.names[k]}' runs its joint servos: name the robot-level servo "
                f"({', '.join(self.level.registry.arm_names())})"
            )
        return active

    def _arm_op(self, k: int, op: SlotOp, algo: int, payload: bytes | None, wait: bool) -> None:
        """Post a robot-level mailbox operation for the SV that claims robot ``k``; with the
        clock stopped a get/put/params is carried out here, a select or shadow waits for the
        next tick (its hand-over needs that tick's measurement), as does any operation
        behind one still pending (``_servo_tick``)."""
        lv = self.level
        r = lv.robots[k : k + 1].reshape(())
        what = f"robot '{self.names[k]}': robot-level {op.name.lower()}"
        lock = SpinLock(lv.arm_lock_addr[k], f"robot-level servo mailbox of '{self.names[k]}'")
        lock.acquire(OP_TIMEOUT_S)
        try:
            deadline = time.monotonic() + OP_TIMEOUT_S
            while (pending := atomic.load32(lv.arm_op_addr[k])) != SlotOp.NONE:
                if time.monotonic() > deadline:
                    raise ServoError(
                        f"{what}: the robot-level {_op_name(pending).lower()} asked before "
                        f"it was not taken within {OP_TIMEOUT_S:g} s (are the SVs running?)"
                    )
                before = _op_name(pending).lower()
                self._servo_tick(f"{what} waits for the {before} asked before it")
            if payload is not None:
                lv.arm_staging[k, : len(payload)] = np.frombuffer(payload, np.uint8)
            r["arm_op_algo"] = algo
            if not self._clock_running() and op not in (SlotOp.SELECT, SlotOp.SHADOW):
                apply_arm_op(lv, k, int(op), _NoHands())
                self._arm_refused(k)
                return
            done = int(r["arm_ops_done"])
            atomic.store32(lv.arm_op_addr[k], int(op))  # published last: the SV acts on it
            if not wait:
                return
            while int(r["arm_ops_done"]) == done:
                if op in (SlotOp.SELECT, SlotOp.SHADOW) and int(r["power"]) != PowerState.ON:
                    return  # no SV serves an unpowered arm: carried out at its first tick on
                if time.monotonic() > deadline + OP_TIMEOUT_S:
                    raise ServoError(
                        f"{what}: the SV did not carry it out within {OP_TIMEOUT_S:g} s "
                        f"(is the clock running?)"
                    )
                self._servo_tick(f"{what} waits for the next servo tick")
            self._arm_refused(k)
        finally:
            lock.release()

    def _servo_tick(self, what: str) -> None:
        """Let time pass until the SV's next tick for ``what``: a short sleep while the
        clock runs; a step of a lockstep instance's stopped clock through ``pause`` (a
        program's, as its ``wait()`` steps it); else ServoError saying the clock must run
        (kalictl in lockstep, or a halt)."""
        if self._clock_running():
            time.sleep(0.0005)
        elif self.inst.fault["active"]:
            raise ServoError(f"{what}, and the system is halted ({self.inst.fault_text()})")
        elif self.inst.lockstep and self._pause is not None:
            self._pause()
        else:
            how = "lockstep: kalictl clock step 1" if self.inst.lockstep else "kalictl reset"
            raise ServoError(f"{what}, and the clock is stopped ({how})")

    def _arm_refused(self, k: int) -> None:
        if int(self.level.robots["arm_op_status"][k]) == layout.OP_REFUSED:
            text = decode(self.level.arm_staging[k].tobytes())
            raise ServoError(f"robot '{self.names[k]}': {text}")

    # ------------------------------------------------------------------ single words

    def enable_servo(self, robot: str | int, joint: int, on: bool = True) -> None:
        """Run (or stop: zero torque) one joint's servo."""
        i = self.slot(robot, joint)
        self.level.slot_structs[i].enabled = int(flag(f"enable_servo {self._where(i)}", on))

    def range_check(self, robot: str | int, joint: int, on: bool = True) -> None:
        """Turn SIO's joint-range check for one joint on or off."""
        i = self.slot(robot, joint)
        on = flag(f"range_check {self._where(i)}", on)
        self.level.joints["range_check"][i] = int(on)

    def set_safe(self, robot: str | int, joint: int, safe_rad: float) -> None:
        """Set a joint's tracking-error tolerance (rad) before a runaway halt."""
        i = self.slot(robot, joint)
        try:
            value = float(safe_rad)
        except (TypeError, ValueError):
            value = math.nan
        if isinstance(safe_rad, bool) or not 0.0 < value <= math.pi:
            raise ServoError(f"safe {safe_rad!r:.60} rad for {self._where(i)}, must be in (0, π]")
        self.level.joints["safe"][i] = value

    # ------------------------------------------------------------------ power

    def power(self, robot: str | int, on: bool) -> None:
        """Ask SIO to enable (or disable) a robot's amplifiers; see ``wait_power``."""
        k = self.robot_index(robot)
        on = flag(f"power of robot '{self.names[k]}'", on)
        try:
            self.inst.command_power(k, on)
        except InstanceError as exc:
            raise ServoError(str(exc)) from None

    def _faults(self) -> int:
        """The stamp of a command: the faults raised so far (low 32 bits), read before the
        fault check and written before the command word.  SIO drops a command whose stamp is
        not the current count, so a halt after the check voids it (LinuxCNC: a halt forgets
        every pending command)."""
        return int(self.inst.fault["count"]) & 0xFFFFFFFF

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
        if not isinstance(mode, str) or mode not in modes:
            raise ServoError(
                f"feed-forward of robot '{self.names[k]}': mode {mode!r:.60}, must be one of "
                f"{', '.join(modes)}"
            )
        self._ff_records()["mode"][k] = modes[mode]

    def feedforward_state(self, robot: str | int) -> tuple[FfMode, FfState]:
        """(mode asked for, what SIO does with it) of a robot's feed-forward; ServoError if
        the mode word holds no FfMode (written outside ``feedforward``; SIO and the dynamics
        process keep the last valid mode meanwhile)."""
        k = self.robot_index(robot)
        rec = self._ff_records()[k]
        mode, state = int(rec["mode"]), int(rec["state"])
        if mode not in FF_MODES or state not in FF_STATES:
            raise ServoError(
                f"feed-forward of robot '{self.names[k]}': mode word {mode}, state {state} in "
                f"the arena; modes are {', '.join(f'{m.value} {m.name}' for m in FfMode)}"
            )
        return FfMode(mode), FfState(state)

    def _ff_records(self) -> np.ndarray:
        if self.inst.arena.lookup(layout.KEY_FEEDFORWARD) is None:
            raise ServoError("feed-forward: SIO has not laid out its records yet")
        return self.inst.arena.existing(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, len(self.names))

    # ------------------------------------------------------------------ calibration (3.5.1)

    def calibrate(self, robot: str | int) -> None:
        """Ask SIO to calibrate a powered robot against its index pulses; see ``calibration``."""
        k = self.robot_index(robot)
        stamp = self._faults()
        if self.inst.fault["active"]:
            raise ServoError(
                f"calibrate: robot '{self.names[k]}' cannot calibrate while a fault is active "
                f"({self.inst.fault_text()}); kalictl reset first"
            )
        self.level.robots["cmd_faults"][k] = stamp
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


FF_MODES = frozenset(int(m) for m in FfMode)
FF_STATES = frozenset(int(m) for m in FfState)
_OPS = frozenset((SlotOp.PUT, SlotOp.GET, SlotOp.SELECT, SlotOp.PARAMS, SlotOp.SHADOW))


def apply_op(level: ServoLevel, i: int, op: int) -> bool:
    """Carry out mailbox operation ``op`` on slot ``i`` (the SV, or a client while the clock
    is stopped and no SV runs); True if done, False if refused.

    Every word and byte of the mailbox is a client's, so each is checked first: ``op`` must be
    PUT, GET, SELECT or PARAMS and ``op_algo`` a registered index; a PUT record must have
    every field finite and pass the algorithm's own ``set_params`` with its own parameters (on
    a copy, which also recomputes the terms derived from them; that copy is what is put); a
    PARAMS value must pass ``set_params`` (NaN = unchanged), on a copy too.  A refusal
    changes no servo data: ``op_status`` = OP_REFUSED and the reason, as UTF-8, in the staging
    bytes.  Anything an algorithm raises refuses the operation the same way, never the SV.
    ``ops_done`` is incremented either way.  GET and SELECT allocate nothing; PUT, PARAMS
    and a refusal allocate, only when asked for.
    """
    s = level.slot_structs[i]
    try:
        why = _carry_out(level, i, op, int(s.op_algo))
    except Exception as exc:  # an algorithm's own code raised: refuse, never halt
        why = f"{_op_name(op)} refused: {type(exc).__name__}: {exc}"
    s.op_status = _post_reason(level.staging[i], why)
    s.ops_done += 1
    return not why


def _op_name(op: int) -> str:
    return SlotOp(op).name if op in _OPS else f"operation {op}"


def _carry_out(level: ServoLevel, i: int, op: int, a: int) -> str:
    """Apply one checked mailbox operation; '' when done, else why it was refused."""
    registry = level.registry
    if op not in _OPS:
        ops = ", ".join(f"{SlotOp(o).name} {int(o)}" for o in sorted(_OPS))
        return f"mailbox operation {op} is not one of {ops}"
    if op == SlotOp.SHADOW and a == layout.SHADOW_OFF:
        shadow.end_joint(level, i, ShadowState.STOPPED)
        return ""
    if not 0 <= a < len(registry):
        return (
            f"{SlotOp(op).name} refused: algorithm index {a}, registered 0..{len(registry) - 1} "
            f"({', '.join(registry.names())})"
            + (f", {layout.SHADOW_OFF} off" if op == SlotOp.SHADOW else "")
        )
    alg = registry[a]
    size = alg.dtype.itemsize
    s = level.slot_structs[i]
    if op == SlotOp.GET:
        ctypes.memmove(level.staging[i].ctypes.data, ctypes.addressof(level.structs[i][a]), size)
    elif op == SlotOp.SHADOW:
        return shadow.start_joint(level, i, a)
    elif op == SlotOp.SELECT and s.shadow_state == ShadowState.RUNNING and s.shadow == a:
        s.algo = a  # it ran on the joint's inputs all along: it goes on from its own state
        shadow.end_joint(level, i, ShadowState.SELECTED)
    elif op == SlotOp.SELECT:
        handover(level, i, a)
    elif op == SlotOp.PUT:
        trial = level.staging[i, :size].copy().view(alg.dtype).reshape(())
        for name in alg.dtype.names or ():
            value = trial[name]
            if value.dtype.kind == "f" and not math.isfinite(float(value)):
                return f"PUT '{alg.name}' refused: field {name} is {float(value)}, must be finite"
        view = struct_view(trial)
        try:
            alg.set_params(view, alg.get_params(view))
        except KaliError as exc:
            return f"PUT '{alg.name}' refused: {_bare(exc)}"
        ctypes.memmove(ctypes.addressof(level.structs[i][a]), ctypes.addressof(view), size)
    else:  # PARAMS
        values = level.staging[i, : 8 * len(alg.params)].view(np.float64)
        changes = {p: float(v) for p, v in zip(alg.params, values, strict=True) if v == v}
        trial = level.data[i][a].copy()
        view = struct_view(trial)
        try:
            alg.set_params(view, changes)
        except KaliError as exc:
            return f"PARAMS '{alg.name}' refused: {_bare(exc)}"
        ctypes.memmove(ctypes.addressof(level.structs[i][a]), ctypes.addressof(view), size)
    return ""


def _bare(exc: KaliError) -> str:
    """An error's message without its subsystem prefix (the refusal names the operation)."""
    return str(exc).removeprefix(f"{exc.subsystem}: ")


def refusal_text(level: ServoLevel, i: int) -> str:
    """The reason the SV gave for refusing slot ``i``'s last mailbox operation."""
    return decode(level.staging[i].tobytes())


def handover(level: ServoLevel, i: int, a: int) -> None:
    """Switch slot ``i`` to algorithm ``a``, initialising its state from the running servo so
    the torque does not jump (bumpless transfer)."""
    s = level.slot_structs[i]
    level.registry[a].handover(
        level.structs[i][a],
        Handover(s.position, s.velocity, s.demand, s.error, s.torque),
    )
    s.algo = a


def apply_arm_op(level: ServoLevel, k: int, op: int, hands: ArmHands) -> bool:
    """Carry out robot-level mailbox operation ``op`` on robot ``k`` (the SV that claimed the
    robot, or a client while the clock is stopped); True if done, False if refused.

    As ``apply_op``, for the robot's record of robot-level servo ``arm_op_algo``: GET, PUT
    (every float finite, the algorithm's own ``set_params`` passed, on a copy) and PARAMS
    (on a copy); SELECT calls ``hands.select(a)`` with ``a`` a robot-level index or
    ``ARM_NONE`` for the joint servos, SHADOW ``hands.trial(a)`` (``ARM_NONE``: the running
    trial ends) — the SV's hand-overs, which need this tick's inputs; a client never carries
    out either.  A refusal changes nothing; ``arm_op_status`` and the staging
    bytes say why, and ``arm_ops_done`` counts either way.
    """
    r = level.robots[k : k + 1].reshape(())
    try:
        why = _carry_out_arm(level, k, op, int(r["arm_op_algo"]), hands)
    except Exception as exc:  # an algorithm's own code raised: refuse, never halt
        why = f"{_op_name(op)} refused: {type(exc).__name__}: {exc}"
    r["arm_op_status"] = _post_reason(level.arm_staging[k], why)
    r["arm_ops_done"] = int(r["arm_ops_done"]) + 1
    return not why


def _post_reason(staging: np.ndarray, why: str) -> int:
    """A mailbox's status word for ``why`` ('' = done), the reason written as UTF-8 into its
    ``staging`` bytes when refused."""
    if not why:
        return 0
    text = why.encode()[: layout.SERVO_STAGING_BYTES - 1]
    staging[: len(text)] = np.frombuffer(text, np.uint8)
    staging[len(text)] = 0
    return layout.OP_REFUSED


def _carry_out_arm(level: ServoLevel, k: int, op: int, a: int, hands: ArmHands) -> str:
    """Apply one checked robot-level mailbox operation; '' when done, else why refused."""
    arms = level.registry.arms
    if op not in _OPS:
        ops = ", ".join(f"{SlotOp(o).name} {int(o)}" for o in sorted(_OPS))
        return f"mailbox operation {op} is not one of {ops}"
    known = ", ".join(f"{i} {alg.name}" for i, alg in enumerate(arms))
    if op == SlotOp.SELECT and a == layout.ARM_NONE:
        hands.select(a)
        return ""
    if op == SlotOp.SHADOW and a == layout.ARM_NONE:
        shadow.end_arm(level, k, ShadowState.STOPPED)
        return ""
    if not 0 <= a < len(arms):
        return (
            f"{SlotOp(op).name} refused: robot-level algorithm index {a}, registered {known}"
            + (f", {layout.ARM_NONE} joint servos" if op == SlotOp.SELECT else "")
            + (f", {layout.ARM_NONE} off" if op == SlotOp.SHADOW else "")
        )
    alg = arms[a]
    rec = level.arm_data[k][a]
    size = alg.dtype.itemsize
    staging = level.arm_staging[k]
    if op == SlotOp.SHADOW:
        return hands.trial(a)
    if op == SlotOp.SELECT:
        hands.select(a)
    elif op == SlotOp.GET:
        staging[:size] = rec.reshape(1).view(np.uint8)
    elif op == SlotOp.PUT:
        trial = staging[:size].copy().view(alg.dtype).reshape(())
        for name in alg.dtype.names or ():
            value = np.asarray(trial[name])
            if value.dtype.kind == "f" and not np.isfinite(value).all():
                return f"PUT '{alg.name}' refused: field {name} is {value}, must be finite"
        try:
            alg.set_params(trial, alg.get_params(trial))
        except KaliError as exc:
            return f"PUT '{alg.name}' refused: {_bare(exc)}"
        rec[...] = trial
    else:  # PARAMS
        values = staging[: 8 * len(alg.params)].view(np.float64)
        changes = {p: float(v) for p, v in zip(alg.params, values, strict=True) if v == v}
        trial = rec.copy()
        try:
            alg.set_params(trial, changes)
        except KaliError as exc:
            return f"PARAMS '{alg.name}' refused: {_bare(exc)}"
        rec[...] = trial
    return ""


def _one_record(what: str, data: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``data`` as one record of ``dtype`` (a put's), else ServoError saying ``what``."""
    rec = np.asarray(data)
    if rec.dtype != dtype or rec.size != 1:
        raise ServoError(
            f"{what}: data of dtype {rec.dtype} and size {rec.size}, expected one record of {dtype}"
        )
    return rec
