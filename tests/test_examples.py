"""The example robot programs in scripts/ run as a newcomer runs them, ``kalictl run
PROGRAM``, here against a lockstep instance (a waiting program steps its clock)."""

from __future__ import annotations

import re
from collections.abc import Callable

import pytest

from .conftest import ROOT
from .test_launcher import kalictl


def test_square_example_draws_its_square(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    r = kalictl("-i", name, "run", "scripts/example_square.py")
    assert r.returncode == 0, r.stdout + r.stderr
    m = re.search(r"square of 10 cm done; the tool is ([\d.]+) mm from its start", r.stdout)
    assert m and float(m.group(1)) < 3.0, r.stdout  # the servo still settling


def test_carry_example_puts_the_bar_back(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    r = kalictl("-i", name, "run", "scripts/example_carry.py")
    assert r.returncode == 0, r.stdout + r.stderr
    m = re.search(r"put back at \(([-\d.]+), ([-\d.]+), ([-\d.]+)\) m", r.stdout)
    assert m, r.stdout
    assert [float(v) for v in m.groups()] == pytest.approx([0.0, 0.0, 0.585], abs=0.003)


def test_pid_tuning_example_prints_its_table(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    r = kalictl("-i", name, "run", "scripts/example_tune_pid.py")
    assert r.returncode == 0, r.stdout + r.stderr
    rows = re.findall(r"^\s*([\d.]+)\s+([\d.]+)\s+([\d.]+)$", r.stdout, re.M)
    assert len(rows) == 3, r.stdout
    rms = sorted(float(row[1]) for row in rows)
    assert rms[0] > 0 and rms[1] > 1.05 * rms[0] and rms[2] > 1.05 * rms[1]  # each gain tells
    assert re.search(r"kp back to 9000; the arm is where it started", r.stdout), r.stdout


def test_run_says_when_the_instance_or_program_is_missing(kali: Callable[..., str]) -> None:
    r = kalictl("-i", "nosuchinstance", "run", "scripts/example_square.py")
    assert r.returncode != 0 and "nosuchinstance" in r.stderr
    r = kalictl("-i", "nosuchinstance", "run", str(ROOT / "scripts" / "nothere.py"))
    assert r.returncode != 0 and "nothere.py" in r.stderr
