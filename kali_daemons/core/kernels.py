"""The servo path's per-tick arithmetic as compiled kernels, and the numpy reference each one
must equal.

The C is in ``csrc/`` (a file per owner), compiled into the controller's and the simulator's
libraries (``kernel_args.LIBRARIES``) by ``python -m kali_daemons.core.kernels``, or by
``load`` at configure when none is found, never inside a cycle.  Every kernel, its library,
owner, argument block and reference are declared once in ``kernel_args``; ``load`` refuses a
library whose structs differ from the ctypes classes (``check_block``) or the dtypes
(``check_record``).  Every kernel is bound once (``Kernel``): its argument block holds the
arrays' addresses and strides, so the arrays must never move; the bound kernel keeps them
alive, and a call is then ``kernel()``, with no allocation.

Build, cache and the kernels' table: docs/internals/kernels.md; why C through ctypes and not
numba: docs/decisions/0001-ctypes-not-numba.md.
"""

from __future__ import annotations

import ctypes
import hashlib
import math
import os
import subprocess
import tempfile
from collections.abc import Callable
from ctypes import c_int64, c_void_p
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import kernel_args, layout
from .errors import DaemonError

if TYPE_CHECKING:
    from ..robots.chain import Chain
    from ..servo.algorithms.arm import ArmInput

CSRC = Path(__file__).with_name("csrc")  # the kernels' C, a file per owner
HEADER = kernel_args.HEADER  # generated from kernel_args.py: every struct the C uses
CFLAGS = ("-O2", "-std=c99", "-shared", "-fPIC", "-ffp-contract=off", "-fno-fast-math")
COUNTER_BITS = 12  # the HCTL-2000's counter (figure C.3)
COUNTER_MODULO = 1 << COUNTER_BITS
COUNTER_HALF = COUNTER_MODULO // 2  # wrap threshold of figure C.3

# the code of ``kali_checks``: joint i out of range is i, its runaway n + i
NO_FAULT = -1


View = kernel_args.View
Copy = kernel_args.Copy
Field = kernel_args.Field  # one field of a struct, as ``kali_layout`` and ``kali_fields`` list it
McgillArgs = kernel_args.STRUCTS["McgillArgs"]  # its binder keeps the block (hardware.mcgill)
_KERNELS = kernel_args.KERNELS


def view(a: np.ndarray) -> ctypes.Structure:
    """``a`` (1-D, any stride) as a ``View``; the caller keeps ``a`` alive."""
    assert a.ndim == 1, f"a kernel takes 1-D arrays, not shape {a.shape}"
    return View(a.ctypes.data, a.strides[0])


# kali_sio_tick's results (the tick's events) and its stages
SIO_FED, SIO_DONE, SIO_CAPTURE, SIO_SENSOR, SIO_ROBOTS, SIO_CHECK, SIO_CURRENT, SIO_WAIT = range(8)
ST_READ, ST_VELOCITY, ST_SENSORS, ST_ROBOTS, ST_CHECKS, ST_FEED, ST_WAIT, ST_BACK, ST_OUT = range(9)
# kali_sv_serve's results: what it hands back to the SV's Python
SV_DONE, SV_ARM, SV_FAULT, SV_LEFT, SV_SLOT = range(5)
SV_START = 0  # its stage for a feed taken (the lockstep executive's serve)
SV_FEED = 7  # its stage for a tick signalled: the feed awaited first (an SV's cycle)
# kali_clock_wait's results
WAIT_SIGNAL, WAIT_IDLE, WAIT_INTR, WAIT_SHUTDOWN = range(4)
# kali_wrench_tick's results (sio/wrench.py builds the message)
WRENCH_OK, WRENCH_SATURATED, WRENCH_RATED, WRENCH_CONTACT, WRENCH_SILENT = range(5)

# the records the kernels read and write in place: their number in ``kali_fields`` and the
# dtype the C struct (generated from it) must have, field for field
RECORDS: dict[str, tuple[int, np.dtype]] = {
    source: (number, dtype) for number, (_, source, dtype) in enumerate(kernel_args.RECORDS)
}

# --------------------------------------------------------------------------------------------
# Build and load (outside any cycle)


