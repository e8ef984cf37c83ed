"""Servo plugins loaded into a running instance (``kalictl servo load FILE``,
``kali.servo.load(path)``): thesis 3.4's table of servo algorithms extended while the arms
run, as Polymetis swaps a policy and ros2_control loads a controller.

The arena is laid out before any process starts, so it holds spares (``layout``'s
``SERVO_LOADABLE`` joint servos, ``ARM_LOADABLE`` robot-level ones, ``MAX_LOADS`` files) and a
table of the files loaded.  A client ``offer``s a file, checked first as a plugin the config
names is (imported, each algorithm registered, its step run once at its defaults), then more:
its step's cost against the servo period, the cost of loading it against the gap an SV loads
it in, and (given) the schedulability check.  Then its compiled code goes into the instance's
directory, every joint's (robot's) record of each algorithm is initialised in the spares,
the names are written, and the entry offered.  Each SV takes it after a cycle, once that
tick is acknowledged (``take``: the compiled code executed, its algorithms registered at the
entry's indices, their records viewed), and says so in the entry; the client returns once
every SV has it, and only then may a servo be selected or tried in shadow.  The other
readers (the dynamics process, the recorder, clients) take an entry once every SV has said.
An entry an SV could not take stays, its algorithms refusing in every process
(``Registry.stand_in``).  Loads are serialised by the table's lock, held to the end.
"""

from __future__ import annotations

import re
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ..core import atomic, layout
from ..core.errors import ConfigError, ServoError
from ..core.layout import LoadState
from ..core.pyfile import compile_file, guarded, import_compiled
from ..core.spinlock import SpinLock
from ..runtime.instance import decode
from ..runtime.paths import instance_dir
from .algorithms.algorithm import JointInfo, initialise, step_cost_us
from .algorithms.registry import Registry
from .level import ServoLevel

LOAD_TIMEOUT_S = 5.0  # how long a loading client waits for every SV to take the file
LOCK_TIMEOUT_S = LOAD_TIMEOUT_S + 1.0  # for the table's lock, held through another's load
# an SV loads a file in the gap after its cycle: its cost (what ``take`` does, on the
# loading client's CPU clock) may be this share of a servo period, the rest of the gap left
GAP_SHARE = 0.5
STEP_SHARE = 1.0  # a step of a loaded servo must take less than this share of a period
TAKEN, COULD_NOT = 1, 2
_WORD = re.compile(r"\W")  # ``SERVO_LOAD.taken``: SV k registered it, or could not

# (cost of a step, µs) -> None, or ScheduleError: the schedulability check of running it
Guard = Callable[[str, float], None]


@dataclass(frozen=True)
class Loaded:
    """A plugin file loaded while running, as ``ServoClient.loaded`` lists it."""

    file: str  # the file the user named
    servos: list[str]  # what it registered, joint servos first
    verdict: str | None  # '' every SV has it; else why one could not; None: not said yet


def module_name(inst_name: str, entry: int) -> str:
    """The module a loaded file's code becomes in every process: one per instance and entry."""
    return f"kali_loaded_servo_{_WORD.sub('_', inst_name)}_{entry}"


def verdict(level: ServoLevel, entry: int) -> str | None:
    """Entry ``entry`` as the SVs left it: '' if every SV has taken it, the reason if one
    could not, None while some SV has not said yet."""
    e = level.loads["entries"][entry]
    taken = e["taken"][: max(1, int(level.ctrl["sv_count"]))]
    if (taken == COULD_NOT).any():
        return decode(bytes(e["reason"])) or "an SV could not load it"
    if (taken == TAKEN).all():
        return ""
    return None


