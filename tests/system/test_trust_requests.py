"""Issue 24, items 4-7: no request outcome is lost, arms are owned by one program, Ctrl-C under
``kalictl run`` stops the arms, and lockstep runs are bit-for-bit repeatable.  Lockstep
instances; programs are real subprocesses."""

from __future__ import annotations

import collections
import os
import select
import signal
import subprocess
import sys
import textwrap
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from numpy.lib.recfunctions import repack_fields

from kali_daemons.client import Kali, MotionFailedError, pose
from kali_daemons.client.common import RequestLostError
from kali_daemons.core import layout
from kali_daemons.core.errors import QueueFullError
from kali_daemons.core.layout import FaultCode, MotionKind, PowerState, RequestState
from kali_daemons.core.spinlock import pid_alive
from kali_daemons.runtime import flightrec
from kali_daemons.tg import records
from kali_daemons.wallclock import step_kali_clock

from ..conftest import ROOT
from ..test_tg import powered

ENV = {**os.environ, "PYTHONPATH": str(ROOT)}
KALICTL = [sys.executable, "-m", "kali_daemons"]


def _line(proc: subprocess.Popen, timeout: float = 60.0, stream: Any = None) -> str:
    """The next line ``proc`` prints on ``stream`` (default: its stdout, a pipe);
    AssertionError after ``timeout``."""
    stream = proc.stdout if stream is None else stream
    ready, _, _ = select.select([stream], [], [], timeout)
    assert ready, f"no output from pid {proc.pid} within {timeout:g} s"
    return stream.readline().strip()


def _program(tmp_path: Path, source: str) -> Path:
    path = tmp_path / "prog.py"
    path.write_text(textwrap.dedent(source))
    return path


def test_a_flood_of_10000_requests_every_handle_resolves(kali: Callable[..., str]) -> None:
    """A program floods the queue and collects outcomes when it holds its share of them
    unread: every one of 10,000 handles reads its real outcome (before issue 24: the
    256-record ring wrapped and all but the last 256 read QUEUED forever).  One that keeps
    more than its share unread loses its oldest outcomes (LOST, saying why), and only it:
    its later requests are taken (issue 51: they waited behind its own unread outcome, as
    did every other program's)."""
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        home = k.servo.level.arm("demand", 0).copy()
        nudge = home + np.radians([0.5, 0, 0, 0, 0, 0])
        handles = []
        outstanding: collections.deque = collections.deque()
        full = 0
        for i in range(10_000):
            while len(outstanding) >= layout.STATUS_SHARE:
                outstanding.popleft().wait(timeout=60)
            while True:
                try:
                    if i % 500 == 0:  # now and then a real motion of the left arm
                        h = left.move_joints(nudge if i % 1000 else home, speed=1.0, wait=False)
                    else:  # stops of the right arm: done as soon as the TG takes them
                        h = k._request(MotionKind.STOP, [1])
                    break
                except QueueFullError:
                    full += 1
                    step_kali_clock(k.inst, 10)
            handles.append(h)
            outstanding.append(h)
        while outstanding:
            outstanding.popleft().wait(timeout=60)
        states = collections.Counter(h.state for h in handles)
        assert states == {RequestState.DONE: 10_000}, states
        assert full > 0  # the queue pushed back
        tg = k.inst.arena.record(layout.KEY_TG_STATE, layout.TG_STATE)
        assert int(tg["taken_seq"]) == handles[-1].seq and int(tg["evicted"]) == 0
        # more than its share unread: its oldest give way, its new requests are taken
        unread = []
        while len(unread) < layout.STATUS_SHARE + 8:
            try:
                unread.append(k._request(MotionKind.STOP, [1]))
            except QueueFullError:
                step_kali_clock(k.inst, 10)
        step_kali_clock(k.inst, 20)
        assert all(h.state == RequestState.DONE for h in unread[8:])
        assert int(tg["evicted"]) == 8
        for h in unread[:8]:
            assert h.state == RequestState.LOST
            with pytest.raises(RequestLostError, match=rf"request {h.seq} lost: its outcome was"):
                h.wait(timeout=1)
        # a record given to another request behind a handle's back (a writer outside the
        # protocol) is LOST, and its wait says so instead of hanging
        h = left.move_joints(home, wait=False)
        step_kali_clock(k.inst, 10)
        rec = k.status[records.find(k.status, h.seq)]
        rec["seq"] = h.seq + 100_000
        assert h.state == RequestState.LOST
        with pytest.raises(RequestLostError, match=rf"request {h.seq} lost: "):
            h.wait(timeout=1)
        assert k.inst.fault_text() is None
        del rec, tg


