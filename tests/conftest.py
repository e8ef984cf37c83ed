"""Shared fixtures: unique instance names, arenas and whole instances that clean up."""

from __future__ import annotations

import importlib
import os
import re
import subprocess
import sys
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.hardware.mcgill.boards import records
from kali_daemons.runtime.config import KaliConfig, parse_config
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher

ROOT = Path(__file__).resolve().parent.parent
DEFAULT_TEXT = (ROOT / "config" / "default.yaml").read_text()


@pytest.fixture(scope="session", autouse=True)
def warm_spawner(tmp_path_factory: pytest.TempPathFactory) -> Iterator[None]:
    """One warm spawner (``kali_daemons.tools.spawner.serve``) for this test process and the
    kalictl it runs: each of the session's hundreds of starts forks from it rather than
    importing every daemon's modules anew.  It ends, removing its socket, with the session."""
    path = tmp_path_factory.mktemp("spawner") / "warm.sock"
    env = {launcher.RENDERING[0]: launcher.RENDERING[1], **os.environ, **launcher.SINGLE_THREADED}
    argv = ["-m", "kali_daemons.tools.spawner", "--serve", str(path), launcher.SPAWNER_ROOM]
    server = subprocess.Popen(
        [sys.executable, *argv],
        stdin=subprocess.PIPE,
        start_new_session=True,
        env=env,
    )
    deadline = time.monotonic() + 60.0
    while not path.exists() and server.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    os.environ[launcher.SPAWNER_ENV] = str(path)
    try:
        yield
    finally:
        del os.environ[launcher.SPAWNER_ENV]
        assert server.stdin is not None
        server.stdin.close()  # its input ends: it exits
        server.wait(timeout=10.0)


def boards_of(inst: Instance) -> np.ndarray:
    """The simulated McGill boards' registers of ``inst``, one record per robot: what the
    white-box tests of the board and its safety paths look at."""
    return records(inst.arena, inst.cell.n_robots)


def unique_name(prefix: str = "t") -> str:
    """An instance name no other test (or test run) uses."""
    return f"{prefix}{os.getpid()}-{uuid.uuid4().hex[:8]}"


class ByArm:
    """A uniform cell's servo level (every arm with the same joint count, as the default
    config's two PUMAs): ``JOINT_STATE`` fields as live ``(robots, joints)`` views, the
    ``ROBOT_STATE`` fields as they are, so ``by_arm["q"][k, j]`` is arm k's joint j."""

    def __init__(self, level: object) -> None:
        self.level = level

    def __getitem__(self, field: str) -> np.ndarray:
        level = self.level
        if field in (layout.JOINT_STATE.names or ()):
            return level.joints[field].reshape(level.n_robots, -1)  # type: ignore[attr-defined]
        return level.robots[field]  # type: ignore[attr-defined]


def make_config(
    instance: str, edits: dict[str, str] | None = None, base: str = "default.yaml"
) -> KaliConfig:
    """The config ``config/<base>`` (default: default.yaml) for ``instance``, with regex
    substitutions ``pattern -> repl``."""
    return parse_config(
        config_text(instance, edits, base), f"<test {instance}>", str(ROOT / "config")
    )


def config_text(
    instance: str, edits: dict[str, str] | None = None, base: str = "default.yaml"
) -> str:
    """The text of ``make_config``'s config (for ``kalictl start -c FILE``)."""
    source = DEFAULT_TEXT if base == "default.yaml" else (ROOT / "config" / base).read_text()
    text = re.sub(r"(?m)^instance: .*$", f"instance: {instance}", source)
    # no web viewer server per test instance (tests/test_viewer.py turns it on where it is the
    # point): the suite starts dozens of instances
    text = re.sub(r"(?m)^  web: auto\b", "  web: off ", text)
    if not re.search(r"(?m)^dashboard:", text):  # a config taking the default dashboard
        text += "dashboard: {web: off}\n"
    for pattern, repl in (edits or {}).items():
        text, n = re.subn(pattern, repl, text, flags=re.M)
        assert n, f"config edit {pattern!r} matched nothing"
    return text


def wait_for(
    cond: Callable[[], bool], timeout: float = 20.0, what: str = "condition", poll_s: float = 0.001
) -> float:
    """Poll ``cond`` until true; the seconds it took; AssertionError naming ``what`` after
    ``timeout`` s."""
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout, f"not within {timeout:g} s: {what}"
        time.sleep(poll_s)
    return time.monotonic() - t0