def take(level: ServoLevel, sv: int | None = None) -> int:
    """Take the entries of the loads table ``level`` has not yet (outside the cycle): SV
    ``sv`` every offered one, saying in the entry whether it could; any other reader (None)
    those every SV has said of.  Returns how many were taken."""
    loads = level.loads
    before = level.taken
    while level.taken < int(loads["generation"]):
        k = level.taken
        e = loads["entries"][k]
        if int(e["state"]) != LoadState.OFFERED:
            break
        if sv is None:  # a reader: what every SV said
            said = verdict(level, k)
            if said is None:
                break
            if said:
                _hold(level, k, said)
            else:
                _register(level, k)
        else:
            why = _register(level, k)
            if why:
                text = f"sv.{sv}: {why}".encode()[: layout.SERVO_LOAD["reason"].itemsize]
                loads["entries"]["reason"][k] = text
            loads["entries"]["taken"][k, sv] = COULD_NOT if why else TAKEN
        level.taken = k + 1
    if level.taken != before:
        level.view_loaded()
    return level.taken - before


def _register(level: ServoLevel, k: int) -> str:
    """Import entry ``k``'s compiled code and register its algorithms at the entry's
    indices; '' when done, else why not (its indices then held by stand-ins)."""
    e = level.loads["entries"][k]
    registry = level.registry
    origin = decode(bytes(e["origin"]))
    names = [n for n in decode(bytes(e["names"])).split(",") if n]
    n0, a0 = len(registry), len(registry.arms)
    why = ""
    if (n0, a0) != (int(e["joint_first"]), int(e["arm_first"])):
        why = (
            f"its servos are numbered from {int(e['joint_first'])} (robot-level "
            f"{int(e['arm_first'])}), this process has {n0} ({a0})"
        )
    else:
        try:
            got = _import(level, k, registry, origin, Path(decode(bytes(e["path"]))))
        except ConfigError as exc:
            got, why = [], _bare(exc)
        if not why and got != names:
            registry.truncate(n0, a0)
            why = f"{origin} registered {', '.join(got)} here, {', '.join(names)} when loaded"
    if why:
        _hold(level, k, why)
    return why


def _bare(exc: ConfigError) -> str:
    """``exc``'s message without its subsystem's prefix."""
    return str(exc).removeprefix(f"{exc.subsystem}: ")


def _hold(level: ServoLevel, k: int, why: str) -> None:
    """Entry ``k``'s indices held by stand-ins that refuse, saying ``why``."""
    e = level.loads["entries"][k]
    names = [n for n in decode(bytes(e["names"])).split(",") if n]
    n_joint, n_arm = int(e["n_joint"]), int(e["n_arm"])
    level.registry.stand_in(names[:n_joint], names[n_joint : n_joint + n_arm], why)


def _import(level: ServoLevel, k: int, registry: Registry, origin: str, path: Path) -> list[str]:
    """Entry ``k``'s module (``import_compiled``) registered into ``registry``, guarded;
    ConfigError naming ``origin`` for whatever fails."""
    with guarded(f"plugin {origin!r}"):
        try:
            module = import_compiled(path, module_name(level.inst.name, k), origin)
        except Exception as exc:
            raise ConfigError(
                f"plugin {origin!r}: import failed: {type(exc).__name__}: {exc}"
            ) from exc
        return registry.load_module(origin, module)


