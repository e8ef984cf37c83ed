"""The servo programming interface (thesis 3.4, DESIGN 4): what a servo algorithm declares
and how its private data is viewed in shared memory; ``registry`` holds them by name.

A ``ServoAlgorithm`` is a name, the dtype of its private data (a record per joint in the
arena, so any SV runs any joint, 3.3.4) and plain functions over that record, viewed as a
ctypes ``Structure`` (``struct_view``: Python floats, no numpy).  ``step`` and ``handover``
run inside the servo cycle (no allocation, numpy, I/O or logging); ``init``, ``set_params``
and ``get_params`` outside it.  ``joint_aware`` and ``velocity_aware`` give ``init`` the
joint's ``JointInfo`` and ``step`` the demand's velocity.  More: docs/guide/servos.md.
"""

from __future__ import annotations

import ctypes
import functools
import math
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ...core import layout
from ...core.errors import ConfigError
from ...robots import RobotType

STATUS_OK = 0  # what ``step`` returns when all is well
MAX_DATA_BYTES = layout.SERVO_STAGING_BYTES  # private data must fit the put/get mailbox
NUMERIC_KINDS = "biuf"  # bool, signed and unsigned integers, floats: what ctypes maps


class Handover(NamedTuple):
    """The state of a joint when a servo takes it over (bumpless transfer).

    The SV fills it from the joint's slot at the tick of the switch: this tick's measurement
    and demand, and what the previous servo did last.
    """

    position: float  # rad, measured this tick
    velocity: float  # rad/s, measured this tick
    demand: float  # rad, this tick's position demand
    error: float  # rad, the previous servo's last error
    torque: float  # N·m, the previous servo's last output


@dataclass(frozen=True)
class ServoAlgorithm:
    """One servo algorithm as the SV runs it (thesis 3.4: the servo function, its private
    data structure, its init function, and the get/put helpers for on-line changes).

    ``data`` below is the ``struct_view`` of one joint's record of ``dtype``.
    """

    name: str  # registry name, e.g. "pid"; lower case, digits, '_', at most 32 characters
    dtype: np.dtype  # private data: an aligned structured dtype of numeric scalars
    params: tuple[str, ...]  # parameter names accepted by init/set_params, returned by get_params
    # init(data, init_data, sample_interval_s): parameters from init_data (missing keys: the
    # algorithm's defaults), precomputed terms, and state reset.  Outside the cycle.
    init: Callable[[Any, Mapping[str, float], float], None]
    # step(data, demand, position) -> (torque N·m, error rad, status, 0 = ok).  In the cycle.
    step: Callable[[Any, float, float], tuple[float, float, int]]
    # handover(data, h): set the state so the next step continues from h.torque.  In the cycle.
    handover: Callable[[Any, Handover], None]
    # set_params(data, values): change some parameters, keep the state.  Outside the cycle.
    set_params: Callable[[Any, Mapping[str, float]], None]
    # get_params(data) -> every parameter's current value.  Outside the cycle.
    get_params: Callable[[Any], dict[str, float]]
    doc: str = ""
    # True: ``init`` takes a fourth argument, the ``JointInfo`` of the joint the record is
    # for (None where it is for no joint: the checks at registration and of its cost)
    joint_aware: bool = False
    # True: ``step`` takes a fourth argument, the demand's velocity, rad/s (the dynamics
    # process's rows interpolated as the demand; 0 where no dynamics process runs)
    velocity_aware: bool = False


@dataclass(frozen=True)
class JointInfo:
    """The joint a servo's record is for, given to an ``init`` that asks for it
    (``ServoAlgorithm.joint_aware``): the robot's name, the joint (1..n, as the thesis
    numbers the PUMA's) and the robot's type: its limits (``rtype.q_min[joint - 1]``,
    ``qd_max``, ...), drive (gear ratios, motor constants, current limits) and model
    (``rtype.urdf``, ``kinematics``).  Outside the cycle."""

    robot: str
    joint: int
    rtype: RobotType


def initialise(
    alg: ServoAlgorithm,
    data: Any,
    init_data: Mapping[str, float],
    period_s: float,
    joint: JointInfo | None = None,
) -> None:
    """``alg.init`` on ``data``, with ``joint`` where the algorithm asked for it.  Outside
    the cycle."""
    if alg.joint_aware:
        alg.init(data, init_data, period_s, joint)  # type: ignore[call-arg]
    else:
        alg.init(data, init_data, period_s)


def step(
    alg: ServoAlgorithm, data: Any, demand: float, position: float, velocity: float
) -> tuple[float, float, int]:
    """``alg.step`` on ``data``, with the demand's ``velocity`` where the algorithm asked for
    it.  Inside the cycle."""
    if alg.velocity_aware:
        return alg.step(data, demand, position, velocity)  # type: ignore[call-arg]
    return alg.step(data, demand, position)


# ------------------------------------------------------------------------------ parameters


class Param(NamedTuple):
    """A parameter declared once: name, default, unit, one line of doc, and its bounds.

    ``minimum`` is inclusive unless ``positive`` (then the value must be strictly above it);
    ``maximum`` is inclusive (a gain beyond it is a typo, not a tuning: ``kalictl servo set``
    refuses it naming the bound).  Used by the built-ins and available to plugins through
    ``resolve_params``.
    """

    name: str
    default: float
    unit: str
    doc: str
    minimum: float = 0.0
    positive: bool = False
    maximum: float = math.inf


