"""``kalictl start`` and ``kalictl stop``: create, launch, supervise start-up, clean up.

Only this module creates and unlinks an instance's segment and semaphores (owner-only,
0600).  ``start`` returns when every process is ACTIVE, or fails naming the one that is not
and cleans up.  ``stop`` leaves no process, no ``/dev/shm`` object and no semaphore behind,
whatever state the instance is in (also after a ``kill -9`` of any Kali process, and with
any of its spinlocks held by a stopped or dead process: it reads the process table and the
``/dev/shm`` names without them); the next ``start`` detects and cleans an instance left by
a crash.  Start, stop and that clean-up are serialised per instance by an OS lock
(``flock``) on ``<runtime dir>/<instance>.lock``, so a second ``start`` never takes a first
one's half-made instance for a stale one.

Long on purpose: ``start`` and ``stop``, with the locking, the checks and the clean-up they
share.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import glob
import json
import os
import select
import shutil
import signal
import socket
import stat
import subprocess
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import posix_ipc

from ..core import layout
from ..core.arena import Arena, foreign_object, segment_name, shm_path, user_text
from ..core.errors import ArenaError, ConfigError, InstanceError
from ..core.layout import ProcState, RunMode
from ..core.spinlock import holder_text, pid_alive
from ..hardware import hardware_kind
from ..robots.cell import check_clear_at_rest, check_scene_apart
from ..runtime.config import KaliConfig, cell_of, ms_to_ns, ns_to_ms
from ..runtime.instance import Instance, all_semaphore_names, check_instance_name, decode
from ..runtime.paths import instance_dir, log_dir, private_dir, private_log_dir, runtime_dir
from ..servo import Registry, registry_for
from ..tg.functions import registry_for as functions_for
from ..wallclock import start_kali_clock
from . import snapshot
from .spawner import PACKAGE

# the module each kind of process runs as (``python -m kali_daemons.<module>``)
MODULES = {
    "wallclock": "wallclock",
    "plant": "plant",
    "tg": "tg",
    "sio": "sio",
    "sv": "servo.sv",
    "dynamics": "dynamics",
    "viewer": "viewer",
    "bridge": "bridge",
    "link": "link",
    "hand": "link.hand",
    "camera": "plant.camera",
}
# kinds that run as their own process in lockstep too, never hosted by the executive: a
# bridge that dies (or is killed) must leave the cell running, lockstep or not; a link and a
# hand hold libfranka, whose calls block holding the interpreter lock; a camera renders for
# tens of milliseconds a frame on its own timer
OWN_PROCESS = frozenset({"wallclock", "bridge", "link", "hand", "camera"})

STOP_GRACE_S = 3.0
KILL_GRACE_S = 2.0
LIFECYCLE_WAIT_S = 60.0  # longest ``stop`` waits for a start or stop of the instance to end


INSTANCE_MARK = "instance"  # a file in an instance's directory holding its name


def _make_instance_dir(instance: str) -> Path:
    """A new, empty, private ``instance_dir`` (a left-over one removed first), marked as the
    instance's so that ``_remove_instance_dir`` never removes a directory it did not make."""
    path = instance_dir(instance)
    _remove_instance_dir(path, instance)
    private_dir(runtime_dir(), "runtime directory", "KALI_RUNTIME_DIR")
    path.mkdir(mode=0o700)
    (path / INSTANCE_MARK).write_text(f"{instance}\n")
    return path


def _remove_instance_dir(path: Path, instance: str) -> bool:
    """Remove an instance's directory if it is one (a real directory of this user holding
    the instance's mark); True if it was removed.  Anything else at the path is left."""
    try:
        st = os.lstat(path)
        mark = (path / INSTANCE_MARK).read_text()
    except OSError:
        return False
    if not stat.S_ISDIR(st.st_mode) or st.st_uid != os.geteuid() or mark != f"{instance}\n":
        return False
    shutil.rmtree(path, ignore_errors=True)
    return not path.exists()