def _digest() -> str:
    h = hashlib.sha256()
    for source in sorted(CSRC.glob("*.[ch]")):
        h.update(source.name.encode())
        h.update(source.read_bytes())
    h.update(" ".join(CFLAGS).encode())
    return h.hexdigest()[:16]


def _writable(d: Path) -> bool:
    try:
        d.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return os.access(d, os.W_OK)


def library_path(library: str = "controller") -> Path:
    """Where this source's ``library`` is (or goes): see the module docstring."""
    name = f"{library}-{_digest()}.so"
    env = os.environ.get("KALI_KERNEL_DIR")
    if env:
        return Path(env) / name
    here = Path(__file__).parent / "__pycache__"
    if _writable(here):
        return here / name
    return Path.home() / ".cache" / "kali" / name


def build(
    path: Path | None = None, source: Path | None = None, library: str = "controller"
) -> Path:
    """Compile ``library``'s translation unit (``source``, default ``csrc/<library>.c``, with
    the files it includes beside it) into ``path`` (default ``library_path(library)``);
    atomic, so a process loading it meanwhile sees the old file or the whole new one."""
    path = library_path(library) if path is None else path
    source = CSRC / f"{library}.c" if source is None else source
    path.parent.mkdir(parents=True, exist_ok=True)
    cc = os.environ.get("CC", "cc")
    fd, tmp = tempfile.mkstemp(prefix=".kernels-", suffix=".so", dir=path.parent)
    os.close(fd)
    try:
        done = subprocess.run(
            [cc, *CFLAGS, "-o", tmp, str(source), "-lm"],
            capture_output=True,
            text=True,
            check=False,
        )
        if done.returncode != 0:
            raise DaemonError(
                f"kernels: '{cc}' could not compile {source} (exit {done.returncode}): "
                f"{done.stderr.strip()[:2000]}"
            )
        os.replace(tmp, path)
    except FileNotFoundError:
        raise DaemonError(
            f"kernels: no C compiler '{cc}' to build {source} (install gcc, or set CC)"
        ) from None
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return path


_libs: dict[str, ctypes.CDLL] = {}


def load(library: str = "controller") -> ctypes.CDLL:
    """One of the kernels' libraries (``kernel_args.LIBRARIES``), built first if this source
    has none yet (outside any cycle)."""
    if library not in _libs:
        path = library_path(library)
        if not path.exists():
            build(path, library=library)
        _libs[library] = open_library(path, library)
    return _libs[library]


def open_library(path: Path, library: str = "controller") -> ctypes.CDLL:
    """The library at ``path`` with its kernels typed, once its structs are found to be the
    ctypes argument blocks (``check_block``) and the records' dtypes (``check_record``): a
    DaemonError otherwise.  Outside any cycle."""
    lib = ctypes.CDLL(str(path))
    for name in kernel_args.library_kernels(library):
        fn = getattr(lib, name)
        fn.argtypes = (c_void_p,)
        fn.restype = c_int64
    lib.kali_fields.argtypes = (c_int64,)
    lib.kali_fields.restype = ctypes.POINTER(Field)
    lib.kali_layout.argtypes = (ctypes.c_char_p,)
    lib.kali_layout.restype = ctypes.POINTER(Field)
    for struct in kernel_args.library_blocks(library):
        check_block(lib, path, struct)
    for record, (number, dtype) in RECORDS.items():
        check_record(lib, path, record, number, dtype)
    return lib


def _table(table: Any) -> tuple[dict[str, tuple[int, int, str]], int]:
    fields: dict[str, tuple[int, int, str]] = {}
    k = 0
    while table[k].name is not None:
        f = table[k]
        fields[ctypes.string_at(f.name).decode()] = (f.offset, f.size, f.kind.decode())
        k += 1
    return fields, table[k].offset


def struct_fields(lib: ctypes.CDLL, number: int) -> tuple[dict[str, tuple[int, int, str]], int]:
    """Record ``number``'s C struct in ``lib``: {field: (offset, size, kind)} and its size."""
    table = lib.kali_fields(number)
    assert table, f"kernels: kali_fields knows no record {number}"
    return _table(table)