def offer(
    level: ServoLevel,
    source: str,
    origin: str,
    pause: Callable[[], None] | None = None,
    guard: Guard | None = None,
) -> list[str]:
    """Load the plugin whose text is ``source`` (the user's file ``origin``) into every SV
    of ``level``'s instance and return the names it registered (module docstring).
    ``pause`` lets a tick pass where the clock is stepped (a lockstep program); without it
    and with the clock stopped, the file is offered and the SVs take it at their next tick.
    ServoError naming the file and what it failed, before anything is offered, for a file
    that does not load, registers nothing new, a step that raises, returns a non-finite
    torque or is too slow for the servo period, a load too slow for the gap after a cycle,
    or no spare left; after offering, for an SV that could not take it."""
    inst = level.inst
    lock = SpinLock(_lock_address(level), "servo loads table")
    lock.acquire(LOCK_TIMEOUT_S)
    try:
        _settle_earlier(level, pause)
        k = int(level.loads["generation"])
        if k >= layout.MAX_LOADS:
            raise ServoError(
                f"load {origin!r}: {layout.MAX_LOADS} plugin files are loaded already, the "
                f"most an instance holds; name it in the config's plugins and restart"
            )
        folder = instance_dir(inst.name) / "loaded"
        folder.mkdir(parents=True, exist_ok=True)
        path = folder / f"{k}-{_WORD.sub('_', Path(origin).stem)}.code"
        try:
            compile_file(source, origin, path)
        except SyntaxError as exc:
            raise ServoError(
                f"load {origin!r}: syntax error at line {exc.lineno}: {exc.msg}"
            ) from None
        registry = level.registry
        n0, a0 = len(registry), len(registry.arms)
        try:
            names = _import(level, k, registry, origin, path)
        except ConfigError as exc:
            raise ServoError(f"load {_bare(exc).removeprefix('plugin ')}") from None
        try:
            _check(level, origin, path, n0, a0, guard)
        except BaseException:
            registry.truncate(n0, a0)
            raise
        level.view_loaded()
        _initialise(level, n0, a0)
        _publish(level, k, path, origin, names, n0, a0)
        level.taken = k + 1
        why = _await(level, k, pause)
        if why:
            joint, arm = registry.names()[n0:], registry.arm_names()[a0:]
            registry.truncate(n0, a0)
            registry.stand_in(joint, arm, why)
            raise ServoError(f"load {origin!r}: offered, but {why}")
        return names
    finally:
        lock.release()


def _lock_address(level: ServoLevel) -> int:
    found = level.inst.arena.lookup(layout.KEY_SERVO_LOADS)
    assert found is not None
    return level.inst.arena.address_of_field(found[0], layout.SERVO_LOADS, "lock")


def _settle_earlier(level: ServoLevel, pause: Callable[[], None] | None) -> None:
    """Take every entry before this load's: one offered by a client that went away before
    every SV had it is settled once they have."""
    while True:
        take(level)
        k = level.taken
        if k >= int(level.loads["generation"]):
            return
        if _await(level, k, pause) is None:
            raise ServoError(
                f"load: plugin file {k} of this instance was offered and not every SV has "
                f"taken it yet: the clock is stopped (lockstep: kalictl clock step 1)"
            )


def _check(
    level: ServoLevel, origin: str, path: Path, n0: int, a0: int, guard: Guard | None
) -> None:
    """What a file loaded while running must pass beyond a start-up plugin's checks
    (``offer``); ServoError naming the file, the servo, the figure and the limit."""
    registry = level.registry
    new = registry.names()[n0:] + registry.arm_names()[a0:]
    if not new:
        raise ServoError(f"load {origin!r}: it registered no servo")
    spare = (
        layout.SERVO_LOADABLE - (n0 - level.configured[0]),
        layout.ARM_LOADABLE - (a0 - level.configured[1]),
    )
    counts = (len(registry) - n0, len(registry.arms) - a0)
    for kind, count, left in zip(("joint", "robot-level"), counts, spare, strict=True):
        if count > left:
            raise ServoError(
                f"load {origin!r}: it registers {count} {kind} servos, {left} of the "
                f"instance's spares are left; name it in the config's plugins and restart"
            )
    period_us = level.servo_period_s * 1e6
    worst = 0.0
    for a in range(n0, len(registry)):
        try:
            cost = step_cost_us(registry[a], level.servo_period_s)
        except Exception as exc:
            raise ServoError(
                f"load {origin!r}: servo '{registry[a].name}' raised {type(exc).__name__}: "
                f"{exc} when stepped at its defaults on a small error"
            ) from None
        if cost >= STEP_SHARE * period_us:
            raise ServoError(
                f"load {origin!r}: servo '{registry[a].name}' takes {cost:.0f} µs a step, "
                f"the servo period is {period_us:.0f} µs: too slow to run at all"
            )
        worst = max(worst, cost)
    cost = load_cost_us(path, origin)
    if cost > GAP_SHARE * period_us:
        raise ServoError(
            f"load {origin!r}: loading it takes {cost:.0f} µs, more than the "
            f"{GAP_SHARE * period_us:.0f} µs an SV may spend between two servo ticks "
            f"({GAP_SHARE:g} of the period); move slow work out of its module's top level "
            f"or name it in the config's plugins"
        )
    if guard is not None and worst > 0.0:
        guard(f"load {origin!r} (a joint running '{registry[n0].name}')", worst)


