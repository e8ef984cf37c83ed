"""Test-and-set spinlocks on arena words (thesis 3.6.1, appendix A).

The lock word holds the holder's thread id (0 when free; a process's main thread has its
pid), set by one atomic compare-exchange, so a lock held by a process or thread that died can
be recognised and taken over, and two threads of one program exclude each other.  Waiting
spins a bounded number of times and then sleeps with a growing back-off: on two cores, a
SCHED_FIFO waiter that spun without bound would starve a holder sharing its CPU (DESIGN
section 10).
"""

from __future__ import annotations

import os
import threading
import time

from . import atomic
from .errors import LockError

SPIN_TRIES = 64  # compare-exchanges before the first sleep (~60 µs)
FIRST_BACKOFF_S = 20e-6
MAX_BACKOFF_S = 1e-3


PF_EXITING = 0x4  # /proc/<pid>/stat flags: the process is tearing itself down


def pid_alive(pid: int) -> bool:
    """True if ``pid`` names a running process.  A zombie counts as dead, and so does a
    process already exiting (killed, freeing its locked memory: that can take longer than a
    serious deadline, and it will never acknowledge again)."""
    if pid <= 0:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return _running(f.read())
    except OSError:
        return False


def _running(stat: bytes) -> bool:
    """Whether a /proc/<pid>/stat text is a process's that runs: not a zombie, not exiting."""
    try:
        fields = stat.rsplit(b")", 1)[1].split()
        state, flags = fields[0], int(fields[6])
    except (IndexError, ValueError):
        return False
    return state not in (b"Z", b"X") and not flags & PF_EXITING


class ProcStat:
    """``pid_alive`` for one process, its /proc/<pid>/stat opened once and read again in
    place: no path lookup, no open (a sixth of the cost, ~10 µs here), for whoever asks
    every tick (the wall clock, of each process late for it).  The file stays the process's:
    once it is gone a read fails, and a new process with its pid is not taken for it."""

    __slots__ = ("fd", "pid")

    def __init__(self, pid: int) -> None:
        self.pid = pid
        try:
            self.fd = os.open(f"/proc/{pid}/stat", os.O_RDONLY | os.O_CLOEXEC) if pid > 0 else -1
        except OSError:
            self.fd = -1

    def alive(self) -> bool:
        """True while the process runs (not a zombie, not exiting)."""
        if self.fd < 0:
            return False
        try:
            return _running(os.pread(self.fd, 1024, 0))
        except OSError:  # ESRCH: reaped
            return False

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1


_STATES = {
    b"R": "running",
    b"S": "sleeping",
    b"D": "in the kernel",
    b"T": "stopped",
    b"t": "stopped by a debugger",
    b"Z": "dead",
    b"X": "dead",
}


def holder_text(pid: int) -> str:
    """A lock holder as a message names it: ``pid 4242 (python3, stopped)``; never in a
    cycle (it reads /proc and builds a string)."""
    if pid <= 0:
        return "nobody"
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            raw = f.read()
    except OSError:
        return f"pid {pid} (dead)"
    comm = raw[raw.find(b"(") + 1 : raw.rfind(b")")].decode("utf-8", "replace")
    state = raw.rsplit(b")", 1)[1].split()[0]
    return f"pid {pid} ({comm}, {_STATES.get(state, state.decode('ascii', 'replace'))})"


class SpinLock:
    """A spinlock on the 32-bit arena word at absolute address ``addr``.

    The word holds the id of the thread that took it (Linux's thread id: a process's main
    thread has its pid), so two threads of one program exclude each other like two programs
    (a program and its periodic function, ``Kali.control``), and a lock whose thread died is
    recovered even while its process lives.  ``acquire``/``release`` are safe inside a cycle
    on the uncontended path (one compare-exchange, no allocation); contention falls back to
    sleeping.  One object may be shared by threads: each call uses the calling thread's id.
    """

    __slots__ = ("_addr", "_local", "name", "recoveries")

    def __init__(self, addr: int, name: str) -> None:
        self._addr = addr
        # per thread: its compare-exchange (whose ``expected`` cell no two threads may share)
        # and its id as it last took the lock (``release`` needs no system call for it)
        self._local = threading.local()
        self._local.cas = atomic.CompareExchange32()
        self.name = name
        self.recoveries = 0  # locks taken over from dead holders by this object

    def _cas_of_thread(self) -> atomic.CompareExchange32:
        """The calling thread's compare-exchange, made on its first use of this lock (for
        the thread that made the lock: at once, outside any cycle)."""
        cas = getattr(self._local, "cas", None)
        if cas is None:
            cas = self._local.cas = atomic.CompareExchange32()
        return cas

    @property
    def holder(self) -> int:
        """The thread id holding the lock (a process's pid for its main thread), 0 if free."""
        return atomic.load32(self._addr)

    def try_acquire(self) -> bool:
        """Take the lock if it is free; never waits."""
        me = threading.get_native_id()
        ok, _ = self._cas_of_thread()(self._addr, 0, me)
        if ok:
            self._local.me = me
        return ok

    def acquire(self, timeout: float = 5.0) -> None:
        """Take the lock, recovering it from a dead holder; raise LockError after ``timeout`` s."""
        me = threading.get_native_id()  # a forked child's own: never its parent's
        cas = self._cas_of_thread()
        ok, seen = cas(self._addr, 0, me)
        if ok:
            self._local.me = me
            return
        if seen == me:
            raise LockError(f"lock '{self.name}' is already held by this thread (id {seen})")
        tries = 0
        backoff = FIRST_BACKOFF_S
        deadline = time.monotonic() + timeout
        while True:
            if seen == 0:
                ok, seen = cas(self._addr, 0, me)
                if ok:
                    self._local.me = me
                    return
            tries += 1
            if tries < SPIN_TRIES:
                seen = atomic.load32(self._addr)
                continue
            if seen and not pid_alive(seen):
                ok, seen = cas(self._addr, seen, me)
                if ok:
                    self._local.me = me
                    self.recoveries += 1
                    return
                continue
            if time.monotonic() > deadline:
                raise LockError(
                    f"lock '{self.name}' held by {holder_text(seen)} for more than {timeout:g} s"
                )
            time.sleep(backoff)
            backoff = min(backoff * 2, MAX_BACKOFF_S)
            seen = atomic.load32(self._addr)

    def release(self) -> None:
        """Free the lock; raise LockError if this thread does not hold it."""
        loc = self._local
        me = getattr(loc, "me", 0) or threading.get_native_id()  # as it took the lock
        ok, seen = self._cas_of_thread()(self._addr, me, 0)
        if not ok:
            raise LockError(f"lock '{self.name}' released by pid {me} but held by pid {seen}")

    def __enter__(self) -> SpinLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()
