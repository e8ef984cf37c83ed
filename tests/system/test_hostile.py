"""Hostile input (issue 7 item 3, DESIGN 7): a rogue client writes garbage straight into the
arena, past every check of the client library, and Kali neither crashes nor moves an arm.

One lockstep instance serves the module: both arms powered, calibrated and holding.  Each test
writes one kind of garbage where a client may write (the TG's motion queue, the servo slots'
mailbox and words, the robots' command words, the feed-forward mode, the set-point FIFO, the
clock's command), steps the clock, and checks that every process is still alive and ACTIVE
with the same pid, that no fault was raised, that no joint moved by more than two encoder
counts (measured, and the plant's truth), and, where the garbage has a reply channel (a
request's status record, a mailbox's ``op_status``, the clock's ``cmd_status``), that it was
refused with a reason naming the value.  A good request afterwards still works.

What "rejected" means, per place:

- motion queue entry with a sequence number matching its place: REFUSED, the message in its
  status record; nothing moves;
- motion queue entry whose sequence number does not match its place, a forged tail, a head
  moved back: dropped and counted in the queue's ``discarded`` (no status record to answer
  in); the TG never replays an entry;
- servo mailbox: ``op_status`` = OP_REFUSED, the reason in the slot's staging bytes
  (``ServoClient`` raises it as a ServoError), the servo's data unchanged;
- a slot's algorithm word outside the registry: the SV restores the robot's configured servo,
  bumplessly;
- feed-forward mode word outside FfMode: the last valid mode stays in force (SIO and the
  dynamics process); ``ServoClient.feedforward_state`` raises, ``status --json`` shows
  INVALID(n);
- power command or calibration word outside its values: ignored, SIO clears it and says so
  in the robot's message;
- a tracking-error limit (``safe``) not in (0, π], NaN included: SIO keeps the last valid one;
- a set-point FIFO row that is not finite or beyond ±4π rad, a ratio stamp below 1: refused by
  SIO, which holds (``rejected``);
- a clock command word outside ClockCommand, or a step or time that is not finite, too
  large or (a step) not a whole number: refused, ``cmd_status`` -1 and the reason;
- a period in the process table ``set_control_rate`` would refuse: the clock keeps the last
  valid one.

The last tests run on a second instance, so what a regression there breaks cannot spoil the
others; the clock commands come last.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core import atomic, layout
from kali_daemons.core.channels import InterpolatingFifo, RequestQueue
from kali_daemons.core.errors import ChannelError, ClockError, ServoError
from kali_daemons.core.layout import (
    CalibState,
    ClockCommand,
    FaultCode,
    FfMode,
    FfState,
    MotionKind,
    PowerState,
    ProcState,
    RequestState,
    SlotOp,
)
from kali_daemons.core.spinlock import pid_alive
from kali_daemons.robots.puma560 import kinematics
from kali_daemons.runtime.instance import Instance, decode
from kali_daemons.servo.level import refusal_text
from kali_daemons.tg import records
from kali_daemons.tools import introspect, launcher
from kali_daemons.wallclock import release, set_control_rate, step_kali_clock

from ..conftest import leftovers, make_config, unique_name
from ..test_servo_level import COUNT, power_all

HOLD_COUNTS = 2.0  # an arm that did not move stays within this many encoder counts
STEP = 30  # ticks stepped after each piece of garbage (three TG periods)
J6 = 5  # the left arm's joint 6: slot 5, the joint the mailbox garbage goes to


@dataclass
class Cell:
    """The module's instance as the rogue sees it, and where everything was."""

    name: str
    kali: Kali
    pids: dict[str, int]
    q0: np.ndarray = field(default_factory=lambda: np.zeros((2, 6)))
    truth0: np.ndarray = field(default_factory=lambda: np.zeros((2, 6)))
    faults: int = 0

    @property
    def inst(self) -> Instance:
        """The attached instance."""
        return self.kali.inst

    def truth(self) -> np.ndarray:
        """The plant's true joint angles, (robots, 6) (never read by the controller)."""
        truth = self.inst.arena.existing(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, 12)
        return truth["q"].reshape(2, 6).copy()

    def rebase(self) -> None:
        """Take where the arms are now as where they hold."""
        self.q0 = self.kali.servo.level.joints["q"].reshape(2, 6).copy()
        self.truth0 = self.truth()
        self.faults = int(self.inst.fault["count"])


