"""Where an instance keeps its files: the daemons' logs and flight dumps (``log_dir``), its
own directory of copied user files (``instance_dir``) and the lifecycle locks
(``runtime_dir``), each checked private before use.  Outside any cycle.
"""

from __future__ import annotations

import os
import stat
from pathlib import Path

from ..core.arena import user_text
from ..core.errors import InstanceError


def log_dir(instance: str) -> Path:
    """Where the daemons' logs and flight dumps go: ``$KALI_LOG_DIR/<instance>`` or
    ``/tmp/kali-<instance>``: one directory per instance, so two instances never write the
    same ``<process>.log`` (one KALI_LOG_DIR shared by two instances interleaved them)."""
    base = os.environ.get("KALI_LOG_DIR")
    return Path(base) / instance if base else Path(f"/tmp/kali-{instance}")


def private_log_dir(path: Path) -> Path:
    """Create the log directory ``path`` (mode 0700) or check the one there: it must be a real
    directory (not a symbolic link) of this user that neither group nor others can write, so
    no other user can plant a link the daemons' logs or flight dumps would follow, or swap
    the files; InstanceError naming the directory and its owner otherwise."""
    return private_dir(path, "log directory", "KALI_LOG_DIR")


def private_dir(path: Path, what: str, env: str) -> Path:
    """Create ``path`` (mode 0700) or check it is a real directory of this user that neither
    group nor others can write; InstanceError naming it, its owner and ``env`` otherwise."""
    path.mkdir(mode=0o700, parents=True, exist_ok=True)
    st = os.lstat(path)
    if not stat.S_ISDIR(st.st_mode):
        raise InstanceError(f"{what} {path} is not a directory (a symbolic link?)")
    if st.st_uid != os.geteuid():
        raise InstanceError(
            f"{what} {path} belongs to {user_text(st.st_uid)}, not {user_text()}: "
            f"remove it or set {env} to a directory of your own"
        )
    if st.st_mode & 0o022:
        raise InstanceError(
            f"{what} {path} has mode {stat.S_IMODE(st.st_mode):04o}: group or others "
            f"may write it; chmod go-w it or set {env}"
        )
    return path


def instance_dir(instance: str) -> Path:
    """The instance's own directory, ``<runtime dir>/<instance>``: the copies of the user
    files it runs on (``files/``, ``tools.snapshot``), made by ``kalictl start`` and
    removed by ``kalictl stop``."""
    return runtime_dir() / instance


def runtime_dir() -> Path:
    """Where the instances' lifecycle locks live: ``$KALI_RUNTIME_DIR``, else
    ``$XDG_RUNTIME_DIR/kali``, else ``/run/kali`` for root and ``/tmp/kali-run-<uid>``."""
    env = os.environ.get("KALI_RUNTIME_DIR")
    if env:
        return Path(env)
    xdg = os.environ.get("XDG_RUNTIME_DIR")
    if xdg:
        return Path(xdg) / "kali"
    return Path("/run/kali") if os.geteuid() == 0 else Path(f"/tmp/kali-run-{os.geteuid()}")
