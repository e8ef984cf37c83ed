"""The flight recorder: the last seconds of every servo tick, dumped to a file on every halt.

SIO writes one row per servo tick into a ring in the arena (``layout.KEY_FLIGHT_RING``):
positions and velocities, demands and their velocities, the servo, feed-forward and sent
torques, motor currents, each arm's wrist wrench, and its own timing.  When the system
halts (DESIGN 7) the wall clock, once it has stopped, copies the ring in chronological order
to ``flight-<instance>-<time>-tick<T>.npz`` in the instance's log directory, once per fault, and
names the file in the ring's header, so ``kalictl status`` shows it and ``kalictl flight``
summarises what led to the halt.

- ``FlightRecorder``: the writer, inside SIO's cycle (one compiled call a tick, ``record``).
- ``FlightDumper``: the wall clock's side, outside any cycle (the clock is stopped).
- ``read_ring``, ``load``, ``summary``, ``latest_dump``: readers for kalictl and tests.

Long on purpose: the flight recorder's writer, its dump and its reading back, on one ring's
layout.
"""

from __future__ import annotations

import ctypes
import logging
import os
import time
from pathlib import Path

import numpy as np

from ..core import layout
from ..core.arena import Arena
from ..core.errors import ArenaError, ArenaFullError, InstanceError, KaliError
from ..core.kernels import Kernel, View, view
from ..core.layout import ProcState
from ..core.spinlock import pid_alive
from .config import ms_to_ns
from .instance import FaultInfo, Instance, decode
from .paths import log_dir

# of the dump files; 2 added ``n_joints`` (arms of different joint counts, NaN-padded), 3
# ``wrench`` (each arm's wrist sensor, NaN for an arm without one), 4 ``shadow_torque`` (a
# shadow trial's torque, never applied: NaN where none ran), 5 ``qd`` and ``demand_qd`` (the
# velocities); the earlier formats still load
FORMAT_VERSION = 5
READABLE_FORMATS = (1, 2, 3, 4, 5)
log = logging.getLogger("kali.flight")
SIO_IDLE_TIMEOUT_S = 1.0  # how long the dumper waits for SIO to finish a tick in progress
# kali_flight_row's offsets (FlightArgs ``off_<name>``) of the row's timing and last fields
OFFSETS = (
    ("tick", "tick"), ("t", "t_ns"), ("lat", "latency_ns"), ("late", "late_ns"),
    ("wait", "wait_ns"), ("ran", "ran_ns"), ("shadow", "shadow_torque"), ("wrench", "wrench"),
)  # fmt: skip


def _one(rec: np.ndarray, field: str) -> np.ndarray:
    """A writable one-element view of a 0-d record's field (kept for the cycle)."""
    return rec[field].reshape(1)


def attach_ring(arena: Arena, header: np.ndarray) -> np.ndarray:
    """The ring of the flight recorder whose header is ``header``, shaped as SIO laid it out
    (its rows, joints and robots); for readers outside SIO."""
    shape = layout.flight_row(int(header["n_joints"]), int(header["n_robots"]))
    return arena.existing(layout.KEY_FLIGHT_RING, shape, int(header["rows"]))


