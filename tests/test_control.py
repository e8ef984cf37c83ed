"""A program's periodic functions (thesis 3.6.2 ``control`` and ``release``, issue 28 item 5):
``Kali.control`` returns at once and runs the function in a thread of the program on the
wall clock while the program goes on; ``release(message)``, returning False, raising and
``close`` end it, leaving nothing behind.  Lockstep instances: the program's own waits step
the clock, so every count is exact."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap
import threading
from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.client import Control, Kali
from kali_daemons.core.errors import ClockError
from kali_daemons.core.layout import FaultCode, ProcState
from kali_daemons.runtime.daemon import RELEASED_ELSEWHERE, RETURNED_FALSE
from kali_daemons.wallclock import release, step_kali_clock

from .conftest import ROOT


def slots_of(k: Kali, pid: int) -> list[str]:
    """Names of the occupied process-table slots carrying ``pid``."""
    procs = k.inst.procs
    return [
        bytes(p["name"]).rstrip(b"\0").decode()
        for p in procs
        if p["state"] != ProcState.FREE and int(p["pid"]) == pid
    ]


def kali_threads() -> list[str]:
    """The periodic functions' threads alive in this process."""
    return [t.name for t in threading.enumerate() if t.name.startswith("kali ")]


def test_control_returns_at_once_and_runs_at_its_period_while_the_program_moves_an_arm(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        ticks = np.full(1000, -1, dtype=np.int64)
        seen = np.zeros((1000, 6))
        n = 0

        def every_10ms(tick: int) -> None:  # shares the program's objects: k, its arrays
            nonlocal n
            ticks[n] = tick
            seen[n] = k.servo.level.arm("demand", 0)
            n += 1

        ctl = k.control(every_10ms, period_ms=10)
        assert isinstance(ctl, Control) and ctl.running and ctl.ticks == 0  # nothing stepped
        assert ctl.name in k.inst.process_names()  # registered before control() returned
        assert ctl.name.startswith("prog.") and not ctl.serious and ctl.period_ms == 10.0
        before = ctl.ticks
        k.sleep(1.0)  # 1000 ticks of 1 ms
        assert abs(ctl.ticks - before - 100) <= 1, ctl.ticks
        start = k.servo.level.arm("demand", 0).copy()
        target = start + np.radians([10, -8, 6, 0, 5, 0])
        t0, c0 = int(k.inst.clock["tick"]), ctl.ticks
        left.move_joints(target, speed=0.5)  # blocks, stepping the clock (Kali.pause)
        elapsed = int(k.inst.clock["tick"]) - t0
        assert elapsed > 300 and abs(ctl.ticks - c0 - elapsed / 10) <= 1, (elapsed, ctl.ticks)
        assert ctl.running and ctl.error is None and ctl.reason == ""
        ran = ticks[: ctl.ticks]
        assert ran[0] % 10 == 0 and set(np.diff(ran).tolist()) == {10}, ran  # on the clock
        # it saw the arm move: the demand it read went from the start to the target
        during = seen[c0 : ctl.ticks]
        assert np.abs(during[0] - start).max() < math.radians(0.5)
        np.testing.assert_allclose(during[-1], target, atol=1e-9)
        assert np.unique(during[:, 0]).size > 20  # every 10 ms a new demand
        assert k.inst.fault_text() is None


def test_release_stops_it_and_keeps_its_message(
    kali: Callable[..., str], capsys: pytest.CaptureFixture[str]
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        ctl = k.control(lambda tick: None, period_ms=5, name="sampler")
        k.sleep(0.1)
        assert ctl.ticks in (20, 21)
        ctl.release("the part has left the conveyor")
        assert not ctl.running and ctl.reason == "the part has left the conveyor"
        assert "control 'sampler' released: the part has left the conveyor" in (
            capsys.readouterr().err
        )
        assert "sampler" not in k.inst.process_names() and kali_threads() == []
        count = ctl.ticks
        k.sleep(0.1)
        assert ctl.ticks == count  # the tick count stops growing
        ctl.release("again")  # releasing an ended one does nothing
        assert ctl.reason == "the part has left the conveyor"
        # a name is free again once released; a taken one is refused, nothing registered
        again = k.control(lambda tick: None, period_ms=5, name="sampler")
        with pytest.raises(ClockError, match="process 'sampler' already exists"):
            k.control(lambda tick: None, name="sampler")
        # another process's release (wallclock.release) ends it too
        release(k.inst, "sampler")
        assert again.join(timeout=30)
        assert again.reason == RELEASED_ELSEWHERE and "sampler" not in k.inst.process_names()
        assert k.inst.fault_text() is None


def test_returning_false_releases_it(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        ticks: list[int] = []

        def five_times(tick: int) -> bool:
            ticks.append(tick)
            return len(ticks) < 5

        ctl = k.control(five_times, period_ms=10)
        assert ctl.join(timeout=30)  # lockstep: the wait steps the clock
        assert ctl.ticks == 5 and ticks[-1] - ticks[0] == 40 and not ctl.running
        assert ctl.reason == RETURNED_FALSE and ctl.error is None
        assert ctl.name not in k.inst.process_names()
        k.sleep(0.1)
        assert ctl.ticks == 5 and k.inst.fault_text() is None


def test_a_non_serious_function_that_raises_is_released_with_its_error(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:

        def boom(tick: int) -> None:
            if tick >= 30:
                raise RuntimeError(f"boom at tick {tick}")

        ctl = k.control(boom, period_ms=10, name="flaky")
        assert ctl.join(timeout=30)
        assert ctl.error == "RuntimeError: boom at tick 30" and ctl.reason == ctl.error
        assert ctl.ticks == 4 and "flaky" not in k.inst.process_names()
        before = int(k.inst.clock["tick"])
        k.sleep(0.1)  # the system runs on: the clock steps, nothing halted
        assert int(k.inst.clock["tick"]) == before + 100 and k.inst.fault_text() is None


def test_a_serious_function_that_raises_halts_naming_it(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:

        def boom(tick: int) -> None:
            if tick >= 20:
                raise ValueError("sensor out of range")

        ctl = k.control(boom, period_ms=10, serious=True, name="guard")
        assert ctl.serious
        assert ctl.join(timeout=30)
        fault = k.inst.read_fault()
        assert fault.code == FaultCode.DAEMON_ERROR.name and fault.process == "guard"
        assert "ValueError: sensor out of range" in k.inst.fault_text()
        assert ctl.error == "ValueError: sensor out of range"
        assert "guard" not in k.inst.process_names()


def test_bad_arguments_are_refused_and_register_nothing(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        names = k.inst.process_names()
        for args, kw, match in [
            ((lambda tick: None,), {"period_ms": 2.5}, r"2\.5 ms must be a whole multiple"),
            ((lambda tick: None,), {"period_ms": math.nan}, "must be a whole multiple"),
            ((lambda tick: None,), {"period_ms": 120_000}, "longer than 60000 ms"),
            (("not a function",), {}, "is not callable"),
            ((lambda tick: None,), {"serious": 1}, "serious 1 is not True or False"),
            ((lambda tick: None,), {"name": "x" * 40}, "must be 1..23 bytes"),
            ((lambda tick: None,), {"name": "tg"}, "process 'tg' already exists"),
            ((lambda tick: None,), {"priority": 120}, "priority 120"),
        ]:
            with pytest.raises(ClockError, match=match):
                k.control(*args, **kw)
        assert k.inst.process_names() == names and kali_threads() == [] and k.controls == []


def test_close_and_exit_release_every_function_leaving_nothing_behind(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    k = Kali(name)
    ctls = [k.control(lambda tick: None, period_ms=p) for p in (1, 10, 20)]
    k.sleep(0.05)
    assert [c.ticks for c in ctls] == [50, 5, 3] and len(kali_threads()) == 3
    k.close()
    assert [c.running for c in ctls] == [False] * 3 and kali_threads() == []
    assert {c.reason for c in ctls} == {"released by the program"}
    with Kali(name) as k:
        assert [n for n in k.inst.process_names() if n.startswith("prog.")] == []
        # a program that exits without closing: its functions are released at exit
        prog = subprocess.Popen(
            [
                sys.executable,
                "-c",
                textwrap.dedent(
                    """
                    import os
                    from kali_daemons.client import Kali
                    kali = Kali()
                    a = kali.control(lambda tick: None, period_ms=1)
                    b = kali.control(lambda tick: None, period_ms=10, serious=True)
                    kali.sleep(0.1)
                    print(os.getpid(), a.ticks, b.ticks, flush=True)
                    """
                ),
            ],
            cwd=ROOT,
            env={"KALI_INSTANCE": name, "PATH": "/usr/bin:/bin"},
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        out, err = prog.communicate(timeout=120)
        assert prog.returncode == 0, err
        pid, a, b = (int(v) for v in out.split())
        assert (a, b) == (100, 10)
        assert slots_of(k, pid) == []  # no slot left, none DIED
        step_kali_clock(k.inst, 50)  # the clock runs on without them
        assert k.inst.fault_text() is None
    # the fixture checks that the instance leaves no /dev/shm object and no process


def test_a_release_while_another_program_steps_the_clock_holds_no_tick(
    kali: Callable[..., str],
) -> None:
    """Released while another process steps the clock, a function may be signalled once more
    before the clock sees the release: it acknowledges that signal unrun, or a lockstep tick
    would wait for it (a serious one: DEADLINE).  Started and released over and over
    at every phase of the other's 1-tick steps; every tick goes through, nothing is left."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        stepper = subprocess.Popen(
            [
                sys.executable,
                "-c",
                textwrap.dedent(
                    f"""
                    from kali_daemons.runtime.instance import Instance
                    from kali_daemons.wallclock import step_kali_clock
                    with Instance.attach({name!r}) as inst:
                        for _ in range(2000):
                            step_kali_clock(inst, 1)
                    """
                ),
            ],
            cwd=ROOT,
            env={"PATH": "/usr/bin:/bin"},
            stderr=subprocess.PIPE,
            text=True,
        )
        start = int(k.inst.clock["tick"])
        released = 0
        while stepper.poll() is None:
            ctl = k.control(lambda tick: None, period_ms=1, serious=True)
            threading.Event().wait(0.001 * (released % 4))  # a different phase each time
            ctl.release()
            assert not ctl.running and ctl.error is None
            released += 1
        assert stepper.returncode == 0, stepper.stderr.read()  # type: ignore[union-attr]
        assert int(k.inst.clock["tick"]) == start + 2000 and k.inst.fault_text() is None
        assert released > 20 and slots_of(k, os.getpid()) == [] and kali_threads() == []
