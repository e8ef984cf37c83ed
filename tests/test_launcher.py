"""kalictl start/stop with real processes: nothing is left behind, whatever happened."""

from __future__ import annotations

import os
import signal
import stat
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from kali_daemons.core import layout
from kali_daemons.core.errors import InstanceError
from kali_daemons.core.layout import FaultCode, RunMode
from kali_daemons.core.spinlock import pid_alive
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher

from .conftest import ROOT, config_text, leftovers, make_config, unique_name

PROCESSES = ["wallclock", "plant", "tg", "sio", "sv.0", "sv.1", "dynamics", "viewer"]


def kalictl(
    *args: str, env: dict[str, str] | None = None, timeout: float = 120
) -> subprocess.CompletedProcess:
    """Run the real command line, as a user would."""
    return subprocess.run(
        [sys.executable, "-m", "kali_daemons", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, **(env or {})},
        timeout=timeout,
    )


@pytest.mark.serial
def test_start_status_mem_stop_from_the_command_line(tmp_path: Path) -> None:
    name = unique_name()
    cfg = tmp_path / "k.yaml"
    cfg.write_text(make_config(name).text.replace("instance: default", f"instance: {name}"))
    env = {"KALI_LOG_DIR": str(tmp_path / "logs")}
    try:
        r = kalictl("start", "-c", str(cfg), env=env)
        assert r.returncode == 0, r.stderr
        assert f"instance '{name}' started" in r.stdout and "real time (clock running)" in r.stdout
        assert "feed-forward" not in r.stdout  # every arm of the shipped config starts with it
        time.sleep(0.3)
        r = kalictl("-i", name, "status")
        assert r.returncode == 0, r.stderr
        assert "clock running" in r.stdout and "fault: none" in r.stdout
        for p in PROCESSES:
            assert f"\n{p} " in r.stdout
        r = kalictl("-i", name, "mem")
        assert r.returncode == 0, r.stderr
        for key in ("clock", "processes", "fault", "config", "free list:", "fragmentation"):
            assert key in r.stdout
        r = kalictl("-i", name, "rate", "tg", "20")
        assert r.returncode == 0 and "tg: period 20 ms" in r.stdout
        r = kalictl("-i", name, "rate", "tg", "2.5")
        assert r.returncode == 1 and "2.5 ms must be a whole multiple of the 1 ms" in r.stderr
        r = kalictl("-i", name, "clock", "step", "3")
        assert r.returncode == 1 and "clock step needs lockstep mode" in r.stderr
    finally:
        r = kalictl("-i", name, "stop", env=env)
    assert r.returncode == 0 and "stopped: 8 processes left on request" in r.stdout
    assert leftovers(name) == ([], [])
    r = kalictl("-i", name, "status")
    assert r.returncode == 1 and f"no instance '{name}'" in r.stderr


def test_start_names_the_arms_starting_with_feed_forward_off_and_how_to_turn_it_on(
    tmp_path: Path,
) -> None:
    """Issue 52 item 5: an arm started without the dynamics feed-forward lags on a path
    (1.3 mm on the Panda's 5 cm/s circle); ``kalictl start`` says which and how to turn it
    on, one line, and nothing where every arm starts with it (the shipped configs)."""
    name = unique_name()
    cfg = tmp_path / "k.yaml"
    cfg.write_text(config_text(name, {r"^(  - \{name: right,.*), ff: full\}$": r"\1, ff: off}"}))
    env = {"KALI_LOG_DIR": str(tmp_path / "logs")}
    try:
        r = kalictl("start", "-c", str(cfg), "--lockstep", env=env)
        assert r.returncode == 0, r.stderr
        hints = [line for line in r.stdout.splitlines() if "feed-forward" in line]
        assert hints == [
            f"feed-forward off: right (its servos alone follow its motions, and lag); turn it on "
            f"with ff: full in the config or kalictl -i {name} ff on right"
        ], r.stdout
    finally:
        r = kalictl("-i", name, "stop", env=env)
    assert r.returncode == 0, r.stderr
    assert leftovers(name) == ([], [])


def test_status_before_any_tick_shows_no_lateness_rather_than_nan(
    kali: Callable[..., str],
) -> None:
    """A lockstep instance not stepped yet has no lateness to show: its percentiles say '-'
    (they printed 'nanus')."""
    name = kali(lockstep=True)
    r = kalictl("-i", name, "status")
    assert r.returncode == 0, r.stderr
    assert "nan" not in r.stdout, r.stdout
    row = next(line for line in r.stdout.splitlines() if line.startswith("sio "))
    assert row.split()[-4:-2] == ["-", "-"], row  # late p50, late p99