def test_a_halt_reads_halted_at_once_and_a_request_after_reset_meets_the_present(
    kali: Callable[..., str],
) -> None:
    """A halt makes every request read HALTED at once, with the fault (before: RUNNING until
    reset and a TG tick); a request put after ``reset`` is judged by the state it finds (here:
    power off), not HALTED by the cleared fault (before: the TG's first tick halted it)."""
    name = kali(lockstep=True)
    with powered(name) as k:
        left = k.robot("left")
        start = k.servo.level.arm("demand", 0).copy()
        away = start - np.radians([30, 0, 0, 0, 0, 0])  # from the right arm
        running = left.move_joints(away, speed=0.2, wait=False)
        step_kali_clock(k.inst, 100)
        assert running.state == RequestState.RUNNING
        queued = left.move_joints(start, wait=False)
        k.inst.raise_fault(FaultCode.ESTOP, "test", "operator pressed the e-stop")
        for h in (running, queued):
            assert h.state == RequestState.HALTED, h.state
            assert "operator pressed the e-stop" in h.message
        with pytest.raises(MotionFailedError, match="system is halted"):
            left.move_joints(start, wait=False)  # nothing is queued while halted
        k.inst.clear_fault()  # kalictl reset
        assert running.state == RequestState.HALTED  # before the TG has ticked: still halted
        after = left.move_joints(start, wait=False)
        step_kali_clock(k.inst, 20)
        assert running.state == queued.state == RequestState.HALTED
        # SIO cuts power as it sees the halt: the motion is refused or ends for that reason
        assert after.state in (RequestState.REFUSED, RequestState.ABORTED), after.state
        assert "'left' is not powered" in after.message, after.message
        k.servo.power("left", True)
        step_kali_clock(k.inst, 1500)
        assert k.servo.power_state("left") == PowerState.ON
        left.move_joints(start + np.radians([2, 0, 0, 0, 0, 0]), timeout=30)  # DONE


