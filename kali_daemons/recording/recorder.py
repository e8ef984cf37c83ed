"""Recording a run to MCAP: every servo tick of every arm (``kali.record``, ``kalictl record``).

The recorder, a non-serious clocked process of its own (every TG period), drains the rows SIO
already writes to the flight recorder's ring (nothing is copied twice in SIO's cycle), with
the TG's set-points, the requests, the faults, the servo level's changes, the simulator's
truth (``events``) and each camera's new frames, as ROS 2 messages (``messages``) any MCAP
reader decodes.  In lockstep the clock waits for it, so no tick is lost; in real time a
recorder more than the ring behind writes the ticks it lost to ``/kali/gaps``.  A failure to
write ends the recording with the reason in its status; the arms never notice.  The topics:
docs/guide/data.md.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from ..core import layout
from ..core.errors import KaliError
from ..core.layout import ProcState, RequestState
from ..hardware.camera import CameraRing
from ..runtime.daemon import Daemon
from ..runtime.instance import Instance, decode
from ..runtime.paths import instance_dir
from .events import TRUTH_FIELDS, ServoWatch, TruthRecords, byte_offsets
from .mcapfile import McapFile, TickBlock
from .messages import (
    CAMERA_INFO_DEF,
    FAULT_DEF,
    GAP_DEF,
    IMAGE_DEF,
    JOINT_STATE_DEF,
    REQUEST_DEF,
    ROW_COLUMNS,
    SERVO_CHANGE_DEF,
    SERVO_DEF,
    SETPOINT_DEF,
    SIM_TRUTH_DEF,
    STAMP_AT,
    WRENCH_DEF,
    Cdr,
    Laid,
)

NAME = "recorder"  # its process-table slot
START_TIMEOUT_S = 20.0
STOP_TIMEOUT_S = 30.0
STATUS_S = 0.5  # how often a recording's status file is brought up to date
# a drain's truth bytes begin with a head of four words: the stamp (sec, nanosec), the tick,
# the simulated time (s) and the plant's cycles; each arm's wrenches as SimTruth orders them
TRUTH_HEAD = 32
TRUTH_WRENCHES = ("ft_wrench", "grasp_wrench")


def status_path(instance: str) -> Path:
    """Where the recorder of ``instance`` says what it does (JSON)."""
    return instance_dir(instance) / "recorder.json"


class Recording:
    """Drains an instance's flight-recorder ring into an MCAP file (``drain``), from the
    rows written after it was made; the cycle logic of the recorder process, which a test
    can drive too."""

    def __init__(self, inst: Instance, path: Path) -> None:
        self.inst = inst
        self.path = path
        cfg = inst.config
        self.header = inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
        h = self.header
        if int(h["rows"]) == 0:
            raise KaliError(f"recording: instance '{inst.name}': SIO has no flight recorder yet")
        self.rows = int(h["rows"])
        row = layout.flight_row(int(h["n_joints"]), int(h["n_robots"]))
        self.ring = inst.arena.existing(layout.KEY_FLIGHT_RING, row, self.rows)
        self.names = [r.name for r in cfg.robots]
        self.spans = [cfg.joints.span(k) for k in range(len(self.names))]
        self.joint_names = [
            [f"{r.name}_joint{j + 1}" for j in range(r.n_joints)] for r in cfg.robots
        ]
        self.sensors = [r.ft.sheet is not None for r in cfg.robots]
        self.base_ns = int(inst.clock["base_tick_ns"])
        self.next = int(h["count"])  # the first row to record
        self.written = 0  # servo ticks written
        self.gaps = 0  # ticks lost
        self.first_tick = self.last_tick = -1
        path.parent.mkdir(parents=True, exist_ok=True)
        self._file = open(path, "xb")  # noqa: SIM115 - open until close(); never over a file
        self.writer = McapFile(self._file, profile="ros2", library="kali")
        self.writer.metadata("kali", {"instance": inst.name, "robots": ",".join(self.names)})
        schemas = {
            kind: self.writer.schema(name, "ros2msg", text.encode())
            for kind, name, text in (
                ("joints", "sensor_msgs/msg/JointState", JOINT_STATE_DEF),
                ("wrench", "geometry_msgs/msg/WrenchStamped", WRENCH_DEF),
                ("servo", "kali_msgs/msg/ServoTick", SERVO_DEF),
                ("gap", "kali_msgs/msg/Gap", GAP_DEF),
                ("request", "kali_msgs/msg/Request", REQUEST_DEF),
                ("fault", "kali_msgs/msg/Fault", FAULT_DEF),
                ("setpoint", "kali_msgs/msg/SetPoint", SETPOINT_DEF),
                ("change", "kali_msgs/msg/ServoChange", SERVO_CHANGE_DEF),
                ("truth", "kali_msgs/msg/SimTruth", SIM_TRUTH_DEF),
                ("image", "sensor_msgs/msg/Image", IMAGE_DEF),
                ("camera_info", "sensor_msgs/msg/CameraInfo", CAMERA_INFO_DEF),
            )
        }

        def channel(topic: str, kind: str) -> int:
            schema = schemas["image" if kind == "depth" else kind]  # a depth image is an Image
            return self.writer.channel(topic, "cdr", schema)

        self._channels = [
            {kind: channel(f"/kali/{name}/{topic}", kind)
             for kind, topic in (("joints", "joint_states"), ("servo", "servo"),
                                 ("wrench", "wrench"), ("setpoint", "setpoint"),
                                 ("change", "servo_changes"))
             if kind != "wrench" or self.sensors[k]}
            for k, name in enumerate(self.names)
        ]  # fmt: skip
        self.servos = ServoWatch(inst)
        self.truth = TruthRecords(inst) if inst.config.simulated else None
        self._truth_ch = [
            channel(f"/kali/sim/{name}/truth", "truth") for name in self.names
        ] if self.truth is not None else []  # fmt: skip
        self._events_ch = {
            kind: channel(f"/kali/{topic}", kind)
            for kind, topic in (("gap", "gaps"), ("request", "requests"), ("fault", "faults"))
        }
        cameras = cfg.scene.cameras
        self._cameras = [  # each camera's ring, its channels, the stamp of its last frame
            (CameraRing(inst.arena, cameras, i), {
                kind: channel(f"/kali/cameras/{c.name}/{topic}", kind)
                for kind, topic in (("image", "image"), ("depth", "depth"),
                                    ("camera_info", "camera_info"))
            }, [0])
            for i, c in enumerate(cameras)
        ]  # fmt: skip
        self._cdr = Cdr()
        self._block = TickBlock()  # every arm's messages of a servo tick
        for k in range(len(self.names)):
            self._arm_messages(k)
        self._laid_messages()
        self.requests = inst.arena.existing(
            layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING
        )
        # what was written of each status record (seq, state) and of the faults (count)
        self._seq, self._state = self.requests["seq"], self.requests["state"]  # views
        self._said_seq, self._said_state = self._seq.copy(), self._state.copy()
        # the same fields' bytes, gathered at once: most drains find them as they were
        raw = self.requests.reshape(-1).view(np.uint8)
        self._status_bytes = raw, byte_offsets(self.requests, ("seq", "state"))
        self._said_status = raw[self._status_bytes[1]]
        self._faults = int(inst.fault["count"])
        self.tg = inst.arena.existing(layout.KEY_TG_ROBOTS, layout.TG_ROBOT, len(self.names))
        self._tg_tick, self._tg_setpoint = self.tg["tick"], self.tg["setpoint"]  # views
        self._tg_ticks = [int(t) for t in self._tg_tick]  # the last set-point written

    def _arm_messages(self, k: int) -> None:
        """Arm ``k``'s joint state, servo tick and wrench messages, laid out once in the
        tick block."""
        n = self.spans[k].stop - self.spans[k].start
        zeros, c, ch, span = np.zeros(n), self._cdr, self._channels[k], self.spans[k]
        c.reset()  # sensor_msgs/msg/JointState
        c.header(0)
        c.strings([name.encode() for name in self.joint_names[k]])
        cols = [(col, c.float64s(zeros), n) for col in ("q", "qd", "torque")]
        self._block.add(ch["joints"], c.bytes(), -1, cols, span)
        c.reset()  # kali_msgs/msg/ServoTick
        c.header(0)
        tick_at = c.int64(0)
        cols = [(col, c.float64s(zeros), n) for col in ROW_COLUMNS.values()]
        self._block.add(ch["servo"], c.bytes(), tick_at, cols, span)
        if self.sensors[k]:
            c.reset()  # geometry_msgs/msg/WrenchStamped
            c.header(0, f"{self.names[k]}_tool".encode())
            at = c.float64_fixed(np.zeros(6))
            self._block.add(ch["wrench"], c.bytes(), -1, [("wrench", at, 6)], k)

    def drain(self) -> int:
        """Write every whole row written since the last drain; the ticks written."""
        h, rows = self.header, self.rows
        count = int(h["count"])
        if count <= self.next:
            return 0
        if count - self.next > rows - 1:  # lapped: those rows are gone
            lost_from = self.next
            self.next = count - (rows - 1)
            self._gap(lost_from, self.next - lost_from)
        data = self.ring[np.arange(self.next, count) % rows].copy()
        after = int(h["count"])
        whole = max(0, after + 1 - rows - self.next)  # rows the writer may have overwritten
        if whole:
            self._gap(self.next, whole)
            data = data[whole:]
        if len(data):
            ticks = data["tick"].astype(np.int64)
            self.writer.ticks(self._block, data, ticks * self.base_ns)
            if self.first_tick < 0:
                self.first_tick = int(ticks[0])
            self.last_tick = int(ticks[-1])
            self.written += len(data)
        self.next = count
        self._events()
        return len(data)

    def _gap(self, first_row: int, rows: int) -> None:
        """Rows ``first_row`` .. + ``rows`` were overwritten before they were drained."""
        tick = self.last_tick + 1 if self.last_tick >= 0 else 0
        t = tick * self.base_ns
        c = self._cdr
        c.reset()  # kali_msgs/msg/Gap
        c.header(t)
        c.int64(tick)
        c.int64(rows)
        self.writer.message(self._events_ch["gap"], t, c.bytes(), t)
        self.gaps += rows

    def _events(self) -> None:
        """The requests whose state changed since the last drain (each one's outcome at
        least: a record is given to another request only long after) and a new fault."""
        tick = max(self.last_tick, 0)
        t = tick * self.base_ns
        c, add = self._cdr, self.writer.message
        raw, at = self._status_bytes
        glance = raw[at]
        changed = np.zeros(0, np.int64)
        if not np.array_equal(glance, self._said_status):
            self._said_status = glance
            seq, state = self._seq.copy(), self._state.copy()
            changed = np.flatnonzero(
                (seq != 0) & ((seq != self._said_seq) | (state != self._said_state))
            )
            self._said_seq, self._said_state = seq, state
        for i in changed:
            r = self.requests[i]
            now = (int(self._said_seq[i]), int(self._said_state[i]))
            c.reset()  # kali_msgs/msg/Request
            c.header(t)
            c.uint64(now[0])
            c.string(RequestState(now[1]).name.encode())
            c.int32(int(r["client_pid"]))
            c.float64(float(r["duration_s"]))
            c.float64(float(r["progress"]))
            c.string(decode(r["message"]).encode())
            add(self._events_ch["request"], t, c.bytes(), t)
        for k, (msg, tick_v, q_v) in enumerate(self._setpoints):  # each arm's newest
            tg_tick = int(self._tg_tick[k])
            if tg_tick == self._tg_ticks[k]:
                continue
            self._tg_ticks[k] = tg_tick
            msg.stamp(tg_tick * self.base_ns)  # kali_msgs/msg/SetPoint
            tick_v[0] = tg_tick
            q_v[:] = self._tg_setpoint[k, : len(q_v)]
            add(self._channels[k]["setpoint"], tg_tick * self.base_ns, msg.bytes(), t)
        for k, joint, kind, servo, params in self.servos.changes():
            c.reset()  # kali_msgs/msg/ServoChange
            c.header(t)
            c.int64(tick)
            c.int32(joint)
            c.string(kind.encode())
            c.string(servo.encode())
            c.strings([n.encode() for n in params])
            c.float64s(np.array(list(params.values()), dtype=np.float64))
            add(self._channels[k]["change"], t, c.bytes(), t)
        if self.truth is not None:
            self._sample_truth()
        self._camera_frames()
        count = int(self.inst.fault["count"])
        if count != self._faults:
            self._faults = count
            f = self.inst.read_fault()
            c.reset()  # kali_msgs/msg/Fault
            c.header(t)
            c.int64(int(f.tick))
            for text in (str(f.code), f.process, f.message):
                c.string(text.encode())
            add(self._events_ch["fault"], t, c.bytes(), t)

    def _camera_frames(self) -> None:
        """Each camera's latest frame, once: its colour (rgb8), depth (32FC1, metres along the
        view) and intrinsics (a pinhole: no distortion), stamped with the tick it shows, in
        the camera's optical frame (x right, y down, z along the view)."""
        c, add = self._cdr, self.writer.message
        for ring, ch, shown in self._cameras:
            if ring.stamp() == shown[0]:  # no new frame: no copy of the last
                continue
            frame = ring.read()
            if frame is None or frame.stamp_ns == shown[0]:
                continue
            shown[0] = frame.stamp_ns
            t = frame.tick * self.base_ns
            optical = f"{ring.name}_optical".encode()
            h, w = frame.depth.shape
            for kind, pixels, encoding, size in (
                ("image", frame.image, b"rgb8", 3),
                ("depth", frame.depth, b"32FC1", 4),
            ):
                c.reset()  # sensor_msgs/msg/Image
                c.header(t, optical)
                c.uint32(h)
                c.uint32(w)
                c.string(encoding)
                c.uint8(0)  # little endian
                c.uint32(w * size)
                c.octets(pixels)
                add(ch[kind], t, c.bytes(), t)
            c.reset()  # sensor_msgs/msg/CameraInfo
            c.header(t, optical)
            c.uint32(h)
            c.uint32(w)
            c.string(b"plumb_bob")
            c.float64s(np.zeros(5))
            c.float64_fixed(frame.K.reshape(-1))
            c.float64_fixed(np.eye(3).reshape(-1))
            c.float64_fixed(np.hstack([frame.K, np.zeros((3, 1))]).reshape(-1))
            for v in (0, 0, 0, 0, 0, 0):  # binning, then the region of interest: all of it
                c.uint32(v)
            c.uint8(0)
            add(ch["camera_info"], t, c.bytes(), t)

    def _laid_messages(self) -> None:
        """Each arm's set-point and truth messages laid out once (``Laid``), with views of
        the fields every drain refills."""
        c = self._cdr
        self._setpoints: list[tuple[Laid, np.ndarray, np.ndarray]] = []
        self._truths: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
        self._truth_head = np.zeros(TRUTH_HEAD // 8, "<u8")
        for k, span in enumerate(self.spans):
            n = span.stop - span.start
            c.reset()  # kali_msgs/msg/SetPoint
            c.header(0)
            tick_at, q_at = c.int64(0), c.float64s(np.zeros(n))
            msg = Laid(c)
            self._setpoints.append((msg, msg.field(tick_at, "<i8"), msg.field(q_at, "<f8", n)))
            if self.truth is not None:
                self._truths.append(self._truth_message(k, span))

    def _truth_message(self, k: int, span: slice) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Arm ``k``'s SimTruth message laid out once, and where each of its bytes comes from
        in a drain's truth bytes (``_sample_truth``): (the message, its bytes, theirs)."""
        assert self.truth is not None
        arms, joints = self.truth.arms, self.truth.joints
        arm = TRUTH_HEAD + k * arms.strides[0]
        first = TRUTH_HEAD + arms.nbytes + span.start * joints.strides[0]

        def at(records: np.ndarray, field: str) -> int:
            return int(records.dtype.fields[field][1])  # type: ignore[index]

        c = self._cdr
        c.reset()  # kali_msgs/msg/SimTruth
        c.header(0)
        # (its offset, a value's bytes, where each of its values starts in the source)
        parts = [(STAMP_AT, 8, [0]), (c.int64(0), 8, [8]), (c.float64(0.0), 8, [16])]
        parts.append((c.uint64(0), 8, [24]))
        rows = range(span.stop - span.start)
        for f in TRUTH_FIELDS:
            starts = [first + j * joints.strides[0] + at(joints, f) for j in rows]
            parts.append((c.float64s(np.zeros(len(rows))), 8, starts))
        for f in TRUTH_WRENCHES:
            parts.append((c.float64_fixed(np.zeros(6)), 48, [arm + at(arms, f)]))
        parts.append((c.uint8(0), 1, [arm + at(arms, "grasped")]))
        dst = [np.arange(n) + o + e * n for o, n, starts in parts for e in range(len(starts))]
        src = [np.arange(n) + s for _, n, starts in parts for s in starts]
        msg = np.frombuffer(Laid(c).buf, np.uint8).copy()
        return msg, np.concatenate(dst), np.concatenate(src)

    def _sample_truth(self) -> None:
        """Every arm's truth as the plant has it now, stamped with the clock's tick: the
        drain's truth bytes (a head, then the arms' and the joints' records) gathered into
        each arm's message at once."""
        assert self.truth is not None
        tick = int(self.inst.clock["tick"])
        t = tick * self.base_ns
        head = self._truth_head
        world = self.truth.world[0]
        head.view("<u4")[:2] = divmod(t, 1_000_000_000)
        head[1] = tick
        head.view("<f8")[2] = int(world["sim_time_ns"]) / 1e9
        head[3] = int(world["ticks"])
        src = np.concatenate(
            [head.view(np.uint8), self.truth.arms.view(np.uint8), self.truth.joints.view(np.uint8)]
        )
        for k, (msg, dst, at) in enumerate(self._truths):
            msg[dst] = src[at]
            self.writer.message(self._truth_ch[k], t, msg.tobytes(), t)

    def close(self) -> None:
        """Finish the file (its index and summary), outside any cycle."""
        try:
            self.writer.finish()
        finally:
            self._file.close()

    def status(self, state: str, error: str = "") -> dict[str, Any]:
        return {
            "pid": os.getpid(), "state": state, "path": str(self.path), "ticks": self.written,
            "first_tick": self.first_tick, "last_tick": self.last_tick, "gaps": self.gaps,
            "bytes": self._file.tell() if not self._file.closed else self.path.stat().st_size,
            "error": error,
        }  # fmt: skip


class Recorder(Daemon):
    """The recorder process: a non-serious clocked process that drains the ring each period
    (``Recording``); ends on SIGTERM (``stop``), draining what is left and finishing the
    file."""

    kind = NAME
    realtime = False  # file I/O and compression: never at SCHED_FIFO
    takes_named_slot = False

    def __init__(
        self, instance: str, name: str, path: Path, period_ms: float, cpu: int | None = None
    ) -> None:
        super().__init__(instance, name, period_ms=period_ms, serious=False, stage=9)
        self._cpu = cpu  # bound there, at normal priority (not real-time: never SCHED_FIFO)
        self.path = path
        self.recording: Recording | None = None
        self.error = ""
        self._said_at = 0.0  # when the status file was last written

    def _fail(self, exc: BaseException) -> None:
        """A recorder that fails says so in its status and leaves; it never halts the cell
        (the arms never notice a recording)."""
        self.error = f"{type(exc).__name__}: {exc}"
        self.log.error("recorder failed: %s", self.error)
        if self.recording is not None:
            self._end()

    def on_configure(self) -> None:
        if self._cpu is not None:
            os.sched_setaffinity(0, {self._cpu})
            self.inst.procs[self.slot]["cpu"] = self._cpu
        self.recording = Recording(self.inst, self.path)
        self._say("recording")

    def cycle(self, tick: int) -> None:
        if self.recording is None or self.error:
            return
        try:
            self.recording.drain()
        except OSError as exc:  # a full disk: the recording ends, the arms never notice
            self.error = f"cannot write {self.path}: {exc.strerror or exc}"
            self._end()
            return
        except Exception as exc:  # a fault of the recorder's own: ends it, halts nothing
            self.error = f"{type(exc).__name__}: {exc}"
            self._end()
            return
        now = time.monotonic()
        if now >= self._said_at + STATUS_S:
            self._said_at = now
            self._say("recording")

    def on_deactivate(self) -> None:
        if self.recording is not None and not self.error:
            try:
                self.recording.drain()
            except OSError as exc:
                self.error = f"cannot write {self.path}: {exc.strerror or exc}"
        self._end()

    def _end(self) -> None:
        if self.recording is None:
            return
        try:
            self.recording.close()
        except OSError as exc:
            self.error = self.error or f"cannot finish {self.path}: {exc.strerror or exc}"
        self._say("failed" if self.error else "done")
        self.recording = None

    def _say(self, state: str) -> None:
        assert self.recording is not None
        doc = self.recording.status(state, self.error)
        part = status_path(self.instance_name).with_suffix(".part")
        part.write_text(json.dumps(doc))
        os.replace(part, status_path(self.instance_name))


def read_status(instance: str) -> dict[str, Any] | None:
    """The last recorder's status document, or None if there was none."""
    try:
        doc: dict[str, Any] = json.loads(status_path(instance).read_text())
        return doc
    except (FileNotFoundError, json.JSONDecodeError):
        return None


def running(inst: Instance) -> int:
    """The recorder's pid on ``inst``, or 0."""
    i = inst.find_slot(NAME)
    if i < 0 or int(inst.procs[i]["state"]) in (ProcState.FREE, ProcState.DIED):
        return 0
    return int(inst.procs[i]["pid"])


def start(inst: Instance, path: Path) -> int:
    """Start recording instance ``inst`` to ``path`` (a new file): the recorder process,
    returning its pid once it records; KaliError naming why not."""
    if running(inst):
        doc = read_status(inst.name) or {}
        raise KaliError(
            f"record: instance '{inst.name}' is already recording to {doc.get('path', '?')}"
        )
    path = Path(path).absolute()
    if path.exists():
        raise KaliError(f"record: {path} exists: a recording is never written over")
    if not path.parent.is_dir():
        raise KaliError(f"record: {path.parent} is not a directory")
    if not os.access(path.parent, os.W_OK):
        raise KaliError(f"record: {path.parent} cannot be written")
    with contextlib.suppress(FileNotFoundError):
        status_path(inst.name).unlink()
    log = instance_dir(inst.name) / "recorder.log"
    with open(log, "ab") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "kali_daemons.recording", "--instance", inst.name, "--out",
             str(path)],
            stdout=out, stderr=out, start_new_session=True,
        )  # fmt: skip
    deadline = time.monotonic() + START_TIMEOUT_S
    while time.monotonic() < deadline:
        i = inst.find_slot(NAME)
        if i >= 0 and int(inst.procs[i]["state"]) == ProcState.ACTIVE:
            return proc.pid
        if proc.poll() is not None:
            raise KaliError(f"record: the recorder ended at start: {_tail(log)}")
        time.sleep(0.01)
    proc.kill()
    raise KaliError(f"record: the recorder did not start within {START_TIMEOUT_S:g} s")