@contextmanager
def _started(tmp_path_factory: pytest.TempPathFactory, prefix: str) -> Iterator[str]:
    """Start a lockstep instance for a module; stop it after and check nothing is left."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("KALI_LOG_DIR", str(tmp_path_factory.mktemp("logs")))
        name = unique_name(prefix)
        try:
            launcher.start(make_config(name), lockstep=True)
            yield name
        finally:
            launcher.stop(name)
            assert leftovers(name) == ([], []), f"instance {name} left something behind"


@pytest.fixture(scope="module")
def cell(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Cell]:
    """Both arms powered, calibrated (so Cartesian requests get as far as planning) and
    settled, holding within a count."""
    with _started(tmp_path_factory, "h") as name, Kali(name) as kali:
        kali.ready()
        step_kali_clock(kali.inst, 1500)
        pids = {r["name"]: r["pid"] for r in launcher.describe(kali.inst)}
        c = Cell(name, kali, pids)
        c.rebase()
        yield c


def untouched(c: Cell) -> None:
    """Every process alive and ACTIVE with its pid, no fault, both arms powered and where
    they held (measured and true joints within HOLD_COUNTS encoder counts)."""
    inst = c.inst
    for row in launcher.describe(inst):
        name = row["name"]
        assert row["pid"] == c.pids[name] and pid_alive(c.pids[name]), f"{name} died"
        assert row["state"] == ProcState.ACTIVE.name, f"{name} is {row['state']}"
    assert not int(inst.fault["active"]), inst.fault_text()
    assert int(inst.fault["count"]) == c.faults, inst.fault_text(last=True)
    servo = c.kali.servo
    assert [servo.power_state(r) for r in servo.names] == [PowerState.ON] * 2
    moved = np.abs(servo.level.joints["q"].reshape(2, 6) - c.q0) / COUNT
    assert moved.max() <= HOLD_COUNTS, f"measured joints moved (counts):\n{moved}"
    moved = np.abs(c.truth() - c.truth0) / COUNT
    assert moved.max() <= HOLD_COUNTS, f"true joints moved (counts):\n{moved}"


# ------------------------------------------------------------------------------ the motion queue


def _joints_request(c: Cell) -> np.ndarray:
    """A JOINTS request for the left arm to stay where it is (a move to nowhere)."""
    req = np.zeros((), dtype=layout.MOTION_REQUEST)
    req["kind"] = MotionKind.JOINTS
    req["n_robots"] = 1
    req["joints"][0, :6] = c.kali.start_point(0)
    req["speed_scale"] = 0.5
    return req


def _path_request(c: Cell) -> np.ndarray:
    """A PATH request moving the left flange 1 cm up: valid, so never sent unaltered."""
    req = np.zeros((), dtype=layout.MOTION_REQUEST)
    req["kind"] = MotionKind.PATH
    req["n_robots"] = 1
    req["n_segments"] = 1
    here = c.kali.robot("left").base @ kinematics.fkine(c.kali.start_point(0))
    req["poses"][0] = here
    req["poses"][0, 2, 3] += 0.01
    req["grasps"][0] = np.eye(4)
    req["speed"] = 0.05
    req["angular_speed"] = 0.5
    return req


def _scaled(f: float) -> Callable[[np.ndarray], np.ndarray]:
    """An edit: the poses' rotations multiplied by ``f`` (no longer rigid)."""

    def edit(poses: np.ndarray) -> np.ndarray:
        out = poses.copy()
        out[..., :3, :3] *= f
        return out

    return edit


# A request edit: field -> value, {index: value}, or a function of the field's old value.
Edits = dict[str, object]
NAN, INF = math.nan, math.inf