def load_cost_us(path: Path, origin: str, tries: int = 3) -> float:
    """What ``take`` costs an SV for the file compiled at ``path``: its code executed and
    registered into a scratch registry, the least of ``tries``, µs of this process's CPU."""
    best = float("inf")
    for n in range(tries):
        name = f"kali_loaded_servo_probe_{n}"
        t0 = time.thread_time_ns()
        try:
            module = import_compiled(path, name, origin)
            Registry(builtins=False).load_module(origin, module)
        except (ConfigError, Exception):
            return 0.0  # it loaded a moment ago: a file that changes its mind is not timed
        finally:
            sys.modules.pop(name, None)
        best = min(best, (time.thread_time_ns() - t0) / 1000.0)
    return best


def _initialise(level: ServoLevel, n0: int, a0: int) -> None:
    """Every joint's record of each new joint servo, every robot's of each new robot-level
    one, at the algorithm's defaults; their names in the arena.  Nobody runs them yet."""
    registry, period = level.registry, level.servo_period_s
    robots = level.cfg.robots
    joints = [
        JointInfo(robots[level.map.robot_of[i]].name, level.map.joint_of[i] + 1,
                  robots[level.map.robot_of[i]].type)
        for i in range(level.n)
    ]  # fmt: skip
    for a in range(n0, len(registry)):
        for i in range(level.n):
            initialise(registry[a], level.structs[i][a], {}, period, joints[i])
        level.servo_names[a]["name"] = registry[a].name.encode()[:31]
    for a in range(a0, len(registry.arms)):
        for r in range(level.n_robots):
            registry.arms[a].init(level.arm_data[r][a], {}, period)
        level.servo_names[level.arm_names_at + a]["name"] = registry.arms[a].name.encode()[:31]


def _publish(
    level: ServoLevel, k: int, path: Path, origin: str, names: list[str], n0: int, a0: int
) -> None:
    """Write entry ``k`` whole, then its state, then the table's generation: an SV reads
    the generation, then the entry."""
    entries = level.loads["entries"]
    registry = level.registry
    entries["joint_first"][k], entries["n_joint"][k] = n0, len(registry) - n0
    entries["arm_first"][k], entries["n_arm"][k] = a0, len(registry.arms) - a0
    entries["taken"][k] = 0
    entries["path"][k] = str(path).encode()
    entries["origin"][k] = origin.encode()[: layout.SERVO_LOAD["origin"].itemsize]
    entries["names"][k] = ",".join(names).encode()
    entries["reason"][k] = b""
    arena = level.inst.arena
    offset = arena.lookup(layout.KEY_SERVO_LOADS)[0]  # type: ignore[index]
    entry = arena.address_of_field(offset, layout.SERVO_LOADS, "entries")
    atomic.store32(entry + k * layout.SERVO_LOAD.itemsize, LoadState.OFFERED)  # state: first
    atomic.store32(arena.address_of_field(offset, layout.SERVO_LOADS, "generation"), k + 1)


def _await(level: ServoLevel, k: int, pause: Callable[[], None] | None) -> str | None:
    """Wait until every SV has said of entry ``k``: '' if all took it, else the reason;
    None where nobody runs the SVs (the clock stopped, no ``pause``)."""
    deadline = time.monotonic() + LOAD_TIMEOUT_S
    while (why := verdict(level, k)) is None:
        running = int(level.inst.clock["mode"]) != layout.RunMode.STOPPED
        if pause is not None and not running and level.inst.lockstep:
            pause()
        elif not running:
            return None
        elif time.monotonic() > deadline:
            waiting = [
                f"sv.{n}"
                for n, t in enumerate(level.loads["entries"][k]["taken"])
                if n < int(level.ctrl["sv_count"]) and t == 0
            ]
            raise ServoError(
                f"load: {', '.join(waiting)} did not take the file within "
                f"{LOAD_TIMEOUT_S:g} s (are they running?)"
            )
        else:
            time.sleep(0.001)
    return why