@contextmanager
def lifecycle_lock(instance: str, operation: str, wait_s: float = 0.0) -> Iterator[None]:
    """Hold ``instance``'s lifecycle lock (an exclusive ``flock``) for ``operation``.

    Waits up to ``wait_s`` for another start or stop to finish (never for a holder that is
    stopped), then refuses with InstanceError naming the holder's pid and operation, which
    the holder writes into the file.  The holder removes the file as it lets go, so nothing
    is left behind; a locker checks it locked the file that has the name (not one removed
    while it waited).
    """
    path = private_dir(runtime_dir(), "runtime directory", "KALI_RUNTIME_DIR") / (
        f"{instance}.lock"
    )
    deadline = time.monotonic() + wait_s
    while True:
        fd = os.open(path, os.O_RDWR | os.O_CREAT | os.O_NOFOLLOW | os.O_CLOEXEC, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            pid, held_for = _lock_holder(fd)
            os.close(fd)
            who = holder_text(pid) if pid else "another kalictl"
            if time.monotonic() >= deadline or "stopped" in who:
                raise InstanceError(
                    f"instance '{instance}': {operation} refused: {who} holds its lifecycle "
                    f"lock {path} for kalictl {held_for}; try again when it is done"
                ) from None
            time.sleep(0.05)
            continue
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if not same:  # removed by the last holder between our open and our flock
            os.close(fd)
            continue
        break
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()} {operation}\n".encode(), 0)
        yield
    finally:
        path.unlink(missing_ok=True)  # still ours: a waiter finds the new file's inode
        os.close(fd)


def _lock_holder(fd: int) -> tuple[int, str]:
    """The (pid, operation) a lifecycle lock's holder wrote; (0, "?") if not written yet."""
    try:
        words = os.pread(fd, 64, 0).decode("ascii", "replace").split()
        return int(words[0]), words[1]
    except (OSError, ValueError, IndexError):
        return 0, "?"


def check_not_squatted(instance: str, own_too: bool = True) -> None:
    """InstanceError naming the object and its owner if a ``/dev/shm`` name of ``instance``
    is taken by an object that is not this user's Kali's (another user's, or too small to
    be a segment or semaphore): neither mapped nor removed.  ``own_too=False`` (stop) lets
    this user's own broken objects through to be removed, and another user's real Kali
    objects too (root may stop anyone's instance)."""
    for path in shm_objects(instance):
        sem = os.path.basename(path).startswith("sem.")
        why = foreign_object(path, semaphore=sem, any_owner=not own_too)
        if why is None or (not own_too and os.lstat(path).st_uid == os.geteuid()):
            continue
        raise InstanceError(
            f"instance '{instance}': {why}; kalictl will not use or remove it: its owner "
            f"must, or use another instance name (-i NAME)"
        )


def check_owner(instance: str) -> None:
    """InstanceError unless this user may stop or replace ``instance``: every /dev/shm object
    of it must be this user's (root may stop anyone's)."""
    if os.geteuid() == 0:
        return
    for path in shm_objects(instance):
        try:
            uid = os.lstat(path).st_uid
        except FileNotFoundError:
            continue
        if uid != os.geteuid():
            raise InstanceError(
                f"instance '{instance}' is not yours: {path} belongs to {user_text(uid)}; "
                f"only its owner (or root) can stop it"
            )


def shm_objects(instance: str) -> list[str]:
    """Every ``/dev/shm`` entry belonging to ``instance`` (segment and semaphores)."""
    seg = "/dev/shm" + segment_name(instance)
    return sorted(
        glob.glob(glob.escape(seg)) + glob.glob(glob.escape(f"/dev/shm/sem.kali.{instance}.") + "*")
    )


def is_kali_process(pid: int, instance: str) -> bool:
    """True if ``pid`` is alive and is a Kali daemon of ``instance`` (guards against pid reuse)."""
    if not pid_alive(pid):
        return False
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
    except OSError:
        return False
    if not any(a.startswith(b"kali_daemons.") for a in argv):
        return False
    try:
        return argv[argv.index(b"--instance") + 1] == instance.encode()
    except (ValueError, IndexError):
        return False


def instance_pids(instance: str) -> list[int]:
    """Pids of the live daemons of ``instance``: from its arena, and from /proc."""
    pids: set[int] = set()
    try:
        arena = Arena.attach(instance)
    except ArenaError:
        arena = None
    if arena is not None:
        try:
            procs = arena.existing(layout.KEY_PROCESSES, layout.PROCESS, layout.MAX_PROCESSES)
            pids.update(int(p) for p in procs["pid"] if p > 0)
            del procs
        except ArenaError:
            pass
        arena.close()
    for d in glob.glob("/proc/[0-9]*"):
        pids.add(int(d[6:]))
    return sorted(p for p in pids if p != os.getpid() and is_kali_process(p, instance))