def stop(inst: Instance) -> dict[str, Any]:
    """Stop the recording (the recorder drains what is left and finishes the file); its
    final status.  KaliError if none runs."""
    pid = running(inst)
    if not pid:
        raise KaliError(f"record: instance '{inst.name}' is not recording")
    os.kill(pid, signal.SIGTERM)
    deadline = time.monotonic() + STOP_TIMEOUT_S
    while time.monotonic() < deadline:
        if running(inst) != pid:
            break
        time.sleep(0.01)
    else:
        raise KaliError(f"record: the recorder (pid {pid}) did not finish in {STOP_TIMEOUT_S:g} s")
    doc = read_status(inst.name)
    if doc is None:
        raise KaliError("record: the recorder ended without a word (recorder.log)")
    return doc


def _tail(log: Path) -> str:
    lines = log.read_text(errors="replace").strip().splitlines()
    return lines[-1] if lines else "(no output)"


def main(argv: list[str] | None = None) -> None:
    """``python -m kali_daemons.recording --instance NAME --out PATH``."""
    ap = argparse.ArgumentParser(prog="kali_daemons.recording")
    ap.add_argument("--instance", required=True)
    ap.add_argument("--out", required=True, type=Path)
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO,
        format=f"%(asctime)s {NAME}[%(process)d] %(levelname)s %(message)s",
        stream=sys.stderr,
    )
    with Instance.attach(args.instance) as inst:  # drained every TG period: each set-point
        period_ms = inst.config.clock.tg_period_ms
        # beside the viewer, the other process of the cell at normal priority: on its CPU,
        # not migrating between the two (~1 % of a core less at four arms)
        cpu = inst.config.process("viewer").cpu
    sys.exit(Recorder(args.instance, NAME, args.out, period_ms, cpu).main())
