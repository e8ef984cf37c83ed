"""Test-and-set spinlocks across real processes: mutual exclusion and dead-holder recovery."""

from __future__ import annotations

import multiprocessing as mp
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from kali_daemons.core import atomic
from kali_daemons.core.arena import Arena
from kali_daemons.core.errors import LockError
from kali_daemons.core.spinlock import ProcStat, SpinLock, pid_alive

COUNTER = np.dtype([("lock", "<u4"), ("_pad", "<u4"), ("count", "<u8")])


def _lock_and_counter(a: Arena) -> tuple[SpinLock, np.ndarray]:
    off = a.shmalloc("counter", COUNTER.itemsize)
    lock = SpinLock(a.address_of_field(off, COUNTER, "lock"), "counter")
    return lock, a.view(off, COUNTER)


def _incrementer(instance: str, n: int, start: mp.Event) -> None:
    a = Arena.attach(instance)
    lock, rec = _lock_and_counter(a)
    start.wait()
    for _ in range(n):
        with lock:
            value = int(rec["count"])  # a plain read-modify-write: only the lock protects it
            rec["count"] = value + 1


def test_processes_incrementing_under_the_lock_get_the_exact_count(arena: Arena) -> None:
    instance = arena.name.removeprefix("/kali.")
    _lock_and_counter(arena)
    ctx = mp.get_context("spawn")
    start = ctx.Event()
    procs = [ctx.Process(target=_incrementer, args=(instance, 3000, start)) for _ in range(4)]
    for p in procs:
        p.start()
    start.set()
    for p in procs:
        p.join(120)
        assert p.exitcode == 0
    _, rec = _lock_and_counter(arena)
    assert int(rec["count"]) == 4 * 3000


def _hold_forever(instance: str, held: mp.Event) -> None:
    a = Arena.attach(instance)
    lock, _ = _lock_and_counter(a)
    lock.acquire()
    held.set()
    time.sleep(600)


def test_lock_held_by_a_killed_process_is_recovered(arena: Arena) -> None:
    instance = arena.name.removeprefix("/kali.")
    lock, _ = _lock_and_counter(arena)
    ctx = mp.get_context("spawn")
    held = ctx.Event()
    p = ctx.Process(target=_hold_forever, args=(instance, held))
    p.start()
    assert held.wait(30)
    assert lock.holder == p.pid
    held_by = rf"held by pid {p.pid} \(python[^,]*, sleeping\) for more than"
    with pytest.raises(LockError, match=rf"lock 'counter' {held_by}"):
        lock.acquire(timeout=0.05)  # a live holder is waited for, not robbed
    os.kill(p.pid, signal.SIGKILL)
    p.join(10)
    t = time.monotonic()
    lock.acquire(timeout=2.0)
    assert time.monotonic() - t < 1.0
    assert lock.holder == os.getpid()
    assert lock.recoveries == 1
    lock.release()
    assert lock.holder == 0


def test_misuse_is_an_error(arena: Arena) -> None:
    lock, _ = _lock_and_counter(arena)
    with pytest.raises(LockError, match=r"released by pid \d+ but held by pid 0"):
        lock.release()
    lock.acquire()
    with pytest.raises(LockError, match="already held by this thread"):
        lock.acquire()
    lock.release()
    assert lock.try_acquire()
    assert not lock.try_acquire()
    lock.release()


def test_pid_alive_treats_zombies_as_dead() -> None:
    ctx = mp.get_context("fork")
    p = ctx.Process(target=os._exit, args=(0,))
    p.start()
    time.sleep(0.2)  # exited but not yet reaped: a zombie
    assert not pid_alive(p.pid)
    p.join()
    assert pid_alive(os.getpid())
    assert not pid_alive(0)


def test_a_kept_proc_stat_tells_running_zombie_and_reaped_and_is_not_fooled_by_reuse() -> None:
    """``ProcStat`` (the wall clock's per-tick look-up of a process late for it) says what
    ``pid_alive`` says: alive while it runs, dead as a zombie and once reaped; its file stays
    the process's, so a later process given the same pid is not taken for it."""
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    stat = ProcStat(child.pid)
    try:
        assert stat.alive() and pid_alive(child.pid)
        os.kill(child.pid, signal.SIGKILL)
        deadline = time.monotonic() + 5.0
        while stat.alive():  # a zombie until reaped: dead already
            assert time.monotonic() < deadline
            time.sleep(0.001)
        assert not pid_alive(child.pid)
        child.wait()
        assert not stat.alive()  # reaped: the kept file reads nothing
        os.close(stat.fd)
        stat.fd = os.open(f"/proc/{os.getpid()}/stat", os.O_RDONLY)  # as if the pid were reused
        assert stat.alive()  # a process is read through the file, not through its pid
    finally:
        child.kill()
        child.wait()
        stat.close()
    assert not ProcStat(0).alive() and not ProcStat(child.pid).alive()


def test_atomic_primitives_on_an_arena_word(arena: Arena) -> None:
    off = arena.shmalloc("words", 16)
    a32, a64 = arena.address(off), arena.address(off + 8)
    atomic.store32(a32, 7)
    assert atomic.exchange32(a32, 9) == 7
    cas = atomic.CompareExchange32()
    assert cas(a32, 9, 11) == (True, 9)
    assert cas(a32, 9, 12) == (False, 11)
    assert atomic.fetch_add32(a32, 1) == 11 and atomic.load32(a32) == 12
    atomic.store64(a64, 2**40)
    assert atomic.fetch_add64(a64, 5) == 2**40 and atomic.load64(a64) == 2**40 + 5


def test_threads_of_one_process_take_the_lock_in_turn(arena: Arena) -> None:
    """A program's periodic function runs in a thread of it (``Kali.control``) and may take
    the locks the program takes (a request queue's): the lock word holds the taking thread's
    id, so two threads sharing one lock object exclude each other instead of one being told
    the process already holds it; a thread that dies holding it leaves it to be recovered."""
    import threading

    lock, rec = _lock_and_counter(arena)
    errors: list[BaseException] = []

    def work() -> None:
        try:
            for _ in range(2000):
                with lock:
                    value = int(rec["count"])
                    rec["count"] = value + 1
        except BaseException as exc:
            errors.append(exc)

    threads = [threading.Thread(target=work) for _ in range(3)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors, errors[0]
    assert int(rec["count"]) == 6000
    dead = threading.Thread(target=lock.acquire)  # ends holding it
    dead.start()
    dead.join()
    assert lock.holder == dead.native_id != os.getpid()
    lock.acquire(timeout=2.0)  # recovered from the dead thread
    assert lock.holder == threading.get_native_id() and lock.recoveries == 1
    lock.release()