@dataclass
class StopReport:
    """What ``stop`` found and removed."""

    stopped: list[int] = field(default_factory=list)  # pids that left on request
    killed: list[int] = field(default_factory=list)  # pids that needed SIGKILL
    removed: list[str] = field(default_factory=list)  # /dev/shm entries unlinked
    left: list[str] = field(default_factory=list)  # entries it would not remove, and why


def stop(instance: str) -> StopReport:
    """Stop every process of ``instance`` and remove its segment and semaphores; another
    user's instance is refused (``check_owner``) before anything is touched.  Waits for a
    start or stop of the instance in progress to end (``lifecycle_lock``)."""
    check_instance_name(instance)
    check_owner(instance)
    check_not_squatted(instance, own_too=False)
    with lifecycle_lock(instance, "stop", wait_s=LIFECYCLE_WAIT_S):
        return _stop(instance)


def _stop(instance: str) -> StopReport:
    """``stop`` with the lifecycle lock held.  Takes no arena lock: the process table is
    read in place and every name is known, so it works whoever holds what."""
    report = StopReport()
    pids = instance_pids(instance)
    try:
        arena = Arena.attach(instance)
    except ArenaError:
        arena = None
    dirs = [instance_dir(instance)]
    if arena is not None:
        arena.header["shutdown"] = 1
        files = _arena_text(arena, layout.KEY_CONFIG_FILES)
        if files:  # started with another runtime directory (its files/ is in the arena)
            dirs.append(Path(files).parent)
        arena.close()
    for name in all_semaphore_names(instance):  # wake every waiter so it sees shutdown
        if foreign_object(shm_path(name, semaphore=True), semaphore=True, any_owner=True):
            continue  # not a semaphore (squatted): never mapped
        try:
            sem = posix_ipc.Semaphore(name)
        except posix_ipc.ExistentialError:
            continue
        sem.release()
        sem.close()
    left = _wait_gone(pids, STOP_GRACE_S)
    report.stopped = [p for p in pids if p not in left]
    for p in left:
        _signal(p, signal.SIGTERM)
    left = _wait_gone(left, KILL_GRACE_S)
    for p in left:
        _signal(p, signal.SIGKILL)
    report.killed = left
    _wait_gone(left, KILL_GRACE_S)
    before = set(shm_objects(instance))
    for path in shm_objects(instance):  # the segment, the semaphores, anything under our names
        why = _remove_entry(path)
        if why:
            report.left.append(f"{path}: {why}")
    report.removed = sorted(before - set(shm_objects(instance)))
    for d in dirs:
        if _remove_instance_dir(d, instance):
            report.removed.append(str(d))
    return report


def _remove_entry(path: str) -> str:
    """Remove the ``/dev/shm`` entry ``path`` under an instance's name: a file (segment,
    semaphore, or this user's broken object), a symbolic link (not what it points to), an
    empty directory; '' once gone, else why it is left (a directory holding files is not
    Kali's to empty).  Never raises: ``stop`` goes on to the next."""
    try:
        st = os.lstat(path)
        if stat.S_ISDIR(st.st_mode):
            os.rmdir(path)
        else:
            os.unlink(path)
    except FileNotFoundError:
        return ""
    except OSError as exc:
        if exc.errno == errno.ENOTEMPTY:
            return "a directory holding files (not Kali's; remove it yourself)"
        return f"not removed: {exc.strerror}"
    return ""


def _arena_text(arena: Arena, key: str) -> str:
    """A text record of the arena ('' if there is none or it is not text)."""
    found = arena.lookup(key)
    if found is None:
        return ""
    raw = bytes(arena.view(found[0], np.dtype("u1"), found[1]))
    return raw.split(b"\0", 1)[0].decode("utf-8", "replace")


def _signal(pid: int, sig: int) -> None:
    try:
        os.kill(pid, sig)
    except ProcessLookupError:
        pass


