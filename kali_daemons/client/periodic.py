"""A program's periodic functions (thesis 3.6.2 ``control`` and ``release``).

    with Kali() as kali:
        ctl = kali.control(every_10ms, period_ms=10)   # returns at once
        kali.robot("left").move_joints(target)          # the function runs meanwhile
        ctl.release("done with it")                     # thesis release(message)

``Kali.control`` runs the function in a thread of the calling program (a
``daemon.FunctionDaemon``) on the wall clock, with a slot in the process table under the
program's pid: in lockstep the clock waits for it, so a run is as deterministic as one with a
process per function.  A thread, not a child process, so the function shares the program's
objects, what the program owns by pid (leases, shared transforms) and its GIL.  A program's
functions end with it (``Kali.close``, ``atexit``); one killed outright leaves its slot to the
clock, which finds its pid dead.
"""

from __future__ import annotations

import atexit
import itertools
import logging
import math
import os
import sys
import threading
import time
import weakref
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..core.errors import ClockError, KaliError
from ..runtime.daemon import FunctionDaemon
from ..wallclock.api import check_period

if TYPE_CHECKING:
    from .motion import Kali

FUNCTION_STAGE = 8  # lockstep stage: after every Kali daemon of a tick (they use 0..4)
JOIN_POLL_S = 0.002  # how often join looks whether the thread has ended (real time)
RELEASED = "released by the program"  # the reason of a release without a message
log = logging.getLogger("kali.control")
_numbers = itertools.count()  # default names: prog.<pid>.<n>, unique in the program
_live: weakref.WeakSet[Control] = weakref.WeakSet()  # released at exit if still running


class Control:
    """One periodic function of this program (``Kali.control``): ``release(message)``,
    ``running``, ``ticks``, ``error``, ``reason``, ``join(timeout)``."""

    def __init__(self, kali: Kali, daemon: FunctionDaemon, period_ms: float) -> None:
        self._kali = kali
        self._daemon = daemon
        self.name = daemon.name
        self.period_ms = period_ms
        self.serious = daemon.serious
        # how long release waits for the thread: a lockstep tick's longest wait, and a margin
        self._release_s = kali.inst.config.clock.lockstep_ack_timeout_s + 1.0

    @property
    def running(self) -> bool:
        """True until the function has been released and its slot freed."""
        thread = self._daemon.thread
        return thread is not None and thread.is_alive()

    @property
    def ticks(self) -> int:
        """How many times the function has run."""
        return int(self._daemon.ticks[0])

    @property
    def error(self) -> str | None:
        """What the function raised (``Type: message``), or None."""
        return self._daemon.error

    @property
    def reason(self) -> str:
        """Why it ended (the release message, its return, its error); "" while it runs."""
        return self._daemon.reason

    def release(self, message: str = "") -> None:
        """Stop running the function (thesis ``release(message)``): ``message``, the reason,
        is kept (``reason``) and printed to stderr if given.  From the function itself it
        ends after this call; from the program it returns once the slot is free.
        ClockError if the function is still inside a call (blocked) after the lockstep
        timeout: it ends when that call returns.  Releasing an ended one does nothing."""
        if not isinstance(message, str):
            raise ClockError(f"release of '{self.name}': message {message!r:.60} is not text")
        if not self.running:
            return
        self._daemon.release(message or RELEASED)
        if message:
            print(f"kali: control '{self.name}' released: {message}", file=sys.stderr)
        thread = self._daemon.thread
        if thread is None or threading.current_thread() is thread:
            return
        thread.join(self._release_s)
        if thread.is_alive():
            raise ClockError(
                f"release of '{self.name}': the function is still in its call after "
                f"{self._release_s:g} s; it ends when that returns"
            )

    def join(self, timeout: float | None = None) -> bool:
        """Wait until the function has been released (it returned False or raised, or
        ``release``); True if it has, False after ``timeout`` s.  In a lockstep instance
        the wait steps the clock while the function runs (``Kali.pause``: nothing else steps
        it).  ClockError from the function itself, which would wait for ever."""
        if timeout is not None and not (
            isinstance(timeout, int | float) and not isinstance(timeout, bool) and timeout >= 0
        ):
            raise ClockError(f"join of '{self.name}': timeout {timeout!r:.60}, must be s >= 0")
        thread = self._daemon.thread
        if thread is None:
            return True
        if threading.current_thread() is thread:
            raise ClockError(f"join of '{self.name}': called from the function itself")
        deadline = math.inf if timeout is None else time.monotonic() + timeout
        inst = self._kali.inst
        while thread.is_alive():
            if time.monotonic() > deadline:
                return False
            halted = inst.fault["active"] or inst.shutting_down
            if inst.lockstep and not self._daemon.reason and not halted:
                try:
                    self._kali.pause()  # the function runs in the ticks this steps
                except KaliError:  # a halt meanwhile: the clock steps no more
                    thread.join(JOIN_POLL_S)
            else:  # leaving, or in real time: no tick needed
                thread.join(JOIN_POLL_S)
        return True

    def __repr__(self) -> str:
        state = "running" if self.running else f"ended: {self.reason}"
        return f"Control({self.name!r}, {self.period_ms:g} ms, {self.ticks} ticks, {state})"


def start(
    kali: Kali,
    func: Callable[[int], object],
    period_ms: float,
    serious: bool,
    name: str | None,
    cpu: int | None,
    priority: int,
) -> Control:
    """``Kali.control``: check the arguments, register ``func`` and start its thread;
    ClockError naming the argument otherwise, nothing registered."""
    what = f"control '{name}'" if name is not None else "control"
    if not callable(func):
        raise ClockError(f"{what}: {func!r:.60} is not callable")
    if not isinstance(serious, bool):
        raise ClockError(f"{what}: serious {serious!r:.60} is not True or False")
    if name is not None and not isinstance(name, str):
        raise ClockError(f"control: name {name!r:.60} is not text")
    if cpu is not None and (isinstance(cpu, bool) or not isinstance(cpu, int) or cpu < 0):
        raise ClockError(f"{what}: cpu {cpu!r:.60} is not a CPU number")
    if isinstance(priority, bool) or not isinstance(priority, int) or not 0 <= priority <= 99:
        raise ClockError(f"{what}: priority {priority!r:.60}, must be 0 (SCHED_OTHER) .. 99")
    check_period(kali.inst, what, period_ms)
    if name is None:
        name = f"prog.{os.getpid()}.{next(_numbers)}"
    daemon = FunctionDaemon(
        kali.inst.name,
        name,
        func,
        period_ms=period_ms,
        serious=serious,
        stage=FUNCTION_STAGE,
        cpu=cpu,
        priority=priority,
        lock_memory=False,
    )
    daemon.start_thread()
    control = Control(kali, daemon, float(period_ms))
    _live.add(control)
    return control


@atexit.register
def _release_at_exit() -> None:
    """At the interpreter's exit (after the main thread, before daemon threads are cut
    off): release every function still running, so no slot is left behind."""
    for control in list(_live):
        try:
            control.release()
        except KaliError as exc:
            log.warning("at exit: %s", exc)
