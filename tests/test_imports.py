"""A lean daemon set (issue 26 item 4): each process imports only what its role needs, and
the set's memory (PSS, ``introspect.pss_kib``) stays within its budget.

The wall clock, SIO and the SVs read a robot type's drive facts, never its kinematics or
dynamics: they must not load Pinocchio, MuJoCo or rerun, whichever types the cell holds (a
Panda's kinematics are numerical, on Pinocchio).  The plant needs MuJoCo only, the dynamics
process Pinocchio only, the viewer Pinocchio and rerun.
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from kali_daemons.runtime.instance import Instance
from kali_daemons.servo.client import ServoClient
from kali_daemons.tools import launcher
from kali_daemons.tools.introspect import pss_kib
from kali_daemons.wallclock import step_kali_clock

from .conftest import ROOT
from .test_launcher import kalictl

HEAVY = ("pinocchio", "mujoco", "rerun")
MIB = 1024  # KiB

# The daemon module of each process, and the heavy libraries it may not load
BARRED = {
    "kali_daemons.wallclock.clock": HEAVY,
    "kali_daemons.sio.daemon": HEAVY,
    "kali_daemons.servo.sv.daemon": HEAVY,
    "kali_daemons.tg.daemon": ("mujoco", "rerun"),  # a Panda's kinematics are on Pinocchio
    "kali_daemons.plant.daemon": ("pinocchio", "rerun"),
    "kali_daemons.dynamics.daemon": ("mujoco", "rerun"),
    "kali_daemons.viewer.daemon": HEAVY,  # its drawing (dashboard) only where it has a sink
    "kali_daemons.viewer.dashboard": ("mujoco",),
}

# Budgets of the default cell in lockstep (issue 26): the whole set and the wall clock
SET_PSS_MIB = 400
WALLCLOCK_PSS_MIB = 40


def loaded_after(module: str, config: str) -> list[str]:
    """The top-level packages of ``HEAVY`` that importing ``module`` and then parsing
    ``config/<config>`` (resolving every robot's type, as each daemon does when it attaches)
    loads into a fresh interpreter."""
    code = (
        f"import sys, {module}\n"
        "from pathlib import Path\n"
        "from kali_daemons.runtime.config import parse_config\n"
        f"path = Path({str(ROOT / 'config' / config)!r})\n"
        "cfg = parse_config(path.read_text(), str(path), str(path.parent))\n"
        "assert all(r.type.n_joints for r in cfg.robots)\n"
        f"print(sorted({{m.split('.')[0] for m in sys.modules}} & set({HEAVY!r})))\n"
    )
    r = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=120
    )
    assert r.returncode == 0, r.stderr
    return json.loads(r.stdout.replace("'", '"'))


@pytest.mark.parametrize("config", ["default.yaml", "mixed.yaml"])
@pytest.mark.parametrize("module", sorted(BARRED))
def test_each_daemon_imports_only_what_its_role_needs(module: str, config: str) -> None:
    loaded = loaded_after(module, config)
    assert not set(loaded) & set(BARRED[module]), f"{module} with {config} loads {loaded}"


def libraries_mapped(pid: int) -> set[str]:
    """Which of ``HEAVY`` process ``pid`` has mapped (its shared libraries in /proc/PID/maps)."""
    maps = Path(f"/proc/{pid}/maps").read_text()
    return {lib for lib in HEAVY if lib in maps}


def run_a_while(name: str) -> list[dict[str, object]]:
    """Power the arms, move one, and run the clock 1 s of simulated time; the process rows."""
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            step_kali_clock(inst, 30)
            for robot in client.names:
                client.power(robot, True)
            step_kali_clock(inst, 300)
        finally:
            client.close()
    robot = "left" if "left" in client.names else client.names[0]
    r = kalictl("-i", name, "move", robot, "--joints", "5,45,-180,0,45,0", "--speed", "0.2")
    assert r.returncode == 0, r.stderr
    with Instance.attach(name) as inst:
        step_kali_clock(inst, 700)
        return launcher.describe(inst)


@pytest.mark.serial
def test_the_default_set_fits_its_memory_budget(kali: Callable[..., str]) -> None:
    """Default cell, lockstep, after a move: the wall clock's PSS <= 40 MiB, the set's
    <= 400 MiB, and ``kalictl status --memory`` shows every process and the sum."""
    name = kali(lockstep=True, separate=True)  # the daemon set as it runs in real time
    rows = run_a_while(name)
    pss = {str(r["name"]): pss_kib(int(r["pid"]))[0] for r in rows}  # type: ignore[call-overload]
    assert len(pss) == 8
    table = ", ".join(f"{k} {v / MIB:.1f}" for k, v in pss.items())
    assert pss["wallclock"] <= WALLCLOCK_PSS_MIB * MIB, f"PSS MiB: {table}"
    assert sum(pss.values()) <= SET_PSS_MIB * MIB, f"PSS MiB: {table}"
    for daemon in ("wallclock", "sio", "sv.0", "sv.1"):
        pid = next(int(r["pid"]) for r in rows if r["name"] == daemon)  # type: ignore[call-overload]
        assert not libraries_mapped(pid), f"{daemon} maps {libraries_mapped(pid)}"
    out = kalictl("-i", name, "status", "--memory")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    head = next(i for i, line in enumerate(lines) if line.startswith("memory "))
    memory = lines[head + 1 :]
    assert [line.split()[0] for line in memory[:9]] == [*pss, "total"]
    assert all(line.split()[-1] == "MB" for line in memory[:9])


@pytest.mark.serial
def test_a_panda_brings_no_pinocchio_into_the_clock_sio_or_the_svs(
    kali: Callable[..., str],
) -> None:
    """A mixed cell (PUMA 560 and Panda, whose kinematics are numerical on Pinocchio): the
    wall clock, SIO and the SVs map none of Pinocchio, MuJoCo or rerun while they run."""
    name = kali(lockstep=True, base="mixed.yaml", separate=True)  # a process each
    with Instance.attach(name) as inst:
        step_kali_clock(inst, 100)
        rows = launcher.describe(inst)
    for r in rows:
        if r["name"] in ("wallclock", "sio") or str(r["name"]).startswith("sv."):
            mapped = libraries_mapped(int(r["pid"]))  # type: ignore[call-overload]
            assert not mapped, f"{r['name']} maps {sorted(mapped)}"