def _wait_gone(pids: list[int], timeout: float) -> list[int]:
    deadline = time.monotonic() + timeout
    left = [p for p in pids if pid_alive(p)]
    while left and time.monotonic() < deadline:
        time.sleep(0.01)
        left = [p for p in left if pid_alive(p)]
    return left


def _create(
    cfg: KaliConfig,
    instance: str,
    lockstep: bool,
    record: str = "",
    registry: Registry | None = None,
) -> Arena:
    """Create the segment, every record of the layout (``layout.blocks``, in order, zeroed)
    and every semaphore (owner-only), then seal the arena: the daemons only attach.

    ``record`` is the viewer's recording file ('' for none), in its dashboard record;
    ``registry`` the servo algorithms (their private data is laid out per joint).
    """
    registry = registry_for(cfg.plugins, cfg.base_dir, cfg.files) if registry is None else registry
    cell = cell_of(cfg, *registry.dtypes())
    arena = Arena.create(instance, cfg.arena_kib * 1024)
    try:
        arena.header["lockstep"] = int(lockstep)
        for b in layout.blocks(cell):
            arena.shmalloc(b.key, b.nbytes)
        clock = arena.record(layout.KEY_CLOCK, layout.CLOCK)
        clock["base_tick_ns"] = ms_to_ns(cfg.clock.base_tick_ms)
        clock["serious_miss_tolerance_ms"] = cfg.clock.serious_miss_tolerance_ms
        clock["lockstep_timeout_ms"] = int(cfg.clock.lockstep_ack_timeout_s * 1000)
        clock["busy_wait_ns"] = cfg.clock.busy_wait_us * 1000
        clock["lockstep"] = int(lockstep)
        # a networked robot's state packets are the cell's interrupt (decision 0015)
        # (in real time: in lockstep the links take turns with the plant, decision 0015)
        networked = any(hardware_kind(k).links for k in cfg.hardware_kinds)
        clock["paced"] = int(networked and not lockstep)
        clock["mode"] = RunMode.STOPPED
        clock["step_target"] = -1
        del clock
        arena.record(layout.KEY_PROCESSES, layout.PROCESS, layout.MAX_PROCESSES)
        arena.record(layout.KEY_FAULT, layout.FAULT)
        arena.record(layout.KEY_MISSES, layout.MISS_LOG)
        arena.record(layout.KEY_DASHBOARD, layout.DASHBOARD)["record"] = record.encode()
        for key, value in (
            (layout.KEY_CONFIG, cfg.text),
            (layout.KEY_CONFIG_DIR, cfg.base_dir),
            (layout.KEY_CONFIG_FILES, cfg.files),
        ):
            text = value.encode()
            raw = arena.record(key, np.dtype("u1"), len(text) + 1)
            raw[: len(text)] = np.frombuffer(text, np.uint8)
            del raw
        _write_cell(arena.record(layout.KEY_CELL, layout.CELL), cfg)
        arena.header["sealed"] = 1
        for name in all_semaphore_names(instance):
            posix_ipc.Semaphore(name, posix_ipc.O_CREX, mode=0o600, initial_value=0).close()
    except BaseException:
        arena.close()
        _stop(instance)
        raise
    return arena


def _write_cell(rec: np.ndarray, cfg: KaliConfig) -> None:
    """The cell's record (``layout.CELL``) from ``cfg``: what the safety path reads."""
    rec["n_robots"] = len(cfg.robots)
    rec["n_svs"] = sum(1 for p in cfg.processes if p.kind == "sv")
    for k, r in enumerate(cfg.robots):
        out = rec["robots"][k]
        n = r.n_joints
        out["name"] = r.name.encode()
        out["model"] = r.type.name.encode()[: layout.TYPE_NAME_BYTES]
        out["hardware"] = r.hardware.kind.encode()
        out["hardware_version"] = hardware_kind(r.hardware.kind).version
        out["n_joints"] = n
        out["first_joint"] = cfg.joints.base[k]
        out["rad_per_count"][:n] = r.type.drive.rad_per_count
        out["max_current"][:n] = r.type.drive.max_current


@dataclass
class StartReport:
    """What ``start`` did."""

    instance: str
    pids: dict[str, int]
    stale_cleaned: list[str]
    seconds: float
    log_dir: Path