# (case, base request, edits, what the refusal must say)
QUEUE_GARBAGE: list[tuple[str, str, Edits, str]] = [
    ("kind 0", "joints", {"kind": 0}, "motion kind 0 is not one this TG carries out; kinds: 1"),
    ("kind 200", "joints", {"kind": 200}, "motion kind 200 is not one"),
    ("no robots", "joints", {"n_robots": 0}, "0 robots in the request; this cell has 1 to 2"),
    ("5 robots", "joints", {"n_robots": 5}, "5 robots in the request"),
    ("255 robots", "path", {"n_robots": 255}, "255 robots in the request"),
    ("robot 7", "joints", {"robots": {0: 7}}, "robot index 7; robots are 0..1"),
    ("robot 255", "path", {"robots": {0: 255}}, "robot index 255"),
    ("robot twice", "joints", {"n_robots": 2, "robots": {1: 0}}, "robot listed twice: [0, 0]"),
    ("joint nan", "joints", {"joints": {(0, 2): NAN}}, "joint 3: target nan rad, must be finite"),
    ("joint inf", "joints", {"joints": {(0, 0): INF}}, "joint 1: target inf rad"),
    ("joint huge", "joints", {"joints": {(0, 1): 1e300}}, "joint 2: target 5.73e+301° outside"),
    ("joint -huge", "joints", {"joints": {(0, 5): -1e300}}, "joint 6: target -5.73e+301°"),
    ("scale nan", "joints", {"speed_scale": NAN}, "speed_scale nan, must be in (0, 1]"),
    ("scale 0", "joints", {"speed_scale": 0.0}, "speed_scale 0.0, must be in (0, 1]"),
    ("scale -1", "joints", {"speed_scale": -1.0}, "speed_scale -1.0"),
    ("scale 2", "joints", {"speed_scale": 2.0}, "speed_scale 2.0"),
    ("scale huge", "joints", {"speed_scale": 1e300}, "speed_scale 1e+300"),
    (
        "scale tiny",
        "joints",
        {"speed_scale": 1e-300, "joints": {(0, 5): 0.0}},
        "joint motion would last 3.41e+297 s, more than the 3600 s a request may take",
    ),
    ("no segments", "path", {"n_segments": 0}, "0 path targets; 1 to 16 allowed"),
    ("17 segments", "path", {"n_segments": 17}, "17 path targets"),
    ("speed nan", "path", {"speed": NAN}, "path speed is nan, must be finite"),
    ("speed inf", "path", {"speed": INF}, "path speed is inf"),
    ("speed 0", "path", {"speed": 0.0}, "speed 0.0 m/s must be > 0 and ≤ 5.0 m/s"),
    ("speed -1", "path", {"speed": -1.0}, "speed -1.0 m/s must be > 0"),
    ("speed huge", "path", {"speed": 1e300}, "speed 1e+300 m/s must be"),
    (
        "speeds tiny",
        "path",
        {"speed": 5e-324, "angular_speed": 5e-324},
        "it would last inf s, more than the 3600 s a motion may take",
    ),
    ("angular nan", "path", {"angular_speed": NAN}, "path angular_speed is nan"),
    ("angular 11", "path", {"angular_speed": 11.0}, "angular_speed 11.0 rad/s must be > 0"),
    ("transition nan", "path", {"transition_s": NAN}, "path transition_s is nan"),
    ("transition -1", "path", {"transition_s": -1.0}, "transition_s -1.0 s must be ≥ 0"),
    ("transition huge", "path", {"transition_s": 1e300}, "shorter than transition_s 1e+300 s"),
    ("target nan", "path", {"poses": {(0, 0, 3): NAN}}, "path targets[0] is not finite"),
    ("target far", "path", {"poses": {(0, 1, 3): 1e300}}, "targets[0] is 1e+300 m from its"),
    ("target scaled", "path", {"poses": _scaled(1e300)}, "a rotation entry of 9.97e+299"),
    ("target skewed", "path", {"poses": _scaled(1.5)}, "targets[0] is not a rigid pose"),
    ("target 3 m away", "path", {"poses": {(0, 0, 3): 3.0}}, "'left': pose out of reach"),
    ("grasp nan", "path", {"grasps": {(0, 1, 1): NAN}}, "grasp of robot 'left' is not finite"),
    ("grasp zero", "path", {"grasps": {0: np.zeros((4, 4))}}, "'left' bottom row is [0.0, 0"),
    ("grasp far", "path", {"grasps": {(0, 2, 3): -1e300}}, "grasp of robot 'left' is 1e+300 m"),
    ("grasp mirrored", "path", {"grasps": _scaled(-1.0)}, "'left' is not a rigid pose"),
    ("config 0x10", "path", {"config": {0: 0x10}}, "configuration byte 0x10 names none of"),
    ("config 0x07", "path", {"config": {0: 0x07}}, "configuration byte 0x7 names none of"),
    ("config 0xff", "path", {"config": {0: 0xFF}}, "configuration byte 0xff"),
    ("stop robot 9", "joints", {"kind": MotionKind.STOP, "robots": {0: 9}}, "robot index 9"),
    ("abort nobody", "joints", {"kind": MotionKind.ABORT, "n_robots": 0}, "0 robots in the"),
]


def _edit(req: np.ndarray, edits: Edits) -> None:
    """Apply ``edits`` to a request record in place."""
    for name, value in edits.items():
        if callable(value):
            req[name] = value(req[name])
        elif isinstance(value, dict):
            for index, x in value.items():
                req[name][index] = x
        else:
            req[name] = value


def _queue(c: Cell) -> RequestQueue:
    return c.kali.queue


