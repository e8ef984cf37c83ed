"""A user's Python file imported as a module of its own: a servo plugin (``plugins:``), a TG
function plugin (``tg_functions:``) or a robot type (``robots[].model: arm.py``), named in the
config; and ``guarded``, the bounds every run of such code outside the cycle is held to.

Each file becomes one module named after its path, so two files may share a name, and is
registered in ``sys.modules`` (dataclasses and pickling look modules up there).  Outside any
cycle: once per process while it parses the config.
"""

from __future__ import annotations

import importlib.util
import marshal
import os
import re
import signal
import sys
import threading
import traceback
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from types import FrameType, ModuleType

from .errors import ConfigError

# Longest a user file may take to load and be checked (its import, ``register``, the checks
# of its ROBOT): a real one takes well under a second (Pinocchio and MuJoCo load its URDF);
# $KALI_USER_CODE_S sets another
USER_CODE_ENV = "KALI_USER_CODE_S"
USER_CODE_S = 10.0


def user_code_s() -> float:
    """The time limit of ``guarded`` code: $KALI_USER_CODE_S if it is a time in (0, 600] s,
    else USER_CODE_S."""
    try:
        value = float(os.environ.get(USER_CODE_ENV, USER_CODE_S))
    except ValueError:
        return USER_CODE_S
    return value if 0.0 < value <= 600.0 else USER_CODE_S


class _Overtime(BaseException):
    """Raised in the main thread when guarded user code outlives its time (a BaseException,
    so the code's own ``except Exception`` does not swallow it)."""


def import_file(path: Path, prefix: str) -> ModuleType | None:
    """The module of the Python file at ``path`` (absolute), named ``prefix_<stem>_<crc>``;
    None if it cannot be a module (not a Python file).  Whatever its code raises is raised
    again, the half-made module forgotten, for the caller to say which file it was."""
    stem = re.sub(r"\W", "_", path.stem)
    name = f"{prefix}_{stem}_{zlib.crc32(str(path).encode()):08x}"
    spec = importlib.util.spec_from_file_location(name, path)
    if spec is None or spec.loader is None:
        return None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def compile_file(source: str, origin: str, target: Path) -> None:
    """Compile ``source`` (the text of the user's file ``origin``, named so in tracebacks)
    and write its code to ``target`` (marshal), for ``import_compiled``; SyntaxError as
    ``compile`` raises it."""
    code = compile(source, origin, "exec", dont_inherit=True)
    target.write_bytes(marshal.dumps(code))


def import_compiled(path: Path, name: str, origin: str) -> ModuleType:
    """The module of the code ``compile_file`` wrote to ``path``, named ``name`` (its
    ``__file__`` the user's ``origin``): no parse, no compile, so a process loads it in
    ~50 µs here where an import of the source costs ~1 ms.  Whatever its code raises is
    raised again, the half-made module forgotten."""
    code = marshal.loads(path.read_bytes())
    module = ModuleType(name)
    module.__file__ = origin
    sys.modules[name] = module
    try:
        exec(code, module.__dict__)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def mirror(root: str | Path, path: Path) -> Path:
    """Where the instance's copy of the user file ``path`` (absolute) lives under ``root``
    (``kali_daemons.tools.snapshot``): at its absolute path below it, so files a user file finds
    relative to itself are found beside the copy."""
    return Path(root) / path.relative_to(path.anchor)


_active = threading.local()  # whether a guarded block runs in this thread already


@contextmanager
def guarded(what: str, path: Path | None = None, seconds: float | None = None) -> Iterator[None]:
    """Run a block that runs user code (a file's import, its ``register``, the checks of its
    ROBOT) so that it cannot end the process or hang it: a ``sys.exit`` in it is a
    ConfigError, and so is a block still running after ``seconds``; each names ``what`` and
    the line of ``path`` the code was at.

    The time is kept by SIGALRM, so only in the main thread (``kalictl``, the daemons, a
    program's main thread); elsewhere, and inside another guarded block, the outer bound
    holds.  ``seconds``: default ``user_code_s()``.  Outside any cycle."""
    seconds = user_code_s() if seconds is None else seconds
    timed = threading.current_thread() is threading.main_thread() and not getattr(
        _active, "on", False
    )
    previous = None
    if timed:

        def overtime(_sig: int, _frame: FrameType | None) -> None:
            raise _Overtime

        previous = signal.signal(signal.SIGALRM, overtime)
        # again every second after the first: code that catches the first is stopped anyway
        signal.setitimer(signal.ITIMER_REAL, seconds, 1.0)
        _active.on = True
    try:
        yield
    except SystemExit as exc:
        raise ConfigError(
            f"{what}: its code called sys.exit({exc.code!r}){_line(exc, path)}; a robot type "
            f"or plugin file only defines things, it must not end the process loading it"
        ) from None
    except _Overtime as exc:
        raise ConfigError(
            f"{what}: still running after {seconds:g} s{_line(exc, path, 'stopped at')}; a "
            f"robot type or plugin file must load in well under that (a loop?)"
        ) from None
    finally:
        if timed:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, previous)
            _active.on = False


def _line(exc: BaseException, path: Path | None, how: str = "at") -> str:
    """`` (<how> line N of PATH)`` for the deepest frame of ``exc`` in ``path``, or ''."""
    if path is None:
        return ""
    line = None
    for frame in traceback.extract_tb(exc.__traceback__):
        if Path(frame.filename) == path:
            line = frame.lineno
    return "" if line is None else f" ({how} line {line} of {path})"
