"""A user's Python file imported as a module of its own: a servo plugin (``plugins:``) or a
robot type (``robots[].model: arm.py``), named in the config.

Each file becomes one module named after its path, so two files may share a name, and is
registered in ``sys.modules`` (dataclasses and pickling look modules up there).  Outside any
cycle: once per process while it parses the config.
"""

from __future__ import annotations

import importlib.util
import re
import sys
import zlib
from pathlib import Path
from types import ModuleType


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
