"""Waiting for an arena word to change: Linux's futex on the shared mapping.

A process that waits for another's write to the arena (a program for the wall clock to take
its command, or to finish the ticks it asked for) sleeps in ``wait`` until the writer's
``wake``, instead of polling with sleeps that each cost the kernel's timer slack and a
wake-up.  The futex is the shared (not process-private) kind, keyed by the word's physical
page, so it works across the processes that map the arena.  A wait always has a timeout: a
waiter re-reads the word and its other reasons to stop (the instance stopped, a deadline)
at least that often, so a wake that is missed costs a timeout, never a hang.
"""

from __future__ import annotations

import ctypes
import platform

from .errors import KaliError

FUTEX_WAIT, FUTEX_WAKE = 0, 1  # not FUTEX_PRIVATE_FLAG: the word is shared between processes
_SYS_FUTEX = {"x86_64": 202, "aarch64": 98}  # the futex system call's number
_WAKE_ALL = 0x7FFFFFFF


class FutexError(KaliError):
    """The machine has no futex system call Kali knows."""

    subsystem = "futex"


_number = _SYS_FUTEX.get(platform.machine())
if _number is None:  # pragma: no cover - depends on the machine
    raise FutexError(f"no futex system call number known for {platform.machine()}")
_syscall = ctypes.CDLL(None, use_errno=True).syscall
_syscall.restype = ctypes.c_long
_syscall.argtypes = [
    ctypes.c_long,  # the call's number
    ctypes.c_void_p,  # the word
    ctypes.c_int,  # the operation
    ctypes.c_uint32,  # WAIT: the value expected; WAKE: how many to wake
    ctypes.c_void_p,  # WAIT: the relative timeout (a timespec)
    ctypes.c_void_p,
    ctypes.c_uint32,
]


class _Timespec(ctypes.Structure):
    _fields_ = [("tv_sec", ctypes.c_long), ("tv_nsec", ctypes.c_long)]


class Waiter:
    """One process's waits on 32-bit arena words, each at most ``timeout_s`` (its timespec
    allocated once).  Not shared between threads."""

    __slots__ = ("_timeout", "_timeout_addr")

    def __init__(self, timeout_s: float) -> None:
        ns = round(timeout_s * 1e9)
        self._timeout = _Timespec(ns // 1_000_000_000, ns % 1_000_000_000)
        self._timeout_addr = ctypes.addressof(self._timeout)

    def wait(self, addr: int, expected: int) -> None:
        """Sleep while the 32-bit word at ``addr`` (4-byte aligned) still holds ``expected``,
        until a ``wake`` on it or the timeout; at once if it no longer does.  The caller
        re-reads the word: a wake, a timeout and a signal all just return."""
        _syscall(_number, addr, FUTEX_WAIT, expected & 0xFFFFFFFF, self._timeout_addr, None, 0)


def wake(addr: int) -> None:
    """Wake every process waiting on the 32-bit word at ``addr`` (after writing it)."""
    _syscall(_number, addr, FUTEX_WAKE, _WAKE_ALL, None, None, 0)


__all__ = ["FutexError", "Waiter", "wake"]
