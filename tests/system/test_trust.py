"""Nothing a client does can wedge the safety path (issue 24, items 1 and 2).

A client that takes an arena lock and is then stopped (Ctrl-Z, a debugger, a hung program)
or dies holding it must not keep a halt from being recorded, the amplifiers from being cut,
``kalictl estop``, ``status`` or ``stop`` from working; ``status`` names the lock and its
holder.  Start, stop and stale clean-up of one instance are serialised, an empty instance
name is refused, and objects squatted under an instance's names are refused naming their
owner, never mapped.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from kali_daemons.core import atomic, layout
from kali_daemons.core.arena import SEM_BYTES
from kali_daemons.core.errors import InstanceError
from kali_daemons.core.layout import FaultCode, PowerState, ProcState, RunMode
from kali_daemons.core.spinlock import pid_alive
from kali_daemons.hardware.mcgill import registers
from kali_daemons.runtime.instance import Instance, command_semaphore_name
from kali_daemons.tools import launcher
from kali_daemons.wallclock import start_kali_clock

from ..conftest import ROOT, boards_of, config_text, leftovers, unique_name, wait_for
from ..test_launcher import kalictl

NOBODY = 65534
HOLDER = """
import os, signal, sys
from kali_daemons.runtime.instance import Instance
from kali_daemons.core.spinlock import SpinLock
inst = Instance.attach(sys.argv[1])
for name, addr in inst.lock_words():
    SpinLock(addr, name).acquire(timeout=5)
