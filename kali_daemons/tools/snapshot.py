"""The user files an instance runs on: copies taken once, at ``kalictl start``.

Each robot type file the config names (``robots[].model: arm.py``) with its URDF and the
meshes that URDF names, its scene file, each servo plugin file and each TG function plugin
file is copied into the instance's directory (``paths.instance_dir``), at its absolute path
below ``files/`` (``pyfile.mirror``), so a file that finds its URDF beside itself
(``Path(__file__).with_name``) finds the copy.  Every process of the instance, every program
and every kalictl command then loads the copies (``KaliConfig.files``): moving, editing or
breaking a file after start changes nothing until the next start.  The config's own text is
in the arena.

A robot type that names its URDF by an absolute path outside the copies would read the file
where it is, so it is refused, naming the path.  Outside any cycle.
"""

from __future__ import annotations

import dataclasses
import shutil
import xml.etree.ElementTree as ET
from pathlib import Path
from typing import TYPE_CHECKING

from ..core.errors import ConfigError
from ..core.pyfile import mirror
from ..robots import is_type_file
from ..servo.algorithms.registry import plugin_file

if TYPE_CHECKING:
    from ..runtime.config import KaliConfig

MAX_COPY_BYTES = 256 << 20  # all of an instance's user files; a URDF's meshes are the bulk
# Kali's own files (its package, and the source tree's config/ in a checkout) and whatever is
# installed beside it: not the user's, never copied
KALI_HOME = Path(__file__).resolve().parents[2]


def _users(path: Path) -> bool:
    """Whether ``path`` is a user's file rather than Kali's or an installed package's."""
    return not path.is_relative_to(KALI_HOME)


def user_files(cfg: KaliConfig) -> list[Path]:
    """The files ``cfg`` loads from outside Kali, absolute, each once: its robot type files,
    their URDFs and meshes, its scene file, its servo and TG function plugin files."""
    found: dict[Path, None] = {}
    for r in cfg.robots:
        if is_type_file(r.model):
            found[Path(r.model)] = None
            urdf = Path(r.type.urdf).resolve()
            for path in (urdf, *_meshes(urdf)):
                found[path] = None
    scene = Path(cfg.scene.source).resolve()
    if _users(scene):
        found[scene] = None
    base = Path(cfg.base_dir)
    for spec in (*cfg.plugins, *cfg.tg_functions):
        plugin = plugin_file(spec, base)
        if plugin is not None:
            found[plugin] = None
    return list(found)


def _meshes(urdf: Path) -> list[Path]:
    """The mesh files a URDF names by a path (relative to the URDF, or absolute), that exist;
    ``package://`` and other URLs are the robot's installed packages, not copied."""
    try:
        root = ET.parse(urdf).getroot()
    except (ET.ParseError, OSError):
        return []  # the type's checks have loaded it: nothing more to find
    out = []
    for mesh in root.iter("mesh"):
        name = mesh.get("filename", "")
        if not name or "://" in name:
            continue
        path = (urdf.parent / name.removeprefix("file:")).resolve()
        if path.is_file():
            out.append(path)
    return out


def take(cfg: KaliConfig, root: Path) -> KaliConfig:
    """Copy ``cfg``'s user files under ``root`` (a new, private directory) and return ``cfg``
    reading them from there (``KaliConfig.files``), each copy loaded and checked once more
    here, as every process will load it; ConfigError naming a file that cannot be copied or
    a robot type whose copy would still read its URDF from the original."""
    files = user_files(cfg)
    total = 0
    for path in files:
        try:
            total += path.stat().st_size
        except OSError as exc:
            raise ConfigError(f"{cfg.source}: user file {path}: {exc.strerror}") from None
    if total > MAX_COPY_BYTES:
        raise ConfigError(
            f"{cfg.source}: the user files to copy for the instance take {total >> 20} MiB, at "
            f"most {MAX_COPY_BYTES >> 20} MiB (robot type files, URDFs and their meshes, plugins)"
        )
    for path in files:
        copy = mirror(root, path)
        copy.parent.mkdir(mode=0o700, parents=True, exist_ok=True)
        try:
            shutil.copyfile(path, copy)
        except OSError as exc:
            raise ConfigError(f"{cfg.source}: user file {path}: cannot copy: {exc}") from None
    robots = tuple(
        dataclasses.replace(r, model=str(mirror(root, Path(r.model))))
        if is_type_file(r.model)
        else r
        for r in cfg.robots
    )
    out = dataclasses.replace(cfg, robots=robots, files=str(root))
    for r in out.robots:
        if is_type_file(r.model):
            urdf = Path(r.type.urdf).resolve()  # loads and checks the copy
            if _users(urdf) and not urdf.is_relative_to(root):
                raise ConfigError(
                    f"{cfg.source}: robot '{r.name}': robot type file "
                    f"{r.model.removeprefix(str(root))} names its URDF {urdf} by a path of its "
                    f"own; Kali runs an instance on copies of its files taken at start, so name "
                    f"it relative to the file: Path(__file__).with_name('{urdf.name}')"
                )
    return out
