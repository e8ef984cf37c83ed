"""A start's spawner (``kali_daemons.tools.spawner``): started for the start, or forked from a
warm spawner (``$KALI_SPAWNER``) that has imported every hosted daemon's modules once, as this
test session's is (``conftest.warm_spawner``)."""

from __future__ import annotations

import json
import os
import socket
from collections.abc import Callable
from pathlib import Path

import pytest

from kali_daemons.client import Kali
from kali_daemons.tools import launcher, spawner
from kali_daemons.wallclock import step_kali_clock


def run_a_cell(kali: Callable[..., str]) -> None:
    """Start a lockstep cell, power an arm, step it."""
    with Kali(kali()) as k:
        k.ready(["left"])
        step_kali_clock(k.inst, 20)
        assert k.inst.fault_text() is None


def ask(path: str) -> dict[str, object]:
    """The warm spawner's first line to a connection (it forks a start spawner for it, which
    ends when the connection closes)."""
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as conn:
        conn.connect(path)
        return dict(json.loads(conn.makefile("r").readline()))


def test_a_start_forks_from_the_warm_spawner_and_without_one_starts_its_own(
    kali: Callable[..., str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The session's warm spawner answers with the package it forks (this one) and the
    connections it has taken; a start through it takes one and runs a cell; one with
    ``$KALI_SPAWNER`` unset takes none, starting a spawner of its own, and runs a cell too."""
    path = os.environ[launcher.SPAWNER_ENV]
    first = ask(path)
    assert first["package"] == spawner.PACKAGE
    assert str(Path(launcher.__file__).resolve().parents[1]) == spawner.PACKAGE
    run_a_cell(kali)
    served = first["served"]
    assert isinstance(served, int) and ask(path)["served"] == served + 2
    monkeypatch.delenv(launcher.SPAWNER_ENV)
    run_a_cell(kali)
    assert ask(path)["served"] == served + 3


def test_a_spawner_socket_nobody_answers_is_passed_over(
    kali: Callable[..., str], monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    """``$KALI_SPAWNER`` naming a socket no spawner holds (one left by a killed one, or none
    at all): the start starts its own spawner and the cell runs."""
    stale = tmp_path / "stale.sock"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as left:
        left.bind(str(stale))  # bound, never listening: a connection is refused
        for path in (stale, tmp_path / "none.sock"):
            assert launcher._warm_spawner(str(path)) is None
            monkeypatch.setenv(launcher.SPAWNER_ENV, str(path))
            run_a_cell(kali)


@pytest.mark.serial
def test_a_start_of_a_process_per_daemon_starts_its_own_spawner(
    kali: Callable[..., str],
) -> None:
    """A lockstep start with a process per daemon (as a real-time start) takes no connection
    of the warm spawner: each of its processes imports, and maps, only what it uses."""
    path = os.environ[launcher.SPAWNER_ENV]
    served = ask(path)["served"]
    with Kali(kali(separate=True)) as k:
        k.ready(["left"])
        step_kali_clock(k.inst, 20)
    assert ask(path)["served"] == served + 1  # this look only