class FlightRecorder:
    """The ring as SIO writes it: one row per servo tick (``record``), inside the cycle.

    ``create=True`` (SIO) allocates the header and ring sized by ``layout.flight_rows`` from
    the servo period, or attaches to them after a restart and carries on counting.  ``slot``
    is SIO's process-table slot: its ``release_ns`` (the due time of the tick being served)
    gives each row's wake-up lateness.  ``bind`` names, once, the arrays each row copies.
    """

    def __init__(self, inst: Instance, n_joints: int, create: bool = False, slot: int = -1) -> None:
        cfg = inst.config
        period_ns = ms_to_ns(cfg.clock.servo_period_ms)
        rows = layout.flight_rows(period_ns)
        n_robots = len(cfg.robots)
        row = layout.flight_row(n_joints, n_robots)
        a = inst.arena
        if create:
            try:
                self.header = a.record(layout.KEY_FLIGHT, layout.FLIGHT)
                self.ring = a.record(layout.KEY_FLIGHT_RING, row, rows)
            except ArenaFullError as exc:
                raise ArenaFullError(
                    f"flight recorder: {layout.FLIGHT_SECONDS:g} s of {n_joints} joints at a "
                    f"{cfg.clock.servo_period_ms:g} ms servo period needs {rows} rows of "
                    f"{row.itemsize} B ({rows * row.itemsize // 1024} KiB), "
                    f"{str(exc).removeprefix('arena: ')}; raise "
                    f"arena_kib (now {cfg.arena_kib}) in the config"
                ) from None
            h = self.header
            if int(h["rows"]) == 0:
                h["rows"], h["n_joints"], h["servo_period_ns"] = rows, n_joints, period_ns
                h["n_robots"] = n_robots
        else:
            self.header = a.existing(layout.KEY_FLIGHT, layout.FLIGHT)
            self.ring = a.existing(layout.KEY_FLIGHT_RING, row, rows)
        h = self.header
        held = (int(h["rows"]), int(h["n_joints"]), int(h["n_robots"]))
        if held != (rows, n_joints, n_robots):
            raise ArenaError(
                f"flight recorder: ring holds {held[0]} rows of {held[1]} joints and {held[2]} "
                f"robots, this process expects {rows} of {n_joints} and {n_robots}"
            )
        self.n_joints = n_joints
        self._rows = rows
        self._count = _one(self.header, "count")
        r = self.ring
        self._tick, self._t = r["tick"], r["t_ns"]
        self._lat, self._late, self._wait = r["latency_ns"], r["late_ns"], r["wait_ns"]
        self._ran = r["ran_ns"]
        self._dst = tuple(r[f] for f in layout.FLIGHT_FIELDS)
        self._wrench = r["wrench"]
        self._src: tuple[np.ndarray, ...] = ()
        self._src_wrench = np.zeros((n_robots, layout.WRENCH))
        self._release = (
            inst.procs["release_ns"][slot : slot + 1] if slot >= 0 else np.zeros(1, np.int64)
        )

    def bind(
        self,
        q: np.ndarray,
        qd: np.ndarray,
        demand: np.ndarray,
        demand_qd: np.ndarray,
        servo_torque: np.ndarray,
        ff_torque: np.ndarray,
        torque: np.ndarray,
        current: np.ndarray,
        shadow_torque: np.ndarray,
        wrench: np.ndarray | None = None,
    ) -> None:
        """Outside the cycle: the arrays (flat over all joints, ``joints.JointMap`` order)
        every row copies, and ``wrench`` (robots × 6, e.g. ``FT_STATE['tool']``; None: no
        sensors, zeros recorded); they must stay the same objects, updated in place."""
        src = (q, qd, demand, demand_qd, servo_torque, ff_torque, torque, current, shadow_torque)
        for name, a in zip(layout.FLIGHT_FIELDS, src, strict=True):
            if a.shape != (self.n_joints,):
                raise ArenaError(
                    f"flight recorder: {name} has shape {a.shape}, expected ({self.n_joints},)"
                )
        if wrench is not None:
            if wrench.shape != self._src_wrench.shape:
                raise ArenaError(
                    f"flight recorder: wrench has shape {wrench.shape}, expected "
                    f"{self._src_wrench.shape}"
                )
            self._src_wrench = wrench
        self._src = src
        self._bind_kernel()

    def _bind_kernel(self) -> None:
        """``record_reference`` compiled (``csrc/flightrec.c``'s ``kali_flight_row``), bound to the
        ring and the sources ``bind`` named; it carries on the ring's count.  Outside the
        cycle."""
        fields = self.ring.dtype.fields
        assert fields is not None
        cols = layout.FLIGHT_FIELDS[:-1]  # the float64 ones; shadow_torque is single
        for name, a in zip(layout.FLIGHT_FIELDS, self._src, strict=True):
            assert a.dtype == np.float64, f"flight recorder: {name} is {a.dtype}, not float64"
            assert fields[name][0].base == (np.float32 if name == "shadow_torque" else np.float64)
        table = (View * len(cols))(*(view(a) for a in self._src[: len(cols)]))
        offsets = np.array([fields[f][1] for f in cols], dtype=np.int64)
        w = self._src_wrench
        assert w.dtype == np.float64 and w.ndim == 2
        self._kernel = Kernel(
            "kali_flight_row",
            (table, offsets, w, self.ring, self._src, self._release, self._count),
            n=self.n_joints,
            n_robots=w.shape[0],
            rows=self._rows,
            ring=self.ring.ctypes.data,
            row_size=self.ring.dtype.itemsize,
            **{f"off_{k}": fields[f][1] for k, f in OFFSETS},
            off_cols=offsets.ctypes.data,
            cols=ctypes.cast(table, ctypes.POINTER(View)),
            n_cols=len(cols),
            shadow=self._src[-1],
            wrench=w.ctypes.data,
            wrench_row=w.strides[0],
            wrench_col=w.strides[1],
            release=self._release.ctypes.data,
            count=self._count.ctypes.data,
        )
        self._args = self._kernel.args

    @property
    def kernel_args(self) -> ctypes.Structure:
        """The row kernel's argument block (``bind`` first), for a kernel that writes the row
        itself (SIO's compiled tick sets its tick and times there)."""
        return self._args

    def record(self, tick: int, t_read_ns: int, latency_ns: int, wait_ns: int, ran_ns: int) -> None:
        """Inside the cycle (no allocation, no I/O, no logging): one servo tick's row, as
        ``record_reference`` writes it (compiled: ``bind`` first)."""
        a = self._args
        a.tick, a.t_read, a.latency, a.wait, a.ran = tick, t_read_ns, latency_ns, wait_ns, ran_ns
        self._kernel()

    def record_reference(
        self, tick: int, t_read_ns: int, latency_ns: int, wait_ns: int, ran_ns: int
    ) -> None:
        """One servo tick's row, in numpy: what ``record`` does (its kernel's reference).
        ``wait_ns`` is the part of ``latency_ns`` SIO slept for the servos (the SVs' share,
        on every CPU), so a slow tick tells whether SIO or the servos were slow; ``ran_ns``
        the CPU time SIO's thread had from the read to the write (``rt.thread_time_ns``: its
        work, with posting the feeds and waking inside the wait).  A tick whose own share
        (latency - wait) is far above it lost the difference to something else on its CPU:
        the clock above it, interrupts, or the host taking the vCPU (a pause the host does
        not report as steal still counts as run time).

        The row count is published last, so a reader copying the ring knows which rows may
        be torn (``read_ring``).
        """
        n = int(self._count[0])
        r = n % self._rows
        self._tick[r] = tick
        self._t[r] = t_read_ns
        self._lat[r] = latency_ns
        self._late[r] = t_read_ns - self._release[0]
        self._wait[r] = wait_ns
        self._ran[r] = ran_ns
        for dst, src in zip(self._dst, self._src, strict=True):  # layout.FLIGHT_FIELDS
            dst[r] = src
        self._wrench[r] = self._src_wrench
        self._count[0] = n + 1