@pytest.mark.parametrize(
    ("base", "edits", "says"),
    [pytest.param(b, e, s, id=case) for case, b, e, s in QUEUE_GARBAGE],
)
def test_a_garbage_motion_request_is_refused_with_the_value_and_moves_nothing(
    cell: Cell, base: str, edits: Edits, says: str
) -> None:
    req = _joints_request(cell) if base == "joints" else _path_request(cell)
    _edit(req, edits)
    pushed = [f.indices()[1] for f in cell.kali.fifos]
    seq = _queue(cell).put(req)  # a raw record: only its dtype is checked on the way in
    step_kali_clock(cell.inst, STEP)
    rec = cell.kali.status[records.find(cell.kali.status, seq)]
    assert int(rec["seq"]) == seq
    message = decode(rec["message"])
    assert int(rec["state"]) == RequestState.REFUSED, message
    assert says in message
    assert [f.indices()[1] for f in cell.kali.fifos] == pushed  # not one set-point pushed
    assert [int(b) for b in cell.kali.tg_robots["busy_seq"]] == [0, 0]
    untouched(cell)


def _raw_queue(c: Cell) -> tuple[np.ndarray, np.ndarray]:
    """The motion queue's header and slots as a rogue maps them (no RequestQueue object)."""
    arena = c.inst.arena
    header = arena.existing(layout.KEY_MOTION_QUEUE, layout.QUEUE_HEADER)
    entry = layout.queue_entry(layout.MOTION_REQUEST)
    slots = arena.existing(layout.KEY_MOTION_QUEUE + ".slots", entry, layout.MOTION_QUEUE_CAPACITY)
    return header, slots


def _forge(c: Cell, req: np.ndarray, seq: int) -> None:
    """Write ``req`` with sequence number ``seq`` at the tail and publish it, as a rogue
    would (outside the producers' lock and the seq rule)."""
    header, slots = _raw_queue(c)
    tail = int(header["tail"])
    slot = slots[tail % layout.MOTION_QUEUE_CAPACITY]
    slot["payload"] = req
    slot["seq"] = seq
    header["tail"] = tail + 1


def _move_request(c: Cell, degrees: float) -> np.ndarray:
    """A valid JOINTS request turning the left arm's joint 6 by ``degrees`` (it would move)."""
    req = _joints_request(c)
    req["joints"][0, J6] += math.radians(degrees)
    return req


def test_forged_queue_entries_and_counters_are_dropped_and_never_replayed(cell: Cell) -> None:
    queue = _queue(cell)
    header, _ = _raw_queue(cell)
    pushed = [f.indices()[1] for f in cell.kali.fifos]
    dropped = queue.discarded
    # entries whose seq does not match their place: zero, the previous place's, absurd, ahead
    for forged in ("zero", "previous", "max", "ahead"):
        tail = int(header["tail"])
        seq = {"zero": 0, "previous": tail, "max": 2**64 - 1, "ahead": tail + 8}[forged]
        _forge(cell, _move_request(cell, 5.0), seq)
        step_kali_clock(cell.inst, STEP)
    assert queue.discarded == dropped + 4
    # a tail far ahead of the head, then one behind it: the TG skips to it, replaying nothing
    header["tail"] = int(header["tail"]) + 1000
    step_kali_clock(cell.inst, STEP)
    header["tail"] = int(header["tail"]) - 5
    step_kali_clock(cell.inst, STEP)
    assert queue.discarded == dropped + 6
    assert [f.indices()[1] for f in cell.kali.fifos] == pushed
    untouched(cell)
    # the queue still works, and a head moved back does not replay what was taken
    left = cell.kali.robot("left")
    there = left.move_joints(_move_request(cell, 3.0)["joints"][0, :6], speed=1.0, timeout=30)
    back = left.move_joints(_joints_request(cell)["joints"][0, :6] - math.radians(3.0) * _e6())
    step_kali_clock(cell.inst, 300)
    assert there.state == back.state == RequestState.DONE
    cell.rebase()
    pushed = [f.indices()[1] for f in cell.kali.fifos]
    header["head"] = int(header["head"]) - 2  # the consumer's word: both moves again?
    step_kali_clock(cell.inst, STEP)
    assert [f.indices()[1] for f in cell.kali.fifos] == pushed
    untouched(cell)


def _e6() -> np.ndarray:
    """Unit vector of joint 6."""
    e = np.zeros(6)
    e[J6] = 1.0
    return e