def block_fields(lib: ctypes.CDLL, name: str) -> tuple[dict[str, tuple[int, int, str]], int] | None:
    """Argument block ``name``'s C struct in ``lib`` as ``struct_fields`` gives a record's;
    None if the library has no such block."""
    table = lib.kali_layout(name.encode())
    return _table(table) if table else None


def ctypes_fields(struct: type[ctypes.Structure]) -> dict[str, tuple[int, int, str]]:
    """A ctypes class's fields as ``block_fields`` gives a C struct's."""
    return {
        name: (
            getattr(struct, name).offset,
            getattr(struct, name).size,
            kernel_args.ctypes_kind(t),
        )
        for name, t, *_ in struct._fields_
    }


def check_block(lib: ctypes.CDLL, path: Path, struct: type[ctypes.Structure]) -> None:
    """Refuse ``lib`` (a DaemonError naming the block, the first field that differs and both
    its offsets) unless its C struct named as ``struct`` has ``struct``'s fields at the same
    offsets, of the same size and kind, and the same size: a kernel reads its arguments
    where the ctypes class put them."""
    name = struct.__name__
    found = block_fields(lib, name)
    if found is None:
        raise DaemonError(
            f"kernels: {path.name} has no argument block {name}; its kernel_args.h is not "
            f"kernel_args.py's (regenerate: python -m kali_daemons.core.kernel_args)"
        )
    c_fields, c_size = found
    py_fields = ctypes_fields(struct)
    for field in [*py_fields, *(f for f in c_fields if f not in py_fields)]:
        c, py = c_fields.get(field), py_fields.get(field)
        if c != py:
            at_c = f"offset {c[0]} ({c[1]} B, kind '{c[2]}')" if c else "absent"
            at_py = f"offset {py[0]} ({py[1]} B, kind '{py[2]}')" if py else "absent"
            raise DaemonError(
                f"kernels: {path.name} does not match {name}: field '{field}' is at {at_c} "
                f"in C, {at_py} in ctypes; both come from kernel_args.py (regenerate "
                f"kernel_args.h: python -m kali_daemons.core.kernel_args, then rebuild)"
            )
    if c_size != ctypes.sizeof(struct):
        raise DaemonError(
            f"kernels: {path.name} does not match {name}: the C struct is {c_size} B, "
            f"the ctypes class {ctypes.sizeof(struct)} B"
        )


def dtype_fields(dtype: np.dtype) -> dict[str, tuple[int, int, str]]:
    """A structured dtype's fields as ``struct_fields`` gives a C struct's."""
    return {
        name: (offset, sub.itemsize, sub.kind)
        for name, (sub, offset, *_) in (dtype.fields or {}).items()
    }


def check_record(lib: ctypes.CDLL, path: Path, record: str, number: int, dtype: np.dtype) -> None:
    """Refuse ``lib`` (a DaemonError naming the record and the first difference) unless
    its struct for ``record`` has ``dtype``'s fields at the same offsets, of the same size
    and kind, and the same size: the kernels step the arena's records in place."""
    c_fields, c_size = struct_fields(lib, number)
    np_fields = dtype_fields(dtype)
    for name in [*np_fields, *(f for f in c_fields if f not in np_fields)]:
        c, n = c_fields.get(name), np_fields.get(name)
        if c != n:
            raise DaemonError(
                f"kernels: {path.name} does not match {record}: field '{name}' is "
                f"(offset, size, kind) {c} in C, {n} in the dtype; the generated struct must "
                "mirror the dtype (regenerate kernel_args.h: "
                "python -m kali_daemons.core.kernel_args)"
            )
    if c_size != dtype.itemsize:
        raise DaemonError(
            f"kernels: {path.name} does not match {record}: the C struct is {c_size} B, "
            f"the dtype {dtype.itemsize} B"
        )