def read_ring(header: np.ndarray, ring: np.ndarray, writer_idle: bool = False) -> np.ndarray:
    """A consistent copy of the ring's rows, oldest first, while the writer may still write.

    Rows the writer may have overwritten during the copy (it publishes ``count`` after each
    row, so the row after the last counted one may be half written) are dropped, so every
    row returned is whole; ``writer_idle``: the writer is known to be between rows.
    """
    rows = int(header["rows"])
    before = int(header["count"])
    data = ring[:rows].copy()
    after = int(header["count"])
    first = max(0, before - rows, after + (0 if writer_idle and after == before else 1) - rows)
    return data[np.arange(first, before) % rows]


def fault_info(inst: Instance) -> FaultInfo:
    """A copy of the instance's fault record (the latest fault, even if cleared)."""
    return inst.read_fault()


class FlightDumper:
    """The wall clock's side: after a halt, write the ring to a file, once per fault.

    Outside any cycle: it runs when the clock has stopped (nothing real-time is signalled),
    waits for SIO to finish a tick it may still be in, then writes the file.  A fault raised
    while the ring does not exist yet (SIO not configured) is not dumped.
    """

    def __init__(self, inst: Instance, directory: Path | None = None) -> None:
        self.inst = inst
        self.directory = log_dir(inst.name) if directory is None else directory
        self.header: np.ndarray | None = None
        self.ring: np.ndarray | None = None
        self._sio = next((p.name for p in inst.config.processes if p.kind == "sio"), "sio")

    def close(self) -> None:
        """Drop the views (they pin the arena's buffer); safe to call twice."""
        self.header = self.ring = None

    def _attach(self) -> bool:
        if self.header is not None:
            return True
        a = self.inst.arena
        if a.lookup(layout.KEY_FLIGHT) is None or a.lookup(layout.KEY_FLIGHT_RING) is None:
            return False
        header = a.existing(layout.KEY_FLIGHT, layout.FLIGHT)
        if int(header["rows"]) == 0:
            return False  # SIO is laying it out
        self.ring = attach_ring(a, header)
        self.header = header
        return True

    def pending(self) -> bool:
        """True when a fault has been raised that is not dumped yet (cheap: a few reads)."""
        fault_ns = int(self.inst.fault["time_ns"])
        if fault_ns == 0 or not self._attach():
            return False
        assert self.header is not None
        return int(self.header["dumped_fault_ns"]) != fault_ns

    def dump_if_halted(self) -> Path | None:
        """Dump the ring if a fault was raised since the last dump; the file, or None."""
        if not self.pending():
            return None
        assert self.header is not None and self.ring is not None
        h = self.header
        fault = fault_info(self.inst)
        h["dumped_fault_ns"] = fault.time_ns  # claimed first: one attempt per fault
        t0 = time.monotonic()
        data = read_ring(h, self.ring, writer_idle=self._wait_sio_idle())
        try:
            path = write_dump(self.inst, data, fault, self.directory)
        except Exception as exc:  # a failed dump must not take the wall clock down with it
            why = f"flight recorder: dump to {self.directory} failed: {type(exc).__name__}: {exc}"
            log.error("%s", why)
            h["dump_message"] = _fit(why)
            return None
        log.info("flight recorder: %s", path)
        h["dump_path"] = str(path).encode()[: layout.FLIGHT_PATH_BYTES - 1]
        h["dump_tick"] = fault.tick
        h["dumps"] = int(h["dumps"]) + 1
        span = f"ticks {int(data['tick'][0])}..{int(data['tick'][-1])}" if len(data) else "empty"
        h["dump_message"] = _fit(
            f"{len(data)} servo ticks ({span}) in {1000 * (time.monotonic() - t0):.0f} ms"
        )
        return path

    def _wait_sio_idle(self) -> bool:
        """Wait (bounded) until SIO has acknowledged the last tick it was signalled, or is no
        longer cycling; True if it is idle (between rows)."""
        i = self.inst.find_slot(self._sio)
        if i < 0:
            return True
        p = self.inst.procs
        deadline = time.monotonic() + SIO_IDLE_TIMEOUT_S
        while True:
            if int(p["ack_tick"][i]) >= int(p["signal_tick"][i]):
                return True
            if not pid_alive(int(p["pid"][i])):
                return False  # killed, perhaps in the middle of a row
            if int(p["state"][i]) != ProcState.ACTIVE:
                return True  # its cycle raised or it left: not inside ``record``
            if time.monotonic() > deadline:
                return False
            time.sleep(0.001)


