"""The machine's stalls, told from a broken process (real time only): of the wall clock's CPU
(``ClockWitness``, for those who judge by its ticks) and of another CPU (``CpuWitness``, for
the clock judging a process bound there).

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

from ..core.kernels import Kernel
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
# a CPU's witness: above every Kali process on it (the clock's 90 the highest), as
# cyclictest's stall detector is in the benchmarks; a wake-up costs its CPU ~20 µs here (a
# VM's timer), so it wakes every 2 ms, and a stall is counted to within that
WITNESS_PRIORITY = 99
WITNESS_PERIOD_NS = 2_000_000


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


class CpuWitness:
    """The time the machine did not run one CPU, as a thread bound to it above every process
    there sees it (``csrc/witness.c``): each wake-up of it, every ``WITNESS_PERIOD_NS``, more
    than ``stall_ns`` late was such time, and so is its wake-up that late now.  The wall
    clock starts one for each other CPU a serious process is bound to, and judges a process
    there only on the time the machine gave its CPU (``lost_since``;
    docs/decisions/0004-clock-stall-rule.md).  The clock's process holds it; ``start`` and
    ``close`` outside the cycle."""

    def __init__(self, cpu: int, stall_ns: int, ring: int) -> None:
        self.cpu = cpu
        self._stall_ns = stall_ns
        self._ring_ns = np.zeros(ring, dtype=np.int64)
        self._ring_lost = np.zeros(ring, dtype=np.int64)
        self._kernel = Kernel(
            "kali_witness_start",
            (self._ring_ns, self._ring_lost),
            cpu=cpu,
            priority=WITNESS_PRIORITY,
            period_ns=WITNESS_PERIOD_NS,
            stall_ns=stall_ns,
            ring_ns=self._ring_ns.ctypes.data,
            ring_lost=self._ring_lost.ctypes.data,
            ring=ring,
        )
        self._stop = self._kernel.sibling("kali_witness_stop")
        self._args = self._kernel.args

    def start(self) -> int:
        """Start its thread: 0, or the error refusing it (EPERM without the privilege of
        SCHED_FIFO, and then the CPU has no witness)."""
        return self._kernel()

    def close(self) -> None:
        """End its thread (within a period)."""
        self._stop()

    def guard(self, tid: int, priority: int, after_ns: int) -> None:
        """Have the thread guard the bottom half of thread ``tid`` (the clock's): if it
        stands below (``below``) for more than ``after_ns``, the thread puts it back at
        SCHED_FIFO ``priority``.  Before ``start``."""
        a = self._args
        a.guard_tid, a.guard_priority, a.guard_after_ns = tid, priority, after_ns

    def below(self, now_ns: int) -> None:
        """The guarded thread goes below its priority now (before it does: never unseen)."""
        self._args.bottom_since = now_ns

    def above(self) -> None:
        """The guarded thread is back at its priority."""
        self._args.bottom_since = 0

    def lost_since(self, t_ns: int, now_ns: int) -> int:
        """The time the machine did not run the CPU since ``t_ns`` (monotonic), at
        ``now_ns``: the stalls its wake-ups since saw, and the one it is in if its wake-up
        is over ``stall_ns`` late now; as far back as its ring reaches, as the clock's own
        (``WallClock._lost_since``).  0 if its thread is not running."""
        a = self._args
        if not a.running:
            return 0
        for _ in range(4):  # the thread's wake-up takes well under a microsecond
            seq = a.seq
            if seq & 1:
                continue
            due, lost, wakes = int(a.due), int(a.lost), int(a.wakes)
            before = self._lost_at(t_ns, wakes, lost)
            if a.seq == seq:
                break
        else:
            return 0
        late = now_ns - due
        return lost - before + (late if late > self._stall_ns else 0)

    def _lost_at(self, t_ns: int, wakes: int, lost: int) -> int:
        """The sum lost after the last wake-up at or before ``t_ns`` (the oldest the ring
        holds if none)."""
        ring = len(self._ring_ns)
        n = min(wakes, ring)
        if n == 0:
            return lost
        at_ns, at_lost = self._ring_ns, self._ring_lost
        j = wakes - 1
        for _ in range(n):
            k = j % ring
            if at_ns[k] <= t_ns:
                return int(at_lost[k])
            j -= 1
        return int(at_lost[(wakes - n) % ring])