class Kernel:
    """One kernel bound to its arguments at configure: ``kernel()`` runs it (inside the
    cycle: no allocation) and returns its int64 result.  Array arguments become ``View``s;
    the kernel keeps them, and whatever ``keep`` holds (a copy table), alive.  It runs in
    ``library`` (default: the one its owner's kernels are in, ``kernel_args.library_of``)."""

    __slots__ = ("_args", "_fn", "_keep", "_lib", "_ptr")

    def __init__(
        self, name: str, keep: tuple[object, ...] = (), library: str | None = None, /,
        **fields: object,
    ) -> None:  # fmt: skip
        arrays = tuple(v for v in fields.values() if isinstance(v, np.ndarray))
        for f, value in fields.items():
            if isinstance(value, np.ndarray):
                fields[f] = view(value)
        self._args = _KERNELS[name](**fields)
        self._keep = keep + arrays
        self._lib = load(library or kernel_args.library_of(name))
        self._fn = getattr(self._lib, name)
        self._ptr = ctypes.addressof(self._args)

    def __call__(self) -> int:
        return self._fn(self._ptr)

    @property
    def address(self) -> tuple[int, int]:
        """The kernel's C function and its argument block, as addresses, for a kernel that
        calls it (``kali_sio_front`` calls the boards' kernels through them)."""
        return ctypes.cast(self._fn, c_void_p).value or 0, self._ptr

    def sibling(self, name: str) -> Callable[[], int]:
        """Another kernel of the library on this one's argument block (a part of it the
        tests check against its reference)."""
        fn, ptr = getattr(self._lib, name), self._ptr
        return lambda: fn(ptr)

    @property
    def args(self) -> ctypes.Structure:
        """The argument block: a kernel's scalar inputs and outputs are read and written
        here between calls (``sv.units.Unit``)."""
        return self._args


def copies(pairs: list[tuple[np.ndarray, np.ndarray]], library: str = "controller") -> Kernel:
    """One kernel copying each flat ``src`` into its ``dst`` (same length and item size), in
    ``library`` (every library has it: the simulator's own copies run in its own)."""
    n = len(pairs[0][0])
    table = (Copy * len(pairs))()
    for c, (src, dst) in enumerate(pairs):
        assert len(src) == n == len(dst) and src.itemsize == dst.itemsize in (4, 8), (src, dst)
        table[c] = Copy(view(src), view(dst), src.itemsize)
    arrays = tuple(a for pair in pairs for a in pair)
    ptr = ctypes.cast(table, ctypes.POINTER(Copy))
    return Kernel("kali_copy", (table, *arrays), library, n=n, m=len(pairs), copies=ptr)


def chain_pose(chain: Chain, q: np.ndarray, out: np.ndarray) -> Kernel:
    """``kali_chain_pose`` bound to ``chain``: each call puts the flange pose at the angles
    now in ``q`` (``chain.n`` float64, contiguous) into ``out`` (4×4 float64, C order);
    ``chain.flange_pose`` is its reference.  The kernel keeps all three alive."""
    n = chain.n
    for what, a, shape in (
        ("origins", chain.origins, (n + 1, 4, 4)),
        ("axes", chain.axes, (n, 3)),
        ("q", q, (n,)),
        ("out", out, (4, 4)),
    ):
        assert a.shape == shape and a.dtype == np.float64 and a.flags.c_contiguous, (
            f"kernels: chain pose {what} must be float64 {shape}, C order, not {a.dtype} {a.shape}"
        )
    return Kernel(
        "kali_chain_pose",
        (chain, q, out),
        n=n,
        origins=chain.origins.ctypes.data,
        axes=chain.axes.ctypes.data,
        q=q.ctypes.data,
        out=out.ctypes.data,
    )


# each robot-level built-in's kernel and the dtype of the record it steps
ARM_KERNELS: dict[str, tuple[str, np.dtype]] = {
    "impedance": ("kali_impedance", layout.IMPEDANCE_DTYPE),
    "computed_torque": ("kali_computed_torque", layout.CT_DTYPE),
}