def _fit(text: str) -> bytes:
    return text.encode()[: layout.MESSAGE_BYTES - 1]


def dump_name(instance: str, fault: FaultInfo) -> str:
    """``flight-<instance>-<YYYYmmdd-HHMMSS>-tick<T>.npz``: sorts by time, names the tick."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(fault.time_ns / 1e9))
    return f"flight-{instance}-{stamp}-tick{fault.tick}.npz"


def write_dump(inst: Instance, data: np.ndarray, fault: FaultInfo, directory: Path) -> Path:
    """Write ``data`` (ring rows, oldest first) and the fault to a new file; its path.

    Arrays per field, shaped (ticks, robots, J) with J the most joints an arm has (an arm with fewer
    has NaN in the rest; ``n_joints`` says how many it has); the fault and the robot and joint names
    as plain strings, so ``np.load`` needs no pickle.  Written under a temporary name and renamed,
    so a reader never sees half a file; an existing file is never overwritten.
    """
    cfg = inst.config
    names = [r.name for r in cfg.robots]
    nr = len(names)
    jm = cfg.joints
    width = jm.widest
    joints = inst.arena.existing(layout.KEY_JOINTS, layout.JOINT_STATE, jm.total)

    def by_robot(flat: np.ndarray) -> np.ndarray:
        """(..., joints) flat → (..., robots, width), NaN where an arm has no such joint."""
        out = np.full((*flat.shape[:-1], nr, width), np.nan)
        for k in range(nr):
            out[..., k, : jm.counts[k]] = flat[..., jm.span(k)]
        return out

    def per_robot(values: list[np.ndarray]) -> np.ndarray:
        return by_robot(np.concatenate([np.asarray(v, dtype=np.float64) for v in values]))

    arrays: dict[str, np.ndarray] = {
        "format": np.array(FORMAT_VERSION),
        "instance": np.array(inst.name),
        "robots": np.array(names),
        "n_joints": np.array(jm.counts),
        "joints": np.array([f"joint {j + 1}" for j in range(width)]),
        "servo_period_ns": np.array(ms_to_ns(cfg.clock.servo_period_ms)),
        "base_tick_ns": np.array(int(inst.clock["base_tick_ns"])),
        "fault_code": np.array(fault.code),
        "fault_process": np.array(fault.process),
        "fault_tick": np.array(fault.tick),
        "fault_message": np.array(fault.message),
        "fault_time_ns": np.array(fault.time_ns),
        "safe": by_robot(np.array(joints["safe"])),
        "current_limit": per_robot([r.type.drive.max_current for r in cfg.robots]),
        "rad_per_count": per_robot([r.type.drive.rad_per_count for r in cfg.robots]),
    }
    for f in ("tick", "t_ns", "latency_ns", "late_ns", "wait_ns", "ran_ns"):
        arrays[f] = np.ascontiguousarray(data[f])
    for f in layout.FLIGHT_FIELDS:
        arrays[f] = by_robot(np.ascontiguousarray(data[f]).reshape(len(data), jm.total))
    wrench = np.array(data["wrench"], dtype=np.float64)  # (ticks, robots, 6)
    wrench[:, [r.ft.sheet is None for r in cfg.robots]] = np.nan
    arrays["wrench"] = wrench
    directory.mkdir(parents=True, exist_ok=True)
    base = dump_name(inst.name, fault)
    path = directory / base
    k = 1
    while path.exists():
        k += 1
        path = directory / base.replace(".npz", f"-{k}.npz")
    part = path.with_name(path.name + ".part")
    with open(part, "xb") as out:
        np.savez(out, **arrays)  # type: ignore[arg-type]  # (none of them named allow_pickle)
    os.replace(part, path)
    return path


def dump_now(inst: Instance, directory: Path | None = None) -> Path:
    """Write the ring as it stands, without a halt (``kalictl flight --now``), to
    ``ring-<instance>-<time>-tick<T>.npz`` in the log directory (never taken for a halt's
    dump); the fault fields say it was asked for.  Outside any cycle."""
    header = inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
    if int(header["rows"]) == 0:
        raise InstanceError(f"flight recorder: instance '{inst.name}': SIO has not laid it out")
    data = read_ring(header, attach_ring(inst.arena, header))
    tick = int(inst.clock["tick"])
    asked = FaultInfo(
        code="NONE", process="kalictl", tick=tick,
        message="the ring as it stood, asked for (kalictl flight --now); no halt",
        time_ns=time.time_ns(), pid=os.getpid(), active=False, count=int(inst.fault["count"]),
    )  # fmt: skip
    path = write_dump(inst, data, asked, directory or log_dir(inst.name))
    final = path.with_name(path.name.replace("flight-", "ring-", 1))
    os.replace(path, final)
    return final


def latest_dump(directory: Path, instance: str) -> Path | None:
    """The newest dump of ``instance`` in ``directory``, or None."""
    files = [p for p in directory.glob(f"flight-{instance}-*.npz") if p.is_file()]
    return max(files, key=lambda p: p.stat().st_mtime_ns) if files else None


def find_latest(instance: str, wait_s: float = 5.0) -> Path:
    """The dump of the running instance's latest halt (waiting up to ``wait_s`` for one still
    being written), or, with no instance running, the newest in its log directory.

    Never an earlier halt's dump as this one: a running instance that has not halted, or
    whose latest halt has no dump (the dump failed or is not written yet), is an
    InstanceError saying so, naming the dump there is and whose it is."""
    try:
        inst = Instance.attach(instance)
    except KaliError:
        inst = None
    directory = log_dir(instance)
    if inst is not None:
        with inst:
            return _dump_of_this_halt(inst, directory, wait_s)
    found = latest_dump(directory, instance)
    if found is None:
        raise InstanceError(
            f"flight recorder: no dump of instance '{instance}' in {directory} (one is written "
            f"at every halt; name a file, or set $KALI_LOG_DIR as it was at kalictl start)"
        )
    return found


def _dump_of_this_halt(inst: Instance, directory: Path, wait_s: float) -> Path:
    """The dump whose fault time is the instance's latest fault's; InstanceError if none."""
    fault_ns = int(inst.fault["time_ns"])
    if fault_ns == 0:
        older = latest_dump(directory, inst.name)
        where = (
            f"; {older} is from an earlier run (kalictl flight {older} reads it)"
            if older
            else f"; no dump in {directory}"
        )
        raise InstanceError(
            f"flight recorder: instance '{inst.name}' has not halted since it started{where}"
        )
    dumper = FlightDumper(inst, directory)
    try:
        deadline = time.monotonic() + wait_s
        while dumper.pending() and time.monotonic() < deadline:
            time.sleep(0.01)
        h = dumper.header
        named = decode(h["dump_path"]) if h is not None else ""
        why = decode(h["dump_message"]) if h is not None else "no flight recorder in the arena"
    finally:
        dumper.close()
    if named and dump_fault_ns(Path(named)) == fault_ns:
        return Path(named)
    earlier = f"; {named} is of an earlier halt" if named else ""
    raise InstanceError(
        f"flight recorder: no dump of this halt ({inst.fault_text(last=True)}): {why}{earlier}"
    )


def dump_fault_ns(path: Path) -> int | None:
    """The fault time recorded in a dump file, or None if it cannot be read."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return int(z["fault_time_ns"])
    except Exception:  # a missing, damaged or foreign file: it is not this halt's dump
        return None