def resolve_params(
    algo: str,
    specs: Sequence[Param],
    values: Mapping[str, float],
    base: Mapping[str, float],
    kind: str = "servo",
) -> dict[str, float]:
    """``base`` (every parameter) updated with ``values``, checked against ``specs``.

    Outside the cycle.  ConfigError names the ``kind`` of algorithm ("servo", "tg
    function"), the algorithm, the parameter, the value and the bound, or the unknown key
    with the known ones.
    """
    known = {p.name: p for p in specs}
    out = dict(base)
    for key, raw in values.items():
        spec = known.get(key)
        if spec is None:
            raise ConfigError(
                f"{kind} {algo}: unknown parameter {key!r}; parameters: {', '.join(known)}"
            )
        try:
            value = float(raw)
        except (TypeError, ValueError):
            raise ConfigError(
                f"{kind} {algo}: parameter {key} = {raw!r} is not a number ({spec.unit})"
            ) from None
        if not math.isfinite(value):
            raise ConfigError(f"{kind} {algo}: parameter {key} = {value} must be finite")
        if value < spec.minimum or (spec.positive and value == spec.minimum):
            bound = f"> {spec.minimum:g}" if spec.positive else f">= {spec.minimum:g}"
            raise ConfigError(
                f"{kind} {algo}: parameter {key} = {value:g} {spec.unit} must be {bound}"
            )
        if value > spec.maximum:
            raise ConfigError(
                f"{kind} {algo}: parameter {key} = {value:g} {spec.unit} must be "
                f"<= {spec.maximum:g} (the algorithm's declared bound)"
            )
        out[key] = value
    return out


def defaults(specs: Sequence[Param]) -> dict[str, float]:
    """Every parameter at its declared default."""
    return {p.name: p.default for p in specs}


# ------------------------------------------------------------------------------ private data


@functools.cache
def struct_type(dtype: np.dtype) -> type[ctypes.Structure]:
    """The ctypes ``Structure`` class laid out exactly like ``dtype`` (cached per dtype)."""
    struct = np.ctypeslib.as_ctypes_type(dtype)
    assert ctypes.sizeof(struct) == dtype.itemsize, (dtype, ctypes.sizeof(struct))
    return struct


def struct_view(record: np.ndarray) -> Any:
    """A ctypes ``Structure`` over ``record`` (a writable 0-d or 1-element array of a
    structured dtype, e.g. an arena block), without copying: writes through either one are
    seen by the other.  The structure keeps the record's buffer alive.  Outside the cycle.
    """
    if record.dtype.fields is None:
        raise TypeError(f"struct_view needs a structured record, got dtype {record.dtype}")
    if record.size != 1:
        raise ValueError(f"struct_view needs one record, got an array of shape {record.shape}")
    if not record.flags.writeable or not record.flags.c_contiguous:
        raise ValueError("struct_view needs a writable, contiguous record")
    # numpy's stubs give an ndarray the buffer protocol only from Python 3.12 on
    return struct_type(record.dtype).from_buffer(record)  # type: ignore[arg-type]


def check_dtype(dtype: Any) -> str | None:
    """What is wrong with ``dtype`` as a servo's private data, or None if it is fine."""
    if not isinstance(dtype, np.dtype):
        return f"dtype {dtype!r} is a {type(dtype).__name__}, not a numpy dtype (use np.dtype)"
    dt = dtype
    if dt.fields is None:
        return f"dtype {dt} is not a structured dtype (give named fields)"
    if not dt.isalignedstruct:
        return f"dtype {dt} is not aligned (build it with np.dtype([...], align=True))"
    for field, (ft, _offset, *_title) in dt.fields.items():
        if ft.subdtype is not None:
            return (
                f"dtype field {field!r} is an array {ft.base.str} {ft.shape}; only scalars "
                f"are allowed (give each element a field)"
            )
        if ft.kind not in NUMERIC_KINDS or not ft.isnative:
            return (
                f"dtype field {field!r} has type {ft.str}; only native-endian numeric scalars "
                f"(bool, int, uint, float) are allowed"
            )
        if ft.itemsize > 8:
            return f"dtype field {field!r} has type {ft.str}; at most 8 bytes per field"
    if dt.itemsize > MAX_DATA_BYTES:
        return (
            f"private data is {dt.itemsize} B, at most {MAX_DATA_BYTES} B "
            f"(the put/get mailbox, layout.SERVO_STAGING_BYTES)"
        )
    try:
        struct_type(dt)
    except (NotImplementedError, TypeError, ValueError) as exc:
        return f"dtype {dt} has no ctypes equivalent ({exc})"
    return None


# ------------------------------------------------------------------------------ cost

STEP_SAMPLES = 400  # calls of a servo's step timed (at most STEP_BUDGET_S)
STEP_BUDGET_S = 0.2


def step_cost_us(alg: ServoAlgorithm, period_s: float, record: np.ndarray | None = None) -> float:
    """The cost of one ``step`` of ``alg``, µs: the 90th percentile of calls timed on a
    scratch copy of ``record`` (a joint's own private data of ``alg``: its parameters), or
    on one initialised with the algorithm's defaults.  Outside any cycle (the kalictl
    process): the joint's record is never written."""
    rec = np.zeros(1, alg.dtype)
    data = struct_view(rec)
    if record is None:
        initialise(alg, data, {}, period_s)
    else:
        rec[0] = record.reshape(-1)[0]
    alg.handover(data, Handover(0.0, 0.0, 0.0, 0.0, 0.0))
    times: list[int] = []
    end = time.monotonic() + STEP_BUDGET_S
    clock = time.perf_counter_ns
    for k in range(STEP_SAMPLES):
        demand = 1e-3 * math.sin(k * 0.01)
        t0 = clock()
        step(alg, data, demand, 0.0, 0.0)
        times.append(clock() - t0)
        if time.monotonic() > end and len(times) >= 10:
            break
    return float(np.percentile(times, 90)) / 1000.0