def test_a_client_attaching_with_other_sizes_is_refused_with_the_sizes(cell: Cell) -> None:
    arena = cell.inst.arena
    key = layout.KEY_MOTION_QUEUE
    small = np.dtype([("kind", "u1"), ("x", "<f8")])
    with pytest.raises(ChannelError, match=r"'tg.requests' exists with entry_bytes \d+, attach"):
        RequestQueue(arena, key, small, layout.MOTION_QUEUE_CAPACITY)
    with pytest.raises(ChannelError, match="exists with capacity 64, attach asked for 65"):
        RequestQueue(arena, key, layout.MOTION_REQUEST, layout.MOTION_QUEUE_CAPACITY + 1)
    with pytest.raises(ChannelError, match="entry of dtype"):
        _queue(cell).put(np.zeros((), dtype=small))
    with pytest.raises(ChannelError, match="field 'n_robots' missing"):
        _queue(cell).put({"kind": 1})
    record = cell.kali.servo.get_servo("left", 6, "pid")
    with pytest.raises(ServoError, match=r"data of dtype .* expected one record of"):
        cell.kali.servo.put_servo("left", 6, "pd", record)
    untouched(cell)


# ------------------------------------------------------------------------------ the servo level


def _post(c: Cell, op: int, algo: int, payload: bytes | None = None) -> tuple[int, str]:
    """Post a raw mailbox operation on the left arm's joint 6, as a rogue (no lock, no check),
    step the clock and return (op_status, the SV's reason)."""
    lv = c.kali.servo.level
    s = lv.slot_structs[J6]
    if payload is not None:
        lv.staging[J6, : len(payload)] = np.frombuffer(payload, np.uint8)
    s.op_algo = algo
    done = int(s.ops_done)
    atomic.store32(lv.op_addr[J6], op)
    step_kali_clock(c.inst, 3)
    assert atomic.load32(lv.op_addr[J6]) == SlotOp.NONE and int(s.ops_done) == done + 1
    return int(s.op_status), refusal_text(lv, J6)


def _params(values: dict[str, float], names: tuple[str, ...]) -> bytes:
    """A PARAMS payload: one float64 per parameter, NaN = unchanged."""
    out = np.full(len(names), math.nan)
    for k, v in values.items():
        out[names.index(k)] = v
    return out.tobytes()


def _record(c: Cell, **fields: float) -> bytes:
    """The joint's PID record as it is, with ``fields`` replaced: a PUT payload."""
    rec = c.kali.servo.get_servo("left", J6 + 1, "pid").copy()
    for k, v in fields.items():
        rec[k] = v
    return rec.tobytes()


PID_PARAMS = ("kp", "ki", "kv", "fe", "fv", "integration_band", "integration_reset", "bias_tau")
MAILBOX_GARBAGE: list[tuple[str, int, int, Callable[[Cell], bytes | None], str]] = [
    ("op 99", 99, 0, lambda c: None, "mailbox operation 99 is not one of PUT 1, GET 2"),
    ("op 2**32-1", 2**32 - 1, 0, lambda c: None, "mailbox operation 4294967295 is not one"),
    ("select algo 77", SlotOp.SELECT, 77, lambda c: None, "SELECT refused: algorithm index 77"),
    ("get algo max", SlotOp.GET, 2**32 - 1, lambda c: None, "algorithm index 4294967295"),
    ("put algo 3", SlotOp.PUT, 3, _record, "PUT refused: algorithm index 3, registered 0..2"),
    (
        "params kp inf",
        SlotOp.PARAMS,
        0,
        lambda c: _params({"kp": INF}, PID_PARAMS),
        "PARAMS 'pid' refused: servo pid: parameter kp = inf must be finite",
    ),
    (
        "params kv negative",
        SlotOp.PARAMS,
        0,
        lambda c: _params({"kv": -5.0}, PID_PARAMS),
        "parameter kv = -5 N·m·s/rad must be >= 0",
    ),
    (
        "params fe zero",
        SlotOp.PARAMS,
        0,
        lambda c: _params({"kp": 1.0, "fe": 0.0}, PID_PARAMS),
        "parameter fe = 0 Hz must be > 0",
    ),
    ("put kp nan", SlotOp.PUT, 0, lambda c: _record(c, kp=NAN), "field kp is nan, must be"),
    ("put lpfe2 inf", SlotOp.PUT, 0, lambda c: _record(c, lpfe2=-INF), "field lpfe2 is -inf"),
    ("put kp -1", SlotOp.PUT, 0, lambda c: _record(c, kp=-1.0), "parameter kp = -1 N·m/rad"),
    ("put all ones", SlotOp.PUT, 0, lambda c: b"\xff" * 1024, "field kp is nan"),
]


