"""TG functions (thesis 3.2.3: a position equation's transforms may be "objects and
functions"): a transform the trajectory generator computes every tick, inside its cycle, from
the time, the cell's sensors and its own private data in the arena.

A ``TgFunction`` is a name, the aligned dtype of its private data (its parameters are
fields), ``evaluate(data, t, sensors, out)`` (in the TG cycle: Python floats and the record
only, no arrays allocated, no I/O, no logging) and ``derive(data)`` (outside it, after its
parameters change).  The registry holds the built-ins, then the config's ``tg_functions``
plugins.  A function that raises, or in real time takes more than ``FUNCTION_SHARE`` of the
TG period, holds the motions using it (ABORTED); it runs on the TG's thread, so one that keeps
the TG past its deadline halts the cell (DEADLINE, naming it).  In lockstep an overlong
evaluation is only counted: wall time decides nothing there.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..core import atomic, layout, rt
from ..core.errors import ConfigError
from ..core.layout import FunctionStatus
from ..core.pyfile import guarded
from ..core.spinlock import pid_alive
from ..runtime.instance import decode
from ..servo.algorithms.algorithm import Param, check_dtype, defaults, resolve_params, struct_type
from ..servo.algorithms.registry import import_plugin, plugin_file

FUNCTION_SHARE = 0.2  # of the TG period one evaluation may take
_NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,31}")


class Sensors:
    """What a TG function may read, per robot in config order (read-only views of the
    arena, this tick's): ``q[k]`` the measured joint angles (rad), ``wrench[k]`` the contact
    wrench in world axes (N, N·m; zeros without a wrist sensor), ``names[k]``."""

    def __init__(self, names: Sequence[str], q: Sequence[np.ndarray], wrench: Sequence[np.ndarray]):
        self.names = list(names)
        self.q = [_read_only(a) for a in q]
        self.wrench = [_read_only(a) for a in wrench]


def _read_only(a: np.ndarray) -> np.ndarray:
    view = a.view()
    view.flags.writeable = False
    return view


def _nothing(data: Any) -> None:
    """No derived terms."""


@dataclass(frozen=True)
class TgFunction:
    """One function the TG can evaluate in a loop (see the module's docstring)."""

    name: str  # lower case, digits, '_', at most 32 characters
    dtype: np.dtype  # private data: an aligned structured dtype of numeric scalars
    params: tuple[Param, ...]  # each a field of ``dtype``
    evaluate: Callable[[Any, float, Sensors, np.ndarray], None]
    derive: Callable[[Any], None] = _nothing
    doc: str = ""


# ------------------------------------------------------------------------------ built-ins


CONVEYOR = TgFunction(
    "conveyor",
    np.dtype([(n, "<f8") for n in ("x", "y", "z", "vx", "vy", "vz")], align=True),
    (
        Param("x", 0.0, "m", "position at t = 0, world x", minimum=-10.0, maximum=10.0),
        Param("y", 0.0, "m", "position at t = 0, world y", minimum=-10.0, maximum=10.0),
        Param("z", 0.0, "m", "position at t = 0, world z", minimum=-10.0, maximum=10.0),
        Param("vx", 0.0, "m/s", "velocity, world x", minimum=-5.0, maximum=5.0),
        Param("vy", 0.0, "m/s", "velocity, world y", minimum=-5.0, maximum=5.0),
        Param("vz", 0.0, "m/s", "velocity, world z", minimum=-5.0, maximum=5.0),
    ),
    lambda d, t, s, out: _translate(out, d.x + d.vx * t, d.y + d.vy * t, d.z + d.vz * t),
    doc="a frame moving at constant velocity: (x, y, z) + (vx, vy, vz)·t",
)

LINE = TgFunction(
    "line",
    np.dtype(
        [(n, "<f8") for n in ("x0", "y0", "z0", "x1", "y1", "z1", "speed", "length")], align=True
    ),
    (
        Param("x0", 0.0, "m", "start, x", minimum=-10.0, maximum=10.0),
        Param("y0", 0.0, "m", "start, y", minimum=-10.0, maximum=10.0),
        Param("z0", 0.0, "m", "start, z", minimum=-10.0, maximum=10.0),
        Param("x1", 0.0, "m", "end, x", minimum=-10.0, maximum=10.0),
        Param("y1", 0.0, "m", "end, y", minimum=-10.0, maximum=10.0),
        Param("z1", 0.0, "m", "end, z", minimum=-10.0, maximum=10.0),
        Param("speed", 0.05, "m/s", "speed along the line", positive=True, maximum=5.0),
    ),
    lambda d, t, s, out: _along(d, t, out),
    derive=lambda d: setattr(d, "length", math.dist((d.x0, d.y0, d.z0), (d.x1, d.y1, d.z1))),
    doc="a point going from (x0, y0, z0) to (x1, y1, z1) at speed, then staying there",
)

SINE = TgFunction(
    "sine",
    np.dtype([(n, "<f8") for n in ("amplitude", "frequency_hz", "phase_rad", "axis")], align=True),
    (
        Param("amplitude", 0.01, "m", "of the offset", minimum=-1.0, maximum=1.0),
        Param("frequency_hz", 0.5, "Hz", "of the offset", maximum=50.0),
        Param("phase_rad", 0.0, "rad", "at t = 0", minimum=-10.0, maximum=10.0),
        Param("axis", 2.0, "", "0, 1, 2: along x, y or z of the frame before it", maximum=2.0),
    ),
    lambda d, t, s, out: _sine(d, t, out),
    doc="an offset amplitude·sin(2π·f·t + phase) along one axis",
)


def _translate(out: np.ndarray, x: float, y: float, z: float) -> None:
    out[0, 3] = x
    out[1, 3] = y
    out[2, 3] = z


def _along(d: Any, t: float, out: np.ndarray) -> None:
    s = 1.0 if d.length <= 0.0 else min(1.0, d.speed * t / d.length)
    _translate(out, d.x0 + s * (d.x1 - d.x0), d.y0 + s * (d.y1 - d.y0), d.z0 + s * (d.z1 - d.z0))


def _sine(d: Any, t: float, out: np.ndarray) -> None:
    out[min(2, max(0, round(d.axis))), 3] = d.amplitude * math.sin(
        2.0 * math.pi * d.frequency_hz * t + d.phase_rad
    )


# ------------------------------------------------------------------------------ registry


class FunctionRegistry:
    """TG functions by index (what ``TG_FUNCTION.algo`` stores, plus one) and name: the
    built-ins, then the plugins' in the order loaded.  Built outside the cycle."""

    def __init__(self) -> None:
        self._functions: list[TgFunction] = []
        self._source = "builtins"
        for fn in (CONVEYOR, LINE, SINE):
            self.register(fn)

    def __len__(self) -> int:
        return len(self._functions)

    def __getitem__(self, index: int) -> TgFunction:
        return self._functions[index]

    def names(self) -> list[str]:
        """Every function's name, in index order."""
        return [f.name for f in self._functions]

    def index(self, name: str) -> int:
        """The index of the function called ``name``; ConfigError naming the known ones."""
        for i, fn in enumerate(self._functions):
            if fn.name == name:
                return i
        raise ConfigError(f"tg function: none called {name!r}; known: {', '.join(self.names())}")

    def register(self, fn: TgFunction) -> None:
        """Add ``fn`` (a plugin's ``register(registry)`` calls this); ConfigError naming the
        plugin and what is wrong with it."""
        where = f"plugin {self._source!r}" if self._source != "builtins" else "builtins"
        if not isinstance(fn, TgFunction):
            raise ConfigError(f"tg function ({where}): {fn!r:.80} is not a TgFunction")
        what = f"tg function {fn.name!r} ({where})"
        if not isinstance(fn.name, str) or not _NAME_RE.fullmatch(fn.name):
            raise ConfigError(f"{what}: a name is lower case letters, digits and '_', ≤ 32")
        if fn.name in self.names():
            raise ConfigError(f"{what}: the name is taken")
        problem = check_dtype(fn.dtype)
        if problem:
            raise ConfigError(f"{what}: {problem}")
        if fn.dtype.itemsize > layout.FUNCTION_DATA_BYTES:
            raise ConfigError(
                f"{what}: private data is {fn.dtype.itemsize} B, at most "
                f"{layout.FUNCTION_DATA_BYTES} B (layout.FUNCTION_DATA_BYTES)"
            )
        for p in fn.params:
            if not isinstance(p, Param) or p.name not in (fn.dtype.names or ()):
                raise ConfigError(f"{what}: parameter {p!r:.60} is not a field of its dtype")
        if not (callable(fn.evaluate) and callable(fn.derive)):
            raise ConfigError(f"{what}: evaluate and derive must be functions")
        self._functions.append(fn)

    def load_plugin(self, spec: str, base_dir: Path | None, files: str = "") -> None:
        """Load plugin ``spec`` (a file or module defining ``register(registry)``; a file
        from the instance's copies under ``files`` when given), its code guarded
        (``pyfile.guarded``)."""
        path = plugin_file(spec, base_dir, files)
        with guarded(f"tg function plugin {spec!r}", path):
            self._load_plugin(spec, import_plugin(spec, path))

    def _load_plugin(self, spec: str, module: Any) -> None:
        """``load_plugin`` once the plugin is imported, inside its guard."""
        register = getattr(module, "register", None)
        if not callable(register):
            raise ConfigError(f"tg function plugin {spec!r}: defines no register(registry)")
        before = len(self._functions)
        self._source = spec
        try:
            register(self)
        except ConfigError:
            del self._functions[before:]
            raise
        except Exception as exc:
            del self._functions[before:]
            raise ConfigError(
                f"tg function plugin {spec!r}: register() raised {type(exc).__name__}: {exc}"
            ) from exc
        except BaseException:  # an exit or its time out (pyfile.guarded): none of it stays
            del self._functions[before:]
            raise
        finally:
            self._source = "builtins"


def registry_for(
    plugins: Sequence[str], base_dir: Path | str | None, files: str = ""
) -> FunctionRegistry:
    """The built-ins plus the config's ``tg_functions`` plugins, in order; files read from
    the instance's copies under ``files`` when given (``KaliConfig.files``)."""
    registry = FunctionRegistry()
    for spec in plugins:
        registry.load_plugin(spec, None if base_dir is None else Path(base_dir), files)
    return registry


# ------------------------------------------------------------------------------ slots


def data_of(slot: np.ndarray, fn: TgFunction) -> Any:
    """Function ``fn``'s private record in ``slot`` (a 0-d ``TG_FUNCTION`` view), as a
    ctypes structure over the arena (writes go through)."""
    # numpy's stubs give an ndarray the buffer protocol only from Python 3.12 on
    return struct_type(fn.dtype).from_buffer(slot["data"])  # type: ignore[arg-type]


def set_params(fn: TgFunction, data: Any, values: Mapping[str, float], fresh: bool) -> None:
    """Set ``values`` (the rest as they are, or at their defaults when ``fresh``) after
    checking them against the declared bounds, then ``derive``; ConfigError, nothing
    changed, for a bad value.  Outside the cycle."""
    base = defaults(fn.params) if fresh else get_params(fn, data)
    resolved = resolve_params(f"'{fn.name}'", fn.params, values, base, kind="tg function")
    for name, value in resolved.items():
        setattr(data, name, value)
    fn.derive(data)


def get_params(fn: TgFunction, data: Any) -> dict[str, float]:
    """Every parameter's current value."""
    return {p.name: float(getattr(data, p.name)) for p in fn.params}


class FunctionSlots:
    """The TG's side of ``tg.functions``: evaluate slot ``i`` for a motion, timed and
    guarded (a raise, or in real time an overlong evaluation, is reported, never raised;
    ``lockstep``: an overlong one is counted only)."""

    def __init__(self, records: np.ndarray, registry: FunctionRegistry, sensors: Sensors,
                 base_tick_ns: int, lockstep: bool = False) -> None:  # fmt: skip
        self.records = records
        self.registry = registry
        self.sensors = sensors
        self.tick_s = base_tick_ns * 1e-9
        self.budget_ns = 0  # set by the TG from its period
        self.lockstep = lockstep
        # 1 + the slot being evaluated (0: none): the TG binds its TG_STATE.phase_function
        self.evaluating = np.zeros(1, dtype=np.int32)
        self._seq = [records["seq"][i : i + 1].ctypes.data for i in range(len(records))]
        self._slots = [records[i : i + 1].reshape(()) for i in range(len(records))]

    def name(self, i: int) -> str:
        return decode(self.records["name"][i]) or f"#{i}"

    def bind(self, i: int) -> tuple[TgFunction, Any]:
        """(function, private data) of slot ``i`` for a motion about to start; ValueError
        naming why it cannot be used.  Outside the cycle."""
        slot = self._slots[i]
        pid = int(slot["owner_pid"])
        if pid <= 0 or not pid_alive(pid):
            raise ValueError(f"tg function #{i} is not set up by any running program")
        algo = int(slot["algo"]) - 1
        if not 0 <= algo < len(self.registry):
            raise ValueError(f"tg function '{self.name(i)}' names function {algo}, unknown here")
        fn = self.registry[algo]
        slot["function"] = fn.name.encode()
        slot["status"] = FunctionStatus.RUNNING
        return fn, data_of(slot, fn)

    def evaluate(self, i: int, fn: TgFunction, data: Any, now_tick: int, out: np.ndarray) -> str:
        """Evaluate slot ``i`` into ``out`` (left as it was while its program changes its
        parameters); why it failed ('' if it did not): it raised, or (real time only) it
        took longer than its budget.  In the cycle."""
        seq = atomic.load32(self._seq[i])
        if seq & 1:
            return ""
        slot = self._slots[i]
        t = (now_tick - int(slot["start_tick"])) * self.tick_s
        out[...] = _EYE
        self.evaluating[0] = i + 1  # whoever halts for a TG that stays in here names it
        t0 = rt.monotonic_ns()
        try:
            fn.evaluate(data, t, self.sensors, out)
        except Exception as exc:
            slot["status"] = FunctionStatus.RAISED
            return f"tg function '{self.name(i)}' ({fn.name}) raised {type(exc).__name__}: {exc}"
        finally:
            self.evaluating[0] = 0
        took = rt.monotonic_ns() - t0
        slot["last_ns"] = took
        slot["evaluations"] += 1
        if took > int(slot["worst_ns"]):
            slot["worst_ns"] = took
        if self.budget_ns and took > self.budget_ns:
            slot["over_budget"] += 1
            if self.lockstep:  # wall time decides nothing in lockstep (docs/guide/lockstep.md)
                return ""
            slot["status"] = FunctionStatus.TOO_LONG
            return (
                f"tg function '{self.name(i)}' ({fn.name}) took {took / 1e6:.1f} ms, more than "
                f"its {self.budget_ns / 1e6:.1f} ms ({FUNCTION_SHARE:.0%} of the TG period)"
            )
        return ""


_EYE = np.eye(4)
_EYE.flags.writeable = False