def _check_servos(cfg: KaliConfig) -> Registry:
    """Load the servo plugins and look up every robot's servo before anything starts, so a
    bad plugin or algorithm name is a ConfigError here, not a daemon failing at start-up;
    the registry (the arena lays out each algorithm's private data)."""
    registry = registry_for(cfg.plugins, cfg.base_dir, cfg.files)
    for robot in cfg.robots:
        try:
            registry.index(robot.servo)
        except ConfigError as exc:
            raise ConfigError(f"{cfg.source}: robot '{robot.name}' servo: {exc}") from None
    functions_for(cfg.tg_functions, cfg.base_dir, cfg.files)  # TG function plugins: loaded here too
    return registry


def _record_path(cfg: KaliConfig, record: str | os.PathLike[str] | None) -> str:
    """The viewer's recording file as an absolute path ('' for none); ConfigError if its
    directory does not exist or the path is too long for the dashboard record."""
    if record is not None:
        path, field = os.path.abspath(os.fspath(record)), "--record"
    elif cfg.dashboard.record is not None:
        path = os.path.join(cfg.base_dir, os.path.expanduser(cfg.dashboard.record))
        path, field = os.path.abspath(path), "dashboard.record"
    else:
        return ""
    if not os.path.isdir(os.path.dirname(path)):
        raise ConfigError(f"{cfg.source}: {field} {path}: no directory {os.path.dirname(path)}")
    if os.path.isdir(path):
        raise ConfigError(f"{cfg.source}: {field} {path}: is a directory, not a file")
    if len(path.encode()) >= layout.URL_BYTES:
        raise ConfigError(
            f"{cfg.source}: {field} {path}: {len(path.encode())} bytes, at most "
            f"{layout.URL_BYTES - 1}"
        )
    return path


def start(
    cfg: KaliConfig,
    lockstep: bool = False,
    instance: str | None = None,
    record: str | os.PathLike[str] | None = None,
    separate: bool = False,
) -> StartReport:
    """Start every process of ``cfg``; returns when all are ACTIVE, else cleans up and raises.

    In real-time mode the clock is started once everyone is ready; in lockstep mode it stays
    stopped at tick 0 until ``clock start`` or ``clock step N``.  A lockstep instance runs
    every daemon in one process, the lockstep executive (``lockstep/executive.py``), unless
    ``separate`` asks for a process per daemon as in real time (for fault injection: a test
    that kills one).  ``record`` (relative to the current directory) overrides the config's
    ``dashboard.record`` (relative to the config's).
    """
    name = check_instance_name(cfg.instance if instance is None else instance)
    if lockstep and not cfg.simulated:
        raise ConfigError(
            f"{cfg.source}: lockstep steps the cell's simulated plant, and this cell has none "
            "(processes.plant.enabled: false): real hardware runs in real time (kalictl start "
            "without --lockstep)"
        )
    t_start = time.monotonic()
    registry = _check_servos(cfg)
    check_clear_at_rest(cfg)  # arms standing in each other: refused before anything runs
    check_scene_apart(cfg.scene)  # and fixtures
    record_path = _record_path(cfg, record)
    with lifecycle_lock(name, "start"):
        return _start(cfg, name, lockstep, record_path, t_start, registry, separate)