print(len(inst.lock_words()), flush=True)
os.kill(os.getpid(), signal.SIGSTOP)
"""


@pytest.fixture
def stopped() -> Iterator[Callable[..., tuple[subprocess.Popen, str]]]:
    """``stopped(script, *args)``: run a Python script that prints one line and then stops
    itself (SIGSTOP), as a program under Ctrl-Z or a debugger; (its process, that line) once
    it is stopped.  Killed afterwards."""
    procs: list[subprocess.Popen] = []

    def start(script: str, *args: str) -> tuple[subprocess.Popen, str]:
        p = subprocess.Popen(
            [sys.executable, "-c", script, *args], stdout=subprocess.PIPE, text=True, cwd=ROOT
        )
        procs.append(p)
        assert p.stdout is not None
        line = p.stdout.readline().strip()
        wait_for(lambda: _state(p.pid) == "T", 10, f"pid {p.pid} stopped")
        return p, line

    yield start
    for p in procs:
        p.kill()
        p.wait(10)


@pytest.fixture
def holder(
    stopped: Callable[..., tuple[subprocess.Popen, str]],
) -> Callable[[str], subprocess.Popen]:
    """``holder(instance)``: a client that takes every lock of the instance and stops itself
    holding them."""

    def start(instance: str) -> subprocess.Popen:
        p, locks = stopped(HOLDER, instance)
        assert int(locks) >= 5  # directory, table, command, queue, mailboxes
        return p

    return start


def _state(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return "gone"


def _pid_of(inst: Instance, name: str) -> int:
    return int(inst.procs[inst.slot_of(name)]["pid"])


@pytest.mark.serial
@pytest.mark.parametrize("lockstep", [True, False], ids=["lockstep", "real-time"])
def test_a_stopped_holder_of_every_lock_keeps_no_halt_estop_status_or_stop_from_working(
    kali: Callable[..., str], holder: Callable[[str], subprocess.Popen], lockstep: bool
) -> None:
    name = kali(lockstep=lockstep, separate=True)  # a process per daemon: sv.0 is killed
    with Instance.attach(name) as inst:
        if lockstep:
            start_kali_clock(inst)  # free-running lockstep: the clock steps on by itself
        r = kalictl("-i", name, "enable")
        assert r.returncode == 0, r.stderr
        robots = inst.arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, 2)
        wait_for(lambda: all(robots["power"] == PowerState.ON), 20, "both arms powered")
        clock_pid = _pid_of(inst, "wallclock")
        held = holder(name)
        assert all(atomic.load32(addr) == held.pid for _, addr in inst.lock_words())

        # A daemon raises the halt: the wall clock finds sv.0 dead.
        t0 = time.monotonic()
        os.kill(_pid_of(inst, "sv.0"), signal.SIGKILL)
        wait_for(lambda: bool(inst.fault["active"]), 10, "the halt recorded")
        wait_for(lambda: int(inst.clock["mode"]) == RunMode.STOPPED, 10, "the clock stopped")
        assert time.monotonic() - t0 < 2.0
        fault = inst.read_fault()
        assert (fault.code, fault.process, fault.pid) == ("PROCESS_DIED", "sv.0", clock_pid)
        assert pid_alive(clock_pid)  # it did not die waiting on a lock
        assert not any(boards_of(inst)["csr"] & registers.CSR_NO_DISABLE)  # amplifiers cut
        if not lockstep:  # (in lockstep the plant stands with the clock)
            wait_for(
                lambda: not any(boards_of(inst)["power"] & registers.POWER_AMPS_ON), 1, "amps off"
            )

        r = kalictl("-i", name, "status")
        assert r.returncode == 0, r.stderr
        assert f"fault: PROCESS_DIED in sv.0 at tick {fault.tick}: process 'sv.0'" in r.stdout
        assert f"lock: 'arena directory' held by pid {held.pid} (python" in r.stdout
        assert "stopped) for over 0.2 s" in r.stdout
        assert f"lock: 'queue tg.requests' held by pid {held.pid}" in r.stdout

        t0 = time.monotonic()
        r = kalictl("-i", name, "estop")
        assert r.returncode == 0, r.stderr
        assert time.monotonic() - t0 < 10.0
        assert all(boards_of(inst)["estop"] == 1)

    t0 = time.monotonic()
    r = kalictl("-i", name, "stop")
    assert r.returncode == 0, r.stderr
    assert leftovers(name) == ([], [])
    assert time.monotonic() - t0 < STOP_BOUND_S


STOP_BOUND_S = launcher.STOP_GRACE_S + 2 * launcher.KILL_GRACE_S + 5.0


def test_a_fault_writer_stopped_half_way_still_halts_and_is_named(
    kali: Callable[..., str], stopped: Callable[..., tuple[subprocess.Popen, str]]
) -> None:
    """The winner of the fault word stops before it has written its record: the clock halts
    all the same, and readers say whose record is unfinished instead of waiting for it."""
    name = kali(lockstep=True)
    script = (
        "import os, signal, sys, time\n"
        "from kali_daemons.runtime.instance import Instance\n"
        "from kali_daemons.core.layout import FaultCode\n"
        "inst = Instance.attach(sys.argv[1])\n"
        "def stop_half_way():  # raise_fault asks the time once it has won, mid-record\n"
        "    print(1, flush=True)\n"
        "    os.kill(os.getpid(), signal.SIGSTOP)\n"
        "    return 0\n"
        "time.time_ns = stop_half_way\n"
        "inst.raise_fault(FaultCode.OPERATOR, 'half-way', 'never finished')\n"
    )
    p, won = stopped(script, name)
    assert won == "1"
    with Instance.attach(name) as inst:
        text = inst.fault_text()
        assert text is not None and text.startswith("UNFINISHED in pid ")
        assert f"left unfinished by pid {p.pid} (python" in text and "stopped)" in text
        refused = kalictl("-i", name, "clock", "start")
        assert refused.returncode == 1 and "fault active" in refused.stderr
        r = kalictl("-i", name, "reset")
        assert r.returncode == 0, r.stderr
        assert inst.fault_text() is None


RACERS = 6  # processes raising a fault at the same instant


def test_many_processes_raising_at_once_record_one_fault_and_count_all(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    script = (
        "import sys, time\n"
        "from kali_daemons.runtime.instance import Instance\n"
        "from kali_daemons.core.layout import FaultCode\n"
        "inst = Instance.attach(sys.argv[1])\n"
        "t = float(sys.argv[2])\n"
        "while time.time() < t: pass\n"
        "print(int(inst.raise_fault(FaultCode.OPERATOR, f'racer', f'racer {sys.argv[3]}')))\n"
    )
    go = time.time() + 3.0
    racers = [
        subprocess.Popen(
            [sys.executable, "-c", script, name, str(go), str(k)],
            stdout=subprocess.PIPE,
            text=True,
            cwd=ROOT,
        )
        for k in range(RACERS)
    ]
    won = [int(p.communicate(timeout=60)[0]) for p in racers]
    assert sum(won) == 1
    with Instance.attach(name) as inst:
        f = inst.read_fault()
        assert f.active and f.code == FaultCode.OPERATOR.name and f.count == 6
        assert f.message == f"racer {won.index(1)}"
        assert f.pid == racers[won.index(1)].pid


def _start_half_way(tmp_path: Path) -> tuple[str, Path, dict[str, str], subprocess.Popen]:
    """A ``kalictl start --lockstep`` of a new instance in the background, returned once it
    is half-way (its segment exists, its daemons are not up yet): (name, config, env, it)."""
    name = unique_name("race")
    cfg = tmp_path / "race.yaml"
    cfg.write_text(config_text(name))
    env = {"KALI_LOG_DIR": str(tmp_path / "logs")}
    first = subprocess.Popen(
        [sys.executable, "-m", "kali_daemons", "-i", name, "start", "-c", str(cfg), "--lockstep"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        cwd=ROOT,
        env={**os.environ, **env},
    )
    wait_for(lambda: bool(launcher.shm_objects(name)), 30, "the first start's segment")
    return name, cfg, env, first


def test_two_starts_of_one_instance_at_once_the_second_is_refused_naming_the_first(
    tmp_path: Path,
) -> None:
    name, cfg, env, first = _start_half_way(tmp_path)
    try:
        # its daemons held stopped until the second start has been answered: the first start
        # is still waiting for them (a start takes well under a second: no race to win)
        wait_for(lambda: bool(launcher.instance_pids(name)), 30, "the first start's daemons")
        held = launcher.instance_pids(name)
        for pid in held:
            os.kill(pid, signal.SIGSTOP)
        try:
            second = kalictl("-i", name, "start", "-c", str(cfg), "--lockstep", env=env)
        finally:
            for pid in held:
                os.kill(pid, signal.SIGCONT)
        _, err = first.communicate(timeout=120)
        assert first.returncode == 0, err
        assert second.returncode == 1
        assert "stale" not in second.stdout + second.stderr
        assert f"instance '{name}': start refused: pid {first.pid} (python" in second.stderr
        assert "for kalictl start; try again when it is done" in second.stderr
        r = kalictl("-i", name, "status")  # what the first reported started is running
        assert r.returncode == 0, r.stderr
        assert r.stdout.count("ACTIVE") == 8, r.stdout
        again = kalictl("-i", name, "start", "-c", str(cfg), "--lockstep", env=env)
        assert again.returncode == 1 and "is already running" in again.stderr
    finally:
        first.kill()
        first.wait(10)
        launcher.stop(name)
    assert leftovers(name) == ([], [])
    assert not (launcher.runtime_dir() / f"{name}.lock").exists()


def test_a_stop_waits_for_a_start_in_progress_instead_of_tearing_it_down(
    tmp_path: Path,
) -> None:
    name, _, _, first = _start_half_way(tmp_path)
    try:
        r = kalictl("-i", name, "stop")
        _, err = first.communicate(timeout=120)
        assert first.returncode == 0, err  # its start finished, then the stop took it down
        assert r.returncode == 0, r.stderr
        # the lockstep executive: one process, every daemon's slot
        assert "1 process left on request" in r.stdout, r.stdout
    finally:
        first.kill()
        first.wait(10)
        launcher.stop(name)
    assert leftovers(name) == ([], [])


def test_a_lifecycle_lock_held_by_a_stopped_kalictl_is_refused_at_once_naming_it(
    stopped: Callable[..., tuple[subprocess.Popen, str]],
) -> None:
    name = unique_name("held")
    script = (
        "import os, signal, sys\n"
        "from kali_daemons.tools import launcher\n"
        "with launcher.lifecycle_lock(sys.argv[1], 'start'):\n"
        "    print('in', flush=True)\n"
        "    os.kill(os.getpid(), signal.SIGSTOP)\n"
    )
    p, line = stopped(script, name)
    assert line == "in"
    t0 = time.monotonic()
    with pytest.raises(InstanceError, match=rf"stop refused: pid {p.pid} \(python"):
        launcher.stop(name)
    assert time.monotonic() - t0 < 2.0  # not the whole LIFECYCLE_WAIT_S
    p.kill()
    p.wait(10)
    launcher.stop(name)  # the lock of a dead holder is free again
    assert not (launcher.runtime_dir() / f"{name}.lock").exists()


@pytest.mark.parametrize(
    "how",
    [("-i", ""), ("KALI_INSTANCE", "")],
    ids=["-i ''", "KALI_INSTANCE="],
)
def test_an_empty_instance_name_is_refused_not_taken_as_default(
    tmp_path: Path, how: tuple[str, str]
) -> None:
    name = unique_name("empty")
    cfg = tmp_path / "empty.yaml"
    cfg.write_text(config_text(name))
    args, env = ((how[0], how[1]), {}) if how[0] == "-i" else ((), {how[0]: how[1]})
    for cmd in (["status"], ["stop"], ["estop"], ["start", "-c", str(cfg), "--lockstep"]):
        r = kalictl(*args, *cmd, env=env)
        assert r.returncode == 1, (cmd, r.stdout)
        assert "kalictl: instance: instance name '' is not allowed" in r.stderr, (cmd, r.stderr)
    assert leftovers(name) == ([], [])


def test_a_program_given_an_empty_instance_name_is_refused(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    from kali_daemons.client import Kali

    with pytest.raises(InstanceError, match="instance name '' is not allowed"):
        Kali("")
    monkeypatch.setenv("KALI_INSTANCE", "")
    with pytest.raises(InstanceError, match="instance name '' is not allowed"):
        Kali()


requires_root = pytest.mark.skipif(os.geteuid() != 0, reason="chown to another user needs root")


@requires_root
@pytest.mark.parametrize("what", ["segment", "semaphore"])
def test_an_object_squatted_by_another_user_is_refused_naming_it_and_its_owner(
    what: str,
) -> None:
    name = unique_name("squat")
    path = (
        f"/dev/shm/kali.{name}"
        if what == "segment"
        else "/dev/shm/sem" + command_semaphore_name(name).replace("/", ".")
    )
    Path(path).write_bytes(b"")
    os.chown(path, NOBODY, NOBODY)
    try:
        for cmd in (["start", "--lockstep"], ["status"], ["estop"], ["stop"]):
            r = kalictl("-i", name, *cmd)
            assert r.returncode == 1, (cmd, r.stdout, r.stderr)  # never -SIGBUS
            if cmd[0] in ("start", "stop") or what == "segment":
                assert f"{path} belongs to uid 65534 (nobody), mode 0644, 0 B" in r.stderr
            if cmd[0] in ("start", "stop"):
                assert "kalictl will not use or remove it" in r.stderr
        assert os.path.exists(path)  # never removed as a "stale" instance
    finally:
        os.unlink(path)
    assert leftovers(name) == ([], [])
    assert not (launcher.runtime_dir() / f"{name}.lock").exists()  # nor a lock file


def test_a_too_small_semaphore_of_ones_own_is_never_mapped(tmp_path: Path) -> None:
    """A 0-byte file under a semaphore's name (a crash while creating it, or a squatter of
    the same user): start refuses it by name, stop removes it; neither maps it (SIGBUS)."""
    name = unique_name("sbus")
    path = "/dev/shm/sem" + command_semaphore_name(name).replace("/", ".")
    cfg = tmp_path / "sbus.yaml"
    cfg.write_text(config_text(name))
    Path(path).write_bytes(b"")
    r = kalictl("-i", name, "start", "-c", str(cfg), "--lockstep")
    assert r.returncode == 1, r.stdout
    assert f"{path} belongs to uid {os.geteuid()}" in r.stderr
    assert f"0 B: smaller than a semaphore ({SEM_BYTES} B)" in r.stderr
    r = kalictl("-i", name, "stop")
    assert r.returncode == 0, r.stderr
    assert leftovers(name) == ([], [])


def test_the_process_table_reads_without_the_directory_lock(
    kali: Callable[..., str], holder: Callable[[str], subprocess.Popen]
) -> None:
    """Attaching, looking blocks up, ``kalictl mem`` and the stop's pid list work while a
    stopped process holds every lock."""
    name = kali(lockstep=True)
    holder(name)
    with Instance.attach(name) as inst:
        assert inst.process_names()[0] == "wallclock"
        assert int(inst.procs[inst.slot_of("sio")]["state"]) == ProcState.ACTIVE
        assert len(launcher.instance_pids(name)) == 1  # the lockstep executive
    r = kalictl("-i", name, "mem")
    assert r.returncode == 0, r.stderr
    assert "tg.requests" in r.stdout
