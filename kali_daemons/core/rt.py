"""Operating-system real-time settings for one Kali process (DESIGN sections 1 and 10).

CPU binding, SCHED_FIFO, timer slack, locked memory and sleeping to absolute deadlines.
Each setting is applied where the OS permits; a refusal is reported once, never fatal.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import os
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import posix_ipc

_libc = ctypes.CDLL(None, use_errno=True)
_PR_SET_TIMERSLACK = 29
_MCL_CURRENT, _MCL_FUTURE, _MCL_ONFAULT = 1, 2, 4
_CLOCK_MONOTONIC = 1
_TIMER_ABSTIME = 1


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


_clock_nanosleep = _libc.clock_nanosleep
_clock_nanosleep.argtypes = [
    ctypes.c_int,
    ctypes.c_int,
    ctypes.POINTER(_Timespec),
    ctypes.POINTER(_Timespec),
]
_clock_nanosleep.restype = ctypes.c_int

monotonic_ns = time.monotonic_ns  # CLOCK_MONOTONIC: one time base for every Kali process
# CLOCK_THREAD_CPUTIME_ID: the CPU time the calling thread has had.  The kernel leaves out
# time spent in interrupts and the time the host says it took the vCPU (steal), so a cycle
# whose wall time far exceeds it, with nothing else scheduled, lost the CPU from under it.
thread_time_ns = time.thread_time_ns


class AbsoluteSleeper:
    """Sleeps until an absolute CLOCK_MONOTONIC time, as cyclictest does.

    The timespec is allocated once; ``until`` is safe inside a cycle.  The GIL is released
    for the duration of the sleep (ctypes).
    """

    __slots__ = ("_ref", "_ts")

    def __init__(self) -> None:
        self._ts = _Timespec()
        self._ref = ctypes.byref(self._ts)

    def until(self, deadline_ns: int) -> None:
        """Return at (or after) ``deadline_ns``; resumes after signals."""
        self._ts.tv_sec, self._ts.tv_nsec = divmod(deadline_ns, 1_000_000_000)
        while _clock_nanosleep(_CLOCK_MONOTONIC, _TIMER_ABSTIME, self._ref, None) == 4:  # EINTR
            pass


def spin_until(deadline_ns: int) -> None:
    """Busy-wait to ``deadline_ns`` (the last tens of µs before a tick, DESIGN 10 item 4)."""
    while monotonic_ns() < deadline_ns:
        pass


def poll_semaphore(sem: posix_ipc.Semaphore, deadline_ns: int) -> bool:
    """Busy-wait until ``sem`` is posted or ``deadline_ns`` passes; True if it was posted.

    The value is read, never taken: the caller then takes the post with an ordinary wait,
    which returns at once.  A process polling is no waiter, so the post wakes nobody: no
    wake-up crosses vCPUs, and no IPI pauses the poster's vCPU (DESIGN 10 items 1-2; the
    kernel trace: docs/decisions/0002-sv-polling-and-resting.md).  Bounded by the caller, as
    DESIGN 10 item 1 asks of every spin on these two cores.
    """
    while sem.value == 0:
        if monotonic_ns() >= deadline_ns:
            return False
    return True


_sem_open = _libc.sem_open
_sem_open.argtypes = [ctypes.c_char_p, ctypes.c_int]
_sem_open.restype = ctypes.c_void_p
_sem_close = _libc.sem_close
_sem_close.argtypes = [ctypes.c_void_p]


def semaphore_address(sem: posix_ipc.Semaphore) -> int:
    """Outside the cycle: the C library's ``sem_t`` of the named semaphore ``sem`` has open,
    for a kernel that posts it (SIO's compiled tick posts the SVs' feeds).  The C library maps
    a name once per process and counts its opens, so this is the same semaphore ``sem`` posts;
    ``close_semaphore_address`` gives this open back."""
    ptr = _sem_open(sem.name.encode(), 0)
    if not ptr:
        err = ctypes.get_errno()
        raise OSError(err, f"sem_open {sem.name}: {os.strerror(err)}")
    return ptr


def close_semaphore_address(ptr: int) -> None:
    """Outside the cycle: close an open ``semaphore_address`` made (0, none: nothing)."""
    if ptr:
        _sem_close(ptr)


AUTOGROUP = "/proc/self/autogroup"  # a session's scheduling group, where the kernel has them


@dataclass
class RtReport:
    """What was applied to this process, for the process table and ``kalictl status``."""

    cpu: int  # -1 when not bound
    priority: int  # 0 when SCHED_OTHER
    timer_slack_ns: int
    memory_locked: bool
    warnings: list[str]


def _bind_other_threads(cpu: int) -> None:
    """Bind the threads libraries started at import (BLAS workers, rerun's tokio runtime) to
    ``cpu`` too: ``sched_setaffinity(0)`` moves only the calling thread, and a stray thread
    left free runs on the servo CPU, evicting its caches."""
    for tid in os.listdir("/proc/self/task"):
        with contextlib.suppress(OSError):  # a thread that has just exited
            os.sched_setaffinity(int(tid), {cpu})


def prepare(cpu: int | None, lock_memory: bool = True) -> RtReport:
    """Bind to ``cpu``, set timer slack to 1 ns and lock memory, still as SCHED_OTHER.

    Memory is locked as it is first touched (``MCL_ONFAULT``, Linux >= 4.4): what the process
    has touched stays resident, and its set-up (``on_configure``, warm-ups) and first cycles
    touch what the loop uses; a page first touched later costs one minor fault, once.
    Locking the whole address space instead faulted in every reservation nobody touches,
    72 MB a process: OpenBLAS's 32 MB buffer per thread and its worker's 8 MB stack, which
    numpy maps at import (the wall clock held 103 MB PSS in the default cell, 22 MB this
    way).  A kernel refusing the flag gets the whole-space lock.  Locking before
    ``go_realtime`` keeps that work from starving real-time processes of another instance on
    the same CPU.
    """
    warnings: list[str] = []
    bound = -1
    if cpu is not None:
        try:
            os.sched_setaffinity(0, {cpu})
            bound = cpu
        except OSError as exc:
            warnings.append(f"cannot bind to CPU {cpu}: {exc.strerror}")
        else:
            _bind_other_threads(cpu)
    slack = 0
    if _libc.prctl(_PR_SET_TIMERSLACK, ctypes.c_ulong(1), 0, 0, 0) == 0:
        slack = 1
    else:
        warnings.append("cannot set timer slack to 1 ns")
    locked = False
    if lock_memory:
        if _libc.mlockall(_MCL_CURRENT | _MCL_FUTURE | _MCL_ONFAULT) == 0:
            locked = True
        elif ctypes.get_errno() == errno.EINVAL and _libc.mlockall(_MCL_CURRENT | _MCL_FUTURE) == 0:
            locked = True  # a kernel before 4.4: no MCL_ONFAULT
        else:
            warnings.append(f"mlockall refused ({os.strerror(ctypes.get_errno())})")
    return RtReport(bound, 0, slack, locked, warnings)


def go_realtime(report: RtReport, priority: int, nice: int = 0) -> None:
    """Switch to SCHED_FIFO at ``priority`` (0: stay SCHED_OTHER at ``nice``); record it in
    ``report``."""
    if priority <= 0:
        if nice:
            set_nice(report, nice)
        return
    try:
        os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))
        report.priority = priority
    except OSError as exc:
        report.warnings.append(
            f"SCHED_FIFO priority {priority} refused ({exc.strerror}); running SCHED_OTHER"
        )


def set_nice(report: RtReport, nice: int) -> None:
    """This process's weight at SCHED_OTHER: its nice value and, where the kernel weighs a
    session's processes as one (autogroup, sched(7)), its session's, which is what other
    programs' sessions compete with (each Kali process leads a session of its own)."""
    try:
        os.setpriority(os.PRIO_PROCESS, 0, nice)
        if os.path.exists(AUTOGROUP):
            with open(AUTOGROUP, "w") as f:
                f.write(str(nice))
    except OSError as exc:
        report.warnings.append(f"nice {nice} refused ({exc.strerror}); running at nice 0")


def leave_realtime() -> None:
    """Back to SCHED_OTHER before tearing down, so exiting never stalls real-time processes."""
    try:
        os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))
    except OSError:
        pass
