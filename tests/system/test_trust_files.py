"""An instance runs on what it started with, and its safety path needs nothing but the arena
(issue 51 items 1 and 9).

Every kalictl command used to parse the config again, so each one imported the robot type's
file and the plugins anew: a robot type file moved, broken, made to exit, to sleep or to loop
after start made ``kalictl estop`` fail, lie, dawdle or hang.  Now ``kalictl start`` copies the
user files into the instance's directory and everyone loads the copies; estop, status, stop,
reset, enable and disable read the arena alone.  A user file that exits or loops while it
loads is refused naming it, within a time limit.
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

from kali_daemons.core import layout
from kali_daemons.core.errors import ConfigError
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo import registry_for
from kali_daemons.tools import launcher

from ..conftest import ROOT, boards_of, leftovers, unique_name
from ..robots.test_bring_your_own import write_arm, write_config
from ..test_launcher import kalictl

FAST = 4.0  # s: a safety command is bounded by the arena's work, not by any user file


def _prepend(line: str) -> Callable[[Path], None]:
    def edit(module: Path) -> None:
        module.write_text(line + module.read_text())

    return edit


# what a user (or an accident) does to a robot type file after start
BREAKAGES: dict[str, Callable[[Path], None]] = {
    "moved": lambda m: m.rename(m.with_name("moved_away.py")),
    "syntax error": _prepend("def (:\n"),
    "exits": _prepend("import sys; sys.exit(0)\n"),
    "sleeps 8 s": _prepend("import time; time.sleep(8)\n"),
    "loops": _prepend("while True:\n    pass\n"),
}
SAFETY = (("status",), ("status", "--json"), ("estop",), ("estop", "--release"))


@pytest.fixture
def byo(tmp_path: Path) -> Iterator[tuple[str, Path, dict[str, str]]]:
    """A lockstep instance whose right arm is a user's robot type file (planar3), started
    from the command line: (instance, the type's module, the environment to use)."""
    name = unique_name("f")
    module = write_arm(tmp_path / "arm")
    config = write_config(tmp_path / "arm", name)
    env = {"KALI_LOG_DIR": str(tmp_path / "logs"), "KALI_INSTANCE": name}
    r = kalictl("start", "-c", str(config), "--lockstep", env=env)
    assert r.returncode == 0, r.stderr
    try:
        yield name, module, env
    finally:
        kalictl("stop", env=env)
        assert leftovers(name) == ([], []), f"instance {name} left something behind"


def _timed(*args: str, env: dict[str, str]) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.monotonic()
    try:
        r = kalictl(*args, env=env, timeout=20)
    except subprocess.TimeoutExpired:
        pytest.fail(f"kalictl {' '.join(args)} still running after 20 s")
    return r, time.monotonic() - t0


def test_the_safety_path_needs_nothing_but_the_arena_whatever_the_users_files_do(
    byo: tuple[str, Path, dict[str, str]],
) -> None:
    name, module, env = byo
    original = module.read_text()
    with Instance.attach(name) as inst:
        for what, breakage in BREAKAGES.items():
            module.unlink(missing_ok=True)
            module.with_name("moved_away.py").unlink(missing_ok=True)
            module.write_text(original)
            breakage(module)
            for args in SAFETY:
                r, took = _timed(*args, env=env)
                assert r.returncode == 0, (what, args, r.stderr)
                assert took < FAST, (what, args, f"{took:.1f} s")
            assert "e-stop pressed: left, right" in _timed("estop", env=env)[0].stdout, what
            assert all(boards_of(inst)["estop"] == 1), what  # pressed, really
            assert inst.fault_text() is not None and "emergency stop" in inst.fault_text()
            for args in (("estop", "--release"), ("reset",), ("enable",), ("disable",)):
                r, took = _timed(*args, env=env)
                assert r.returncode == 0, (what, args, r.stderr)
                assert took < FAST, (what, args, f"{took:.1f} s")
            assert not any(boards_of(inst)["estop"]) and inst.fault_text() is None, what


def test_an_instance_runs_on_the_files_it_started_with(
    byo: tuple[str, Path, dict[str, str]], tmp_path: Path
) -> None:
    """Programs and servo commands started after the file broke load the copy taken at start;
    the copies go with the instance."""
    name, module, env = byo
    module.write_text("while True:\n    pass\n")
    program = tmp_path / "program.py"
    program.write_text(
        "from kali_daemons.client import Kali\n"
        "with Kali() as kali:\n"
        "    arm = kali.robot('right')\n"
        "    print(arm.type.name, arm.type.n_joints, len(arm.read_joints()))\n"
    )
    r = subprocess.run(
        [sys.executable, str(program)],
        capture_output=True,
        text=True,
        cwd=ROOT,
        env={**os.environ, **env},
        timeout=30,
    )
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["planar3", "3", "3"]
    r, _ = _timed("servo", "list", env=env)
    assert r.returncode == 0 and "bwpd" in r.stdout, r.stderr  # the config's plugin
    copies = launcher.instance_dir(name) / "files"
    assert (copies / module.relative_to("/")).is_file()
    assert (copies / module.with_name("planar3.urdf").relative_to("/")).is_file()
    with Instance.attach(name) as inst:
        assert inst.cell.names == ("left", "right") and inst.cell.models == ("puma560", "planar3")
        cell = inst.arena.existing(layout.KEY_CELL, layout.CELL)
        assert int(cell["n_robots"]) == 2 and int(cell["n_svs"]) == 2
        del cell


@pytest.mark.parametrize(
    ("line", "said"),
    [
        ("import sys; sys.exit(0)\n", "its code called sys.exit(0) (at line 1 of"),
        ("while True:\n    pass\n", "still running after 2 s (stopped at line"),
    ],
    ids=["exits", "loops"],
)
def test_a_user_file_that_exits_or_loops_is_refused_naming_it(
    tmp_path: Path, line: str, said: str
) -> None:
    module = write_arm(tmp_path / "arm")
    module.write_text(line + module.read_text())
    name = unique_name("f")
    env = {"KALI_LOG_DIR": str(tmp_path / "logs"), "KALI_USER_CODE_S": "2"}
    r, took = _timed("types", str(module), env=env)
    assert r.returncode == 1 and f"robot type file {module}: " in r.stderr, r.stderr
    assert said in r.stderr and took < 2 + FAST
    config = write_config(tmp_path / "arm", name)
    r, took = _timed("start", "-c", str(config), "--lockstep", env=env)
    assert r.returncode == 1 and f"robot type file {module}: " in r.stderr, r.stderr
    assert said in r.stderr and took < 2 + FAST
    assert leftovers(name) == ([], [])


def test_a_plugin_that_exits_or_loops_is_refused_naming_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    plugin = tmp_path / "exits.py"
    plugin.write_text("import sys\nsys.exit(3)\n")
    with pytest.raises(ConfigError, match=r"plugin '.*exits.py': its code called sys.exit\(3\)"):
        registry_for([str(plugin)])
    plugin.write_text("def register(registry):\n    while True:\n        pass\n")
    monkeypatch.setenv("KALI_USER_CODE_S", "1")
    t0 = time.monotonic()
    with pytest.raises(ConfigError, match=r"still running after 1 s \(stopped at line [23] of"):
        registry_for([str(plugin)])
    assert time.monotonic() - t0 < 3
    assert signal.getitimer(signal.ITIMER_REAL) == (0.0, 0.0)  # no alarm left behind
    assert signal.getsignal(signal.SIGALRM) == signal.SIG_DFL
