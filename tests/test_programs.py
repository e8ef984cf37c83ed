"""Robot programs as separate processes (issue 5): a program that dies mid-motion leaves the
motion running and the queue whole; ``client.control`` makes a program itself a periodic
function on the wall clock, blocking (``Kali.control``, which runs one in a thread while the
program goes on: ``test_control.py``).  Lockstep instances; the test steps the clock while
the program runs."""

from __future__ import annotations

import math
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core.errors import MotionError
from kali_daemons.core.layout import RequestState
from kali_daemons.tg import records
from kali_daemons.wallclock import step_kali_clock

from .conftest import ROOT
from .test_tg import powered


def program(source: str, name: str) -> subprocess.Popen[str]:
    """Start ``source`` as a robot program attached to instance ``name``."""
    return subprocess.Popen(
        [sys.executable, "-c", textwrap.dedent(source)],
        cwd=ROOT,
        env={"KALI_INSTANCE": name, "PATH": "/usr/bin:/bin"},
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_a_program_killed_mid_motion_leaves_the_motion_and_the_queue_working(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        start = k.servo.level.arm("demand", 0).copy()
        target = start + np.radians([15, -10, 10, 0, 0, 0])
        prog = program(
            f"""
            import os, signal
            import numpy as np
            from kali_daemons.client import Kali
            kali = Kali()
            h = kali.robot("left").move_joints(np.array({target.tolist()}), wait=False)
            print(h.seq, flush=True)
            os.kill(os.getpid(), signal.SIGKILL)  # dies with its request queued
            """,
            name,
        )
        out, err = prog.communicate(timeout=60)
        assert prog.returncode == -9, err
        seq = int(out.split()[0])
        for _ in range(300):
            step_kali_clock(k.inst, 10)
            if int(k.status["state"][records.find(k.status, seq)]) == RequestState.DONE:
                break
        assert int(k.status["state"][records.find(k.status, seq)]) == RequestState.DONE
        np.testing.assert_allclose(k.servo.level.arm("demand", 0), target, atol=1e-12)
        back = k.robot("left").move_joints(start, wait=False)  # the queue still works
        back.wait(timeout=60)  # (lockstep: waiting steps the clock)
        step_kali_clock(k.inst, 500)
        assert np.abs(k.servo.level.arm("q", 0) - start).max() < math.radians(0.1)
        assert k.inst.fault_text() is None


def test_control_runs_the_programs_function_on_the_wall_clock(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with powered(name) as k:
        prog = program(
            """
            import gc, os
            from kali_daemons import client
            ticks, frozen = [], []
            def every_10ms(tick):
                ticks.append(tick)
                frozen.append(gc.get_freeze_count())
                return len(ticks) < 5  # False releases it
            status = client.control(
                os.environ["KALI_INSTANCE"], every_10ms, name="every_10ms", period_ms=10
            )  # blocks: this process is the periodic function until it is released
            print(status, min(frozen), *ticks, flush=True)
            """,
            name,
        )
        deadline = time.monotonic() + 60
        while prog.poll() is None and time.monotonic() < deadline:
            step_kali_clock(k.inst, 10)
        out, err = prog.communicate(timeout=10)
        assert prog.returncode == 0, err
        status, frozen, *ticks = [int(v) for v in out.split()]
        assert status == 0 and len(ticks) == 5
        assert "every_10ms" not in k.inst.process_names()
        # the start-up heap (numpy, the arena's views, ...) is frozen before the loop, so no
        # collection inside it walks those objects (daemon.freeze_heap)
        assert frozen > 10_000, frozen
        gaps = np.diff(ticks).tolist()  # every 10 ms of the wall clock, on multiples of 10
        assert gaps[1:] == [10] * 3 and 0 < gaps[0] <= 10 and ticks[-1] % 10 == 0, ticks
        assert k.inst.fault_text() is None


def test_sleep_lets_simulated_time_pass_in_lockstep(kali: Callable[..., str]) -> None:
    """``Kali.sleep`` steps a lockstep instance's clock by the time asked for (nothing else
    steps it there); a time that is not one is refused, the clock untouched."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        before = int(k.inst.clock["tick"])
        k.sleep(0.25)
        assert int(k.inst.clock["tick"]) - before == 250  # the default 1 ms tick
        for bad in (-1.0, math.nan, math.inf, "1", True):
            with pytest.raises(MotionError, match="sleep: "):
                k.sleep(bad)  # type: ignore[arg-type]
        assert int(k.inst.clock["tick"]) - before == 250


def test_a_program_computes_on_one_thread_unless_it_asks_for_more(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """``kalictl run`` starts the program with numpy's BLAS single-threaded, as the daemons
    (launcher.SINGLE_THREADED): a periodic function the program runs in a thread
    (``Kali.control``, SCHED_FIFO when asked) must not wait on an OpenBLAS worker thread
    below it on its CPU, the priority inversion that once halted the TG.  A program's own
    setting stands."""
    from .test_launcher import kalictl

    name = kali(lockstep=True)
    script = tmp_path / "threads.py"
    script.write_text(
        "import os\nimport numpy\n"
        "print(os.environ.get('OPENBLAS_NUM_THREADS'), len(os.listdir('/proc/self/task')))\n"
    )
    r = kalictl("-i", name, "run", str(script))
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["1", "1"], r.stdout
    r = kalictl("-i", name, "run", str(script), env={"OPENBLAS_NUM_THREADS": "2"})
    assert r.stdout.split()[0] == "2", r.stdout