def load(path: Path) -> dict[str, np.ndarray]:
    """A dump file's arrays (no pickle); InstanceError if it is not a readable dump: cut
    short, not a zip, a member that does not decompress, or arrays of the wrong shapes."""
    not_dump = f"flight recorder: {path} is not a flight-recorder dump"
    try:
        with np.load(path, allow_pickle=False) as z:
            d = {k: z[k] for k in z.files}
    except (FileNotFoundError, PermissionError, IsADirectoryError) as exc:
        raise InstanceError(f"flight recorder: cannot read {path}: {exc.strerror}") from None
    except ValueError:  # not .npz: numpy's advice to allow pickles is no advice here
        raise InstanceError(
            f"{not_dump} (the .npz Kali writes at a halt, flight-INSTANCE-*.npz)"
        ) from None
    except Exception as exc:  # zipfile, zlib, EOF, OSError: a file cut short or corrupt
        why = str(exc).splitlines()[0][:120] if str(exc) else type(exc).__name__
        raise InstanceError(f"{not_dump} (damaged: {why})") from None
    missing = [k for k in DUMP_KEYS if k not in d]
    if missing:
        raise InstanceError(f"{not_dump} (no {', '.join(missing)})")
    if d["format"].shape != () or int(d["format"]) not in READABLE_FORMATS:
        raise InstanceError(
            f"flight recorder: {path} has format {d['format']!r:.40}, this Kali reads "
            f"{FORMAT_VERSION}"
        )
    _check_shapes(d, not_dump)
    return d


