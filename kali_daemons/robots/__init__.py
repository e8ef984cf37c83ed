"""Robot types, found by name (thesis 3.1, 3.5).

``robot_type("puma560")`` imports ``kali_daemons.robots.puma560`` and returns its ``ROBOT``.
A type is one package here or, for a researcher's own arm, a module file named in the
config (``robot_type("/abs/path/arm.py")``, checked by ``typefile``); see ``profile.py`` for
what it declares.
"""

from __future__ import annotations

import importlib
import re
from functools import cache
from importlib import resources
from pathlib import Path

from ..core.errors import ConfigError
from .profile import MAX_JOINTS, Drive, Kinematics, RobotType
from .typefile import is_type_file, load_type_file

_NAME = re.compile(r"^[a-z][a-z0-9_]*$")


@cache
def robot_type(name: str) -> RobotType:
    """The robot type ``name``: a package under ``kali_daemons/robots``, or a module file
    (``is_type_file``: ends in .py; relative to the current directory, the
    config passes it absolute) defining ``ROBOT``.  Loaded once per process.  ``ConfigError``
    naming the types there if there is none, or the file and what is wrong with it."""
    if isinstance(name, str) and is_type_file(name):
        return _type_file(Path(name).expanduser().resolve())
    if not _NAME.match(name or ""):
        raise ConfigError(
            f"robot type {name!r}: not a type name ({_NAME.pattern}) nor a .py file path"
        )
    try:
        module = importlib.import_module(f"{__name__}.{name}")
    except ModuleNotFoundError as exc:
        if exc.name != f"{__name__}.{name}":
            raise
        raise ConfigError(
            f"robot type {name!r}: no such type (known: {', '.join(known_types())})"
        ) from None
    robot = getattr(module, "ROBOT", None)
    if not isinstance(robot, RobotType):
        raise ConfigError(f"robot type {name!r}: {module.__file__} defines no ROBOT RobotType")
    return robot


@cache
def _type_file(path: Path) -> RobotType:
    """``load_type_file`` once per resolved path (a second import would make a second type)."""
    return load_type_file(path)


def known_types() -> list[str]:
    """The names of the robot types shipped with Kali."""
    return sorted(
        p.name
        for p in resources.files(__name__).iterdir()
        if p.is_dir() and (p / "__init__.py").is_file()
    )


__all__ = [
    "MAX_JOINTS",
    "Drive",
    "Kinematics",
    "RobotType",
    "is_type_file",
    "known_types",
    "robot_type",
]
