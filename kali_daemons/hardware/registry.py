"""Hardware kinds, found by name: what stands behind an arm (docs/decisions/0015).

A kind is a package under ``kali_daemons/hardware`` whose ``KIND`` declares it; the config
names one per robot (``hardware: {kind: mcgill}``, the default), the way it names a robot
type (thesis 3.5: Kali's driver table).
"""

from __future__ import annotations

import difflib
import importlib
import re
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache
from importlib import resources
from typing import Any

import numpy as np

from ..core.arena import Arena
from ..core.errors import ConfigError
from ..core.layout import HARDWARE_KEYS, MAX_JOINTS, Record, dtypes_digest
from .interface import Hardware, Operations

DEFAULT_KIND = "mcgill"
KIND_NAME = re.compile(r"[a-z][a-z0-9_]{0,23}")  # a kind's name: its package's


@dataclass(frozen=True)
class HardwareKind:
    """One kind of hardware behind an arm."""

    name: str
    description: str  # one line, for ``kalictl types`` and error messages
    channels: int  # the joints one arm's hardware carries: an arm may have at most these
    # what any process may do on an instance's arena of ``n`` robots, outside any cycle
    operations: Callable[[Arena, int], Operations]
    # what SIO drives each servo tick: attached to the arena for the config's cell, with
    # ``servo_ticks(ms)`` (at least ``ms`` of servo ticks) and ``semaphore(process)`` (that
    # process's wake-up semaphore); HardwareError if it does not answer
    drive: Callable[[Arena, Any, Callable[[float], int], Callable[[str], Any]], Hardware]
    records: tuple[Record, ...] = ()  # its arena records, keyed hw.<name>.* (layout.Cell)
    # one link process per arm (``kali_daemons.link``, named link.<robot>): it holds the
    # robot's connection, and the first arm's link's packets pace the wall clock
    links: bool = False
    # an arm may have a hand of its own process (hand.<robot>, ``kali_daemons.link``), named
    # by the config's hardware.hand
    hands: bool = False
    # the hardware holds its arms against gravity itself: the feed-forward leaves gravity out
    compensates_gravity: bool = False
    # where it takes an arm's wrist wrench from (``ftsensor.SOURCES``): a sensor's gauges on
    # its ADC, a model of the arm on its joint torques, the robot's own estimate
    wrist: tuple[str, ...] = ("gauges",)
    # why it cannot drive an arm of a robot type at a servo period (s), or "" if it can
    refuses: Callable[[Any, float], str] = lambda rtype, period_s: ""
    # the cell's simulated plant: ``module:Class`` under kali_daemons (its own process runs
    # ``python -m kali_daemons.<module>``; the lockstep executive hosts the class)
    simulator: str = "plant:Plant"

    def __post_init__(self) -> None:
        if any(not isinstance(r.dtype, np.dtype) for r in self.records):
            raise ConfigError(f"hardware kind {self.name!r}: each record has one fixed dtype")
        prefix = f"{HARDWARE_KEYS}{self.name}."
        if any(not r.key.startswith(prefix) for r in self.records):
            raise ConfigError(f"hardware kind {self.name!r}: every record's key starts {prefix}")
        if not 1 <= self.channels <= MAX_JOINTS:
            raise ConfigError(
                f"hardware kind {self.name!r} carries {self.channels} joints per arm; "
                f"Kali's per-arm records hold 1 .. {MAX_JOINTS}"
            )

    @property
    def version(self) -> int:
        """Its records' digest: stored in the arena's cell record at start, so a process of
        another version refuses the arena instead of misreading a register."""
        return dtypes_digest([(r.key, r.dtype) for r in self.records])


def known_kinds() -> list[str]:
    """The names of the hardware kinds shipped with Kali: the packages here with a ``KIND``."""
    return sorted(
        p.name
        for p in resources.files(__name__.rpartition(".")[0]).iterdir()
        if p.is_dir() and (p / "__init__.py").is_file()
    )


@cache
def hardware_kind(name: str) -> HardwareKind:
    """The hardware kind ``name``; ``ConfigError`` naming the kinds there are if there is
    none (with the nearest as a suggestion)."""
    names = known_kinds()
    if not isinstance(name, str) or not KIND_NAME.fullmatch(name) or name not in names:
        near = difflib.get_close_matches(str(name), names, n=1)
        hint = f" (did you mean {near[0]!r}?)" if near else ""
        raise ConfigError(f"no hardware kind {name!r}{hint}; the kinds are: {', '.join(names)}")
    kind = importlib.import_module(f"{__name__.rpartition('.')[0]}.{name}").KIND
    if not isinstance(kind, HardwareKind) or kind.name != name:
        raise ConfigError(f"hardware package {name!r} declares no KIND = HardwareKind({name!r})")
    return kind
