"""The FR3's link: one process per FR3, holding its libfranka connection (decision 0015).

libfranka's calls block and hold the interpreter lock, so each FR3's connection is a process
of its own that never stalls SIO: it publishes every state packet into the arm's record
(``hardware.franka.registers``) and, while torque control runs, answers it with the torques
SIO wrote for it (``writeOnce``).  The first FR3's link posts the wall clock's semaphore with
each packet: the robot's packets are the cell's interrupt, so every state is answered by one
command computed from it (thesis 3.2.1's hardware timer, here the robot's own).  A libfranka
error halts the cell naming the robot and libfranka's words; ``kalictl reset`` runs its error
recovery.
"""

from __future__ import annotations

import os
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import posix_ipc

from ..core import rt
from ..core.errors import HardwareError
from ..core.layout import FaultCode, lateness_bin
from ..hardware.franka import registers
from ..hardware.franka.arms import records
from ..hardware.franka.registers import (
    LINK_CONNECTED,
    LINK_CONTROL,
    LINK_ERROR,
    LINK_ESTOP,
    LS_TCP,
    LS_UDP,
)
from ..hardware.franka.wrench import FlangeWrench
from ..runtime.daemon import Daemon
from .turns import SLICE_S, LinkTurns

# how long a link tries to reach its robot at start (a simulator loads), within what start
# waits for every process (the config's startup_timeout_s)
CONNECT_WAIT_FRACTION = 0.7
CONNECT_RETRY_S = 0.2
ROBOT_PORT = 1337  # libfranka's command port (TCP); the states come over UDP
# A command later than this after its state answers nothing: the robot has moved on to the
# next cycle (1 ms), so SIO's answer to this state is a miss, counted in ``late``
ANSWER_WAIT_S = 0.0009
RECONNECT_S = 0.5  # a lost connection is tried again this often (once the fault is reset)


def franka() -> Any:
    """pylibfranka, imported where it is used: only an FR3 cell's processes load it."""
    import pylibfranka  # only an FR3 cell's links load it (15 MB of libfranka)

    return pylibfranka


def reach(
    connect: Callable[[], Any],
    wait_s: float,
    refused: Callable[[Exception], str],
    after: Callable[[], None] = lambda: None,
) -> Any:
    """``connect()`` tried every ``CONNECT_RETRY_S`` until it answers or ``wait_s`` passes (a
    simulator may still be loading), ``after()`` following each try; HardwareError saying
    ``refused(libfranka's last error)`` then."""
    deadline = time.monotonic() + wait_s
    while True:
        try:
            return connect()
        except Exception as exc:
            if time.monotonic() > deadline:
                raise HardwareError(refused(exc)) from None
            time.sleep(CONNECT_RETRY_S)
        finally:
            after()


