"""The registry of servo algorithms by name (thesis 3.4, DESIGN 4); what one algorithm
declares is in ``algorithm``.

The registry holds the built-ins first (``pid`` = 0, ``pd`` = 1, ``builtins.py``), then the
plugins named in the config, in order.  A plugin is a Python file or module defining
``register(registry)``, which calls ``registry.register(ServoAlgorithm(...))``;
``kali_daemons/examples/servo_plugin_example.py`` is one to copy.
"""

from __future__ import annotations

import importlib
import importlib.util
import math
import re
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ...core.errors import ConfigError
from ...core.pyfile import guarded, import_file, mirror
from .algorithm import (
    ServoAlgorithm,
    check_dtype,
    initialise,
    step,
    struct_view,
)
from .arm import ArmServoAlgorithm, check_arm_dtype, probe_arm_step
from .builtins import register as register_builtins

_NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,31}")
_CALLABLES = ("init", "step", "handover", "set_params", "get_params")

# ------------------------------------------------------------------------------ registry


class Registry:
    """Servo algorithms by index and name: built-ins first (``pid`` 0, ``pd`` 1), then
    plugins in the order loaded.  The index is what the arena's servo slots store.

    Robot-level servos (``arm.ArmServoAlgorithm``) are registered alike and kept apart, with
    indices of their own (``arms``, ``arm_index``: what ``ROBOT_STATE.arm_algo`` stores);
    a name is unique across both kinds.

    Built outside the cycle (``registry_for``); afterwards read-only.
    """

    def __init__(self, builtins: bool = True) -> None:
        self._algos: list[ServoAlgorithm] = []
        self.arms: list[ArmServoAlgorithm] = []  # robot-level servos, by their index
        self._by_name: dict[str, int] = {}
        self._origin: dict[str, str] = {}
        self._source = "builtins"
        if builtins:
            register_builtins(self)

    # ---------------------------------------------------------------- lookup

    def __len__(self) -> int:
        return len(self._algos)

    def __iter__(self) -> Iterator[ServoAlgorithm]:
        return iter(self._algos)

    def __getitem__(self, index: int) -> ServoAlgorithm:
        """The algorithm at ``index`` (as stored in a servo slot); IndexError if none."""
        if not 0 <= index < len(self._algos):
            raise IndexError(f"servo algorithm index {index} outside 0..{len(self._algos) - 1}")
        return self._algos[index]

    def names(self) -> list[str]:
        """Every algorithm's name, in index order."""
        return [a.name for a in self._algos]

    def index(self, name: str) -> int:
        """The index of the algorithm called ``name``; ConfigError listing the known names."""
        try:
            return self._by_name[name]
        except KeyError:
            raise ConfigError(
                f"servo: no algorithm {name!r}; known: {', '.join(self.names())}"
            ) from None

    def by_name(self, name: str) -> ServoAlgorithm:
        """The algorithm called ``name``; ConfigError listing the known names."""
        return self._algos[self.index(name)]

    def origin(self, name: str) -> str:
        """Where the algorithm called ``name`` (of either kind) came from: "builtins" or the
        plugin spec."""
        if name not in self.arm_names():
            self.index(name)
        return self._origin[name]

    def arm_names(self) -> list[str]:
        """Every robot-level servo's name, in index order."""
        return [a.name for a in self.arms]

    def arm_index(self, name: str) -> int:
        """The index of the robot-level servo called ``name``; ConfigError naming them."""
        for i, algo in enumerate(self.arms):
            if algo.name == name:
                return i
        raise ConfigError(
            f"servo: no robot-level algorithm {name!r}; known: {', '.join(self.arm_names())}"
        )

    def dtypes(self) -> tuple[tuple[np.dtype, ...], tuple[np.dtype, ...]]:
        """The private-data dtypes of the joint servos and of the robot-level servos, each in
        index order (what the arena is laid out with)."""
        return tuple(a.dtype for a in self._algos), tuple(a.dtype for a in self.arms)

    def max_itemsize(self) -> int:
        """The largest private data record of any algorithm, bytes (sizes the arena)."""
        return max((a.dtype.itemsize for a in self._algos), default=0)

    # ---------------------------------------------------------------- registration

    def register(self, algo: ServoAlgorithm | ArmServoAlgorithm) -> int:
        """Add ``algo`` at the next index of its kind and return that index.

        Called by a plugin's ``register(registry)``.  ConfigError, naming the plugin (or
        builtins), the algorithm and the fault, if it is not a well-formed ServoAlgorithm or
        ArmServoAlgorithm.
        """
        where = f"plugin {self._source!r}" if self._source != "builtins" else "builtins"
        if not isinstance(algo, ServoAlgorithm | ArmServoAlgorithm):
            raise ConfigError(
                f"{where}: register() was given a {type(algo).__name__}, not a "
                f"ServoAlgorithm or an ArmServoAlgorithm"
            )
        name = algo.name
        if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
            raise ConfigError(
                f"{where}: algorithm name {name!r} must be lower case letters, digits and '_', "
                f"starting with a letter, at most 32 characters"
            )
        if name in self._by_name or name in self.arm_names():
            known = ", ".join(self.names() + self.arm_names())
            raise ConfigError(
                f"{where}: algorithm name {name!r} is already registered by "
                f"{self._origin[name]}; known: {known}"
            )
        arm = isinstance(algo, ArmServoAlgorithm)
        fault = check_arm_dtype(algo.dtype) if arm else check_dtype(algo.dtype)
        if fault is not None:
            raise ConfigError(f"{where}: algorithm {name!r}: {fault}")
        for attr in _CALLABLES:
            value = getattr(algo, attr)
            if not callable(value):
                raise ConfigError(
                    f"{where}: algorithm {name!r}: {attr} is {value!r}, not a callable"
                )
        params = algo.params
        if not isinstance(params, tuple) or not all(isinstance(p, str) for p in params):
            raise ConfigError(
                f"{where}: algorithm {name!r}: params must be a tuple of names, got {params!r}"
            )
        if len(set(params)) != len(params):
            raise ConfigError(f"{where}: algorithm {name!r}: params {params!r} repeat a name")
        self._origin[name] = where
        if isinstance(algo, ArmServoAlgorithm):
            probe_arm_step(algo, f"{where}: robot-level algorithm {name!r}")
            self.arms.append(algo)
            return len(self.arms) - 1
        _probe_step(algo, f"{where}: algorithm {name!r}")
        self._by_name[name] = len(self._algos)
        self._origin[name] = where
        self._algos.append(algo)
        return self._by_name[name]

    def load_plugin(self, spec: str, base_dir: Path | None = None, files: str = "") -> list[str]:
        """Load the plugin ``spec`` and return the names it registered.

        ``spec`` is a file path (``.py``, or containing '/'; relative to ``base_dir``, default
        the current directory; read from the instance's copies under ``files`` when given,
        ``snapshot.mirror``) or a dotted module name.  The module must define
        ``register(registry)``.  Every fault is a ConfigError naming the plugin; its code
        runs guarded (``pyfile.guarded``: no exit, bounded time).
        """
        path = plugin_file(spec, base_dir, files)
        with guarded(f"plugin {spec!r}", path):
            return self._load_plugin(spec, import_plugin(spec, path))

    def load_module(self, spec: str, module: Any) -> list[str]:
        """``load_plugin`` for a plugin already imported (a file loaded while running,
        ``servo.loading``); the caller guards it."""
        return self._load_plugin(spec, module)

    def truncate(self, n: int, n_arms: int) -> None:
        """Forget every algorithm from joint index ``n`` and robot-level index ``n_arms``
        on (a plugin loaded while running that failed a later check)."""
        del self._algos[n:], self.arms[n_arms:]
        self._rebuild_names()

    def stand_in(self, joint: Sequence[str], arm: Sequence[str], why: str) -> None:
        """Hold the indices of algorithms that could not be loaded in this process (a plugin
        loaded while running, ``servo.loading``) with ones that refuse to run: their
        ``init``, ``handover`` and ``set_params`` raise ConfigError saying ``why``, so a
        select, shadow or put of one is refused (``level.apply_op``), and a step halts."""
        for name in joint:
            self._by_name[name] = len(self._algos)
            self._algos.append(_refusing(ServoAlgorithm, name, why))
            self._origin[name] = why
        for name in arm:
            self.arms.append(_refusing(ArmServoAlgorithm, name, why))
            self._origin[name] = why

    def _load_plugin(self, spec: str, module: Any) -> list[str]:
        """``load_plugin`` once the plugin is imported, inside its guard."""
        register = getattr(module, "register", None)
        if register is None:
            raise ConfigError(
                f"plugin {spec!r}: defines no register(registry) function "
                f"(module {module.__name__}, {getattr(module, '__file__', None)})"
            )
        if not callable(register):
            raise ConfigError(f"plugin {spec!r}: register is {register!r}, not a function")
        before, arms_before = len(self._algos), len(self.arms)
        self._source = spec
        try:
            register(self)
        except ConfigError:
            del self._algos[before:], self.arms[arms_before:]
            self._rebuild_names()
            raise
        except Exception as exc:
            del self._algos[before:], self.arms[arms_before:]
            self._rebuild_names()
            raise ConfigError(
                f"plugin {spec!r}: register() raised {type(exc).__name__}: {exc}"
            ) from exc
        except BaseException:  # an exit or its time out (pyfile.guarded): none of it stays
            del self._algos[before:], self.arms[arms_before:]
            self._rebuild_names()
            raise
        finally:
            self._source = "builtins"
        added = [a.name for a in self._algos[before:]] + [a.name for a in self.arms[arms_before:]]
        if not added:
            raise ConfigError(f"plugin {spec!r}: register() registered no algorithm")
        return added

    def _rebuild_names(self) -> None:
        """After dropping a failed plugin's algorithms: names and origins of the rest."""
        self._by_name = {a.name: i for i, a in enumerate(self._algos)}
        kept = set(self._by_name) | set(self.arm_names())
        self._origin = {n: o for n, o in self._origin.items() if n in kept}


