"""The lock-free fault record read at every step of its writer (issue 24, item 1).

A reader that looks at the record at any moment must see either a whole record or
``UNFINISHED``: never the fault word set beside an earlier fault's fields (the halt would be
reported as the last one, or as ``NONE``).
"""

from __future__ import annotations

import sys
import threading
from collections.abc import Callable, Iterator
from types import FrameType

import pytest

from kali_daemons.core.layout import FaultCode
from kali_daemons.runtime import instance as instance_module
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher

from .conftest import make_config, unique_name


@pytest.fixture
def inst() -> Iterator[Instance]:
    """An instance's records and semaphores, no daemons."""
    name = unique_name("fr")
    arena = launcher._create(make_config(name), name, lockstep=True)
    i = Instance(name, arena)
    yield i
    i.close()
    launcher.stop(name)


def _step_writer(
    inst: Instance,
    code: FaultCode,
    process: str,
    message: str,
    read: Callable[[], object] | None = None,
) -> list:
    """Raise a fault in a thread that pauses before every line of ``raise_fault``; at each
    pause this thread reads the record (``read``, else ``read_fault``).  The reads, in
    order."""
    read = read or inst.read_fault
    go, paused = threading.Semaphore(0), threading.Semaphore(0)
    target = Instance.raise_fault.__code__

    def tracer(frame: FrameType, event: str, _arg: object):
        if frame.f_code is not target:
            return None
        if event == "line":
            paused.release()
            go.acquire()
        return tracer

    def writer() -> None:
        sys.settrace(tracer)
        try:
            inst.raise_fault(code, process, message)
        finally:
            sys.settrace(None)
            paused.release()

    t = threading.Thread(target=writer)
    t.start()
    reads = []
    while t.is_alive():
        paused.acquire()
        if not t.is_alive():
            break
        reads.append(read())
        go.release()
    t.join()
    reads.append(read())
    return reads


def test_a_reader_at_any_step_of_the_writer_sees_the_whole_record_or_unfinished(
    inst: Instance, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setattr(instance_module, "FAULT_READ_WAIT_S", 0.005)
    inst.raise_fault(FaultCode.DEADLINE, "sv.0", "the first fault")
    assert inst.clear_fault()

    reads = _step_writer(inst, FaultCode.SERVO, "sv.1", "the second fault")
    assert len(reads) > 5  # the writer was stepped through
    for info in reads:
        if info.active:
            assert info.code in ("SERVO", "UNFINISHED"), info
        if info.code == "SERVO":
            assert (info.process, info.message) == ("sv.1", "the second fault"), info
    last = reads[-1]
    assert (last.active, last.code, last.message) == (True, "SERVO", "the second fault")
    assert last.count == 2


def test_a_reset_while_the_winner_writes_leaves_a_whole_record_and_no_fault(
    inst: Instance, monkeypatch: pytest.MonkeyPatch
) -> None:
    """kalictl reset between the winner's compare-and-swap and its last field."""
    monkeypatch.setattr(instance_module, "FAULT_READ_WAIT_S", 0.005)
    go, paused = threading.Semaphore(0), threading.Semaphore(0)
    real = instance_module.time.time_ns

    def slow_time_ns() -> int:  # called once the fault is won, half-way through the record
        if threading.current_thread() is not threading.main_thread():
            paused.release()
            go.acquire()
        return real()

    monkeypatch.setattr(instance_module.time, "time_ns", slow_time_ns)
    t = threading.Thread(target=inst.raise_fault, args=(FaultCode.SERVO, "sv.1", "half-way"))
    t.start()
    paused.acquire()
    assert inst.read_fault().code == "UNFINISHED"
    assert inst.clear_fault()
    go.release()
    t.join()
    info = inst.read_fault()
    assert (info.active, info.code, info.message) == (False, "SERVO", "half-way")
    assert inst.fault_text() is None


def test_a_halt_counted_is_a_halt_written(inst: Instance, monkeypatch: pytest.MonkeyPatch) -> None:
    """The fault count says a halt happened (SIO and the TG look at it each tick, and
    ``fault_text(last=True)`` reads the record once it is nonzero): at any step of the first
    fault's writer, a reader sees no halt, or that halt's whole record, or UNFINISHED — never
    the record as it was before any fault (``NONE in  at tick 0``, which a program was told
    once in the fault matrix: the count went up before the record was won and written)."""
    monkeypatch.setattr(instance_module, "FAULT_READ_WAIT_S", 0.005)
    texts = _step_writer(
        inst, FaultCode.DEADLINE, "sio", "too slow", lambda: inst.fault_text(last=True)
    )
    assert len(texts) > 5  # the writer was stepped through
    seen = [t for t in texts if t is not None]
    assert seen, texts
    for text in seen:
        assert text.startswith(("DEADLINE in sio", "UNFINISHED")), texts
    assert texts[-1] == "DEADLINE in sio at tick 0: too slow"