def arm_step(algorithm: str, record: Any, inp: ArmInput, tau: np.ndarray) -> Kernel:
    """Robot-level built-in ``algorithm``'s kernel (``ARM_KERNELS``) bound to one robot's
    record of it (0-d, the arena's), its ``ArmInput`` and its torque out (``inp.n``
    float64): each call is one step of the algorithm's Python ``step``
    (``servo.armbuiltins``) on what the SV put in ``inp``, returning its status.  The drive's
    friction comes from ``inp.friction`` (``DriveFriction.coefficients``; none without a
    model).  Outside the cycle."""
    name, dtype = ARM_KERNELS[algorithm]
    n = inp.n
    arrays: dict[str, np.ndarray] = {
        "q_d": inp.q_d, "qd_d": inp.qd_d, "qdd_d": inp.qdd_d, "q": inp.q, "qd": inp.qd,
        "h": inp.h, "M": inp.M, "J": inp.J, "pose": inp.pose, "pose_d": inp.pose_d,
        "wrench": inp.wrench, "tau": tau,
    }  # fmt: skip
    coefficients = getattr(inp.friction, "coefficients", None)
    friction = coefficients() if coefficients is not None else (np.zeros(n),) * 4
    for field, a in zip(("viscous", "gear_w", "coulomb_pos", "coulomb_neg"), friction, strict=True):
        arrays[field] = np.ascontiguousarray(a, dtype=np.float64)
    for field, a in arrays.items():
        assert a.dtype == np.float64 and a.flags.c_contiguous, (
            f"kernels: {algorithm} {field} must be contiguous float64, not {a.dtype} {a.shape}"
        )
    assert n <= layout.MAX_JOINTS, f"kernels: {algorithm} steps at most {layout.MAX_JOINTS} joints"
    wrenches = inp.wrenches
    assert record.dtype == dtype and record.shape == (), record.dtype
    assert wrenches.dtype == np.float64 and wrenches.shape[1:] == (layout.WRENCH,)
    assert wrenches.strides[1] == 8, "kernels: a wrench's six values are contiguous"
    return Kernel(
        name,
        (record, wrenches, *arrays.values()),
        n=n,
        d=record.ctypes.data,
        wrenches=wrenches.ctypes.data,
        wrench_stride=wrenches.strides[0],
        robots=len(wrenches),
        has_sensor=int(inp.has_sensor),
        **{field: a.ctypes.data for field, a in arrays.items()},
    )


def channel_offsets(arms: np.ndarray, robot_of: np.ndarray, joint_of: np.ndarray) -> np.ndarray:
    """Byte offsets from ``arms.ctypes.data`` (a per-arm register array, ``(arms, channels)``)
    of each flat joint's channel: arm ``robot_of[i]``, channel ``joint_of[i]``."""
    start = arms.ctypes.data
    return np.array(
        [arms[k, j : j + 1].ctypes.data - start for k, j in zip(robot_of, joint_of, strict=True)],
        dtype=np.int64,
    )


# --------------------------------------------------------------------------------------------
# The numpy references: what each kernel computes, as SIO and the driver did before them
# (tests/test_sio_kernels.py holds the kernels to these, bit for bit).


def read_reference(
    raw: np.ndarray, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray, rpc: np.ndarray,
    q: np.ndarray,
) -> None:  # fmt: skip
    """``kali_read``: counter readings ``raw`` (int32, flat) accumulated with wrap (figure
    C.3) into ``acc``, ``prev``; angles into ``q``."""
    r = np.bitwise_and(raw, COUNTER_MODULO - 1).astype(np.int32)
    d = np.subtract(r, prev)
    np.add(d, COUNTER_HALF, out=d)
    np.bitwise_and(d, COUNTER_MODULO - 1, out=d)
    np.subtract(d, COUNTER_HALF, out=d)
    np.add(acc, d, out=acc)
    np.copyto(prev, r)
    np.multiply(acc, rpc, out=q)
    np.add(q, offset, out=q)


def velocity_reference(
    q: np.ndarray, q_prev: np.ndarray, qd: np.ndarray, gain: float, b: float
) -> None:
    """``kali_velocity``: backward difference through the first-order low-pass."""
    raw = np.subtract(q, q_prev)
    np.multiply(raw, gain, out=raw)
    np.add(qd, raw, out=qd)
    np.multiply(qd, b, out=qd)
    np.copyto(q_prev, q)


