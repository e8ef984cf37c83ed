"""The servo level as users, kalictl and robot programs change it (thesis 3.4): ``ServoClient``,
the operations on the slots' put/get mailbox (put/get/select, gains, enable, range checking,
``safe``, shadow trials, robot-level servos), power and calibration, over ``level.ServoLevel``.
Outside any cycle: a client waits for the SV to carry an operation out at the slot's next run.

Long on purpose: every operation a user has on the servo level, on one client's state.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ..core import atomic, layout
from ..core.errors import InstanceError, KaliError, ServoError
from ..core.layout import CalibState, FfMode, FfState, PowerState, SlotOp
from ..core.spinlock import SpinLock
from ..runtime.instance import Instance, decode
from . import loading, shadow
from .algorithms.algorithm import ServoAlgorithm, struct_view
from .algorithms.arm import ArmServoAlgorithm
from .level import (
    FF_MODES,
    FF_STATES,
    ServoLevel,
    _op_name,
    apply_arm_op,
    apply_op,
    flag,
    refusal_text,
)
from .shadow import Trial

OP_TIMEOUT_S = 2.0  # how long a client waits for the SV to carry out a mailbox operation
JOINT_SERVOS = "joints"  # what ``select_arm`` takes for "back to the joint servos"
FORCE_SETPOINTS = ("fx", "fy", "fz")  # robot-level parameters the wrist sensor must measure
SQUEEZE_SETPOINT = "fi"  # and a squeeze, along any line: within the smallest force range
SQUEEZE_PARTNER = "partner"  # the arm sharing the squeeze: its config index + 1


class _NoHands:
    """A client's: it carries out neither (``_arm_op`` leaves both to the SV)."""

    def select(self, a: int) -> None:
        raise ServoError("a select is carried out by the SV at the robot's next tick")

    def trial(self, a: int) -> str:
        raise ServoError("a shadow trial is started by the SV at the robot's next tick")


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


def _one_record(what: str, data: np.ndarray, dtype: np.dtype) -> np.ndarray:
    """``data`` as one record of ``dtype`` (a put's), else ServoError saying ``what``."""
    rec = np.asarray(data)
    if rec.dtype != dtype or rec.size != 1:
        raise ServoError(
            f"{what}: data of dtype {rec.dtype} and size {rec.size}, expected one record of {dtype}"
        )
    return rec


class ServoClient:
    """What users, kalictl and robot programs do to the servo level (thesis 3.4)."""

    def __init__(
        self,
        inst: Instance,
        pause: Callable[[], None] | None = None,
        guard: loading.Guard | None = None,
    ) -> None:
        """``pause``: how its user lets time pass (a program's ``Kali.pause``, which steps a
        lockstep instance's stopped clock): given, a call that needs a servo tick (a
        robot-level select or shadow, or one behind it) waits for it as ``wait()`` does;
        without it (kalictl) such a call says the clock must be stepped."""
        self.inst = inst
        self.level = ServoLevel(inst)
        self.names = self.level.names
        self._pause = pause
        self._guard = guard  # a loaded servo's schedulability check (``load``'s default)

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
        """(index, algorithm) of a registered servo algorithm (one loaded while running
        included); ServoError naming them."""
        registry = self.level.registry
        if isinstance(name, str) and name not in registry.names():
            loading.take(self.level)
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
        state, its torque compared, never applied (``kali_daemons.servo.shadow``; ``trials``
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
        if a >= len(registry):
            loading.take(self.level)
        if not 0 <= a < len(registry):
            raise ServoError(
                f"{self._where(i)}: algorithm index {a} in the arena, registered 0.."
                f"{len(registry) - 1}; the SV restores the robot's configured servo at its next run"
            )
        return registry[a].name

    # ------------------------------------------------------------------ loading

    def load(self, path: str | os.PathLike[str], guard: loading.Guard | None = None) -> list[str]:
        """Load the servo plugin file ``path`` into the running instance, every SV, and
        return the names of the servos it registers: then select or try them in shadow as a
        configured plugin's.  Checked first as a plugin the config names is, and more
        (``servo.loading``): ServoError, nothing loaded, naming the file and why.
        ``guard``: the schedulability check of a joint running it (default: the one this
        client was made with; a program's refuses a load that would not fit)."""
        file = Path(path).expanduser().resolve()
        try:
            source = file.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise ServoError(f"load {str(path)!r}: cannot read it: {exc}") from None
        return self.load_source(source, str(file), guard)

    def load_source(
        self, source: str, origin: str, guard: loading.Guard | None = None
    ) -> list[str]:
        """``load`` of a file's text ``source``, ``origin`` its name (a remote program
        sends the text: the file is on its machine)."""
        if not isinstance(source, str) or not isinstance(origin, str):
            raise ServoError("load: a plugin's text and its file name are strings")
        return loading.offer(self.level, source, origin, self._pause, guard or self._guard)

    def loaded(self) -> list[loading.Loaded]:
        """The plugin files loaded while running, in order."""
        loading.take(self.level)
        out = []
        for k in range(int(self.level.loads["generation"])):
            e = self.level.loads["entries"][k]
            names = [n for n in decode(bytes(e["names"])).split(",") if n]
            out.append(
                loading.Loaded(decode(bytes(e["origin"])), names, loading.verdict(self.level, k))
            )
        return out

    # ------------------------------------------------------------------ robot-level servos

    def arm_algorithm(self, name: str) -> tuple[int, ServoAlgorithm | ArmServoAlgorithm]:
        """(index, algorithm) of a robot-level servo; ServoError naming them (and saying so
        when ``name`` is a joint servo)."""
        registry = self.level.registry
        if isinstance(name, str) and name not in registry.arm_names():
            loading.take(self.level)
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
        return self.level.name_of(a, robot_level=True) if a != layout.ARM_NONE else None

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

    def _seen_halts(self, k: int) -> bool:
        """Whether SIO has written robot ``k``'s record since the latest halt."""
        return int(self.level.robots["faults_seen"][k]) == self._faults()

    def power_state(self, robot: str | int) -> PowerState:
        """The robot's amplifier power as SIO drives it; OFF while the system is halted, or
        SIO has not run since a halt (the halt cut the amplifiers at once, and SIO's record
        says so at its next tick, which a clock the halt stopped may not give it)."""
        k = self.robot_index(robot)
        if int(self.inst.fault["active"]) or not self._seen_halts(k):
            return PowerState.OFF
        return PowerState(int(self.level.robots["power"][k]))

    def power_text(self, robot: str | int) -> str:
        """Why a robot is or is not powered, for a message: its power state, SIO's last
        message about it and the tick SIO last wrote its record (whether since the last
        halt)."""
        k = self.robot_index(robot)
        r = self.level.robots[k]
        seen = "" if self._seen_halts(k) else ", not since the last halt"
        return (
            f"{self.names[k]}: {self.power_state(k).name}, SIO says '{decode(r['message'])}' "
            f"(its record written at tick {int(r['tick'])}{seen})"
        )

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
