"""Motion requests from user programs to the trajectory generator (thesis 3.3.2, DESIGN 5).

    from kali_daemons.client import Kali
    with Kali("default") as kali:
        left = kali.robot("left")
        left.move_joints(np.radians([0, 45, -180, 0, 45, 0]))       # blocks until there
        m = left.move_joints(target, speed=0.3, wait=False)        # a handle
        m.wait(timeout=5.0)

Requests go through the TG's Type 1 queue; each request's fate comes back in its status
record.  Everything is validated here before it is queued (the TG validates again): a bad
request raises ``MotionError`` and nothing moves.  A halt wakes every waiting program with
the fault (``MotionFailedError``).
"""

from __future__ import annotations

import math
import os
import time
from types import TracebackType

import numpy as np

from .. import layout
from ..channels import RequestQueue
from ..errors import KaliError
from ..instance import Instance, decode
from ..layout import TERMINAL_STATES, MotionKind, RequestState
from ..servolevel import ServoClient
from ..tg.profiles import MotionError, check_joint_target

POLL_S = 0.002  # how often a waiting program looks at its request's status


class MotionFailedError(MotionError):
    """The system halted (or the request was refused, stopped or aborted) while waiting."""


class MotionHandle:
    """One request: ``done``, ``state``, ``wait(timeout)``, ``cancel()``."""

    def __init__(self, kali: Kali, seq: int, robots: list[int]) -> None:
        self.kali = kali
        self.seq = seq
        self.robots = robots

    @property
    def _status(self) -> np.void | None:
        rec = self.kali.status[self.seq % layout.STATUS_RING]
        return rec if int(rec["seq"]) == self.seq else None

    @property
    def state(self) -> RequestState:
        """Where the request is (QUEUED until the TG has taken it)."""
        rec = self._status
        return RequestState.QUEUED if rec is None else RequestState(int(rec["state"]))

    @property
    def message(self) -> str:
        """Why it was refused, stopped or halted ('' otherwise)."""
        rec = self._status
        return "" if rec is None else decode(rec["message"])

    @property
    def done(self) -> bool:
        """True once the request is over, however it ended."""
        return self.state in TERMINAL_STATES

    def wait(self, timeout: float | None = None) -> None:
        """Block until the motion has arrived; MotionFailedError if it ended any other way (refused,
        stopped, aborted, halted: the message says why), TimeoutError after ``timeout`` s."""
        deadline = None if timeout is None else time.monotonic() + timeout
        inst = self.kali.inst
        while not self.done:
            if inst.fault["active"]:  # the clock, and so the TG, has stopped: say it here
                raise MotionFailedError(f"request {self.seq} halted: {inst.fault_text()}")
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(
                    f"motion: request {self.seq} not done within {timeout:g} s "
                    f"({self.state.name.lower()})"
                )
            time.sleep(POLL_S)
        state = self.state
        if state != RequestState.DONE:
            raise MotionFailedError(f"request {self.seq} {state.name.lower()}: {self.message}")

    def cancel(self) -> None:
        """Stop the motion smoothly on its path (a queued one never starts)."""
        self.kali._request(MotionKind.STOP, self.robots)


class Robot:
    """One arm of the cell, as a user program moves it."""

    def __init__(self, kali: Kali, index: int) -> None:
        self.kali = kali
        self.index = index
        self.name = kali.names[index]

    def read_joints(self) -> np.ndarray:
        """The measured joint angles (rad), a copy."""
        return self.kali.servo.level.robots["q"][self.index].copy()

    def move_joints(
        self, q: np.ndarray, speed: float = 0.5, wait: bool = True, timeout: float | None = None
    ) -> MotionHandle:
        """A smooth joint move to ``q`` (rad, 6 values), every joint arriving together, at
        ``speed`` (0, 1] of the joint speed and acceleration limits.  Blocks until there unless
        ``wait`` is False; returns the request's handle either way."""
        target = _joints(self.name, q)
        if not (isinstance(speed, int | float) and math.isfinite(speed) and 0.0 < speed <= 1.0):
            raise MotionError(
                f"move_joints: robot '{self.name}': speed {speed!r}, must be in (0, 1]"
            )
        handle = self.kali._request(
            MotionKind.JOINTS, [self.index], joints=target[None, :], speed_scale=float(speed)
        )
        if wait:
            handle.wait(timeout)
        return handle

    def stop(self) -> None:
        """Decelerate this arm's motion to rest on its path; queued ones are cancelled."""
        self.kali._request(MotionKind.STOP, [self.index])

    def abort(self) -> None:
        """Drop this arm's motion at once: it holds at the last set-point."""
        self.kali._request(MotionKind.ABORT, [self.index])


def _joints(robot: str, q: np.ndarray) -> np.ndarray:
    try:
        target = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise MotionError(f"move_joints: robot '{robot}': {q!r} is not 6 numbers ({exc})") from None
    if target.shape != (6,):
        raise MotionError(f"move_joints: robot '{robot}': shape {target.shape}, expected (6,)")
    check_joint_target(robot, target)
    return target


class Kali:
    """A user program's connection to a running instance (attach by name)."""

    def __init__(self, instance: str = "default") -> None:
        self.inst = Instance.attach(instance)
        try:
            self.servo = ServoClient(self.inst)
            arena = self.inst.arena
            self.queue = RequestQueue(
                arena, layout.KEY_MOTION_QUEUE, layout.MOTION_REQUEST, layout.MOTION_QUEUE_CAPACITY
            )
            self.status = arena.record(
                layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING
            )
        except KaliError:
            self.inst.close()
            raise
        self.names = self.servo.names

    def robot(self, name: str) -> Robot:
        """The arm called ``name``; ServoError naming the robots otherwise."""
        return Robot(self, self.servo.robot_index(name))

    def _request(self, kind: MotionKind, robots: list[int], **fields: object) -> MotionHandle:
        req = np.zeros((), dtype=layout.MOTION_REQUEST)
        req["kind"] = kind
        req["n_robots"] = len(robots)
        req["robots"][: len(robots)] = robots
        req["client_pid"] = os.getpid()
        for name, value in fields.items():
            if name == "joints":
                req["joints"][: len(robots)] = value
            else:
                req[name] = value
        seq = self.queue.put(req)
        return MotionHandle(self, seq, robots)

    def close(self) -> None:
        """Detach (the motions already requested go on)."""
        self.servo.close()
        self.status = None  # type: ignore[assignment]
        self.queue = None  # type: ignore[assignment]
        self.inst.close()

    def __enter__(self) -> Kali:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