def checks_reference(
    bounds: np.ndarray, q: np.ndarray, demand: np.ndarray, q_min: np.ndarray,
    q_max: np.ndarray, range_check: np.ndarray, fed: np.ndarray, safe: np.ndarray,
    safe_ok: np.ndarray,
) -> int:  # fmt: skip
    """``kali_checks``: NO_FAULT, i (joint i beyond its range) or n + i (its runaway)."""
    n = len(q)
    beyond = (q < q_min) | (q > q_max)
    beyond &= range_check.astype(bool) & fed
    safe_in = (safe > 0.0) & (safe <= math.pi)
    np.copyto(safe_ok, safe, where=safe_in)
    over = (np.abs(demand - q) > safe_ok) & fed
    for k in range(len(bounds) - 1):
        span = slice(int(bounds[k]), int(bounds[k + 1]))
        if beyond[span].any():
            return span.start + int(np.argmax(beyond[span]))
        if over[span].any():
            return n + span.start + int(np.argmax(over[span]))
    return NO_FAULT


def feed_reference(
    demand: np.ndarray, q: np.ndarray, qd: np.ndarray, fed: np.ndarray, slots: np.ndarray,
    not_fed: int, ctrl: np.ndarray, demand_vel: np.ndarray, demand_acc: np.ndarray,
    ff: np.ndarray, mark: np.ndarray,
) -> int:  # fmt: skip
    """``kali_feed``: the slots' demand (and its velocity and acceleration), position,
    velocity and feed-forward, the count fed and done = 0 in ``ctrl``, then busy = the
    slot's mark where fed; the count."""
    for field, src in (
        ("demand", demand), ("position", q), ("velocity", qd), ("demand_vel", demand_vel),
        ("demand_acc", demand_acc), ("ff", ff),
    ):  # fmt: skip
        np.copyto(slots[field], src)
    count = int(np.count_nonzero(fed))
    ctrl["fed"] = count
    ctrl["done"] = 0
    busy = np.full(len(q), not_fed, dtype=np.uint32)
    np.copyto(busy, mark, where=fed)
    np.copyto(slots["busy"], busy)
    return count


def torques_reference(
    slot_torque: np.ndarray, fed: np.ndarray, servo_torque: np.ndarray, ff: np.ndarray,
    torque: np.ndarray,
) -> None:  # fmt: skip
    """``kali_torques``: servo and feed-forward torques of the fed joints, and their sum."""
    f = fed.astype(np.float64)
    np.multiply(slot_torque, f, out=servo_torque)
    np.multiply(ff, f, out=ff)
    np.add(servo_torque, ff, out=torque)


def dac_reference(
    torque: np.ndarray, gkt: np.ndarray, limit: np.ndarray, codes_per_amp: np.ndarray,
    current: np.ndarray, clamped: np.ndarray, zero: float, top: float,
) -> np.ndarray:  # fmt: skip
    """``kali_dac``: motor currents (clamped at the limit) and the DAC codes (uint16)."""
    np.divide(torque, gkt, out=current)
    np.greater(np.abs(current), limit, out=clamped)
    np.minimum(current, limit, out=current)
    np.maximum(current, -limit, out=current)
    codes = current * codes_per_amp
    np.add(codes, zero, out=codes)
    np.rint(codes, out=codes)
    np.maximum(codes, 0, out=codes)
    np.minimum(codes, top, out=codes)
    return codes.astype(np.uint16)


def current_check_reference(
    torque: np.ndarray, fed: np.ndarray, clamped: np.ndarray, over: np.ndarray,
    current_ticks: np.ndarray,
) -> int:  # fmt: skip
    """``kali_current_check``: -1, or the first joint clamped for its ``current_ticks``."""
    np.multiply(torque, fed.astype(np.float64), out=torque)
    np.multiply(over, clamped, out=over)
    np.add(over, clamped, out=over)
    np.multiply(over, fed, out=over)
    hit = over >= current_ticks
    return int(np.argmax(hit)) if hit.any() else -1


def warm() -> list[Path]:
    """Build the libraries if needed and load them; their paths (``python -m
    kali_daemons.core.kernels``)."""
    for library in kernel_args.LIBRARIES:
        load(library)
    return [library_path(library) for library in kernel_args.LIBRARIES]


if __name__ == "__main__":
    for built in warm():
        print(f"kali kernels: {built}")
