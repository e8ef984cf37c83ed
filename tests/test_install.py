"""An installed Kali (a normal, not editable, install) runs from its own files: the robot
types' URDFs, the shipped configs and the example plugins they name are package data, not
files of the source tree."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

from .conftest import ROOT, leftovers, unique_name

NOT_SOURCE = (".git", ".venv", "*cache*", ".hypothesis", "site", "build", "logs", "*.egg-info")
PROGRAM = """
import sys
from pathlib import Path

import numpy as np

import kali_daemons
from kali_daemons.client import Kali
from kali_daemons.runtime.config import DEFAULT_FILE, parse_config
from kali_daemons.tools import launcher

site, name = Path(sys.argv[1]), sys.argv[2]
assert Path(kali_daemons.__file__).is_relative_to(site), kali_daemons.__file__
assert DEFAULT_FILE.is_relative_to(site) and DEFAULT_FILE.is_file(), DEFAULT_FILE
text = DEFAULT_FILE.read_text().replace("web: auto", "web: off")  # no web server in a test
cfg = parse_config(text, str(DEFAULT_FILE), str(DEFAULT_FILE.parent), instance=name)
for r in cfg.robots:
    assert Path(r.type.urdf).is_relative_to(site) and Path(r.type.urdf).is_file(), r.type.urdf
launcher.start(cfg, lockstep=True)
try:
    with Kali(name) as kali:
        left = kali.robot("left")
        for module in sys.modules.values():  # nothing came from the source tree
            path = getattr(module, "__file__", None) or ""
            if module.__name__.startswith("kali_daemons"):
                assert Path(path).is_relative_to(site), (module.__name__, path)
        kali.ready(["left"])  # powered and calibrated through the installed SIO and boards
        kali.sleep(0.05)
        q = left.read_joints()
        assert np.all(np.isfinite(q)) and q.shape == (6,), q
        print("installed cell ran", kali.inst.cell.n_robots, "arms")
finally:
    launcher.stop(name)
"""


def test_an_installed_kali_starts_a_lockstep_cell_from_its_own_files(tmp_path: Path) -> None:
    source = tmp_path / "source"  # a copy: pip builds in the tree it is given
    shutil.copytree(ROOT, source, symlinks=True, ignore=shutil.ignore_patterns(*NOT_SOURCE))
    site = tmp_path / "site"
    pip = subprocess.run(
        [
            sys.executable,
            "-m",
            "pip",
            "install",
            "--quiet",
            "--no-deps",
            "--target",
            str(site),
            str(source),
        ],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert pip.returncode == 0, pip.stdout + pip.stderr
    name = unique_name("inst")
    env = {**os.environ, "PYTHONPATH": str(site), "KALI_LOG_DIR": str(tmp_path / "logs")}
    run = subprocess.run(
        [sys.executable, "-c", PROGRAM, str(site), name],
        capture_output=True,
        text=True,
        cwd=tmp_path,  # not the source tree
        env=env,
        timeout=600,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "installed cell ran 2 arms" in run.stdout
    assert leftovers(name) == ([], [])
