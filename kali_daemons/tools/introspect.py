"""Everything an instance shows about itself, gathered once as plain data (DESIGN 8).

``snapshot`` is what ``kalictl status --json`` prints and what ``kalictl top`` draws: the
clock, the fault, every process's timing, every robot's state, the servo level's latencies,
the TG's requests, the recent missed deadlines, and the flight recorder's last dump.  Like
``halcmd show``, it only reads the arena (Type 4 records, no locks taken but the fault's and
the directory's), so it can run beside a working instance at any time, and it reads the
records directly rather than through ``ServoLevel``, so it works before SIO has laid them
out, and without loading servo plugins.

Units are in the keys (``_rad``, ``_nm``, ``_a``, ``_us``, ``_ms``); values are plain JSON
types, a quantity with no value yet (a percentile of an empty histogram) is ``None``.
"""

from __future__ import annotations

import enum
import fnmatch
import math
import time
from typing import Any

import numpy as np

from ..core import layout
from ..core.layout import CalibState, FfMode, FfState, PowerState, RequestState, RunMode
from ..core.spinlock import holder_text, pid_alive
from ..runtime.instance import Instance, decode, time_ms
from ..servo import shadow
from ..tg import records
from . import launcher

FF_SCALARS = ("weight", "stale_ticks", "stale_events", "heartbeat_tick", "rows_written")