def _start(
    cfg: KaliConfig,
    name: str,
    lockstep: bool,
    record_path: str,
    t_start: float,
    registry: Registry,
    separate: bool = False,
) -> StartReport:
    """``start`` with the lifecycle lock held."""
    check_not_squatted(name)
    stale: list[str] = []
    if shm_objects(name):
        running = instance_pids(name)
        if running:
            raise InstanceError(
                f"instance '{name}' is already running (pids {', '.join(map(str, running))}); "
                f"kalictl -i {name} stop first, or start another with -i NAME"
            )
        stale = shm_objects(name)
        _stop(name)
    logs = private_log_dir(log_dir(name))
    try:  # the user files it runs on: copied once, loaded from the copies from here on
        cfg = snapshot.take(cfg, _make_instance_dir(name) / "files")
        registry = _check_servos(cfg)
    except BaseException:
        _remove_instance_dir(instance_dir(name), name)
        raise
    arena = _create(cfg, name, lockstep, record_path, registry)
    arena.close()
    inst = Instance.attach(name)
    pids: dict[str, int] = {}
    logs_of: dict[str, Path] = {}
    jobs: list[dict[str, str]] = []
    executive = lockstep and not separate
    spawner = Spawner(name, logs / "spawner.log", warm=executive)
    try:
        for p in cfg.processes:
            inst.claim_slot(p.name, 0)
            hosted = executive and p.kind not in OWN_PROCESS
            if hosted:
                continue  # hosted by the executive: it is the wall clock's process
            hosts = executive and p.kind == "wallclock"
            module = "lockstep.executive" if hosts else MODULES[p.kind]
            if p.kind == "plant":  # the cell's hardware's simulator
                module = hardware_kind(cfg.hardware_kinds[0]).simulator.partition(":")[0]
            logs_of[p.name] = logs / f"{p.name}.log"
            jobs.append({"module": module, "instance": name, "name": p.name})
        for job, pid in zip(jobs, spawner.start(jobs, logs_of), strict=True):
            pids[job["name"]] = pid
        if executive:  # one process: every slot is the executive's
            clock = next(p.name for p in cfg.processes if p.kind == "wallclock")
            for p in cfg.processes:
                if p.kind not in OWN_PROCESS:
                    pids[p.name], logs_of[p.name] = pids[clock], logs_of[clock]
        for p in cfg.processes:
            inst.procs[inst.find_slot(p.name)]["pid"] = pids[p.name]
        _wait_ready(inst, cfg, pids, spawner, logs_of)
        if not lockstep:
            start_kali_clock(inst)
    except BaseException:
        inst.close()
        spawner.close()
        _stop(name)
        raise
    spawner.close()
    inst.close()
    return StartReport(name, pids, stale, time.monotonic() - t_start, logs)