class FrankaLink(Daemon):
    """One FR3's libfranka connection: states into its record, SIO's torques out."""

    kind = "link"
    self_timed_in_realtime = True  # the robot times it; the clock watches its heartbeat
    self_timed_always = True  # in lockstep the plant's turns time it (turns.py)

    def on_configure(self) -> None:
        inst = self.inst
        cfg = inst.config
        robot_name = self.name.partition(".")[2]
        self.k = k = next(i for i, r in enumerate(cfg.robots) if r.name == robot_name)
        self.robot = cfg.robots[k]
        self.n = self.robot.n_joints
        self.address = self.robot.hardware.address
        self.label = f"robot '{robot_name}' (FR3 at {self.address})"
        self.arm = records(inst.arena, len(cfg.robots))[k : k + 1].reshape(())
        franka_arms = [i for i, r in enumerate(cfg.robots) if r.hardware.kind == "franka"]
        self.pacer = k == franka_arms[0] and not inst.lockstep
        self._pace = inst.slot_semaphore(inst.slot_of("wallclock")) if self.pacer else None
        self._answer = inst.slot_semaphore(self.slot)
        self._tau = np.zeros(self.n)
        n = self.n  # the record's fields viewed once (``_publish``, every packet)
        self._q, self._dq, self._tau_j = (self.arm[f][:n] for f in ("q", "dq", "tau_J"))
        self._wrench, self._cmd = self.arm["wrench"], self.arm["tau"][:n]
        self._share_hist = self.arm["share_hist"]
        # the arm's wrist wrench from its joint torques, if its config asks for one (wrench.py)
        self._flange = FlangeWrench(self.robot) if self.robot.ft.sheet is not None else None
        self._ctrl: Any = None  # the active torque control, while the arm is powered
        self._robot: Any = None
        self._rt_on = False  # past start-up: at the configured priority
        self.arm["link_pid"] = os.getpid()
        self.arm["error"] = b""
        # lockstep: the plant and this link take turns on each state (turns.py)
        self._turns = LinkTurns(self, self.arm) if inst.lockstep else None
        self._publish(self._connect(CONNECT_WAIT_FRACTION * cfg.startup_timeout_s))

    # ------------------------------------------------------------------ connection

    def _connect(self, wait_s: float) -> Any:
        """Reach the robot within ``wait_s`` (a simulator may still be loading), refusing one
        in a mode Kali cannot drive; its first state.  HardwareError naming the robot
        otherwise."""
        pf = franka()
        self._robot = reach(
            lambda: self._taking(lambda: pf.Robot(self.address, pf.RealtimeConfig.kIgnore)),
            wait_s,
            lambda exc: (
                f"franka: {self.label}: no robot or simulator answers at "
                f"{self.address}:{ROBOT_PORT} within {wait_s:g} s (libfranka: {exc})"
            ),
            after=self._own_scheduling,
        )
        state = self._taking(self._robot.read_once)
        mode = state.robot_mode
        if mode == pf.RobotMode.Reflex:
            self._robot.automatic_error_recovery()  # a reflex left from before Kali
        elif mode not in (pf.RobotMode.Idle, pf.RobotMode.Move):
            raise HardwareError(
                f"franka: {self.label} is in mode {mode.name}, not Idle: release its user "
                "stop and leave guiding mode (Desk) before starting Kali"
            )
        self.arm["status"] = LINK_CONNECTED
        return state

    def _taking(self, call: Callable[[], Any]) -> Any:
        """``call()``, which takes one state; in lockstep the plant sends it on the link's
        asking, while the cell starts (``LinkTurns.ask``)."""
        if self._turns is None:
            return call()
        self._turns.ask()
        result = call()
        self._turns.took()
        return result

    def _own_scheduling(self) -> None:
        """Undo what libfranka's Robot() does to the calling thread (SCHED_FIFO 99, above
        every Kali process and the machine's own floor) and take the configured priority."""
        rt.leave_realtime()
        if self._rt_on:
            rt.go_realtime(self._rt, self._priority)

    def _prepare_os(self, cpu: int | None, lock_memory: bool) -> rt.RtReport:
        """In lockstep the link waits its turn: unbound, as the executive it takes turns
        with (``_go_realtime``)."""
        lockstep = self.inst.lockstep
        return super()._prepare_os(None if lockstep else cpu, lock_memory and not lockstep)

    def _go_realtime(self) -> None:
        """SCHED_FIFO in real time; in lockstep SCHED_OTHER, as the executive."""
        if not self.inst.lockstep:
            super()._go_realtime()
            self._rt_on = True

    # ------------------------------------------------------------------ the loop

    def _loop(self) -> None:
        if self._turns is not None:
            self._lockstep_loop()
            return
        header = self.inst.arena.header
        arm, procs = self.arm, self.inst.procs
        while not self._leave and not header["shutdown"]:
            procs[self.slot]["heartbeat_ns"] = rt.monotonic_ns()
            try:
                if self._robot is None:
                    self._reconnect()
                elif self._ctrl is None:
                    self._idle_step()
                elif int(arm["stop"]) or int(arm["estop"]) or not int(arm["want"]):
                    self._finish_control()
                else:
                    self._control_step()
            except Exception as exc:  # libfranka's: the robot's error, or a lost connection
                self._lost(exc)
        if self._ctrl is not None:
            self._finish_control()

    def _idle_step(self) -> None:
        """Not servoing: publish the next state; start torque control when SIO wants it,
        run the error recovery when reset asks."""
        arm = self.arm
        error = int(arm["status"]) & LINK_ERROR
        if int(arm["recover"]):  # out of any control the halt cut: the reset takes effect
            if error:
                self._robot.automatic_error_recovery()
                arm["error"] = b""
            arm["recover"] = arm["stop"] = error = 0
        estop = bool(int(arm["estop"]))
        arm["status"] = LINK_CONNECTED | (LINK_ESTOP if estop else 0) | error
        if int(arm["want"]) and not int(arm["stop"]) and not estop and not error:
            self._ctrl = self._robot.start_torque_control()
            arm["status"] = LINK_CONNECTED | LINK_CONTROL
            return
        self._estimate(self._robot.read_once())

    def _control_step(self) -> None:
        """One robot cycle in torque control: the state in, SIO's answer to it out."""
        arm = self.arm
        state, dt = self._ctrl.readOnce()
        t_in = rt.monotonic_ns()
        seq = self._publish(state)
        lost = round(dt.to_sec() * 1000.0) - 1
        if lost > 0:
            arm["lost"] += lost
        if not self._answered(seq, t_in):
            arm["late"] += 1
        else:
            share = self._send_torques() - t_in  # Kali's share of the robot's cycle
            self._share_hist[lateness_bin(share)] += 1
            if share > arm["share_max_ns"]:
                arm["share_max_ns"] = share
        if self._flange is not None:  # after the answer: the next state publishes it
            self._flange.update(state, self._q, self._tau_j)

    def _send_torques(self) -> int:
        """SIO's torques out (``writeOnce``); when they went."""
        np.copyto(self._tau, self._cmd)
        self._ctrl.writeOnce(franka().Torques(self._tau.tolist()))
        t_out = rt.monotonic_ns()
        self.arm["sent_ns"] = t_out
        self.arm["answered"] += 1
        return t_out

    def _answered(self, seq: int, t_in: int) -> bool:
        """Wait for SIO's command answering state ``seq`` (its post of this link's semaphore),
        until the robot's next cycle would begin."""
        arm = self.arm
        deadline = t_in + int(ANSWER_WAIT_S * 1e9)
        while int(arm["cmd_seq"]) != seq:
            left = deadline - rt.monotonic_ns()
            if left <= 0:
                return False
            try:
                self._answer.acquire(left / 1e9)
            except posix_ipc.BusyError:
                return int(arm["cmd_seq"]) == seq
        return True

    def _finish_control(self) -> None:
        """End torque control: a last zero command with ``motion_finished`` (libfranka then
        stops the robot: its own brakes hold it), or libfranka's stop if that fails."""
        pf = franka()
        arm = self.arm
        try:
            self._ctrl.readOnce()
            last = pf.Torques([0.0] * self.n)
            last.motion_finished = True
            self._ctrl.writeOnce(last)
        except Exception:
            self._robot.stop()
        finally:
            self._ctrl = None
            arm["status"] = int(arm["status"]) & ~LINK_CONTROL

    def _publish(self, state: Any) -> int:
        """The state packet into the record, ``seq`` last; the clock's interrupt if this
        link paces the cell.  Returns the new ``seq``."""
        arm = self.arm
        self._q[:] = state.q
        self._dq[:] = state.dq
        self._tau_j[:] = state.tau_J
        if self._flange is not None:  # the previous state's: worked out after answering it
            self._wrench[:] = self._flange.out
        arm["success_rate"] = state.control_command_success_rate
        arm["mode"] = int(state.robot_mode.value)
        arm["robot_ms"] = round(state.time.to_sec() * 1000.0)
        arm["state_ns"] = rt.monotonic_ns()
        seq = int(arm["seq"]) + 1
        arm["seq"] = seq
        if self._pace is not None:
            self._pace.release()
        return seq

    def _estimate(self, state: Any) -> None:
        """Not in torque control: publish ``state``, then work its wrench out."""
        self._publish(state)
        if self._flange is not None:
            self._flange.update(state, self._q, self._tau_j)

    # ------------------------------------------------------------------ lockstep

    def _lockstep_loop(self) -> None:
        """Lockstep: as each tick begins, answer the state the last one took and choose the
        next libfranka call on all it did; the call takes this tick's state (``LinkTurns``)."""
        turns = self._turns
        assert turns is not None
        state: Any = None  # the state the last tick took, to answer (None: nothing to answer)
        while turns.go():
            try:
                call, expect = self._choose(state)
                turns.ready(expect)
                if not turns.call():
                    break
                state = call()
                turns.took()
            except Exception as exc:  # libfranka's: out of the turns, the cell halted
                turns.leave()
                self._lost(exc)
                self._sit_out()
                return

    def _choose(self, state: Any) -> tuple[Callable[[], Any], int]:
        """Answer ``state`` (None: none, or the call took it inside libfranka) if in control,
        and choose the next call as the real-time loop would; with what the plant finds
        first on its sockets (``LS_*``)."""
        arm = self.arm
        if self._flange is not None and state is not None:
            self._flange.update(state, self._q, self._tau_j)
        if self._ctrl is not None:
            if int(arm["stop"]) or int(arm["estop"]) or not int(arm["want"]):
                return self._finish_now, LS_UDP  # the last command answers this state
            if state is None:
                return self._read_control, 0
            if int(arm["cmd_seq"]) != int(arm["seq"]):
                arm["late"] += 1
                return self._read_control, 0
            self._send_torques()
            return self._read_control, LS_UDP
        error = int(arm["status"]) & LINK_ERROR
        if int(arm["recover"]):  # out of any control the halt cut: the reset takes effect
            if error:
                return self._recover, LS_TCP
            arm["recover"] = arm["stop"] = 0
        estop = bool(int(arm["estop"]))
        arm["status"] = LINK_CONNECTED | (LINK_ESTOP if estop else 0) | error
        if int(arm["want"]) and not int(arm["stop"]) and not estop and not error:
            return self._start_control, LS_TCP
        return self._read_idle, 0

    def _read_idle(self) -> Any:
        state = self._robot.read_once()
        self._publish(state)
        return state

    def _read_control(self) -> Any:
        state, dt = self._ctrl.readOnce()
        self._publish(state)
        lost = round(dt.to_sec() * 1000.0) - 1
        if lost > 0:
            self.arm["lost"] += lost
        return state

    def _recover(self) -> Any:
        """libfranka's error recovery (a TCP request), then the tick's state."""
        self._robot.automatic_error_recovery()
        arm = self.arm
        arm["error"] = b""
        arm["recover"] = arm["stop"] = 0
        arm["status"] = LINK_CONNECTED | (LINK_ESTOP if int(arm["estop"]) else 0)
        return self._read_idle()

    def _start_control(self) -> None:
        """Torque control: libfranka's Move request, whose handshake takes the tick's state."""
        self._ctrl = self._robot.start_torque_control()
        self.arm["status"] = LINK_CONNECTED | LINK_CONTROL

    def _finish_now(self) -> None:
        """The last command (zero torques, ``motion_finished``), whose handshake takes the
        tick's state."""
        pf = franka()
        last = pf.Torques([0.0] * self.n)
        last.motion_finished = True
        try:
            self._ctrl.writeOnce(last)
        finally:
            self._ctrl = None
            self.arm["status"] = int(self.arm["status"]) & ~LINK_CONTROL

    def _sit_out(self) -> None:
        """Out of the turns after libfranka failed: wait for the instance to end (a lockstep
        cell's link is not reconnected; ``kalictl stop`` and start again)."""
        header, procs = self.inst.arena.header, self.inst.procs
        while not self._leave and not header["shutdown"]:
            procs[self.slot]["heartbeat_ns"] = rt.monotonic_ns()
            time.sleep(SLICE_S)

    # ------------------------------------------------------------------ errors

    def _lost(self, exc: Exception) -> None:
        """libfranka raised: the robot's error (a reflex, a rejected command) or the
        connection lost.  Halt the cell naming both; keep the connection if it still works
        (states keep coming, recovery on reset), else try it again once reset."""
        arm = self.arm
        text = f"{type(exc).__name__}: {exc}".replace("\n", " ")
        arm["error"] = text.encode()[: registers.FRANKA_ARM["error"].itemsize]
        arm["status"] = (int(arm["status"]) & ~LINK_CONTROL) | LINK_ERROR
        self.inst.raise_fault(FaultCode.HARDWARE, self.name, f"{self.label}: libfranka: {text}")
        self._ctrl = None  # after the halt: libfranka's cancelling waits for the robot
        try:
            self._publish(self._robot.read_once())
        except Exception:
            self._robot = None
            arm["status"] = LINK_ERROR

    def _reconnect(self) -> None:
        """The connection is gone: once the halt is reset, try it again."""
        if int(self.inst.fault["active"]):
            time.sleep(RECONNECT_S)
            return
        try:
            self._publish(self._connect(RECONNECT_S))
            self.arm["error"] = b""
        except HardwareError:
            self._robot = None
            self.arm["status"] = LINK_ERROR

    def on_shutdown(self) -> None:
        self.arm["status"] = 0
        self._robot = None