def plain(x: Any) -> Any:
    """``x`` with numpy scalars and arrays as Python ones and NaN or ±inf as None."""
    if isinstance(x, dict):
        return {k: plain(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [plain(v) for v in x]
    if isinstance(x, np.ndarray):
        return plain(x.tolist())
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def pss_kib(pid: int) -> tuple[int, int]:
    """Process ``pid``'s proportional set size and resident set size, KiB, from
    ``/proc/PID/smaps_rollup``.  PSS divides each shared page among the processes mapping it,
    so the PSS of a daemon set adds up to the memory the set takes; RSS counts a shared
    library in full in every process.  ``OSError`` if the process is gone or not ours to
    read."""
    pss = rss = -1
    with open(f"/proc/{pid}/smaps_rollup") as f:
        for line in f:
            key, _, value = line.partition(":")
            if key == "Pss":
                pss = int(value.split()[0])
            elif key == "Rss":
                rss = int(value.split()[0])
    if pss < 0 or rss < 0:  # a kernel thread or a zombie: no mappings at all
        raise ProcessLookupError(f"process {pid}: no memory mappings in /proc/{pid}/smaps_rollup")
    return pss, rss


def _name(kind: type[enum.IntEnum], value: int) -> str:
    """An enum word's name, or INVALID(value) for a word a client wrote outside the enum (a
    snapshot shows the arena as it is and never raises on it)."""
    try:
        return kind(value).name
    except ValueError:
        return f"INVALID({value})"


def percentiles_us(hist: np.ndarray, qs: tuple[float, ...] = (0.5, 0.99, 0.999)) -> list[float]:
    """Quantiles of a lateness-binned histogram in µs (NaN when it is empty)."""
    return [launcher.percentile(hist, q) for q in qs]


def clock_mode(inst: Instance) -> str:
    """The wall clock's mode as status says it: running, stopped, stepping ... as its record
    has it, or ``dead`` once its process is gone (the record keeps its last word)."""
    slot = inst.find_slot("wallclock")
    pid = int(inst.procs[slot]["pid"]) if slot >= 0 else 0
    if pid > 0 and not pid_alive(pid):
        return "dead"
    return _name(RunMode, int(inst.clock["mode"])).lower()


class Introspector:
    """Views of one attached instance, taken once and reused by every ``snapshot``.

    Records that do not exist yet (SIO, the TG or the dynamics process not configured) are
    looked up again at the next snapshot.
    """

    def __init__(self, inst: Instance) -> None:
        self.inst = inst
        cell = inst.cell  # the arena alone: status never parses the config or runs user code
        self.names = list(cell.names)
        self.cell = cell
        self.joints = cell.joints
        self.sv_names = [f"sv.{k}" for k in range(cell.n_svs)]
        self._views: dict[str, np.ndarray] = {}
        self._servo_names: tuple[list[str], list[str]] | None = None  # _names, once written
        self._names_generation = -1  # the servo loads table's, when they were read

    def _view(self, key: str, dtype: np.dtype, count: int | None = None) -> np.ndarray | None:
        v = self._views.get(key)
        if v is None:
            found = self.inst.arena.lookup(key)
            if found is None or found[1] < (count or 1) * dtype.itemsize:
                return None
            v = self._views[key] = self.inst.arena.existing(key, dtype, count)
        return v

    def close(self) -> None:
        """Drop the views (they pin the arena's buffer); safe to call twice."""
        self._views.clear()

    # ------------------------------------------------------------------ pieces

    def histograms(self) -> tuple[np.ndarray, np.ndarray | None]:
        """Copies of every slot's wake-up lateness histogram and of SIO's latency histogram,
        for statistics over an interval (``kalictl top``)."""
        ctrl = self._view(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
        lat = None if ctrl is None else np.array(ctrl["latency_hist"], dtype=np.int64)
        return np.array(self.inst.procs["hist"], dtype=np.int64), lat

    def _clock(self) -> dict[str, Any]:
        c = self.inst.clock
        return {
            "mode": clock_mode(self.inst),
            "tick": int(c["tick"]),
            "time_ms": time_ms(c),
            "base_tick_ms": int(c["base_tick_ns"]) / 1e6,
            "overruns": int(c["overruns"]),
            "skipped_ticks": int(c["skipped_ticks"]),
        }

    def _fault(self) -> dict[str, Any]:
        f = self.inst.read_fault()
        return {
            "active": f.active,
            "code": f.code,
            "process": f.process,
            "pid": f.pid,
            "tick": f.tick,
            "time_ns": f.time_ns,
            "message": f.message,
            "count": f.count,
            "text": self.inst.fault_text(last=True),
        }

    def _locks(self) -> list[dict[str, Any]]:
        return [{"name": h.name, "pid": h.pid, "holder": h.holder} for h in self.inst.held_locks()]

    def _processes(self) -> list[dict[str, Any]]:
        rows = launcher.describe(self.inst)
        for r in rows:
            p = self.inst.procs[int(r["slot"])]
            hist = np.array(p["hist"], dtype=np.int64)
            r["late_p999_us"] = launcher.percentile(hist, 0.999)
            r["max_consecutive_misses"] = int(p["max_consecutive_misses"])
            r["ack_tick"] = int(p["ack_tick"])
        return rows

    def _robots(self) -> list[dict[str, Any]] | None:
        nr = len(self.names)
        rs = self._view(layout.KEY_ROBOTS, layout.ROBOT_STATE, nr)
        js = self._view(layout.KEY_JOINTS, layout.JOINT_STATE, self.joints.total)
        if rs is None or js is None:
            return None
        ff = self._view(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, nr)
        slots = self._view(layout.KEY_SLOTS, layout.SERVO_SLOT, self.joints.total)
        cut = [self.inst.hardware(k).amplifiers_cut()[k] for k in range(nr)]
        out = []
        for k, name in enumerate(self.names):
            r = rs[k].copy()  # one consistent-enough copy of a Type 4 record
            j = js[self.joints.span(k)].copy()  # and of the arm's joints
            err = j["demand"] - j["q"]
            sio_power = _name(PowerState, int(r["power"]))
            out.append(
                {
                    "name": name,
                    "tick": int(r["tick"]),
                    # what drives the motors: OFF once the board cuts them (an e-stop, a halt)
                    # even before SIO, stopped with the clock or stalled, has seen it
                    "power": "OFF" if cut[k] else sio_power,
                    "power_sio": sio_power,  # SIO's last word
                    "amplifiers_cut": cut[k],
                    "calibrated": bool(r["calibrated"]),
                    "calibration": CalibState(int(r["calib_state"])).name,
                    "pots_read": bool(r["pots_read"]),
                    "guided": bool(r["guided"]),  # by hand: the TG will not move it
                    "n_joints": self.joints.counts[k],
                    "q_rad": j["q"],
                    "qd_rad_s": j["qd"],
                    "demand_rad": j["demand"],
                    "error_rad": err,
                    "error_counts": err / self.cell.rad_per_count[k],
                    "safe_rad": j["safe"],
                    "servo_torque_nm": j["servo_torque"],
                    "ff_torque_nm": j["ff_torque"],
                    "torque_nm": j["torque"],
                    "current_a": j["current"],
                    "current_limit_a": self.cell.max_current[k],
                    "message": decode(r["message"]),
                    "feedforward": None if ff is None else self._ff(ff[k]),
                    "servo": None
                    if slots is None
                    else self._servos(name, r, slots[self.joints.span(k)]),
                }
            )
        return out

    def _names(self) -> tuple[list[str], list[str]]:
        """The joint servos' and the robot-level servos' names, each in registry order
        (SIO's ``servo.names``, written at its first start and by each servo plugin loaded
        while running: read again once the loads table's generation moves; empty before)."""
        loads = self._view(layout.KEY_SERVO_LOADS, layout.SERVO_LOADS)
        generation = -1 if loads is None else int(loads["generation"])
        if self._servo_names is not None and generation == self._names_generation:
            return self._servo_names
        self._names_generation = generation
        found = self.inst.arena.lookup(layout.KEY_SERVO_NAMES)
        if found is None:
            return [], []
        raw = self._view(
            layout.KEY_SERVO_NAMES, layout.SERVO_NAME, found[1] // layout.SERVO_NAME.itemsize
        )
        if raw is None:
            return [], []
        recs = raw.copy()
        joint = [decode(bytes(r["name"])) for r in recs if not r["robot_level"]]
        robot = [decode(bytes(r["name"])) for r in recs if r["robot_level"]]
        if joint:  # SIO has written them
            self._servo_names = (joint, robot)
        return joint, robot

    def _servos(self, robot: str, r: np.void, slots: np.ndarray) -> dict[str, Any]:
        """What servos a robot runs, by name: its robot-level servo (None: its joint
        servos) and each joint's, and its shadow trials (``kali_daemons.servo.shadow``)."""
        joint, arm = self._names()
        s = slots.copy()
        a = int(r["arm_algo"])
        rows = shadow.robot_trials(robot, r, s, joint, arm)
        return {
            "robot": None if a == layout.ARM_NONE else shadow.name_of(arm, a),
            "joints": [shadow.name_of(joint, int(x)) for x in s["algo"]],
            "trials": [
                {
                    "joint": t.joint,
                    "level": t.level,
                    "shadow": t.shadow,
                    "state": t.state.name,
                    "ticks": t.ticks,
                    "rms_nm": t.rms,
                    "peak_nm": t.peak,
                }
                for t in rows
            ],
        }

    @staticmethod
    def _ff(rec: np.void) -> dict[str, Any]:
        names = rec.dtype.names or ()
        out: dict[str, Any] = {
            "mode": _name(FfMode, int(rec["mode"])) if "mode" in names else None,
            "state": _name(FfState, int(rec["state"])) if "state" in names else None,
        }
        for f in FF_SCALARS:
            if f in names:
                out[f] = rec[f].item()
        return out

    def _servo(self) -> dict[str, Any] | None:
        ctrl = self._view(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
        if ctrl is None:
            return None
        hist = np.array(ctrl["latency_hist"], dtype=np.int64)
        p50, p99, p999 = percentiles_us(hist)
        sv = []
        for k, name in enumerate(self.sv_names):
            h = np.array(ctrl["sv_exec_hist"][k], dtype=np.int64)
            e50, e99, _ = percentiles_us(h)
            sv.append(
                {
                    "name": name,
                    "servos": int(ctrl["sv_servos"][k]),
                    "exec_last_us": int(ctrl["sv_exec_last_ns"][k]) / 1e3,
                    "exec_max_us": int(ctrl["sv_exec_max_ns"][k]) / 1e3,
                    "exec_p50_us": e50,
                    "exec_p99_us": e99,
                }
            )
        return {
            "ready": bool(ctrl["ready"]),
            "tick": int(ctrl["tick"]),
            "fed": int(ctrl["fed"]),
            "latency_us": {
                "last": int(ctrl["latency_last_ns"]) / 1e3,
                "max": int(ctrl["latency_max_ns"]) / 1e3,
                "p50": p50,
                "p99": p99,
                "p999": p999,
                "ticks": int(hist.sum()),
            },
            "sv": sv,
        }

    def _tg(self) -> dict[str, Any] | None:
        nr = len(self.names)
        tg = self._view(layout.KEY_TG_ROBOTS, layout.TG_ROBOT, nr)
        if tg is None:
            return None
        status = self._view(layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING)
        queue = self._view(layout.KEY_MOTION_QUEUE, layout.QUEUE_HEADER)
        robots = []
        for k, name in enumerate(self.names):
            seq = int(tg["busy_seq"][k])
            entry: dict[str, Any] = {"robot": name, "busy_seq": seq, "tick": int(tg["tick"][k])}
            i = -1 if status is None or not seq else records.find(status, seq)
            if i >= 0:
                s = status[i]  # type: ignore[index]
                entry["state"] = _name(RequestState, int(s["state"]))
                entry["progress"] = float(s["progress"])
                entry["duration_s"] = float(s["duration_s"])
            robots.append(entry)
        queued = None if queue is None else int(queue["tail"]) - int(queue["head"])
        discarded = None if queue is None else int(queue["discarded"])
        return {
            "queued": queued,
            "discarded": discarded,
            "requests": self.requests(),
            "robots": robots,
            "longest_tick": self.tg_longest(),
            "now": self.tg_now(),
        }

    def requests(self) -> dict[str, Any] | None:
        """Who holds the TG's request queue and status records: per program (pid, with its
        name from /proc) its entries unread in the queue, its requests queued or running and
        its unread outcomes; the request waiting for a record (``blocked_seq``: every record
        holds a live request) and since which tick; None before the TG laid them out."""
        status = self._view(layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING)
        state = self._view(layout.KEY_TG_STATE, layout.TG_STATE)
        head = self._view(layout.KEY_MOTION_QUEUE, layout.QUEUE_HEADER)
        slots = self._view(
            layout.KEY_MOTION_QUEUE + ".slots",
            layout.queue_entry(layout.MOTION_REQUEST),
            layout.MOTION_QUEUE_CAPACITY,
        )
        if status is None or state is None or head is None or slots is None:
            return None
        n = layout.MOTION_QUEUE_CAPACITY
        h, t = int(head["head"]), int(head["tail"])
        places = np.arange(h, t) % n if 0 <= t - h <= n else np.zeros(0, dtype=np.int64)
        in_queue = slots["payload"]["client_pid"][places]
        held = records.holders(status.copy())
        pids = sorted(set(held) | {int(p) for p in in_queue})
        programs = [
            {
                "pid": p,
                "program": holder_text(p),
                "in_queue": int(np.count_nonzero(in_queue == p)),
                "live": held.get(p, (0, 0))[0],
                "unread": held.get(p, (0, 0))[1],
            }
            for p in pids
        ]
        s = state.copy()
        return {
            "queue": {"entries": len(places), "capacity": n, "share": layout.MOTION_QUEUE_SHARE},
            "records": {
                "capacity": layout.STATUS_RING,
                "unread_share": layout.STATUS_SHARE,
                "live_share": layout.LIVE_SHARE,
            },
            "blocked_seq": int(s["blocked_seq"]) or None,
            "blocked_tick": int(s["blocked_tick"]) if int(s["blocked_seq"]) else None,
            "evicted": int(s["evicted"]),
            "stops_taken": int(s["stops_taken"]),
            "stops_refused": int(s["stops_refused"]),
            "programs": programs,
        }

    def tg_now(self) -> dict[str, Any] | None:
        """Where the TG is in its tick (``TG_STATE.phase``): the phase, for how long (µs, by
        this process's clock) and the request it works on; None between ticks."""
        state = self._view(layout.KEY_TG_STATE, layout.TG_STATE)
        s = None if state is None else state.copy()
        if s is None or int(s["phase"]) == layout.TgPhase.IDLE:
            return None
        return {
            "phase": _name(layout.TgPhase, int(s["phase"])),
            "for_us": (time.monotonic_ns() - int(s["phase_ns"])) / 1e3,
            "seq": int(s["phase_seq"]),
        }

    def tg_longest(self) -> dict[str, Any] | None:
        """The TG's longest tick since start and its parts, µs (``TG_STATE.longest_*``);
        None before its first tick."""
        state = self._view(layout.KEY_TG_STATE, layout.TG_STATE)
        s = None if state is None else state.copy()
        if s is None or int(s["longest_ns"]) <= 0:
            return None
        return {
            "tick": int(s["longest_tick"]),
            "wall_us": int(s["longest_ns"]) / 1e3,
            "cpu_us": int(s["longest_cpu_ns"]) / 1e3,
            "requests_us": int(s["longest_take_ns"]) / 1e3,
            "starting_us": int(s["longest_start_ns"]) / 1e3,
            "motions_us": int(s["longest_motions_ns"]) / 1e3,
            "requests": int(s["longest_requests"]),
            "motions": int(s["longest_motions"]),
        }

    def _misses(self) -> dict[str, Any]:
        return {
            "total": int(self.inst.misses["count"]),
            "recent": launcher.recent_misses(self.inst, 5),
        }

    def flight(self) -> dict[str, Any] | None:
        """The flight recorder: its ring, and its last dump (None before SIO laid it out)."""
        h = self._view(layout.KEY_FLIGHT, layout.FLIGHT)
        if h is None or int(h["rows"]) == 0:
            return None
        path = decode(h["dump_path"])
        pending = int(self.inst.fault["time_ns"]) not in (0, int(h["dumped_fault_ns"]))
        return {
            "rows": int(h["rows"]),
            "seconds": int(h["rows"]) * int(h["servo_period_ns"]) / 1e9,
            "recorded": int(h["count"]),
            "dumps": int(h["dumps"]),
            "last_dump": path or None,
            "last_dump_tick": int(h["dump_tick"]) if path else None,
            "message": decode(h["dump_message"]),
            "pending": pending,
        }

    def _arena(self) -> dict[str, Any]:
        s = self.inst.arena.stats()
        return {
            "bytes": self.inst.arena.size,
            "used_bytes": s.used_bytes,
            "free_bytes": s.free_bytes,
            "largest_free_bytes": s.largest_free,
        }

    # ------------------------------------------------------------------ all of it

    def snapshot(self) -> dict[str, Any]:
        """Everything ``kalictl status`` shows and more, as one JSON-ready document."""
        inst = self.inst
        return plain(
            {
                "instance": inst.name,
                "mode": "lockstep" if inst.lockstep else "real time",
                "layout_version": int(inst.arena.header["layout_version"]),
                "time_ns": time.time_ns(),
                "monotonic_ns": time.monotonic_ns(),
                "clock": self._clock(),
                "fault": self._fault(),
                "processes": self._processes(),
                "robots": self._robots(),
                "servo": self._servo(),
                "tg": self._tg(),
                "misses": self._misses(),
                "flight": self.flight(),
                "arena": self._arena(),
                "held_locks": self._locks(),
            }
        )


def snapshot(inst: Instance) -> dict[str, Any]:
    """One snapshot of ``inst`` (``kalictl status --json``)."""
    spy = Introspector(inst)
    try:
        return spy.snapshot()
    finally:
        spy.close()


def _value_text(v: np.ndarray) -> str:
    """One field's values on one line: bytes as text, arrays summarised (numpy's ``...``)."""
    if v.dtype.kind == "S":
        texts = [decode(x) for x in np.atleast_1d(v).reshape(-1)]
        return (
            repr(texts[0])
            if v.ndim == 0
            else "[" + ", ".join(map(repr, texts[:4])) + (", ...]" if len(texts) > 4 else "]")
        )
    if v.ndim == 0:
        return str(v.item())
    return np.array2string(
        v.reshape(-1) if v.ndim > 2 else v,
        threshold=12,
        edgeitems=4,
        max_line_width=10_000,
        precision=6,
    ).replace("\n", "")


def record_lines(inst: Instance, cell: layout.Cell, pattern: str = "*") -> list[str]:
    """``kalictl mem --fields``: every record of the layout whose key matches ``pattern`` (a
    glob), its dtype, count, writer and readers, then each field and its values, one line
    per field (across all records of the block), like ``halcmd show``.  Reads the arena
    without locks (Type 4: values of one moment, not one consistent copy)."""

    lines = []
    for b in layout.blocks(cell):
        if not fnmatch.fnmatchcase(b.key, pattern):
            continue
        found = inst.arena.lookup(b.key)
        if found is None or found[1] < b.nbytes:
            lines.append(f"{b.key}: not laid out")
            continue
        view = inst.arena.existing(b.key, b.dtype, b.count)
        count = "1 record" if b.count is None else f"{b.count} records"
        lines.append(
            f"{b.key}  {count} of {b.dtype.itemsize} B  "
            f"writer: {b.record.writer}; readers: {b.record.readers}"
        )
        for name in b.dtype.names or ():
            if name.startswith("_"):
                continue
            lines.append(f"    {name:<26} {_value_text(np.asarray(view[name]))}")
        if b.dtype.names is None:
            lines.append(f"    {'(values)':<26} {_value_text(np.asarray(view))}")
        del view
    return lines
