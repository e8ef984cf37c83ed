"""Non-files under an instance's /dev/shm names (issue 51 item 7).

A symbolic link at the arena's name made ``status``, ``estop`` and ``stop`` die with a
traceback (ELOOP); a directory at a semaphore's name made ``stop`` die (IsADirectoryError);
a semaphore replaced by a directory while an instance ran made ``stop`` kill the daemons,
crash, and leave 13 /dev/shm objects, the arena among them.  Now each is refused or removed
with one line naming the object, and ``stop`` removes everything else whatever it meets.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from kali_daemons.runtime.instance import command_semaphore_name, slot_semaphore_name

from ..conftest import leftovers, unique_name
from ..test_launcher import kalictl


@pytest.fixture
def squat() -> Iterator[Callable[[Path, str], Path]]:
    """``squat(path, kind)``: make a symbolic link, an empty or a full directory at
    ``path``; whatever is left is removed afterwards."""
    made: list[Path] = []

    def make(path: Path, kind: str) -> Path:
        if kind == "symlink":
            path.symlink_to("/tmp/kali-nothing-here")
        else:
            path.mkdir()
            if kind == "full directory":
                (path / "inside").write_text("x")
        made.append(path)
        return path

    yield make
    for path in made:
        if path.is_symlink() or path.is_file():
            path.unlink()
        elif path.is_dir():
            for child in path.iterdir():
                child.unlink()
            path.rmdir()


def _no_traceback(r: object) -> None:
    text = r.stdout + r.stderr  # type: ignore[attr-defined]
    assert "Traceback" not in text, text


def test_a_symlink_at_the_arenas_name_is_named_not_followed(
    squat: Callable[[Path, str], Path],
) -> None:
    name = unique_name("sq")
    link = squat(Path(f"/dev/shm/kali.{name}"), "symlink")
    for args in (("status",), ("estop",), ("status", "--json")):
        r = kalictl("-i", name, *args)
        _no_traceback(r)
        assert r.returncode == 1 and str(link) in r.stderr and "symbolic link" in r.stderr, (
            args,
            r.stderr,
        )
    r = kalictl("-i", name, "stop")
    _no_traceback(r)
    assert r.returncode == 0 and f"instance '{name}' stopped" in r.stdout, r.stderr
    assert not link.is_symlink()  # this user's broken object under the name: removed
    assert leftovers(name) == ([], [])


@pytest.mark.parametrize("kind", ["empty directory", "full directory"])
def test_a_directory_at_a_semaphores_name_does_not_crash_stop(
    squat: Callable[[Path, str], Path], kind: str
) -> None:
    name = unique_name("sq")
    path = squat(Path(f"/dev/shm/sem{command_semaphore_name(name).replace('/', '.')}"), kind)
    r = kalictl("-i", name, "stop")
    _no_traceback(r)
    if kind == "empty directory":
        assert r.returncode == 0 and not path.exists(), r.stderr
    else:  # never emptied: what it holds is not Kali's
        assert r.returncode == 1 and path.exists(), r.stdout
        assert f"left {path}: a directory holding files" in r.stderr, r.stderr


@pytest.mark.serial
def test_a_semaphore_replaced_by_a_directory_while_running_still_stops_clean(
    kali: Callable[..., str], squat: Callable[[Path, str], Path]
) -> None:
    """The fixture's stop must leave nothing: every process, the arena, every semaphore and
    the squat (an empty directory of this user under the instance's name) are gone."""
    name = kali(lockstep=False)
    sem = Path(f"/dev/shm/sem{slot_semaphore_name(name, 3).replace('/', '.')}")
    assert sem.is_file()
    sem.unlink()
    squat(sem, "empty directory")
    r = kalictl("-i", name, "estop")
    _no_traceback(r)
    assert r.returncode == 0, r.stderr
    r = kalictl("-i", name, "status")
    _no_traceback(r)
    assert r.returncode == 0 and "ESTOP" in r.stdout, r.stderr
    r = kalictl("-i", name, "stop")
    _no_traceback(r)
    assert r.returncode == 0, r.stderr
    assert leftovers(name) == ([], []) and not sem.exists()  # no daemon, no object
