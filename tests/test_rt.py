"""Real-time settings of one process: binding, timer slack, FIFO with one warning if refused."""

from __future__ import annotations

import ctypes
import mmap
import os
import threading
from collections.abc import Callable

import posix_ipc
import pytest

from kali_daemons.core import rt
from kali_daemons.runtime import daemon
from kali_daemons.runtime.instance import Instance

PR_GET_TIMERSLACK = 30


def _in_child(fn: Callable[[], int]) -> int:
    """Run ``fn`` in a forked child (so its settings do not leak) and return its exit code."""
    pid = os.fork()
    if pid == 0:
        code = 1
        try:
            code = fn()
        finally:
            os._exit(code)
    return os.waitstatus_to_exitcode(os.waitpid(pid, 0)[1])


def test_prepare_binds_sets_slack_and_locks_memory() -> None:
    def child() -> int:
        report = rt.prepare(0, lock_memory=True)
        libc = ctypes.CDLL(None)
        ok = (
            os.sched_getaffinity(0) == {0}
            and report.cpu == 0
            and libc.prctl(PR_GET_TIMERSLACK, 0, 0, 0, 0) == 1
            and report.timer_slack_ns == 1
            and report.memory_locked == (os.geteuid() == 0)
        )
        return 0 if ok else 3

    assert _in_child(child) == 0


def _mapping(size_kib: int) -> dict[str, int]:
    """The ``Rss`` and ``Locked`` (KiB) of this process's one mapping of ``size_kib``."""
    fields: dict[str, int] = {}
    size = -1
    with open("/proc/self/smaps") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key == "Size":
                size = int(value.split()[0])
            elif size == size_kib and key in ("Rss", "Locked"):
                fields[key] = int(value.split()[0])
    return fields


@pytest.mark.skipif(os.geteuid() != 0, reason="mlockall needs root (or CAP_IPC_LOCK)")
def test_locking_memory_locks_what_is_touched_not_what_is_only_reserved() -> None:
    """A reservation nobody touches (numpy maps OpenBLAS's 32 MB buffer per thread at import)
    stays out of memory when a process locks its memory; what it touches is locked."""

    def child() -> int:
        size = (50 << 20) + (3 << 12)  # a size no other mapping of this process has
        buf = mmap.mmap(-1, size)
        report = rt.prepare(None, lock_memory=True)
        reserved = _mapping(size >> 10)
        buf[: 1 << 20] = b"x" * (1 << 20)
        touched = _mapping(size >> 10)
        ok = (
            report.memory_locked
            and reserved["Rss"] < 4096
            and touched["Rss"] >= 1024
            and touched["Locked"] == touched["Rss"]
        )
        if not ok:
            print(f"reserved {reserved}, touched {touched}", flush=True)
        return 0 if ok else 3

    assert _in_child(child) == 0


def test_fifo_refused_gives_one_warning_and_stays_normal(monkeypatch: pytest.MonkeyPatch) -> None:
    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(rt.os, "sched_setscheduler", refuse)
    report = rt.prepare(None, lock_memory=False)
    rt.go_realtime(report, 85)
    assert report.priority == 0
    assert report.warnings == [
        "SCHED_FIFO priority 85 refused (Operation not permitted); running SCHED_OTHER"
    ]


def test_fifo_granted_as_root() -> None:
    if os.geteuid() != 0:
        pytest.skip("needs root")

    def child() -> int:
        report = rt.prepare(None, lock_memory=False)
        rt.go_realtime(report, 10)
        fifo = os.sched_getscheduler(0) == os.SCHED_FIFO and report.priority == 10
        rt.leave_realtime()
        return 0 if fifo and os.sched_getscheduler(0) == os.SCHED_OTHER else 3

    assert _in_child(child) == 0


def test_absolute_sleeper_never_returns_early() -> None:
    sleeper = rt.AbsoluteSleeper()
    for _ in range(20):
        deadline = rt.monotonic_ns() + 300_000
        sleeper.until(deadline)
        assert rt.monotonic_ns() >= deadline
    t = rt.monotonic_ns()
    sleeper.until(t - 1_000_000)  # a deadline in the past returns at once
    assert rt.monotonic_ns() - t < 50_000_000


