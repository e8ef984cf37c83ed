"""The servo level in the arena (DESIGN 4, thesis 3.3.3 - 3.4, figure 3.3) as SIO, the SVs and
clients see it: ``ServoLevel`` views its records; ``apply_op`` and ``apply_arm_op`` carry out
the put/get mailbox (3.4).

Per robot a ``ROBOT_STATE``; per joint, flat in config order (robot k joint j is
``cfg.joints.base[k] + j``), a ``JOINT_STATE`` and a ``SERVO_SLOT``, which SIO feeds and an
SV claims by test-and-set of ``busy`` (3.3.5); per (slot, algorithm) a private-data record,
so a joint keeps every algorithm's state and any SV can run any joint (3.3.4).

A client never touches a running servo's data: it writes the mailbox, and the SV carries the
operation out at the slot's next run, before the step.  The SV trusts none of it (DESIGN 7):
a bad operation is refused with the reason in the staging bytes, the servo's data unchanged.
``client.ServoClient`` adds the operations users call.  More: docs/internals/servo-level.md.
"""

from __future__ import annotations

import ctypes
import math
from fractions import Fraction
from pathlib import Path
from typing import Protocol

import numpy as np

from ..core import layout
from ..core.channels import InterpolatingFifo
from ..core.errors import KaliError, ServoError
from ..core.layout import CalibState, FfMode, FfState, PowerState, ShadowState, SlotOp
from ..robots import robot_type
from ..runtime.config import ms_to_ns
from ..runtime.instance import Instance, decode
from . import shadow
from .algorithms.algorithm import Handover, JointInfo, ServoAlgorithm, initialise, struct_view
from .algorithms.registry import Registry, registry_for

FIFO_CAPACITY = layout.FIFO_CAPACITY  # TG set-points a TG → SIO FIFO holds (the layout sizes it)
# SIO refuses a set-point beyond ±this (rad) as garbage, holding instead: two full turns either
# way is no joint angle (joint range itself is SIO's range check, which halts)
SETPOINT_BOUND_RAD = 4.0 * math.pi
# numpy's stubs type a structured dtype's ctypes class as a scalar's (dtype[void] matches no
# overload); it is a Structure
SlotStruct: type[ctypes.Structure] = np.ctypeslib.as_ctypes_type(layout.SERVO_SLOT)  # type: ignore[arg-type, assignment]


class ArmHands(Protocol):
    """What carrying out a robot's SELECT or SHADOW needs: this tick's inputs, which only
    the SV that claimed the robot has (``sv.arm.ArmRunner``)."""

    def select(self, a: int) -> None:
        """Switch the robot to robot-level servo ``a`` (ARM_NONE: its joint servos)."""

    def trial(self, a: int) -> str:
        """Start a shadow trial of robot-level servo ``a``; '' or why it was refused."""


def flag(what: str, value: object) -> bool:
    """``value`` as an on/off flag: a bool, or the integers 0 and 1 (numpy's too); ServoError
    naming ``what`` for anything else (an array's truth is ambiguous, a string's meaningless)."""
    if isinstance(value, bool | np.bool_) or (
        isinstance(value, int | np.integer) and int(value) in (0, 1)
    ):
        return bool(value)
    raise ServoError(f"{what}: {value!r:.60} is not a flag (True/False, 1/0)")


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
        # the names, then spares of the servos loaded while running (``loading``), joint
        # servos first: robot-level servo a's name is at ``arm_names_at + a``
        self.arm_names_at = len(self.registry) + layout.SERVO_LOADABLE
        self.servo_names = get(
            layout.KEY_SERVO_NAMES,
            layout.SERVO_NAME,
            self.arm_names_at + len(self.registry.arms) + layout.ARM_LOADABLE,
        )
        self.loads = get(layout.KEY_SERVO_LOADS, layout.SERVO_LOADS)
        self.taken = 0  # entries of the loads table this level has taken (``loading.take``)
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
        self.configured = (len(self.registry), len(self.registry.arms))  # before any load
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
        spares = [("", 0)] * layout.SERVO_LOADABLE
        named = [(n, 0) for n in self.registry.names()] + spares
        named += [(n, 1) for n in self.registry.arm_names()]
        named += [("", 1)] * layout.ARM_LOADABLE
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
                joint = JointInfo(robot.name, j + 1, robot.type)
                for a, alg in enumerate(self.registry):
                    init = init_data_for(robot.model, alg, j)
                    initialise(alg, self.structs[i][a], init, self.servo_period_s, joint)

    def view_loaded(self) -> None:
        """View the private data of every algorithm the registry has beyond these views (a
        plugin loaded while running: its spare blocks, ``loading.take``); outside the
        cycle."""
        a, n = self.inst.arena, self.n
        for k in range(len(self.blocks), len(self.registry)):
            block = a.existing(layout.KEY_SERVO_DATA.format(algo=k), self.registry[k].dtype, n)
            self.blocks.append(block)
            for i in range(n):
                rec = block[i : i + 1].reshape(())
                self.data[i].append(rec)
                self.structs[i].append(struct_view(rec))
        for k in range(len(self.arm_blocks), len(self.registry.arms)):
            dtype = self.registry.arms[k].dtype
            block = a.existing(layout.KEY_ARM_DATA.format(arm=k), dtype, self.n_robots)
            self.arm_blocks.append(block)
            for r in range(self.n_robots):
                self.arm_data[r].append(block[r : r + 1].reshape(()))

    def name_of(self, a: int, robot_level: bool = False) -> str:
        """The name of joint servo (or robot-level servo) ``a`` as SIO and the loading clients
        wrote it in the arena: for a process that has not loaded every plugin (SIO)."""
        at = self.arm_names_at + a if robot_level else a
        if not 0 <= at < len(self.servo_names):
            return f"#{a}"
        return decode(bytes(self.servo_names[at]["name"])) or f"#{a}"

    def close(self) -> None:
        """Drop the ctypes views (they pin the arena's buffer)."""
        self.structs = []
        self.arm_data = []
        self.slot_structs = None  # type: ignore[assignment]


FF_MODES = frozenset(int(m) for m in FfMode)
FF_STATES = frozenset(int(m) for m in FfState)
_OPS = frozenset((SlotOp.PUT, SlotOp.GET, SlotOp.SELECT, SlotOp.PARAMS, SlotOp.SHADOW))


def apply_op(level: ServoLevel, i: int, op: int) -> bool:
    """Carry out mailbox operation ``op`` on slot ``i`` (the SV, or a client while the clock
    is stopped and no SV runs); True if done, False if refused.

    Every word and byte of the mailbox is a client's, so each is checked first: ``op`` must be
    PUT, GET, SELECT, PARAMS or SHADOW and ``op_algo`` a registered index (for SHADOW, or
    ``SHADOW_OFF``); a PUT record must have
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
