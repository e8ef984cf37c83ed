"""An SV's robot-level unit (thesis 3.3.4's Cartesian servo mode): one robot fed whole, claimed
and run by one SV (``ArmRunner``).

SIO feeds a robot whole while it runs a robot-level servo, has a robot-level mailbox
operation pending or runs a shadow trial: its first slot's ``busy`` is ``ARM_FREE``, the
others ``ARM_HELD``, and the SV that wins the first slot's test-and-set runs the robot:
this tick's inputs, the robot's mailbox operation, then either each joint's servo as the
per-slot path runs it or the model at this tick's angles and one robot-level ``step`` for
every joint.  A switch is bumpless both ways (``select``).  Each slot then holds what a joint
servo leaves there, so SIO, the flight recorder and the dashboard see no difference.  A step
that raises or returns a bad status or a non-finite torque halts with a SERVO fault naming
the robot and the algorithm.  The steps in order: docs/internals/servo-level.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...core import atomic, layout, rt
from ...core.errors import ServoError
from ...core.kernels import Kernel, copies
from ...core.layout import ShadowState, SlotOp, SlotReset
from .. import shadow
from ..algorithms.arm import ArmInput
from ..level import apply_arm_op, apply_op, handover

_NO_MODEL = (
    "robot '{robot}' runs no robot-level servo: its config has robot_servos: false "
    "(set robots[].robot_servos: true; the SVs then load its model)"
)

if TYPE_CHECKING:
    from collections.abc import Callable

    from .armmodel import ArmModel
    from .daemon import ServoWorker


class ArmRunner:
    """Robot ``k`` as one unit of SV ``worker``'s work; bound at configure."""

    def __init__(self, worker: ServoWorker, k: int) -> None:
        lv = worker.level
        cfg = worker.inst.config
        self.worker, self.level, self.k = worker, lv, k
        span = lv.map.span(k)
        self.lo, self.hi, self.n = span.start, span.stop, span.stop - span.start
        robot = cfg.robots[k]
        self.name = robot.name
        self.robot = lv.robots[k : k + 1].reshape(())
        self.inp = ArmInput(self.n, lv.servo_period_s, robot.name)
        # its model only where the config lets it run robot-level servos (Pinocchio's cost)
        self.model: ArmModel | None = None
        if robot.robot_servos:
            from .armmodel import ArmModel  # here: it loads Pinocchio (test_imports)

            loads = worker.inst.arena.existing(layout.KEY_LOADS, layout.LOAD, lv.n_robots)
            self.model = ArmModel(robot, self.inp, loads[k : k + 1].reshape(()))
        self.tau = np.zeros(self.n)
        self.tau_prev = np.zeros(self.n)
        slots = lv.slots[span]
        inp = self.inp
        self._torque, self._error = slots["torque"], slots["error"]
        self._status, self._ran, self._sv = slots["status"], slots["ran_tick"], slots["sv"]
        self._exec, self._reset, self._enabled = slots["exec_ns"], slots["reset"], slots["enabled"]
        self._applied = lv.joints["torque"][span]  # what the motors got last tick (SIO)
        self._off = np.zeros(self.n, dtype=bool)
        inp.has_sensor = robot.ft.sheet is not None
        fts = worker.inst.arena.existing(layout.KEY_FT, layout.FT_STATE, lv.n_robots)
        self._wrench = fts["world"][k]
        inp.wrenches = fts["world"]  # every robot's, read in place (a squeeze's partner)
        inp.wrenches.setflags(write=False)
        # this tick's inputs from the slots (and the wrist sensor), in one copy kernel each
        self._gather = copies(
            [
                (slots["demand"], inp.q_d),
                (slots["demand_vel"], inp.qd_d),
                (slots["demand_acc"], inp.qdd_d),
                (slots["position"], inp.q),
                (slots["velocity"], inp.qd),
                (slots["ff"], inp.tau_ff),
            ]
        )
        self._gather_wrench = copies([(self._wrench, inp.wrench)]) if inp.has_sensor else None
        self._op_addr = lv.arm_op_addr[k]
        self._arms = lv.registry.arms
        self._data = lv.arm_data[k]
        # each algorithm's compiled step, bound to this robot's record, inputs and torque
        # (a built-in's: ``ArmServoAlgorithm.bind``); None: its Python ``step``
        self._bound: list[Callable[[], int] | None] = []
        self.bind_loaded()
        self._algo = self.robot["arm_algo"]
        self._guided = self.robot["guided"]
        # the torques of a robot-level step out to the slots (_finish_reference is what it
        # does); the robot's record fields it writes, viewed once
        record = ("arm_status", "arm_exec_ns", "arm_ran_tick")
        self._arm_fields = tuple(self.robot[f] for f in record)
        self._finish = Kernel(
            "kali_arm_finish",
            (self.tau, inp.q_d, inp.q, *self._arm_fields),
            n=self.n,
            tau=self.tau.ctypes.data,
            q_d=inp.q_d.ctypes.data,
            q=inp.q.ctypes.data,
            enabled=self._enabled,
            torque=self._torque,
            error=self._error,
            status=self._status,
            sv=self._sv,
            ran=self._ran,
            exec=self._exec,
            sv_index=worker.index,
            **{f: a.ctypes.data for f, a in zip(record, self._arm_fields, strict=True)},
        )
        self._finish_args = self._finish.args
        # shadow trials (kali_daemons.servo.shadow): a robot-level one's torques, (shadow − active)
        # and its square, and the slots' figures it records into
        self._ops = slots["op"]
        self._shadows = self.robot["shadows"]
        self._trial = self.robot["arm_shadow"]
        self._trial_state = self.robot["arm_shadow_state"]
        self.tau_shadow = np.zeros(self.n)
        self._diff = np.zeros(self.n)
        self._diff2 = np.zeros(self.n)
        self._figures = (
            slots["shadow_torque"],
            slots["shadow_n"],
            slots["shadow_sq"],
            slots["shadow_peak"],
        )

    def bind_loaded(self) -> None:
        """Bind each robot-level servo this runner has not bound yet: at configure, and
        after a plugin was loaded while running (``servo.loading``); outside the cycle."""
        for a in range(len(self._bound), len(self._arms)):
            alg, data = self._arms[a], self._data[a]
            bound = (
                None
                if alg.bind is None or self.model is None
                else alg.bind(data, self.inp, self.tau)
            )
            self._bound.append(bound)

    def run(self, tick: int) -> None:
        """Run the robot for ``tick`` (inside the cycle)."""
        self._gather()
        if self._gather_wrench is not None:
            self._gather_wrench()
        model = self.model
        op = atomic.load32(self._op_addr)
        if op != SlotOp.NONE:
            if model is not None:
                model.update()  # a hand-over needs the model at this tick's angles
            apply_arm_op(self.level, self.k, op, self)
            atomic.store32(self._op_addr, SlotOp.NONE)
        a = int(self._algo)
        if a != layout.ARM_NONE and (model is None or not 0 <= a < len(self._arms)):
            if model is not None:
                model.update()
            self.select(layout.ARM_NONE)  # not an SV's write: back to the joint servos
            a = layout.ARM_NONE
        structs = self.level.slot_structs
        if a == layout.ARM_NONE:
            run = self.worker._run  # each joint's mailbox, servo and shadow trial
            for i in range(self.lo, self.hi):
                run(i, structs[i], tick)
        else:
            if self._ops.any():  # a joint's mailbox (its servo is not running meanwhile)
                for i in range(self.lo, self.hi):
                    if structs[i].op != SlotOp.NONE:
                        apply_op(self.level, i, int(structs[i].op))
                        atomic.store32(self.level.op_addr[i], SlotOp.NONE)
            if not self._step(a, tick):
                return
        trial = int(self._trial_state) == ShadowState.RUNNING
        if a != layout.ARM_NONE and int(self._shadows) > trial:  # joint trials
            step = self.worker.shadow_step
            for i in range(self.lo, self.hi):
                s = structs[i]
                if s.shadow_state == ShadowState.RUNNING:
                    step(i, s, s.ff)  # a joint servo's torque would get the feed-forward
        if trial:
            self._shadow_step(a)

    def _step(self, a: int, tick: int) -> bool:
        """One step of robot-level servo ``a`` over every joint; False if it halted (inside
        the cycle)."""
        t0 = rt.monotonic_ns()
        inp, alg, data = self.inp, self._arms[a], self._data[a]
        assert self.model is not None  # run() selects the joint servos without one
        self.model.update()
        if self._reset.any():
            self._take_reset(a)
        bound = self._bound[a]
        try:
            status = alg.step(data, inp, self.tau) if bound is None else bound()
        except Exception as exc:  # the user's servo: halt and say which
            self._fault(alg.name, f"raised {type(exc).__name__}: {exc}")
            return False
        if status != 0:
            self._fault(alg.name, f"returned torques {self.tau!r}, status {status!r}")
            return False
        args = self._finish_args
        args.tick, args.t0 = tick, t0
        if self._finish():  # a torque not finite: nothing written (kali_arm_finish)
            self._fault(alg.name, f"returned torques {self.tau!r}, status {status!r}")
            return False
        return True

    def _finish_reference(self, tick: int, t0: int) -> bool:
        """What ``kali_arm_finish`` does after a step that returned 0 (its reference): False,
        writing nothing, if a torque is not finite; else a disabled joint gets no torque and
        every slot, and the robot's record, holds what a joint servo leaves there."""
        tau, inp = self.tau, self.inp
        if not np.isfinite(tau).all():
            return False
        np.equal(self._enabled, 0, out=self._off)
        np.copyto(tau, 0.0, where=self._off)  # a disabled joint gets no torque
        self._torque[:] = tau
        np.subtract(inp.q_d, inp.q, out=self._error)
        self._status[:] = 0
        self._ran[:] = tick
        self._sv[:] = self.worker.index
        exe = rt.monotonic_ns() - t0
        self._exec[:] = exe // self.n
        status, exec_ns, ran_tick = self._arm_fields
        status[...], exec_ns[...], ran_tick[...] = 0, exe, tick
        return True

    def _shadow_step(self, a: int) -> None:
        """Step the robot-level servo in shadow trial on this tick's inputs (the model at
        this tick's angles) and record (shadow − active) per joint, the active joint
        servos' torques with the feed-forward SIO adds to them.  A shadow that raises or
        returns a bad status or a non-finite torque ends its trial, never halts (inside
        the cycle)."""
        b = int(self._trial)
        if self.model is None or not 0 <= b < len(self._arms) or b == a:
            shadow.end_arm(self.level, self.k, ShadowState.STOPPED)  # not an SV's write
            return
        if a == layout.ARM_NONE:
            self.model.update()  # the active step did not
        tau = self.tau_shadow
        torque, count, sq, peak = self._figures
        try:
            status = self._arms[b].step(self._data[b], self.inp, tau)
        except Exception:
            shadow.end_arm(self.level, self.k, ShadowState.RAISED)
            return
        if status != 0 or not np.isfinite(tau).all():
            torque[:] = tau
            shadow.end_arm(self.level, self.k, ShadowState.FAILED)
            return
        d = self._diff
        np.subtract(tau, self._torque, out=d)
        if a == layout.ARM_NONE:
            np.subtract(d, self.inp.tau_ff, out=d)
        torque[:] = tau
        count += 1
        np.multiply(d, d, out=self._diff2)
        sq += self._diff2
        np.abs(d, out=d)
        np.maximum(peak, d, out=peak)

    def trial(self, b: int) -> str:
        """Start a shadow trial of robot-level servo ``b`` (the mailbox's SHADOW; the model
        at this tick's angles): level with the torque the motors had last tick, as a select
        would hand over; '' or why it was refused."""
        if self.model is None:
            return "SHADOW refused: " + _NO_MODEL.format(robot=self.name)
        why = shadow.start_arm(self.level, self.k, b)
        if why:
            return why
        np.copyto(self.tau_prev, self._applied)
        try:
            self._arms[b].handover(self._data[b], self.inp, self.tau_prev)
        except Exception:
            shadow.end_arm(self.level, self.k, ShadowState.STOPPED)
            raise
        return ""

    def _take_reset(self, a: int) -> None:
        """The slots' resets under a robot-level servo: at power on it takes the arm over as
        holding its weight at rest, after calibration (new coordinates, same motion) from
        the torque the motors had."""
        shift = bool((self._reset == SlotReset.SHIFT).any())
        prev = self._applied if shift else self.inp.g
        np.copyto(self.tau_prev, prev)
        self._arms[a].handover(self._data[a], self.inp, self.tau_prev)
        if not shift:
            self._torque[:] = 0.0
        self._reset[:] = SlotReset.NONE

    def select(self, a: int) -> None:
        """Switch the robot to robot-level servo ``a`` or, ``ARM_NONE``, to its joint servos,
        bumplessly (the mailbox's SELECT; the model is at this tick's angles)."""
        now = int(self._algo)
        if a == now:
            return
        if a != layout.ARM_NONE and self.model is None:
            raise ServoError(_NO_MODEL.format(robot=self.name))
        np.copyto(self.tau_prev, self._applied)
        running = int(self._trial_state) == ShadowState.RUNNING
        if a != layout.ARM_NONE and running and a == int(self._trial):
            # it ran on the robot's inputs all along: it goes on from its own state
            shadow.end_arm(self.level, self.k, ShadowState.SELECTED)
        elif a == layout.ARM_NONE:
            # the joint servos continue from what the motors had, less the feed-forward SIO
            # adds to them again from this tick
            lv = self.level
            np.subtract(self.tau_prev, self.inp.tau_ff, out=self._torque)
            for i in range(self.lo, self.hi):
                s = lv.slot_structs[i]
                if s.algo < len(lv.registry):
                    handover(lv, i, int(s.algo))
        else:
            self._arms[a].handover(self._data[a], self.inp, self.tau_prev)
        self._guided[...] = a != layout.ARM_NONE and self._arms[a].guides
        self._algo[...] = a

    def _fault(self, algo: str, what: str) -> None:
        self._torque[:] = 0.0
        self.worker.inst.raise_fault(
            layout.FaultCode.SERVO,
            self.worker.name,
            f"robot-level servo '{algo}' on robot '{self.name}' {what}",
        )