def leftovers(instance: str) -> tuple[list[str], list[int]]:
    """/dev/shm objects (and the instance's directory of user file copies) and live daemon
    pids of ``instance``."""
    own = launcher.instance_dir(instance)
    return launcher.shm_objects(instance) + ([str(own)] if own.exists() else []), (
        launcher.instance_pids(instance)
    )


@pytest.fixture(autouse=True)
def _real_time_runs_alone(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> None:
    """A test starting a real-time instance, or a lockstep one of separate processes (bound
    to CPUs at SCHED_FIFO), in this process must be marked ``serial``: scripts/test.sh runs
    the unmarked ones two at a time, where such a cell would miss deadlines for the other's
    sake."""
    if request.node.get_closest_marker("serial"):
        return
    start = launcher._start

    def unmarked(cfg: KaliConfig, name: str, lockstep: bool, *args: object) -> object:
        separate = len(args) > 3 and bool(args[3])
        if not lockstep or separate:
            kind = "a separate lockstep" if lockstep else "a real-time"
            pytest.fail(
                f"{request.node.nodeid} starts {kind} instance: mark it @pytest.mark.serial "
                "(it must run alone)"
            )
        return start(cfg, name, lockstep, *args)

    monkeypatch.setattr(launcher, "_start", unmarked)


@pytest.fixture
def arena() -> Iterator[Arena]:
    """A fresh 1 MiB arena, unlinked afterwards."""
    name = unique_name("a")
    a = Arena.create(name, 1 << 20)
    yield a
    a.close()
    launcher.stop(name)


@pytest.fixture
def kali(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[..., str]]:
    """Start whole instances: ``kali(lockstep=True, edits={...}, base="default.yaml")``
    returns the instance name (``base``: the file under config/ the config is made from;
    ``separate``: a lockstep instance with a process per daemon, for a test that kills one,
    instead of the lockstep executive's one process).

    Every instance started is stopped afterwards and must leave nothing behind.
    """
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path / "logs"))
    started: list[str] = []

    def start(
        lockstep: bool = True,
        edits: dict[str, str] | None = None,
        base: str = "default.yaml",
        separate: bool = False,
    ) -> str:
        name = unique_name()
        started.append(name)
        launcher.start(make_config(name, edits, base), lockstep=lockstep, separate=separate)
        return name

    yield start
    for name in started:
        launcher.stop(name)
        assert leftovers(name) == ([], []), f"instance {name} left something behind"


class HostedCell:
    """Daemons configured in the test's own process on one lockstep instance's arena, as the
    lockstep executive hosts them (``Daemon.host``), for a test that drives their cycle
    logic directly: ``HostedCell(edits, ("plant", "sio", "sv.0"))``, the daemons by name in
    start-up order (the plant makes the boards SIO waits for, SIO the servo level the SVs
    wait for).  ``close`` releases them and removes the instance."""

    def __init__(
        self,
        names: tuple[str, ...],
        edits: dict[str, str] | None = None,
        base: str = "default.yaml",
    ) -> None:
        from kali_daemons.lockstep.executive import HOSTED_ORDER
        from kali_daemons.runtime.instance import Instance

        classes = {kind: (mod, cls) for kind, mod, cls in HOSTED_ORDER}
        self.name = unique_name("host")
        cfg = make_config(self.name, edits, base)
        launcher._create(cfg, self.name, lockstep=True).close()
        self.inst = Instance.attach(self.name)
        self.daemons: dict[str, object] = {}
        try:
            for p in cfg.processes:
                self.inst.claim_slot(p.name, 0)
            for name in names:
                mod, cls = classes[cfg.process(name).kind]
                module = importlib.import_module(f"kali_daemons.{mod}")
                daemon = getattr(module, cls)(self.name, name)
                daemon.host(self.inst)
                self.daemons[name] = daemon
        except BaseException:
            self.close()
            raise

    def __getitem__(self, name: str) -> object:
        return self.daemons[name]

    def close(self) -> None:
        for daemon in reversed(list(self.daemons.values())):
            daemon._finish()  # type: ignore[attr-defined]
        self.inst.close()
        launcher.stop(self.name)
        assert leftovers(self.name) == ([], []), f"instance {self.name} left something behind"
