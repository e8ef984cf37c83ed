"""Benchmark: the cost of one atomic operation on a shared word, as Kali's processes pay it.

What is measured.  Each operation of ``kali_daemons.core.atomic`` (ctypes calls into Debian's
libatomic) on an aligned word of an anonymous shared mmap -- load32, exchange32 (test-and-set),
a CompareExchange32 that succeeds, fetch_add64 -- and an uncontended ``SpinLock``
acquire + release (two compare-exchanges plus the Python around them), each timed over
``--iterations`` calls in a plain ``for`` loop with the garbage collector off.  Optionally the
same operations through the ``atomics`` PyPI package (an ``atomicview`` opened once and held),
if it is importable; it is not a Kali dependency (``pip install atomics`` only to compare).

How to read it.  ``ns/op`` is the wall time of the whole loop divided by the iterations: the
best of ``--repeats`` runs, and the median of them beside it (the gap is scheduling noise).
It includes the interpreter's loop and call overhead, which is what a cycle pays; the two
baseline rows (an empty loop, a call to a Python function that does nothing) show how much of
each figure that is.  Single process, single thread, no contention: cache-line transfers
between CPUs are not measured.

    .venv/bin/python scripts/bench_atomic.py
    .venv/bin/python scripts/bench_atomic.py --iterations 1000000 --repeats 7 --cpu 1
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import mmap
import os
import sys
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass

from harness import table, time_per_op

from kali_daemons.core import atomic
from kali_daemons.core.spinlock import SpinLock

WORD32_OFFSET = 0
WORD64_OFFSET = 8
LOCK_OFFSET = 64  # its own cache line


@dataclass
class Timing:
    """One table row."""

    operation: str
    best_ns: float
    median_ns: float


def _noop(addr: int, value: int) -> int:
    return value


def kali_cases(addr32: int, addr64: int, lock: SpinLock) -> list[tuple[str, Callable[[int], None]]]:
    """The loops over kali_daemons.core.atomic and SpinLock (each binds its callable locally)."""
    load32, xchg32, add64 = atomic.load32, atomic.exchange32, atomic.fetch_add64
    cas = atomic.CompareExchange32()
    acquire, release = lock.acquire, lock.release

    def empty(n: int) -> None:
        for _ in range(n):
            pass

    def noop_call(n: int) -> None:
        f = _noop
        for _ in range(n):
            f(addr32, 1)

    def load(n: int) -> None:
        for _ in range(n):
            load32(addr32)

    def exchange(n: int) -> None:
        for _ in range(n):
            xchg32(addr32, 1)

    def compare_exchange(n: int) -> None:
        atomic.store32(addr32, 0)
        for _ in range(n):
            cas(addr32, 0, 0)  # always succeeds: a locked cmpxchg that writes 0 back

    def fetch_add(n: int) -> None:
        for _ in range(n):
            add64(addr64, 1)

    def spinlock(n: int) -> None:
        for _ in range(n):
            acquire()
            release()

    return [
        ("baseline: empty for loop", empty),
        ("baseline: no-op Python call", noop_call),
        ("kali atomic.load32", load),
        ("kali atomic.exchange32 (test-and-set)", exchange),
        ("kali CompareExchange32 (succeeds)", compare_exchange),
        ("kali atomic.fetch_add64", fetch_add),
        ("kali SpinLock acquire+release", spinlock),
    ]


def atomics_cases(buf: mmap.mmap, stack: ExitStack) -> list[tuple[str, Callable[[int], None]]]:
    """The same word operations through the ``atomics`` package; [] if it is not installed.

    The views stay open until ``stack`` closes (opening one per call would be unfair to it).
    """
    try:
        import atomics  # optional, see the module docstring
    except ImportError:
        return []
    mv = stack.enter_context(memoryview(buf))
    a32 = stack.enter_context(
        atomics.atomicview(buffer=mv[WORD32_OFFSET : WORD32_OFFSET + 4], atype=atomics.UINT)
    )
    a64 = stack.enter_context(
        atomics.atomicview(buffer=mv[WORD64_OFFSET : WORD64_OFFSET + 8], atype=atomics.UINT)
    )

    def load(n: int) -> None:
        f = a32.load
        for _ in range(n):
            f()

    def exchange(n: int) -> None:
        f = a32.exchange
        for _ in range(n):
            f(1)

    def compare_exchange(n: int) -> None:
        a32.store(0)
        f = a32.cmpxchg_strong
        for _ in range(n):
            f(0, 0)

    def fetch_add(n: int) -> None:
        f = a64.fetch_add
        for _ in range(n):
            f(1)

    cases = [
        ("atomics load (uint32 view)", load),
        ("atomics exchange (uint32 view)", exchange),
        ("atomics cmpxchg_strong (succeeds)", compare_exchange),
        ("atomics fetch_add (uint64 view)", fetch_add),
    ]
    return cases


def check(addr32: int, addr64: int, lock: SpinLock) -> None:
    """Sanity: the operations do what they say on this mapping (not a timing)."""
    atomic.store32(addr32, 7)
    old = atomic.exchange32(addr32, 9)
    if (old, atomic.load32(addr32)) != (7, 9):
        raise RuntimeError(f"exchange32: got old {old}, word {atomic.load32(addr32)}; want 7, 9")
    start = atomic.load64(addr64)
    atomic.fetch_add64(addr64, 5)
    if atomic.load64(addr64) != start + 5:
        raise RuntimeError(f"fetch_add64: word {atomic.load64(addr64)}, want {start + 5}")
    lock.acquire()
    held = lock.holder
    lock.release()
    if held != os.getpid() or lock.holder != 0:
        raise RuntimeError(f"SpinLock: holder {held} while held, {lock.holder} after release")


def main(argv: list[str] | None = None) -> int:
    """Run every case and print the table."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--iterations", type=int, default=200_000, help="calls per run (200000)")
    ap.add_argument("--repeats", type=int, default=5, help="runs per operation; best is kept")
    ap.add_argument("--cpu", type=int, default=None, help="bind to this CPU first (optional)")
    args = ap.parse_args(argv)
    if args.iterations < 1 or args.repeats < 1:
        ap.error("--iterations and --repeats must be >= 1")
    if args.cpu is not None:
        os.sched_setaffinity(0, {args.cpu})

    buf = mmap.mmap(-1, mmap.PAGESIZE, flags=mmap.MAP_SHARED | mmap.MAP_ANONYMOUS)
    base = ctypes.addressof(ctypes.c_char.from_buffer(buf))
    addr32, addr64 = base + WORD32_OFFSET, base + WORD64_OFFSET
    lock = SpinLock(base + LOCK_OFFSET, "bench")
    check(addr32, addr64, lock)

    cases = kali_cases(addr32, addr64, lock)
    rows: list[Timing] = []
    with ExitStack() as stack:
        extra = atomics_cases(buf, stack)
        gc.disable()
        try:
            for name, body in cases + extra:
                body(min(args.iterations, 10_000))  # warm up
                best, median = time_per_op(body, args.iterations, args.repeats)
                rows.append(Timing(name, best, median))
        finally:
            gc.enable()

    where = f"CPU {args.cpu}" if args.cpu is not None else "unbound"
    print(
        f"python {sys.version.split()[0]}, kernel {os.uname().release}, {where}, "
        f"{args.iterations} iterations x {args.repeats} runs, anonymous shared mmap"
    )
    if not extra:
        print("(the atomics package is not installed: its rows are left out)")
    cols = [("operation", "left"), "ns/op best", "median"]
    print(table(cols, [[r.operation, f"{r.best_ns:.0f}", f"{r.median_ns:.0f}"] for r in rows]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
