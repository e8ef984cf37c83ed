"""Isolation (issue 7 item 3, DESIGN 7): an instance's shared memory and semaphores are its
owner's alone, another user cannot attach, stop or steer it, and two instances side by side
never see each other.

The other user is ``nobody`` (uid 65534), reached with ``setpriv``: it runs the real kalictl
(the virtual environment is readable by everyone on these machines) and, to take the command
line out of the question, a few lines of ``posix_ipc``/``mmap`` opening the segment and a
semaphore directly.  The test skips, saying why, where no other user can run Python at all.
"""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.arena import segment_name
from kali_daemons.core.errors import InstanceError
from kali_daemons.core.layout import FaultCode, ProcState
from kali_daemons.core.spinlock import pid_alive
from kali_daemons.hardware.mcgill import registers
from kali_daemons.runtime.instance import Instance, command_semaphore_name
from kali_daemons.tools import launcher
from kali_daemons.wallclock import step_kali_clock

from ..conftest import ROOT, boards_of, leftovers, unique_name
from ..test_launcher import kalictl
from ..test_servo_level import power_all

NOBODY = 65534
SETPRIV = shutil.which("setpriv")


def as_nobody(*argv: str) -> subprocess.CompletedProcess[str]:
    """Run ``argv`` as user nobody (no groups), from the repository, with a clean env."""
    assert SETPRIV is not None
    return subprocess.run(
        [SETPRIV, f"--reuid={NOBODY}", f"--regid={NOBODY}", "--clear-groups", *argv],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={"PATH": "/usr/bin:/bin", "HOME": "/nonexistent", "LANG": "C.UTF-8"},
        timeout=120,
    )


def _nobody_runs_python() -> str:
    """Why no other user can run this Python ('' when nobody can)."""
    if os.geteuid() != 0:
        return "switching to another user needs root"
    if SETPRIV is None:
        return "setpriv is not installed"
    r = as_nobody(sys.executable, "-c", "import posix_ipc, kali_daemons")
    if r.returncode != 0:
        return f"user nobody cannot run {sys.executable}: {r.stderr.strip()[-200:]}"
    return ""


def snapshot(inst: Instance) -> dict[str, object]:
    """What another user might have changed: clock, fault, processes, power, the queue."""
    return {
        "tick": int(inst.clock["tick"]),
        "mode": int(inst.clock["mode"]),
        "cmd_seq": int(inst.clock["cmd_seq"]),
        "fault": (int(inst.fault["active"]), int(inst.fault["count"])),
        "procs": [(r["name"], r["pid"], r["state"]) for r in launcher.describe(inst)],
        "csr": boards_of(inst)["csr"].tolist(),
        "estop": boards_of(inst)["estop"].tolist(),
        "shm": launcher.shm_objects(inst.name),
    }