@pytest.mark.parametrize(
    ("op", "algo", "payload", "says"),
    [pytest.param(o, a, p, s, id=case) for case, o, a, p, s in MAILBOX_GARBAGE],
)
def test_garbage_in_a_servo_mailbox_is_refused_with_the_reason_and_changes_nothing(
    cell: Cell, op: int, algo: int, payload: Callable[[Cell], bytes | None], says: str
) -> None:
    servo = cell.kali.servo
    before = {a: servo.get_params("left", J6 + 1, a) for a in ("pid", "pd")}
    active = servo.active("left", J6 + 1)
    status, why = _post(cell, op, algo, payload(cell))
    assert status == layout.OP_REFUSED, why
    assert says in why
    assert {a: servo.get_params("left", J6 + 1, a) for a in ("pid", "pd")} == before
    assert servo.active("left", J6 + 1) == active
    untouched(cell)


def test_a_refused_put_reaches_the_client_as_a_servo_error(cell: Cell) -> None:
    servo = cell.kali.servo
    rec = servo.get_servo("left", J6 + 1, "pid").copy()
    rec["kp"] = math.inf
    with pytest.raises(ServoError, match="robot 'left' joint 6: PUT 'pid' refused: field kp is"):
        servo.put_servo("left", J6 + 1, "pid", rec)
    rec = servo.get_servo("left", J6 + 1, "pid")
    servo.put_servo("left", J6 + 1, "pid", rec)  # the same data back: accepted, no change
    assert servo.get_params("left", J6 + 1) == servo.get_params("left", J6 + 1, "pid")
    step_kali_clock(cell.inst, STEP)
    untouched(cell)


def test_an_algorithm_word_outside_the_registry_is_restored_bumplessly(cell: Cell) -> None:
    servo = cell.kali.servo
    s = servo.level.slot_structs[J6]
    s.algo = 99
    with pytest.raises(ServoError, match="robot 'left' joint 6: algorithm index 99 in the arena"):
        servo.active("left", J6 + 1)
    step_kali_clock(cell.inst, 1)
    assert servo.active("left", J6 + 1) == "pid"  # the robot's configured servo
    s.algo = 2**32 - 1
    step_kali_clock(cell.inst, STEP)
    assert servo.active("left", J6 + 1) == "pid"
    untouched(cell)


def test_command_words_with_undefined_values_are_ignored(cell: Cell) -> None:
    robots = cell.kali.servo.level.robots
    robots["power_cmd"][0] = 7
    robots["power_cmd"][1] = 255
    step_kali_clock(cell.inst, STEP)
    assert [int(v) for v in robots["power_cmd"]] == [0, 0]  # taken, and nothing done
    untouched(cell)


def test_a_feedforward_mode_outside_ffmode_keeps_the_last_valid_mode(cell: Cell) -> None:
    servo = cell.kali.servo
    ff = servo._ff_records()
    assert [int(m) for m in ff["mode"]] == [FfMode.FULL] * 2  # as configured
    torque = servo.level.joints["ff_torque"].reshape(2, 6)
    held = torque.copy()
    assert np.abs(held[:, 1]).min() > 5.0  # joint 2's gravity, at least
    ff["mode"][0] = 7
    ff["mode"][1] = 255
    step_kali_clock(cell.inst, 100)  # ten dynamics cycles
    with pytest.raises(ServoError, match="feed-forward of robot 'left': mode word 7, state 1"):
        servo.feedforward_state("left")
    assert [int(s) for s in ff["state"]] == [FfState.ON] * 2  # full, as configured, still on
    np.testing.assert_allclose(torque, held, atol=0.01)  # N·m: the arms hold still
    snap = introspect.snapshot(cell.inst)
    assert snap["robots"][0]["feedforward"]["mode"] == "INVALID(7)"
    ff["mode"][:] = FfMode.FULL
    del ff, torque
    untouched(cell)