DUMP_KEYS = (
    "format", "robots", "servo_period_ns", "fault_code", "fault_process", "fault_tick",
    "fault_message", "rad_per_count", "current_limit", "tick", "q", "demand", "torque",
    "current",
)  # fmt: skip


def _check_shapes(d: dict[str, np.ndarray], not_dump: str) -> None:
    """Every array the summary reads has the shape ``write_dump`` gives it."""
    robots = d["robots"]
    nr = len(robots) if robots.ndim == 1 else -1
    ticks = d["tick"]
    n = len(ticks) if ticks.ndim == 1 else -1
    rpc = d["rad_per_count"]
    width = rpc.shape[-1] if rpc.ndim == 2 and 1 <= rpc.shape[-1] <= layout.MAX_JOINTS else -1
    want = {
        "robots": (nr,),
        "tick": (n,),
        "rad_per_count": (nr, width),
        "current_limit": (nr, width),
    }
    if "n_joints" in d:
        want["n_joints"] = (nr,)
    for f in ("servo_period_ns", "fault_code", "fault_process", "fault_tick", "fault_message"):
        want[f] = ()
    for f in layout.FLIGHT_FIELDS:
        if f in d:
            want[f] = (n, nr, width)
    for f in ("t_ns", "latency_ns", "late_ns", "wait_ns", "ran_ns"):
        if f in d:
            want[f] = (n,)
    if "wrench" in d:
        want["wrench"] = (n, nr, layout.WRENCH)
    numeric = [
        f for f in want if f not in ("robots", "fault_code", "fault_process", "fault_message")
    ]
    for f, shape in want.items():
        a = d[f]
        if nr < 0 or n < 0 or a.shape != shape:
            expected = str(shape).replace("-1", "n")  # n: a dimension already wrong
            raise InstanceError(f"{not_dump} ({f} has shape {a.shape}, expected {expected})")
        if f in numeric and a.dtype.kind not in "iuf":
            raise InstanceError(f"{not_dump} ({f} holds {a.dtype}, expected numbers)")


