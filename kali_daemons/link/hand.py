"""An FR3's Franka Hand: one process per hand, holding libfranka's gripper connection
(decision 0015).  A gripper command blocks for up to two seconds and holds Python's
interpreter lock, so it never runs in the arm's 1 kHz link: this process carries out the
arm's record's gripper requests (``grip_cmd``, bumped with ``grip_close``) one at a time and
reports each one's outcome (``grip_state``, ``grip_done``) and the fingers' width, as a
motion's outcome is reported.  Non-serious: a hand that dies leaves the arm running.
"""

from __future__ import annotations

import time
from typing import Any

from ..core import futex, rt
from ..hardware.franka.arms import records
from ..hardware.franka.registers import GRIP_BUSY, GRIP_DONE, GRIP_FAILED
from ..runtime.daemon import Daemon
from .franka import CONNECT_WAIT_FRACTION, franka, reach

GRASP_SPEED_M_S = 0.1  # the fingers' speed, closing or opening
GRASP_FORCE_N = 20.0  # the grasp's force (the Hand holds up to 70 N)
IDLE_POLL_S = 0.02  # between commands, the width is read this often
LOCKSTEP_WAIT_S = 0.05  # lockstep: a wait for a request looks at the shutdown this often


class FrankaHand(Daemon):
    """One Franka Hand: the record's gripper requests carried out, their outcomes reported."""

    kind = "hand"
    self_timed_in_realtime = True  # never signalled; the clock watches that it is alive
    self_timed_always = True

    def on_configure(self) -> None:
        cfg = self.inst.config
        robot_name = self.name.partition(".")[2]
        k = next(i for i, r in enumerate(cfg.robots) if r.name == robot_name)
        self.address = cfg.robots[k].hardware.address
        self.label = f"robot '{robot_name}' (Franka Hand at {self.address})"
        self.arm = records(self.inst.arena, len(cfg.robots))[k : k + 1].reshape(())
        self._gripper = self._connect(CONNECT_WAIT_FRACTION * cfg.startup_timeout_s)
        state = self._gripper.read_once()
        self.max_width = float(state.max_width)
        self._publish(state)
        self._done = int(self.arm["grip_cmd"])  # requests before this process: not replayed
        self.arm["grip_done"] = self.arm["grip_sent"] = self._done
        self._futex = futex.Waiter(LOCKSTEP_WAIT_S)
        self.arm["hand_up"] = 1

    def _connect(self, wait_s: float) -> Any:
        pf = franka()
        return reach(
            lambda: pf.Gripper(self.address),
            wait_s,
            lambda exc: (
                f"franka: {self.label}: no gripper answers within {wait_s:g} s (libfranka: {exc})"
            ),
        )

    def _publish(self, state: Any) -> None:
        self.arm["grip_width"] = float(state.width)
        self.arm["grip_held"] = int(bool(state.is_grasped))

    def _loop(self) -> None:
        """Each request carried out as it comes.  In lockstep the plant waits for the
        command (``grip_sent``) and its outcome (``grip_done``), so both fall on the same
        ticks every run, and the fingers' width is read only after a command: an idle read
        would block in libfranka while the clock stands."""
        header, arm = self.inst.arena.header, self.arm
        procs, lockstep = self.inst.procs, self.inst.lockstep
        while not self._leave and not header["shutdown"]:
            procs[self.slot]["heartbeat_ns"] = rt.monotonic_ns()
            cmd = int(arm["grip_cmd"])
            if cmd == self._done:
                if lockstep:  # woken by the request (FrankaOps.grip)
                    self._futex.wait(arm["grip_cmd"].ctypes.data, cmd)
                else:
                    self._publish(self._gripper.read_once())
                    time.sleep(IDLE_POLL_S)
                continue
            arm["grip_state"] = GRIP_BUSY
            arm["grip_sent"] = cmd
            futex.wake(arm["grip_sent"].ctypes.data)
            ok = self._carry_out(bool(int(arm["grip_close"])))
            if not lockstep:
                self._publish(self._gripper.read_once())
            arm["grip_state"] = GRIP_DONE if ok else GRIP_FAILED
            self._done = cmd
            arm["grip_done"] = cmd
            futex.wake(arm["grip_done"].ctypes.data)
            if lockstep:
                self._read_width()

    def _read_width(self) -> None:
        """Lockstep: the fingers' width from the next gripper state (the clock may stand
        meanwhile: libfranka's receive then times out, and the width waits for the next)."""
        try:
            self._publish(self._gripper.read_once())
        except Exception as exc:
            self.log.debug("%s: no gripper state: %s", self.label, exc)

    def on_shutdown(self) -> None:
        self.arm["hand_up"] = 0

    def _carry_out(self, close: bool) -> bool:
        """Close on whatever is between the fingers (a grasp of width 0 that any object
        within the opening satisfies), or open them fully; whether libfranka says it
        succeeded (an exception: it did not, and why is logged)."""
        try:
            if close:
                return bool(
                    self._gripper.grasp(0.0, GRASP_SPEED_M_S, GRASP_FORCE_N, 0.0, self.max_width)
                )
            return bool(self._gripper.move(self.max_width, GRASP_SPEED_M_S))
        except Exception as exc:
            self.log.warning("%s: %s failed: %s", self.label, "grasp" if close else "open", exc)
            return False


if __name__ == "__main__":  # python -m kali_daemons.link.hand --instance NAME --name hand.ROBOT
    from ..runtime.daemon import run_daemon  # run as a program only

    run_daemon(FrankaHand)