def test_two_programs_on_one_arm_the_second_is_refused_naming_the_owner(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """The first program to move an arm owns it: another program's request is refused naming
    its pid and name (before: both were queued and both told DONE); ``force`` and
    ``kalictl move --force`` take it over, stopping the owner's motion; the owner's death
    frees it."""
    name = kali(lockstep=True)
    with powered(name) as k:
        start = k.servo.level.arm("demand", 0).copy()
        far = start - np.radians([40, 0, 0, 0, 0, 0])  # away from the right arm
        prog = _program(
            tmp_path,
            f"""
            import sys
            import numpy as np
            from kali_daemons.client import Kali
            with Kali() as kali:
                h = kali.robot("left").move_joints(np.array({far.tolist()}), speed=0.1,
                                                   wait=False)
                print(h.seq, flush=True)
                sys.stdin.readline()  # the test steps the clock meanwhile
                h2 = kali.robot("left").move_joints(np.array({start.tolist()}), wait=False)
                print(h.state.name, h2.seq, flush=True)
                sys.stdin.readline()
                print(h2.state.name, h2.message, flush=True)
            """,
        )
        owner = subprocess.Popen(
            [sys.executable, str(prog)],
            env={**ENV, "KALI_INSTANCE": name},
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            seq = int(_line(owner))
            step_kali_clock(k.inst, 50)
            assert int(k.status["state"][records.find(k.status, seq)]) == RequestState.RUNNING
            left = k.robot("left")
            theirs = left.move_joints(start, wait=False)
            step_kali_clock(k.inst, 20)
            assert theirs.state == RequestState.REFUSED
            assert f"owned by pid {owner.pid} (prog.py)" in theirs.message, theirs.message
            assert k.owner(0) == (owner.pid, "prog.py")
            k.robot("right").move_joints(k.servo.level.arm("demand", 1), timeout=30)  # free
            cli = [*KALICTL, "-i", name, "move", "left"]
            joints = "--joints=" + ",".join(f"{v:.4f}" for v in np.degrees(start))
            refused = subprocess.run([*cli, joints], env=ENV, capture_output=True, text=True)
            assert refused.returncode == 1
            assert f"owned by pid {owner.pid} (prog.py)" in refused.stderr, refused.stderr
            forced = subprocess.run(
                [*cli, joints, "--force"], env=ENV, capture_output=True, text=True, timeout=120
            )
            assert forced.returncode == 0, forced.stderr
            step_kali_clock(k.inst, 500)  # the forced move stopped the owner's on its path
            assert int(k.status["state"][records.find(k.status, seq)]) == RequestState.STOPPED
            mine = Kali(name, force=True)  # the test takes it over in turn (kalictl exited)
            try:
                took = mine.robot("left").move_joints(start, wait=False)
                step_kali_clock(k.inst, 20)
                owner.stdin.write("\n")
                owner.stdin.flush()
                state, _ = _line(owner).split()
                assert state == "STOPPED"
                step_kali_clock(k.inst, 20)
                owner.stdin.write("\n")
                owner.stdin.flush()
                said = _line(owner)
                assert said.startswith("REFUSED") and f"owned by pid {os.getpid()}" in said, said
                took.wait(timeout=60)
            finally:
                mine.close()
            assert owner.wait(timeout=60) == 0
            again = left.move_joints(start + np.radians([1, 0, 0, 0, 0, 0]), wait=False)
            again.wait(timeout=60)  # the owner is gone: the arm is free again
        finally:
            if owner.poll() is None:
                owner.kill()
                owner.wait()
        assert k.inst.fault_text() is None


@pytest.mark.parametrize("inherited", ["default", "ignored"])
def test_ctrl_c_under_kalictl_run_stops_the_arms_of_a_program_ignoring_sigint(
    kali: Callable[..., str], tmp_path: Path, inherited: str
) -> None:
    """Ctrl-C under ``kalictl run``: the program's arm stops on its path though the program
    ignores SIGINT (before: kalictl waited for the program, the arm went on); a second Ctrl-C
    kills it and nothing is left running; ``--`` passes the rest through.  The move is slow
    (~250 simulated s): the lockstep executive runs it at several times real time, and the
    stop, kalictl's signal handling in wall time, must come before it ends.  The same when
    kalictl starts with SIGINT ignored, as a background job or ``nohup`` starts it (before:
    Python kept it ignored, and kalictl let the arm run on, saying nothing)."""
    name = kali(lockstep=True)
    with powered(name) as k:
        start = k.servo.level.arm("demand", 0).copy()
        far = start - np.radians([60, 0, 0, 0, 0, 0])  # away from the right arm
        prog = _program(
            tmp_path,
            f"""
            import os, signal, sys
            import numpy as np
            from kali_daemons.client import Kali
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            with Kali() as kali:
                h = kali.robot("left").move_joints(np.array({far.tolist()}), speed=0.003,
                                                   wait=False)
                print(os.getpid(), h.seq, *sys.argv[1:], flush=True)
                while True:  # steps the (lockstep) clock for ever, whatever happens
                    kali.pause()
            """,
        )
        ignore = inherited == "ignored"
        run = subprocess.Popen(
            [*KALICTL, "-i", name, "run", str(prog), "--", "--help", "-i", "x"],
            env=ENV,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            preexec_fn=(lambda: signal.signal(signal.SIGINT, signal.SIG_IGN)) if ignore else None,
        )
        try:
            pid_text, seq_text, *argv = _line(run).split()
            pid, seq = int(pid_text), int(seq_text)
            assert argv == ["--help", "-i", "x"]
            t0 = time.monotonic()
            while (i := records.find(k.status, seq)) < 0:
                assert time.monotonic() - t0 < 60, "the program's motion was never taken"
                time.sleep(0.01)
            state = k.status["state"][i : i + 1]
            while int(state[0]) != RequestState.RUNNING:
                assert time.monotonic() - t0 < 60, "the program's motion never ran"
                time.sleep(0.01)
            run.send_signal(signal.SIGINT)
            t0 = time.monotonic()
            while int(state[0]) != RequestState.STOPPED:
                if int(state[0]) == RequestState.DONE or time.monotonic() - t0 > 30:
                    run.kill()  # kalictl's own account of its Ctrl-C, for the message
                    pytest.fail(
                        f"the arm was not stopped: {RequestState(int(state[0])).name} after "
                        f"{time.monotonic() - t0:.1f} s; kalictl said: {run.stderr.read()!r}"
                    )
                time.sleep(0.01)
            held = k.servo.level.arm("demand", 0).copy()
            assert far[0] < held[0] < start[0]  # stopped on its path, short of the target
            said = _line(run, stream=run.stderr)  # once the arm has stopped, not before
            assert "arms stopped on their paths: left" in said, said
            assert pid_alive(pid) and run.poll() is None  # it ignores SIGINT, kalictl waits
            run.send_signal(signal.SIGINT)
            assert run.wait(timeout=30) == 128 + signal.SIGKILL
            assert not pid_alive(pid)  # killed and reaped: no orphan
            assert "killed (second Ctrl-C)" in run.stderr.read()
            del state
        finally:
            if run.poll() is None:
                run.kill()
                run.wait()
        assert k.inst.fault_text() is None


def _burn(seconds: float) -> list[subprocess.Popen]:
    """A busy loop on every CPU for ``seconds``."""
    loop = f"import time\nend = time.monotonic() + {seconds}\nwhile time.monotonic() < end: pass"
    return [subprocess.Popen([sys.executable, "-c", loop]) for _ in range(os.cpu_count() or 1)]


COMPARED = ("tick", "q", "demand", "servo_torque", "ff_torque", "torque", "current", "wrench")


def _cartesian_run(start: Callable[..., str], load: bool) -> np.ndarray:
    """Start a lockstep instance, calibrate the left arm, draw a blended path with its tool
    with full feed-forward, and return the flight recorder's rows (wall-time fields left out)."""
    name = start(lockstep=True)
    burners = _burn(120) if load else []
    try:
        with Kali(name) as k:
            k.ready(["left"])
            left = k.robot("left")
            here = left.read_pose()
            left.feedforward("full")  # the dynamics process's rows are in the run too
            offsets = np.array([[0.0, 0.06, 0.0], [0.0, 0.06, 0.04], [0.0, 0.0, 0.04]])
            path = [pose(here[:3, 3] + d, here) for d in offsets]
            left.move_path(path, speed=0.1, transition_s=0.2, wait=False)
            step_kali_clock(k.inst, 2500)
            assert k.inst.fault_text() is None
            header = k.inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
            ring = flightrec.attach_ring(k.inst.arena, header)
            assert len(ring) == layout.flight_rows(1_000_000)
            rows = flightrec.read_ring(header, ring, writer_idle=True)
            return repack_fields(rows[list(COMPARED)])  # without the fields left out
    finally:
        for b in burners:
            b.kill()
            b.wait()


def test_lockstep_is_bit_for_bit_repeatable_under_load(kali: Callable[..., str]) -> None:
    """The same Cartesian program twice in lockstep, the second time with every CPU busy:
    the flight recorder's rows are identical byte for byte (before: the path's pre-move check
    was sliced by wall time, so its start tick, and every row after, followed the load)."""
    quiet = _cartesian_run(kali, load=False)
    loaded = _cartesian_run(kali, load=True)
    assert len(quiet) == len(loaded) == layout.flight_rows(1_000_000)
    assert np.array_equal(quiet["tick"], loaded["tick"])
    moved = np.abs(np.diff(quiet["demand"], axis=0)).max()
    assert moved > 0  # the rows hold the motion
    for field in COMPARED:  # as bytes: an unpowered arm's servo torque may be NaN
        a = np.ascontiguousarray(quiet[field]).view(np.uint8).reshape(len(quiet), -1)
        b = np.ascontiguousarray(loaded[field]).view(np.uint8).reshape(len(loaded), -1)
        differ = np.flatnonzero((a != b).any(1))
        assert differ.size == 0, (
            f"{field}: {differ.size} rows differ, the first at tick {int(quiet['tick'][differ[0]])}"
        )
    assert quiet.tobytes() == loaded.tobytes()


def test_a_stop_of_a_free_arm_gives_its_program_no_ownership(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """Stopping an arm moves nothing, so a program's STOP of an arm nobody owns does not make
    it the owner: another program can still move the arm (the soak's request flood stops
    the demo's arms between its iterations)."""
    name = kali(lockstep=True)
    with powered(name) as k:
        prog = _program(
            tmp_path,
            """
            import sys
            from kali_daemons.client import Kali
            with Kali() as kali:
                kali.robot("left").stop()
                print("stopped", flush=True)
                sys.stdin.readline()
            """,
        )
        stopper = subprocess.Popen(
            [sys.executable, str(prog)],
            env={**ENV, "KALI_INSTANCE": name},
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            text=True,
        )
        try:
            assert _line(stopper) == "stopped"
            step_kali_clock(k.inst, 20)  # the TG takes the stop
            assert k.owner(0) is None
            target = k.servo.level.arm("demand", 0) + np.radians([2, 0, 0, 0, 0, 0])
            k.robot("left").move_joints(target, speed=1.0, timeout=60)
            assert k.owner(0) == (os.getpid(), k.program.decode())
        finally:
            stopper.kill()
            stopper.wait(10)