def _raw_fifo(c: Cell, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robot ``k``'s TG → SIO FIFO as a rogue maps it: header, ring rows, ratio stamps."""
    arena = c.inst.arena
    key = layout.KEY_FIFO.format(robot=c.kali.names[k])
    cap = int(arena.existing(key, layout.FIFO_HEADER)["capacity"])
    ring = arena.existing(key + ".ring", np.dtype("<f8"), cap * 6).reshape(cap, 6)
    stamps = arena.existing(key + ".ratios", np.dtype("<u8"), cap)
    return arena.existing(key, layout.FIFO_HEADER), ring, stamps


@pytest.mark.parametrize(
    ("row", "stamp"),
    [
        pytest.param(NAN, None, id="nan"),
        pytest.param(INF, None, id="inf"),
        pytest.param(1e300, None, id="huge"),
        pytest.param(-20.0, None, id="four turns"),
        pytest.param(None, 7, id="ratio 7/0"),
        pytest.param(None, 1 | 10 << 32, id="ratio 1/10"),
    ],
)
def test_a_garbage_set_point_in_the_fifo_is_refused_and_the_arm_holds(
    cell: Cell, row: float | None, stamp: int | None
) -> None:
    k = 1  # the right arm: the TG does not move it meanwhile, so the rogue's row is next
    fifo: InterpolatingFifo = cell.kali.fifos[k]
    header, ring, stamps = _raw_fifo(cell, k)
    rejected = fifo.rejected
    tail = int(header["tail"])
    held = np.empty(6)
    fifo.held(held)
    ring[tail % len(ring)] = held
    if row is not None:
        ring[tail % len(ring), 2] = row
    stamps[tail % len(ring)] = int(header["push_ratio"]) if stamp is None else stamp
    header["tail"] = tail + 1
    step_kali_clock(cell.inst, STEP)
    assert fifo.rejected == rejected + 1
    assert np.isfinite(cell.kali.servo.level.joints["demand"].reshape(2, 6)).all()
    del header, ring, stamps
    untouched(cell)


def test_an_undefined_clock_command_is_refused_with_its_value(cell: Cell) -> None:
    c = cell.inst.clock
    tick = int(c["tick"])
    with cell.inst.cmd_lock:
        c["cmd"] = 99
        c["cmd_arg"] = math.nan
        seq = int(c["cmd_seq"]) + 1
        c["cmd_seq"] = seq
        cell.inst.command_semaphore().release()
        deadline = time.monotonic() + 5.0
        while int(c["cmd_done"]) < seq and time.monotonic() < deadline:
            time.sleep(0.001)
    assert int(c["cmd_done"]) == seq
    assert int(c["cmd_status"]) == -1
    assert "unknown clock command 99" in decode(c["cmd_message"])
    assert int(c["tick"]) == tick
    step_kali_clock(cell.inst, STEP)
    untouched(cell)


def test_a_tg_period_no_set_control_rate_would_write_is_not_followed(cell: Cell) -> None:
    inst = cell.inst
    slot = inst.slot_of("tg")
    inst.procs[slot]["period_ticks"] = 0  # the clock signals it every tick
    inst.bump_registry()
    step_kali_clock(inst, STEP)
    assert cell.kali.fifos[0].ratio == 10  # still the configured period's
    untouched(cell)
    inst.procs[slot]["period_ticks"] = 10
    inst.bump_registry()
    step_kali_clock(inst, STEP)
    untouched(cell)


def test_releasing_a_daemon_or_an_absurd_rate_is_refused_by_the_clock_api(cell: Cell) -> None:
    inst = cell.inst
    for daemon in ("sio", "sv.0", "tg", "plant", "wallclock"):
        with pytest.raises(ClockError, match=f"release: '{daemon}' is one of Kali's daemons"):
            release(inst, daemon)
    with pytest.raises(ClockError, match=r"period 1e\+09 ms is longer than 60000 ms"):
        set_control_rate(inst, "tg", 1e9)
    for garbage in (math.nan, math.inf, -10.0, 0, "10", None):
        with pytest.raises(ClockError, match=r"rate of 'tg': .* must be a whole multiple"):
            set_control_rate(inst, "tg", garbage)  # type: ignore[arg-type]
    step_kali_clock(inst, STEP)
    untouched(cell)


def test_after_all_the_garbage_a_good_request_still_moves_the_arm(cell: Cell) -> None:
    left = cell.kali.robot("left")
    start = cell.kali.start_point(0)
    target = start + math.radians(2.0) * _e6()
    left.move_joints(target, speed=1.0, timeout=30)
    step_kali_clock(cell.inst, 300)
    assert abs(float(left.read_joints()[J6] - target[J6])) <= HOLD_COUNTS * COUNT[J6]
    left.move_joints(start, speed=1.0, timeout=30)
    step_kali_clock(cell.inst, 300)
    untouched(cell)  # back where it held


# ------------------------------------------------------------------------------ SIO and clock
#
# SIO's and the wall clock's own client words.  A second instance takes them, so what a
# regression breaks cannot spoil the tests above; the clock commands come last.


@pytest.fixture(scope="module")
def victim(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Kali]:
    """A second instance, both arms powered and holding (not calibrated)."""
    with _started(tmp_path_factory, "v") as name, Kali(name) as kali:
        power_all(kali.inst, kali.servo, 300)
        yield kali


def _repower(k: Kali) -> None:
    """Clear a fault a test's garbage caused and power both arms again."""
    k.inst.clear_fault()
    for robot in k.names:
        k.servo.power(robot, True)
    step_kali_clock(k.inst, 300)


def test_a_calibration_word_with_an_undefined_value_is_ignored(victim: Kali) -> None:
    robots = victim.servo.level.robots
    robots["calib_cmd"][0] = 7  # the word means 1 = calibrate; 7 is garbage
    step_kali_clock(victim.inst, STEP)
    try:
        assert int(robots["calib_state"][0]) == CalibState.IDLE, "garbage started a calibration"
    finally:
        for _ in range(60):  # let a calibration it did start finish before the next test
            if int(robots["calib_state"][0]) not in (CalibState.SEARCH, CalibState.SETTLE):
                break
            step_kali_clock(victim.inst, 100)


def test_a_negative_safe_limit_is_ignored(victim: Kali) -> None:
    victim.servo.level.arm("safe", 1)[2] = -1.0  # ServoClient.set_safe allows (0, π]
    step_kali_clock(victim.inst, STEP)
    try:
        assert not int(victim.inst.fault["active"]), victim.inst.fault_text()
    finally:
        victim.servo.set_safe("right", 3, 0.15)
        _repower(victim)


def test_a_nan_safe_limit_leaves_the_runaway_check_on(victim: Kali) -> None:
    servo = victim.servo
    faults = int(victim.inst.fault["count"])
    servo.set_safe("right", 3, 0.01)
    step_kali_clock(victim.inst, 2)  # SIO takes the valid limit at its next tick
    servo.level.arm("safe", 1)[2] = math.nan  # NaN: every "error > safe" is False
    fifo = servo.level.fifo(1)
    target = servo.level.arm("demand", 1).copy()
    target[2] += 0.05  # a runaway against the last valid limit, 0.01 rad
    fifo.push(target)
    step_kali_clock(victim.inst, 20)
    try:
        assert int(victim.inst.fault["count"]) > faults, "the runaway went unseen"
        assert int(victim.inst.fault["code"]) == FaultCode.RUNAWAY, victim.inst.fault_text()
    finally:
        servo.set_safe("right", 3, 0.15)
        _repower(victim)


def test_a_huge_period_written_into_the_process_table_does_not_starve_the_tg(
    victim: Kali,
) -> None:
    inst = victim.inst
    slot = inst.slot_of("tg")
    inst.procs[slot]["period_ticks"] = 2**32 - 1  # 49 days; set_control_rate allows 60 s
    inst.bump_registry()
    step_kali_clock(inst, STEP)
    assert victim.fifos[0].ratio == 10  # the TG does not follow it (passes today)
    inst.procs[slot]["period_ticks"] = 10
    inst.bump_registry()
    signals = int(inst.procs[slot]["signals"])
    step_kali_clock(inst, STEP)
    assert int(inst.procs[slot]["signals"]) >= signals + 2, "the TG is no longer signalled"


def _clock_command(k: Kali, cmd: int, arg: float) -> tuple[int, str]:
    """Write a clock command as a rogue and wait (2 s at most) for the clock's answer."""
    c = k.inst.clock
    with k.inst.cmd_lock:
        c["cmd"] = cmd
        c["cmd_arg"] = arg
        seq = int(c["cmd_seq"]) + 1
        c["cmd_seq"] = seq
        k.inst.command_semaphore().release()
        deadline = time.monotonic() + 2.0
        while int(c["cmd_done"]) < seq and time.monotonic() < deadline:
            time.sleep(0.001)
    if int(c["cmd_done"]) < seq:
        return 0, f"no answer: {k.inst.fault_text()}"
    return int(c["cmd_status"]), decode(c["cmd_message"])


def test_setting_the_clock_to_nan_is_refused(victim: Kali) -> None:
    status, message = _clock_command(victim, ClockCommand.SET_TIME, math.nan)
    try:
        assert status == -1, f"SET_TIME nan accepted ({message!r}): the running time is NaN"
    finally:
        _clock_command(victim, ClockCommand.SET_TIME, 0.0)


def test_stepping_the_clock_by_nan_or_inf_ticks_is_refused(victim: Kali) -> None:
    """Last: ``int(nan)`` in the wall clock would kill it and halt the instance."""
    for arg in (math.nan, math.inf, 1e300):
        status, message = _clock_command(victim, ClockCommand.STEP, arg)
        assert status == -1, f"STEP {arg}: {message}"
        assert not int(victim.inst.fault["active"]), victim.inst.fault_text()