def test_every_shm_object_and_the_log_directory_are_the_owners_alone(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    name = kali(lockstep=True)
    objs = launcher.shm_objects(name)
    assert len(objs) == 1 + layout.MAX_PROCESSES + 3 + layout.MAX_SV
    for path in objs:
        st = os.stat(path)
        assert stat.S_IMODE(st.st_mode) == 0o600, path
        assert (st.st_uid, st.st_gid) == (os.geteuid(), os.getegid()), path
    logs = tmp_path / "logs"  # the kali fixture's KALI_LOG_DIR
    st = os.stat(logs)
    assert st.st_uid == os.geteuid() and not st.st_mode & 0o022, oct(st.st_mode)


def test_a_log_directory_of_another_user_or_a_symlink_is_refused(tmp_path: Path) -> None:
    other = tmp_path / "theirs"
    other.mkdir()
    link = tmp_path / "link"
    link.symlink_to(other)
    with pytest.raises(InstanceError, match=r"log directory .*/link is not a directory"):
        launcher.private_log_dir(link)
    open_dir = tmp_path / "open"
    open_dir.mkdir()
    open_dir.chmod(0o777)
    with pytest.raises(InstanceError, match="mode 0777: group or others may write it"):
        launcher.private_log_dir(open_dir)
    if os.geteuid() == 0:
        os.chown(other, NOBODY, NOBODY)
        with pytest.raises(InstanceError, match=r"belongs to uid 65534 \(nobody\), not uid 0"):
            launcher.private_log_dir(other)
    made = launcher.private_log_dir(tmp_path / "new" / "logs")
    assert stat.S_IMODE(os.stat(made).st_mode) == 0o700


def test_another_user_cannot_attach_stop_or_steer_an_instance(kali: Callable[..., str]) -> None:
    why = _nobody_runs_python()
    if why:
        pytest.skip(why)
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        before = snapshot(inst)
        for argv in (["status"], ["estop"], ["clock", "step", "5"], ["enable"], ["stop"]):
            r = as_nobody(sys.executable, "-m", "kali_daemons", "-i", name, *argv)
            assert r.returncode == 1, (argv, r.stdout, r.stderr)
            assert "Traceback" not in r.stderr, r.stderr
            if argv == ["stop"]:
                assert f"kalictl: instance: instance '{name}' is not yours: " in r.stderr
                assert "belongs to uid 0 (root); only its owner (or root) can stop it" in r.stderr
            else:
                assert f"kalictl: arena: instance '{name}' is not yours: " in r.stderr
                assert f"/kali.{name} belongs to uid 0 (root), mode 0600; " in r.stderr
                assert "uid 65534 (nobody) may not attach (Kali instances are owner-" in r.stderr
        # past the command line: the segment and a semaphore, opened directly
        probe = textwrap.dedent(
            f"""
            import mmap, os, posix_ipc
            for what, open_it in (
                ("segment", lambda: posix_ipc.SharedMemory({segment_name(name)!r})),
                ("segment read-only", lambda: posix_ipc.SharedMemory(
                    {segment_name(name)!r}, read_only=True)),
                ("file", lambda: os.open("/dev/shm{segment_name(name)}", os.O_RDONLY)),
                ("semaphore", lambda: posix_ipc.Semaphore({command_semaphore_name(name)!r})),
                ("unlink", lambda: posix_ipc.unlink_shared_memory({segment_name(name)!r})),
            ):
                try:
                    open_it()
                except (posix_ipc.PermissionsError, PermissionError) as exc:
                    print(what, "refused:", type(exc).__name__)
                else:
                    print(what, "OPENED")
            """
        )
        r = as_nobody(sys.executable, "-c", probe)
        assert r.returncode == 0, r.stderr
        assert "OPENED" not in r.stdout and r.stdout.count("refused") == 5, r.stdout
        assert snapshot(inst) == before  # nothing changed, nothing stopped
        assert not int(inst.fault["active"])


@pytest.mark.serial
def test_two_instances_side_by_side_never_see_each_other(kali: Callable[..., str]) -> None:
    a, b = kali(lockstep=True, separate=True), kali(lockstep=True, separate=True)
    shm_a, shm_b = set(launcher.shm_objects(a)), set(launcher.shm_objects(b))
    assert len(shm_a) == len(shm_b) == 1 + layout.MAX_PROCESSES + 3 + layout.MAX_SV
    assert not shm_a & shm_b
    assert all(f"kali.{a}" in p and f"kali.{b}" not in p for p in shm_a)
    pids_a, pids_b = set(launcher.instance_pids(a)), set(launcher.instance_pids(b))
    assert len(pids_a) == len(pids_b) == 8 and not pids_a & pids_b
    with Instance.attach(b) as inst_b:
        step_kali_clock(inst_b, 50)
        quiet = snapshot(inst_b)
        robots_b = inst_b.arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, 2)
        joints_b = inst_b.arena.existing(layout.KEY_JOINTS, layout.JOINT_STATE, 12)
        q_b = joints_b["q"].copy()
        with Kali(a) as ka:  # power, move, then e-stop instance a
            power_all(ka.inst, ka.servo, 300)
            left = ka.robot("left")
            target = ka.start_point(0) + np.radians([0, 0, 0, 0, 0, 3])
            left.move_joints(target, speed=1.0, timeout=30)
            assert snapshot(inst_b) == quiet
            r = kalictl("-i", a, "estop")
            assert r.returncode == 0, r.stderr
            assert int(ka.inst.fault["code"]) == FaultCode.ESTOP
            assert not (boards_of(ka.inst)["csr"] & registers.CSR_NO_DISABLE).any()  # amps cut
        assert snapshot(inst_b) == quiet  # clock, fault, processes, boards untouched
        assert np.array_equal(joints_b["q"], q_b) and not robots_b["power"].any()
        r = kalictl("-i", a, "stop")
        assert r.returncode == 0 and f"instance '{a}' stopped" in r.stdout, r.stderr
        assert leftovers(a) == ([], [])
        after = snapshot(inst_b)
        assert after == quiet
        assert all(pid_alive(p) for p in pids_b)
        states = [row[2] for row in after["procs"]]  # type: ignore[attr-defined]
        assert states == [ProcState.ACTIVE.name] * 8
        assert step_kali_clock(inst_b, 10) == quiet["tick"] + 10  # b runs on
        del robots_b, joints_b
    r = kalictl("-i", a, "status")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert f"kalictl: arena: no instance '{a}': /kali.{a} does not exist" in r.stderr


def test_kalictl_names_an_instance_that_does_not_exist_or_cannot(tmp_path: Path) -> None:
    missing = unique_name("gone")
    r = kalictl("-i", missing, "status")
    assert r.returncode == 1 and "Traceback" not in r.stderr
    assert f"no instance '{missing}': /kali.{missing} does not exist (is it started?)" in r.stderr
    r = kalictl("-i", "../etc/passwd", "status")
    assert r.returncode == 1 and "instance name '../etc/passwd' is not allowed" in r.stderr
    r = kalictl("-i", missing, "stop")
    assert r.returncode == 0 and f"instance '{missing}': nothing to stop" in r.stdout
