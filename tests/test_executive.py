"""The lockstep executive (issue 26 item 1): every daemon of a lockstep instance in one
process, in stage order, bit for bit the same as a process per daemon and whatever the
machine's load.  Programs attach, wait and register periodic functions as before: the
periodic programs of tests/test_wallclock.py run against the executive."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
from numpy.lib.recfunctions import repack_fields

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.layout import FaultCode, PowerState, ProcState, RequestState
from kali_daemons.runtime import flightrec
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher
from kali_daemons.wallclock import step_kali_clock

from .conftest import wait_for

ROW_FIELDS = ("tick", *layout.FLIGHT_FIELDS)  # what a row holds of the arms, not of timing


def flight_rows(inst: Instance) -> np.ndarray:
    """SIO's flight-recorder rows so far (the clock stopped), the arms' fields only."""
    rec = flightrec.FlightRecorder(inst, inst.config.joints.total)
    rows = flightrec.read_ring(rec.header, rec.ring, writer_idle=True)
    return repack_fields(rows[list(ROW_FIELDS)])  # those fields' bytes only


def carry_program(name: str) -> tuple[np.ndarray, np.ndarray]:
    """Power both arms, move each through a joint move with full feed-forward, and return
    the flight recorder's last 2 s of rows and the plant's true joint angles."""
    with Kali(name) as k:
        assert [r.ff for r in k.inst.config.robots] == ["full"] * 2  # as default.yaml starts them
        step_kali_clock(k.inst, 30)
        for robot in k.names:
            k.servo.power(robot, True)
        step_kali_clock(k.inst, 600)
        assert [k.servo.power_state(r) for r in k.names] == [PowerState.ON] * 2
        moves = []
        for robot, sign in zip(k.names, (1, -1), strict=True):
            arm = k.robot(robot)
            start = k.servo.level.arm("demand", k.names.index(robot)).copy()
            target = start + sign * np.radians([15, -10, 12, 25, -15, 30])
            moves.append(arm.move_joints(target, speed=1.0, wait=False))
        step_kali_clock(k.inst, 1500)
        assert [h.state for h in moves] == [RequestState.DONE] * 2, [h.message for h in moves]
        assert k.inst.fault_text() is None
        truth = k.inst.arena.existing(
            layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, k.inst.config.joints.total
        )
        return flight_rows(k.inst), truth["q"].copy()


def first_difference(a: np.ndarray, b: np.ndarray) -> str:
    """Where two runs' rows first differ: tick, field, joint and the two values ('' if
    nowhere)."""
    for r in range(min(len(a), len(b))):
        for f in ROW_FIELDS:
            x, y = np.atleast_1d(a[f][r]), np.atleast_1d(b[f][r])
            if x.tobytes() != y.tobytes():
                j = int(np.argmax(x != y))
                return f"tick {int(a['tick'][r])} {f}[{j}]: {x[j]!r} != {y[j]!r}"
    return "" if len(a) == len(b) else f"{len(a)} rows != {len(b)}"


@contextmanager
def cpu_hogs(n: int = 2) -> Iterator[None]:
    """``n`` processes spinning flat out meanwhile: the machine under load."""
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(n)]
    try:
        yield
    finally:
        for h in hogs:
            h.kill()
            h.wait()


def test_one_process_hosts_every_daemon_in_its_slot(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        rows = {r["name"]: r for r in launcher.describe(inst)}
        assert set(rows) == {p.name for p in inst.config.processes}
        assert len({r["pid"] for r in rows.values()}) == 1  # the executive's
        assert all(r["state"] == "ACTIVE" and r["alive"] for r in rows.values())
        assert launcher.instance_pids(name) == [rows["wallclock"]["pid"]]
        step_kali_clock(inst, 100)
        rows = {r["name"]: r for r in launcher.describe(inst)}
        # each slot signalled and acknowledged as at its own period (SVs within SIO's cycle)
        for proc, count in {"plant": 100, "sio": 100, "sv.0": 100, "tg": 10, "viewer": 3}.items():
            assert rows[proc]["signals"] == rows[proc]["acks"] == count, (proc, rows[proc])
            assert rows[proc]["misses"] == 0


@pytest.mark.serial
def test_the_executive_and_separate_processes_give_the_same_rows_bit_for_bit(
    kali: Callable[..., str],
) -> None:
    rows_one, truth_one = carry_program(kali(lockstep=True))
    rows_many, truth_many = carry_program(kali(lockstep=True, separate=True))
    assert len(rows_one) == layout.flight_rows(1_000_000)
    assert rows_one.tobytes() == rows_many.tobytes(), first_difference(rows_one, rows_many)
    assert truth_one.tobytes() == truth_many.tobytes()
    assert np.ptp(rows_one["demand"], axis=0).max() > 0.2  # the arms did move


def test_a_run_is_the_same_bit_for_bit_under_cpu_load(kali: Callable[..., str]) -> None:
    rows_quiet, truth_quiet = carry_program(kali(lockstep=True))
    name = kali(lockstep=True)
    with cpu_hogs():
        rows_loaded, truth_loaded = carry_program(name)
    assert rows_quiet.tobytes() == rows_loaded.tobytes(), first_difference(rows_quiet, rows_loaded)
    assert truth_quiet.tobytes() == truth_loaded.tobytes()


PLUGIN = '''
"""A servo whose hand-over raises: the SV running it fails (a bug in a plugin)."""
import numpy as np
from numpy.lib.recfunctions import repack_fields
from kali_daemons.servo import STATUS_OK, ServoAlgorithm

DTYPE = np.dtype([("kp", "<f8")], align=True)


def init(data, params, period):
    data.kp = 1.0


def step(data, demand, position):
    return data.kp * (demand - position), demand - position, STATUS_OK


def handover(data, h):
    raise RuntimeError("this hand-over is broken")


def set_params(data, params):
    pass


def get_params(data):
    return {}


def register(registry):
    registry.register(
        ServoAlgorithm(
            name="broken", dtype=DTYPE, params=(), init=init, step=step, handover=handover,
            set_params=set_params, get_params=get_params,
        )
    )
'''


@pytest.mark.serial
def test_a_hosted_daemon_that_raises_fails_as_its_own_process_would(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    plugin = tmp_path / "broken_servo.py"
    plugin.write_text(PLUGIN)
    edits = {
        r"^plugins: .*$": f"plugins: [{plugin}]",
        r"^(  - \{name: left,.*)\}$": r"\1, servo: broken}",
    }
    faults = []
    for separate in (False, True):
        name = kali(lockstep=True, edits=edits, separate=separate)
        with Kali(name) as k:
            step_kali_clock(k.inst, 30)
            k.servo.power("left", True)
            step_kali_clock(k.inst, 300, wait=False)
            wait_for(lambda k=k: k.inst.fault_text() is not None, what="the halt")
            f = k.inst.read_fault()
            state = ProcState(int(k.inst.procs[k.inst.find_slot(f.process)]["state"]))
            faults.append((f.code, f.process, state))
            assert "this hand-over is broken" in k.inst.fault_text()
            rows = {r["name"]: r for r in launcher.describe(k.inst)}
            assert rows["sio"]["state"] == "ACTIVE"  # the rest carries on, halted
    for code, who, state in faults:  # whichever SV ran the joint first
        assert code == FaultCode.DAEMON_ERROR.name and who.startswith("sv.")
        assert state == ProcState.ERROR