def test_poll_semaphore_sees_a_post_without_taking_it_and_gives_up_at_its_deadline() -> None:
    """An SV polls its signal and feed so their posts wake nobody (``rt.poll_semaphore``):
    a post already there is seen at once and left for the wait that takes it, a post
    arriving mid-poll ends the poll, and with none the poll ends at its deadline."""
    name = f"/kali-test-poll-{os.getpid()}"
    sem = posix_ipc.Semaphore(name, posix_ipc.O_CREX, mode=0o600)
    try:
        t = rt.monotonic_ns()
        assert not rt.poll_semaphore(sem, t + 2_000_000)
        assert rt.monotonic_ns() - t >= 2_000_000  # the deadline, not earlier
        sem.release()
        assert rt.poll_semaphore(sem, rt.monotonic_ns() + 1_000_000_000)
        assert sem.value == 1  # seen, not taken
        sem.acquire(0)
        poster = threading.Timer(0.02, sem.release)
        poster.start()
        t = rt.monotonic_ns()
        assert rt.poll_semaphore(sem, t + 10_000_000_000)
        assert 15_000_000 <= rt.monotonic_ns() - t < 5_000_000_000
        poster.join()
    finally:
        sem.unlink()
        sem.close()


@pytest.mark.serial
def test_start_up_work_runs_before_a_daemon_goes_real_time(kali: Callable[..., str]) -> None:
    """A daemon's last preparation and its heap's collection and freeze (tens of ms in a
    process holding MuJoCo and Pinocchio) run as SCHED_OTHER: at SCHED_FIFO they starved
    the servo processes of another instance started on the same CPU (sv.0 missed 21 ms)."""
    if os.geteuid() != 0:
        pytest.skip("needs root")
    name = kali(lockstep=False)

    def child() -> int:
        seen: dict[str, int] = {}
        freeze = daemon.freeze_heap

        def recorded_freeze() -> None:
            seen["freeze_heap"] = os.sched_getscheduler(0)
            freeze()

        class Probe(daemon.FunctionDaemon):
            def on_activate(self) -> None:
                seen["on_activate"] = os.sched_getscheduler(0)

        def cycle(tick: int) -> bool:
            seen["cycle"] = os.sched_getscheduler(0)
            return False

        daemon.freeze_heap = recorded_freeze
        code = Probe(name, "probe", cycle, period_ms=1, priority=10).main()
        print(seen, flush=True)
        expected = {
            "on_activate": os.SCHED_OTHER,
            "freeze_heap": os.SCHED_OTHER,
            "cycle": os.SCHED_FIFO,
        }
        return 0 if code == 0 and seen == expected else 3

    assert _in_child(child) == 0


@pytest.mark.serial
def test_no_realtime_daemon_waits_on_a_worker_thread_below_it(kali: Callable[..., str]) -> None:
    """Every process of the servo path runs one thread, but for the wall clock's witnesses of
    the other CPUs (decision 0004): each bound to one, at SCHED_FIFO 99, never waited on.
    numpy's OpenBLAS starts a worker thread at import (one per further CPU), SCHED_OTHER on
    the daemon's CPU; a BLAS call it shares waits on it while SCHED_FIFO work holds that CPU
    (priority inversion): a soak's TG once took 34 ms of wall time for 1.2 ms of CPU in one
    tick and halted (DEADLINE)."""
    name = kali(lockstep=False)
    with Instance.attach(name) as inst:
        for proc in ("wallclock", "plant", "tg", "sio", "sv.0", "sv.1", "dynamics"):
            pid = int(inst.procs[inst.slot_of(proc)]["pid"])
            threads = sorted(os.listdir(f"/proc/{pid}/task"), key=int)
            others = threads[1:] if proc == "wallclock" else threads
            assert threads[0] == str(pid), f"{proc} (pid {pid}) runs threads {threads}"
            if proc == "wallclock":
                cpus = {p.cpu for p in inst.config.processes if p.serious} - {
                    inst.config.process("wallclock").cpu
                }
                assert len(others) == len(cpus), f"wallclock: threads {threads}, CPUs {cpus}"
                for tid in others:
                    assert os.sched_getscheduler(int(tid)) == os.SCHED_FIFO
                    assert os.sched_getparam(int(tid)).sched_priority == 99
                    assert len(os.sched_getaffinity(int(tid))) == 1
            else:
                assert threads == [str(pid)], f"{proc} (pid {pid}) runs threads {threads}"