# Every daemon computes on its one thread.  numpy's OpenBLAS otherwise starts a worker thread
# per further CPU at import, SCHED_OTHER on the daemon's CPU, and a BLAS call it shares waits
# for it while SCHED_FIFO work holds that CPU: a priority inversion
# (docs/decisions/0006-single-threaded-daemons.md).
SINGLE_THREADED = {"OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}
# MuJoCo picks its OpenGL platform as it is imported (the spawner imports it for every daemon):
# the camera process renders offscreen through EGL, in software where there is no GPU
RENDERING = "MUJOCO_GL", "egl"


# the spawner's last argument: room its children write their own command lines over
SPAWNER_ROOM = "--room=" + "." * 160
# a warm spawner's Unix socket (``spawner.serve``): a lockstep executive's start connects
# there, if it answers, instead of starting a spawner of its own
SPAWNER_ENV = "KALI_SPAWNER"


class Spawner:
    """The start's spawner (``spawner.py``): one interpreter that has imported what every
    daemon imports, forking each of the start's processes; until ``close`` it says which of
    them exited, with their status."""

    def __init__(self, instance: str, log_path: Path, warm: bool = False) -> None:
        """``warm``: fork from the warm spawner ``$KALI_SPAWNER`` names, if one answers (for
        a lockstep executive's start only: every other process imports only what it uses,
        a real-time one to map no more than its own libraries)."""
        self.log_path = log_path
        env = {RENDERING[0]: RENDERING[1], **os.environ, **SINGLE_THREADED}
        self.proc: subprocess.Popen[bytes] | None = None
        self.conn = _warm_spawner(os.environ.get(SPAWNER_ENV)) if warm else None
        if self.conn is not None:  # a warm spawner's: the start, then the pipes' protocol
            head = {"env": env, "cwd": os.getcwd(), "instance": instance, "log": str(log_path)}
            self.conn.sendall(json.dumps(head).encode() + b"\n")
            self._fd = self.conn.fileno()
        else:
            # the instance's (is_kali_process), with room for its children's command lines
            argv = ["-m", "kali_daemons.tools.spawner", "--instance", instance, SPAWNER_ROOM]
            with open(log_path, "wb") as log:  # the spawner holds its own descriptor
                self.proc = subprocess.Popen(
                    [sys.executable, *argv],
                    stdin=subprocess.PIPE,
                    stdout=subprocess.PIPE,
                    stderr=log,
                    start_new_session=True,
                    close_fds=True,
                    env=env,
                )
            assert self.proc.stdout is not None
            self._fd = self.proc.stdout.fileno()
        self.exits: dict[int, int] = {}  # pid -> exit status (negative: the signal)
        self._buffer = b""  # what the spawner said, not yet a whole line

    def start(self, jobs: list[dict[str, str]], logs_of: dict[str, Path]) -> list[int]:
        """Fork each job's process (its output in ``logs_of[name]``); their pids, in order."""
        lines = [json.dumps({**job, "log": str(logs_of[job["name"]])}) for job in jobs]
        said = "".join(f"{line}\n" for line in lines).encode() + b"\n"
        if self.conn is not None:
            self.conn.sendall(said)
        else:
            assert self.proc is not None and self.proc.stdin is not None
            self.proc.stdin.write(said)
            self.proc.stdin.flush()
        pids: list[int] = []
        while len(pids) < len(jobs):
            read = self._read(block=True)
            if read is None:
                code = "-" if self.proc is None else self.proc.wait()
                raise InstanceError(
                    f"the start's spawner ended before starting '{jobs[len(pids)]['name']}' "
                    f"(exit {code}):\n" + _tail(self.log_path)
                )
            pids += [int(line) for line in read]
        return pids

    def exited(self, pid: int) -> int | None:
        """``pid``'s exit status if it has exited since the start began, else None."""
        for line in self._read(block=False) or []:
            _, child, status = line.split()
            self.exits[int(child)] = int(status)
        return self.exits.get(pid)

    def _read(self, block: bool) -> list[bytes] | None:
        """The whole lines the spawner has written since the last read; None at its end."""
        fd = self._fd
        if not block and not select.select([fd], [], [], 0)[0]:
            return []
        chunk = os.read(fd, 4096)  # the descriptor itself: nothing read ahead elsewhere
        if not chunk:
            return None
        *lines, self._buffer = (self._buffer + chunk).split(b"\n")
        return lines

    def close(self) -> None:
        """The start is over: the spawner exits, leaving its children to the init process."""
        if self.conn is not None:  # a warm spawner's: it says so by closing the connection
            with contextlib.suppress(OSError):
                self.conn.shutdown(socket.SHUT_WR)
                deadline = time.monotonic() + STOP_GRACE_S
                while time.monotonic() < deadline and self._read(block=False) is not None:
                    time.sleep(0.005)
            self.conn.close()
            return
        assert self.proc is not None
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        try:
            self.proc.wait(timeout=STOP_GRACE_S)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        if self.proc.stdout is not None:
            self.proc.stdout.close()


def _warm_spawner(path: str | None) -> socket.socket | None:
    """A connection to the warm spawner at ``path`` (``$KALI_SPAWNER``), or None: none named,
    none answers there, or it forks another package's modules (an installed Kali's, say): the
    start then starts a spawner of its own."""
    if not path:
        return None
    conn = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    try:
        conn.settimeout(STOP_GRACE_S)
        conn.connect(path)
        said = b""
        while not said.endswith(b"\n"):
            chunk = conn.recv(1)  # its first line only: the rest is the spawner's protocol
            if not chunk:
                raise OSError("closed")
            said += chunk
        conn.settimeout(None)
        if json.loads(said).get("package") != PACKAGE:
            raise OSError("another package")
    except (OSError, ValueError, AttributeError):
        conn.close()
        return None
    return conn


def _wait_ready(
    inst: Instance,
    cfg: KaliConfig,
    pids: dict[str, int],
    spawner: Spawner,
    logs_of: dict[str, Path],
) -> None:
    """Wait until every process is ACTIVE and the clock is ready; name the first that fails."""
    deadline = time.monotonic() + cfg.startup_timeout_s
    while True:
        waiting = []
        for name, pid in pids.items():
            slot = inst.find_slot(name)
            state = ProcState(int(inst.procs[slot]["state"]))
            status = spawner.exited(pid)
            if status is not None or state == ProcState.ERROR:
                raise InstanceError(
                    f"process '{name}' (pid {pid}) failed during start-up "
                    f"(exit {'-' if status is None else status}, state {state.name}):\n"
                    + _tail(logs_of[name])
                )
            if state != ProcState.ACTIVE:
                doing = inst.doing(name)  # a link: "connecting to its FR3"
                waiting.append(f"{name} ({state.name}{': ' + doing if doing else ''})")
        if not waiting and inst.clock["ready"]:
            return
        if time.monotonic() > deadline:
            raise InstanceError(
                f"not ready within startup_timeout_s = {cfg.startup_timeout_s:g} s: "
                + ", ".join(waiting or ["wallclock"])
            )
        time.sleep(0.02)


def _tail(path: Path, lines: int = 15) -> str:
    try:
        text = path.read_text(errors="replace").splitlines()[-lines:]
    except OSError:
        return f"    (no log at {path})"
    return "\n".join("    " + t for t in text)


def describe(inst: Instance) -> list[dict[str, Any]]:
    """The process table as plain rows, for ``kalictl status`` and tests."""
    rows = []
    base_ns = int(inst.clock["base_tick_ns"])
    now = time.monotonic_ns()
    for i in range(layout.MAX_PROCESSES):
        p = inst.procs[i]
        if p["state"] == ProcState.FREE:
            continue
        hist = np.array(p["hist"], dtype=np.int64)
        rows.append(
            {
                "slot": i,
                "name": decode(p["name"]),
                "pid": int(p["pid"]),
                "alive": pid_alive(int(p["pid"])),
                "state": ProcState(int(p["state"])).name,
                "cpu": int(p["cpu"]),
                "priority": int(p["priority"]),
                "periodic": bool(p["periodic"]),
                "period_ms": ns_to_ms(int(p["period_ticks"]) * base_ns),
                "serious": bool(p["serious"]),
                "signals": int(p["signals"]),
                "acks": int(p["acks"]),
                "misses": int(p["misses"]),
                "exec_last_us": int(p["exec_last_ns"]) / 1e3,
                "exec_max_us": int(p["exec_max_ns"]) / 1e3,
                "late_max_us": int(p["late_max_ns"]) / 1e3,
                "late_p50_us": percentile(hist, 0.50),
                "late_p99_us": percentile(hist, 0.99),
                "heartbeat_age_ms": max(0, now - int(p["heartbeat_ns"])) / 1e6,
            }
        )
    return rows


def recent_misses(inst: Instance, n: int = layout.MISS_LOG_LEN) -> list[dict[str, Any]]:
    """The last ``n`` missed deadlines from the clock's log, oldest first."""
    log = inst.misses
    count = int(log["count"])
    rows = []
    for k in range(max(0, count - min(n, layout.MISS_LOG_LEN)), count):
        e = log["entries"][k % layout.MISS_LOG_LEN]
        slot = int(e["slot"])
        rows.append(
            {
                "tick": int(e["tick"]),
                "process": decode(inst.procs[slot]["name"]),
                "slot": slot,
                "signal_ns": int(e["signal_ns"]),
                "due_ns": int(e["due_ns"]),
                "consecutive": int(e["consecutive"]),
            }
        )
    return rows


def percentile(hist: np.ndarray, q: float) -> float:
    """The ``q`` quantile (0..1) of a lateness histogram, in µs at bin upper edges."""
    total = int(hist.sum())
    if total == 0:
        return float("nan")
    b = int(np.searchsorted(np.cumsum(hist), q * total, side="left"))
    return layout.bin_upper_us(min(b, len(hist) - 1))


@dataclass
class Dashboard:
    """Where the viewer's live dashboard is (``kalictl view``), from its dashboard record."""

    ready: bool  # the viewer has set its sinks up
    web_url: str  # what a browser opens; '' if the web viewer is not served
    live_url: str  # the live rerun viewer it streams to; '' if none
    record: str  # the .rrd file it records to; '' if none
    web_pid: int  # the web viewer server's pid, 0 if none
    frames: int
    errors: int
    message: str  # what the viewer could not do, '' if nothing


def dashboard(inst: Instance) -> Dashboard | None:
    """The instance's dashboard record as plain values; None if it has none."""
    if inst.arena.lookup(layout.KEY_DASHBOARD) is None:
        return None
    d = inst.arena.existing(layout.KEY_DASHBOARD, layout.DASHBOARD)
    return Dashboard(
        ready=bool(d["ready"]),
        web_url=decode(d["web_url"]),
        live_url=decode(d["live_url"]) if d["live"] else "",
        record=decode(d["record"]),
        web_pid=int(d["web_pid"]),
        frames=int(d["frames"]),
        errors=int(d["errors"]),
        message=decode(d["message"]),
    )