STAND_IN_DTYPE = np.dtype([("unloaded", "<u8")], align=True)


def _refusing(kind: type, name: str, why: str) -> Any:
    """An algorithm of ``kind`` named ``name`` whose every function raises ``why``."""

    def refuse(*_args: Any) -> Any:
        raise ConfigError(f"servo '{name}' is not loaded here: {why}")

    return kind(
        name=name, dtype=STAND_IN_DTYPE, params=(), init=refuse, step=refuse,
        handover=refuse, set_params=refuse, get_params=refuse, doc=why,
    )  # fmt: skip


PROBE_INTERVAL_S = 0.001  # the test input ``register`` steps a new algorithm with
PROBE_DEMAND, PROBE_POSITION = 0.01, 0.0  # rad: a small error, as at the first tick


def _probe_step(algo: ServoAlgorithm, what: str) -> None:
    """Step ``algo`` once on a scratch record (its defaults, a 0.01 rad error) and check it
    returns (torque, error, status): two finite real numbers and an integer.  Outside the
    cycle; a wrong return would otherwise surface only in an SV at the first powered tick,
    where it halts the system."""
    record = np.zeros(1, dtype=algo.dtype)
    data = struct_view(record)
    try:
        initialise(algo, data, {}, PROBE_INTERVAL_S)
        result = step(algo, data, PROBE_DEMAND, PROBE_POSITION, 0.0)
    except ConfigError:
        raise
    except Exception as exc:
        raise ConfigError(
            f"{what}: step(data, {PROBE_DEMAND}, {PROBE_POSITION}) at its defaults raised "
            f"{type(exc).__name__}: {exc}"
        ) from None
    finally:
        del data
    ok = (
        isinstance(result, tuple)
        and len(result) == 3
        and all(_is_real(v) and math.isfinite(v) for v in result[:2])
        and _is_integer(result[2])
    )
    if not ok:
        raise ConfigError(
            f"{what}: step(data, {PROBE_DEMAND}, {PROBE_POSITION}) at its defaults returned "
            f"{_short(result)}; it must return (torque, error, status): two finite numbers "
            f"(N·m, rad) and an integer status"
        )