def summary(d: dict[str, np.ndarray], last: int = 10) -> list[str]:
    """Lines for ``kalictl flight``: the fault, the ticks covered, each robot's worst tracking
    error, torque, current and (an arm with a wrist sensor) contact force over the whole
    window, and tick by tick up to the fault."""
    ticks = d["tick"]
    fault_tick = int(d["fault_tick"])
    period_ms = int(d["servo_period_ns"]) / 1e6
    lines = [f"fault: {d['fault_code']} in {d['fault_process']} at tick {fault_tick}: "]
    lines[0] += str(d["fault_message"])
    if len(ticks) == 0:
        return [*lines, "the ring is empty: SIO had not run a tick"]

    def us(field: str) -> np.ndarray:
        """A timing field in µs; NaN for a field older dumps do not have."""
        return d[field] / 1e3 if field in d else np.full(len(ticks), np.nan)

    lat_us, late_us, wait_us, ran_us = (
        us(f) for f in ("latency_ns", "late_ns", "wait_ns", "ran_ns")
    )
    lines += [
        f"covers ticks {int(ticks[0])}..{int(ticks[-1])}: {len(ticks)} servo ticks, "
        f"{len(ticks) * period_ms / 1000:.3f} s at {period_ms:g} ms",
        f"SIO sensor-to-DAC p50 {np.median(lat_us):.0f} µs, max {lat_us.max():.0f} µs "
        f"(asleep for the servos p50 {np.median(wait_us):.0f} µs, max {wait_us.max():.0f} "
        f"µs; SIO's own CPU time p50 {np.median(ran_us):.0f} µs, max {ran_us.max():.0f} µs); "
        f"wake-up lateness p50 {np.median(late_us):.0f} µs, max {late_us.max():.0f} µs",
    ]
    err = (d["demand"] - d["q"]) / d["rad_per_count"]  # (ticks, robots, J) encoder counts
    torque, current = d["torque"], d["current"]
    load_pct = 100 * np.abs(current) / d["current_limit"]
    names = [str(n) for n in d["robots"]]
    # the contact force's magnitude, (ticks, robots): NaN for an arm without a sensor and in
    # a dump older than format 3
    wrench = d.get("wrench")
    force = (
        np.full(load_pct.shape[:2], np.nan)
        if wrench is None
        else np.sqrt(np.sum(wrench[..., :3] ** 2, axis=-1))
    )
    sensed = [bool(np.isfinite(force[:, k]).all()) for k in range(len(names))]

    def worst(a: np.ndarray) -> tuple[float, int, int]:
        """Signed value, row and joint of the largest |a| in (ticks, J), NaN (no such joint)
        left out; the latest of ties."""
        flat = np.nan_to_num(np.abs(a[::-1]), nan=-1.0).reshape(-1)
        row, j = np.unravel_index(int(np.argmax(flat)), a.shape)
        row = a.shape[0] - 1 - int(row)
        return float(a[row, j]), row, int(j)

    lines.append("worst over the window per robot (joint, tick):")
    for k, name in enumerate(names):
        e, er, ej = worst(err[:, k])
        t, tr, tj = worst(torque[:, k])
        c, cr, cj = worst(load_pct[:, k])
        line = (
            f"  {name:<8} error {e:+.1f} counts (j{ej + 1}, {int(ticks[er])})  "
            f"torque {t:+.2f} N·m (j{tj + 1}, {int(ticks[tr])})  "
            f"current {c:.0f} % of limit (j{cj + 1}, {int(ticks[cr])})"
        )
        if sensed[k]:
            f, fr, _ = worst(force[:, k : k + 1])
            line += f"  contact force {f:.1f} N ({int(ticks[fr])})"
        lines.append(line)
    end = int(np.searchsorted(ticks, fault_tick, side="right"))  # rows up to the fault
    first = max(0, end - last)
    shown = range(first, len(ticks))
    lines.append(
        f"ticks {int(ticks[first])}..{int(ticks[-1])}, worst joint per robot: "
        "tracking error (counts), torque (N·m), current (A)"
        + (", contact force (N)" if any(sensed) else "")
    )
    lines.append(
        f"  {'tick':>9} {'late µs':>7} {'lat µs':>6} {'servos':>6} {'ran':>5}  "
        + "  ".join(
            f"{name:<{37 if s else 30}}" for name, s in zip(names, sensed, strict=True)
        ).rstrip()
    )
    for row in shown:
        cells = []
        for k in range(len(names)):
            e, _, ej = worst(err[row : row + 1, k])
            t, _, tj = worst(torque[row : row + 1, k])
            c, _, cj = worst(current[row : row + 1, k])
            cell = f"{e:+7.1f} j{ej + 1} {t:+7.2f} j{tj + 1} {c:+6.2f} j{cj + 1}"
            cells.append(f"{cell} {force[row, k]:5.1f}N" if sensed[k] else cell)
        tick = int(ticks[row])
        mark = "  <- fault" if tick == fault_tick else ("  (after)" if tick > fault_tick else "")
        lines.append(
            f"  {tick:>9} {late_us[row]:>7.0f} {lat_us[row]:>6.0f} {wait_us[row]:>6.0f} "
            f"{ran_us[row]:>5.0f}  " + "  ".join(cells) + mark
        )
    return lines