def test_segment_and_semaphores_are_owner_only(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    objs = launcher.shm_objects(name)
    # segment, a semaphore per slot, cmd, ack and done, a feed semaphore per possible SV
    assert len(objs) == 1 + 32 + 3 + layout.MAX_SV
    for path in objs:
        assert stat.S_IMODE(os.stat(path).st_mode) == 0o600, path


@pytest.mark.serial
@pytest.mark.parametrize("victim", PROCESSES)
def test_stop_after_kill_9_leaves_nothing(kali: Callable[..., str], victim: str) -> None:
    name = kali(lockstep=True, separate=True)
    with Instance.attach(name) as inst:
        pid = int(inst.procs[inst.slot_of(victim)]["pid"])
    os.kill(pid, signal.SIGKILL)
    deadline = time.monotonic() + 10
    while pid_alive(pid):  # SIGKILL is delivered asynchronously
        assert time.monotonic() < deadline
        time.sleep(0.005)
    report = launcher.stop(name)
    assert pid not in report.stopped
    assert leftovers(name) == ([], [])


def test_crashed_instance_is_detected_and_cleaned_by_next_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path))
    name = unique_name()
    cfg = make_config(name)
    launcher.start(cfg, lockstep=True)
    try:
        for pid in launcher.instance_pids(name):  # the whole set crashes
            os.kill(pid, signal.SIGKILL)
        time.sleep(0.2)
        shm, pids = leftovers(name)
        assert shm and not pids
        report = launcher.start(cfg, lockstep=True)
        assert report.stale_cleaned, "the stale instance was not reported"
        with Instance.attach(name) as inst:
            assert sorted(inst.process_names()) == sorted(PROCESSES)
    finally:
        launcher.stop(name)
    assert leftovers(name) == ([], [])


def test_start_refuses_a_running_instance(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with pytest.raises(InstanceError, match=rf"instance '{name}' is already running \(pids"):
        launcher.start(make_config(name), lockstep=True)
    with Instance.attach(name) as inst:  # the running instance was not disturbed
        assert sorted(inst.process_names()) == sorted(PROCESSES)


@pytest.mark.serial
def test_two_instances_run_side_by_side(kali: Callable[..., str]) -> None:
    # the servo level only: two whole default cells with feed-forward and dashboard took more
    # than a slower CI machine's two cores, and one halted on a missed deadline meanwhile
    off = r"\1enabled: false, "
    lean = {r"^(  dynamics: +\{)": off, r"^(  viewer: +\{)": off}
    a, b = kali(lockstep=False, edits=lean), kali(lockstep=False, edits=lean)
    with Instance.attach(a) as ia, Instance.attach(b) as ib:
        ta, tb = int(ia.clock["tick"]), int(ib.clock["tick"])
        time.sleep(0.3)
        faults = (ia.fault_text(), ib.fault_text())
        assert int(ia.clock["tick"]) > ta + 100 and int(ib.clock["tick"]) > tb + 100, faults
        assert faults == (None, None)
    launcher.stop(a)
    assert leftovers(a) == ([], [])
    with Instance.attach(b) as ib:  # stopping one leaves the other running
        tb = int(ib.clock["tick"])
        time.sleep(0.1)
        assert int(ib.clock["tick"]) > tb and int(ib.clock["mode"]) == RunMode.RUNNING


def test_failed_start_names_the_process_and_cleans_up(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path))
    name = unique_name()
    cfg = make_config(name, {r"^startup_timeout_s: .*$": "startup_timeout_s: 0.05"})
    with pytest.raises(
        InstanceError, match=r"not ready within startup_timeout_s = 0.05 s: .*plant"
    ):
        launcher.start(cfg, lockstep=True)
    assert leftovers(name) == ([], [])


@pytest.mark.serial
def test_daemon_dying_at_start_up_is_named_with_its_log(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A daemon that cannot run (here: its module is missing) fails start by name, with its
    exit status and its log."""
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path))
    name = unique_name()
    cfg = make_config(name)
    real_start = launcher.Spawner.start

    def start(self: launcher.Spawner, jobs: list[dict[str, str]], logs_of: dict) -> list[int]:
        for job in jobs:
            if job["name"] == "sv.1":  # this one cannot run, as a broken install would
                job["module"] = "servo.no_such_daemon"
        return real_start(self, jobs, logs_of)

    monkeypatch.setattr(launcher.Spawner, "start", start)
    try:
        with pytest.raises(
            InstanceError,
            match=r"process 'sv.1' \(pid \d+\) failed during start-up \(exit 1, state "
            r"SPAWNED\):\n(.|\n)*No module named kali_daemons\.servo\.no_such_daemon",
        ):
            launcher.start(cfg, lockstep=True, separate=True)
        assert leftovers(name) == ([], [])  # the start cleaned up after itself
    finally:
        launcher.stop(name)  # had the start not failed, nothing would be left either


def test_bad_config_starts_nothing(tmp_path: Path) -> None:
    name = unique_name()
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(make_config(name).text.replace("base_tick_ms: 1 ", "base_tick_ms: -1 "))
    r = kalictl("start", "-c", str(cfg))
    assert r.returncode == 1
    assert "clock.base_tick_ms = -1" in r.stderr
    assert leftovers(name) == ([], [])


def test_stop_of_an_unknown_instance_is_harmless() -> None:
    r = kalictl("-i", unique_name(), "stop")
    assert r.returncode == 0 and "nothing to stop" in r.stdout


def test_reset_clears_a_fault(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    r = kalictl("-i", name, "reset")
    assert r.returncode == 0 and "no active fault" in r.stdout
    with Instance.attach(name) as inst:
        inst.raise_fault(FaultCode.OPERATOR, "kalictl", "operator halt for the test")
    r = kalictl("-i", name, "clock", "step", "5")
    assert r.returncode == 1 and "fault active, kalictl reset first" in r.stderr
    r = kalictl("-i", name, "reset")
    assert "cleared: OPERATOR in kalictl at tick 0: operator halt for the test" in r.stdout
    r = kalictl("-i", name, "clock", "step", "5")
    assert r.returncode == 0 and "clock at tick 5" in r.stdout