def _is_real(v: Any) -> bool:
    return isinstance(v, int | float | np.integer | np.floating) and not isinstance(v, bool)


def _is_integer(v: Any) -> bool:
    return isinstance(v, int | np.integer) and not isinstance(v, bool)


def _short(value: Any, limit: int = 80) -> str:
    """``repr(value)`` cut at ``limit`` characters, with its type if that is not obvious."""
    text = repr(value)
    text = text if len(text) <= limit else text[: limit - 3] + "..."
    obvious = isinstance(value, tuple | list | float | int | str | type(None))
    return text if obvious else f"{text} (a {type(value).__name__})"


def _is_path(spec: str) -> bool:
    return spec.endswith(".py") or "/" in spec


def plugin_file(spec: str, base_dir: Path | None, files: str = "") -> Path | None:
    """The file a plugin ``spec`` names, absolute and resolved (None for a module name);
    under the instance's copies ``files`` (``snapshot.mirror``) when given.  ConfigError for
    a missing file or a spec that is neither."""
    if not _is_path(spec):
        if not all(part.isidentifier() for part in spec.split(".")):
            raise ConfigError(
                f"plugin {spec!r}: neither a file path (ending in .py) nor a dotted module name"
            )
        return None
    path = Path(spec)
    relative = ""
    if not path.is_absolute():
        base = base_dir or Path.cwd()
        path = base / path
        what = "the config file's directory" if base_dir else "the current directory"
        relative = f" (a relative path is taken from {what}, {base})"
    path = path.resolve()
    if files:
        path = mirror(files, path)
    if not path.is_file():
        raise ConfigError(f"plugin {spec!r}: file {path} does not exist{relative}")
    return path


def import_plugin(spec: str, path: Path | None) -> Any:
    """Import a plugin, the module ``spec`` or the file ``path`` (``plugin_file``);
    ConfigError for a failed import."""
    if path is None:
        try:
            return importlib.import_module(spec)
        except Exception as exc:
            raise ConfigError(
                f"plugin {spec!r}: import failed: {type(exc).__name__}: {exc}"
            ) from exc
    try:
        module = import_file(path, "kali_servo_plugin")
    except Exception as exc:
        raise ConfigError(
            f"plugin {spec!r}: import of {path} failed: {type(exc).__name__}: {exc}"
        ) from exc
    if module is None:
        raise ConfigError(f"plugin {spec!r}: {path} cannot be imported as a Python file")
    return module


def registry_for(
    plugins: Sequence[str], base_dir: Path | str | None = None, files: str = ""
) -> Registry:
    """The built-ins plus ``plugins`` (the config's ``plugins`` list), in order; read from
    the instance's copies under ``files`` when given (``KaliConfig.files``)."""
    registry = Registry()
    base = None if base_dir is None else Path(base_dir)
    for spec in plugins:
        registry.load_plugin(spec, base, files)
    return registry
