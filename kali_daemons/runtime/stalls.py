"""The machine's stalls of the wall clock's CPU, told from a broken clock (real time only).

On a machine without a real-time kernel, and in a VM above all, the host sometimes stops one
CPU for tens of milliseconds (DESIGN 10).  The clock counts such time against no process when
it wakes late; until it wakes, those who judge by its ticks see only a clock that stands: the
simulated boards' watchdogs (SIO, beside the clock on its CPU, is not signalled either) and
the serious processes that watch the clock (``Daemon._watch_clock``).  They ask this witness:
a clock that should have ticked (running, in real time), is alive and not stopped, yet has
had no CPU time since it last ticked is one the machine holds, and the time is not counted,
for at most ``LONGEST_HELD_NS`` at a stretch.  A clock stopped (SIGSTOP), dead, or spinning in
a fault of its own is counted as before.
"""

from __future__ import annotations

import os

import numpy as np

from ..core.layout import RunMode
from .instance import Instance

# the clock's heartbeat is older than this many of its ticks when it has not run
STALE_TICKS = 2
# the longest stretch a stall is not counted; beyond, it counts again (DESIGN 10: well above
# the longest host stall measured, docs/internals/sio-viewer-core.md)
LONGEST_HELD_NS = 100_000_000
# a clock that had this much CPU time since it last ticked is running (in a fault of its own)
RAN_NS = 1_000_000
STAT_BYTES = 512  # /proc/<pid>/stat: "pid (comm) state ...", the state well inside
STOPPED_STATES = frozenset(b"TtZX")  # stopped, traced, zombie, dead


class TaskClock:
    """The CPU time a process has had (``/proc/<pid>/schedstat``), and whether it is alive and
    not stopped (``/proc/<pid>/stat``): ``ran_ns``.  Reads into preallocated buffers."""

    def __init__(self, pid: int) -> None:
        self._stat = os.open(f"/proc/{pid}/stat", os.O_RDONLY)
        try:
            self._sched = os.open(f"/proc/{pid}/schedstat", os.O_RDONLY)
        except OSError:
            os.close(self._stat)
            raise
        self._buf = bytearray(STAT_BYTES)
        self._bufs = [self._buf]

    def close(self) -> None:
        os.close(self._stat)
        os.close(self._sched)

    def ran_ns(self) -> int:
        """Its CPU time so far, ns; -1 if it is dead or stopped."""
        buf = self._buf
        try:
            n = os.preadv(self._stat, self._bufs, 0)
            end = buf.rfind(b")", 0, n)
            if end < 0 or end + 2 >= n or buf[end + 2] in STOPPED_STATES:
                return -1
            n = os.preadv(self._sched, self._bufs, 0)
        except OSError:  # it died
            return -1
        ns = 0
        for i in range(n):
            c = buf[i]
            if not 48 <= c <= 57:
                break
            ns = ns * 10 + c - 48
        return ns


class ClockWitness:
    """Whether the machine holds the wall clock's CPU (``held``): one per watcher."""

    def __init__(self, inst: Instance) -> None:
        self._inst = inst
        self._clock = inst.clock
        self._stale_ns = STALE_TICKS * int(inst.clock["base_tick_ns"])
        self.enabled = not inst.lockstep
        self._heart: np.ndarray | None = None  # the clock's heartbeat, once it has a slot
        self._task: TaskClock | None = None
        self._since_ns = 0  # when this stall was first seen, 0: none
        self._ran_ns = 0  # the clock's CPU time then
        self._beat = 0  # its heartbeat then: a later one ended that stall

    def close(self) -> None:
        if self._task is not None:
            self._task.close()
            self._task = None

    def held(self, now_ns: int) -> bool:
        """Whether at ``now_ns`` (monotonic) the clock, which should have ticked, has stood
        only because it got no CPU: False while it ticks, and while it is halted, stopped,
        dead or running on."""
        if not self.enabled:
            return False
        heart = self._heart
        if heart is None:
            heart = self._find()
            if heart is None:
                return False
        beat = int(heart[0])
        if now_ns - beat <= self._stale_ns or self._clock["mode"] == RunMode.STOPPED:
            self._since_ns = 0
            return False
        assert self._task is not None
        ran = self._task.ran_ns()
        if self._since_ns == 0 or beat != self._beat:  # a stall not seen before
            self._since_ns, self._ran_ns, self._beat = now_ns, ran, beat
        if ran < 0 or ran - self._ran_ns > RAN_NS:
            return False
        return now_ns - self._since_ns <= LONGEST_HELD_NS

    def _find(self) -> np.ndarray | None:
        """The clock's heartbeat and CPU time, once it runs (once per watcher)."""
        pid = int(self._clock["pid"])
        if not self._clock["ready"] or pid <= 0:
            return None
        i = self._inst.find_slot("wallclock")
        if i < 0:
            return None
        try:
            self._task = TaskClock(pid)
        except OSError:
            self.enabled = False  # gone before it was seen: nothing to witness
            return None
        self._heart = self._inst.procs["heartbeat_ns"][i : i + 1]
        return self._heart
