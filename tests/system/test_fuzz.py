"""Fuzzing every way in (issue 7 item 3, DESIGN 7): each request path takes arbitrary input
and either accepts it or refuses it with a Kali error, never another exception, and no daemon
ever dies of it.

The rule the client library keeps, checked here: a bad argument is a ``KaliError`` subclass
(MotionError for motion requests, ServoError for the servo level, ConfigError for a config,
ChannelError for a raw queue record) whose message names the argument; TypeError, ValueError
and friends never escape.  ``MotionHandle.wait`` (and a move that waits, ``wait=True``) may
also raise TimeoutError, its documented answer for a request not done in time.

- the config: ``parse_config`` on the default file with one field replaced by arbitrary YAML
  values, removed or given an extra key, and on mangled and random text;
- the TG's own checks on random bytes as a motion request (``check_request``, ``plan_joints``,
  ``plan_path`` and the path check), in this process: the TG runs exactly these;
- a live lockstep instance (arms unpowered, so an accepted request is refused by the TG for
  want of power and nothing moves): every method of ``Kali``, ``Robot``, ``MotionSystem``,
  ``MotionHandle`` and ``ServoClient`` with arbitrary arguments, and random bytes as raw
  queue entries and servo mailbox operations; afterwards every process is alive and ACTIVE
  with its pid and no fault was raised;
- ``kalictl``'s argument parsing (click's CliRunner, in this process) with arbitrary words,
  against an instance that does not exist.
"""

from __future__ import annotations

import copy
import math
import re
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from click.testing import CliRunner
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from kali_daemons.client import Kali, MotionHandle
from kali_daemons.core import atomic, layout
from kali_daemons.core.errors import ChannelError, ConfigError, KaliError, MotionError
from kali_daemons.core.layout import MotionKind, ProcState, RequestState, SlotOp
from kali_daemons.core.spinlock import pid_alive
from kali_daemons.robots import puma560
from kali_daemons.robots.cell import base_transform
from kali_daemons.robots.puma560 import kinematics
from kali_daemons.runtime.config import KaliConfig, parse_config
from kali_daemons.tg import records
from kali_daemons.tg.requests import check_request, plan_joints, plan_path
from kali_daemons.tools import launcher
from kali_daemons.tools.cli import main as kalictl
from kali_daemons.wallclock import step_kali_clock

from ..conftest import DEFAULT_TEXT, leftovers, make_config, unique_name

FUZZ = settings(
    database=None,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
    derandomize=True,  # the same examples every run: a failure is reproducible
)
NAMES = ["left", "right"]
REQUEST_BYTES = layout.MOTION_REQUEST.itemsize

# ------------------------------------------------------------------------------ the config

DOC = yaml.safe_load(DEFAULT_TEXT)


def _paths(node: Any, prefix: tuple[Any, ...] = ()) -> list[tuple[Any, ...]]:
    """Every field of the parsed default file, as key paths."""
    out = [prefix] if prefix else []
    if isinstance(node, dict):
        for k, v in node.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            out += _paths(v, (*prefix, i))
    return out


def _dotted(path: tuple[Any, ...]) -> str:
    """A key path as the config's messages write it: ``processes.sv.cpus[1]``."""
    text = ""
    for k in path:
        text += f"[{k}]" if isinstance(k, int) else ("." if text else "") + str(k)
    return text


FIELDS = _paths(DOC)
SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(),
    st.text(max_size=30),
)
YAML_VALUES = st.recursive(
    SCALARS,
    lambda inner: st.one_of(
        st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=8), inner, max_size=3)
    ),
    max_leaves=8,
)


@settings(FUZZ, max_examples=400)
@given(field=st.sampled_from(FIELDS), change=st.one_of(st.just("remove"), YAML_VALUES))
def test_a_config_with_any_field_replaced_or_removed_parses_or_names_the_field(
    field: tuple[Any, ...], change: object
) -> None:
    doc = copy.deepcopy(DOC)
    node = doc
    for k in field[:-1]:
        node = node[k]
    if change == "remove":
        del node[field[-1]]
    else:
        node[field[-1]] = change
    try:
        cfg = parse_config(yaml.safe_dump(doc), "<fuzz>")
    except ConfigError as exc:
        # the message names the field, or the section or entry holding it
        names = [_dotted(field[:i]) for i in range(len(field), 0, -1)]
        assert any(n in str(exc) for n in names), (names, str(exc))
        assert str(exc).startswith("config: <fuzz>: ")
    else:
        assert isinstance(cfg, KaliConfig)


@settings(FUZZ, max_examples=200)
@given(field=st.sampled_from([f for f in FIELDS if isinstance(f[-1], str)]), extra=YAML_VALUES)
def test_an_extra_key_anywhere_in_the_config_is_named(
    field: tuple[Any, ...], extra: object
) -> None:
    doc = copy.deepcopy(DOC)
    node = doc
    for k in field[:-1]:
        node = node[k]
    if not isinstance(node, dict):
        return
    node["zz_extra"] = extra
    with pytest.raises(ConfigError, match="zz_extra"):
        parse_config(yaml.safe_dump(doc), "<fuzz>")


@settings(FUZZ, max_examples=300)
@given(
    at=st.integers(0, len(DEFAULT_TEXT)),
    cut=st.integers(0, 40),
    insert=st.text(max_size=20),
)
def test_mangled_config_text_parses_or_is_a_config_error(at: int, cut: int, insert: str) -> None:
    text = DEFAULT_TEXT[:at] + insert + DEFAULT_TEXT[at + cut :]
    try:
        assert isinstance(parse_config(text, "<fuzz>"), KaliConfig)
    except ConfigError as exc:
        assert str(exc).startswith("config: <fuzz>: ")


@settings(FUZZ, max_examples=200)
@given(
    text=st.one_of(
        st.text(max_size=200), st.binary(max_size=100).map(lambda b: b.decode("latin-1"))
    )
)
def test_random_text_as_a_config_is_a_config_error(text: str) -> None:
    with pytest.raises(ConfigError, match=r"^config: <fuzz>: "):
        parse_config(text, "<fuzz>")


# ------------------------------------------------------------------------------ the TG's checks

BASES = [base_transform((-0.6, 0.0, 0.0), 0.0), base_transform((0.6, 0.0, 0.0), 180.0)]
START = np.array([puma560.QN, puma560.QN], dtype=np.float64)
TYPES = [puma560.ROBOT, puma560.ROBOT]  # the default cell's arms
GARBAGE_F8 = st.one_of(
    st.floats(),
    st.sampled_from([0.0, -1.0, 0.5, 1.0, 1e-300, 5e-324, 1e300, math.nan, math.inf]),
)


def _plausible(draw: st.DrawFn) -> np.ndarray:
    """A request near a valid one, with a few fields replaced by garbage."""
    req = np.zeros((), dtype=layout.MOTION_REQUEST)
    kinds = [MotionKind.JOINTS, MotionKind.PATH, MotionKind.PATH, MotionKind.PATH]
    req["kind"] = draw(st.sampled_from([*kinds, MotionKind.STOP, MotionKind.ABORT, 0, 255]))
    req["n_robots"] = draw(st.sampled_from([1, 1, 1, 1, 2, 0, 255]))
    req["robots"][:2] = draw(st.permutations([0, 1]))
    req["joints"][:2, :6] = START + draw(hnp.arrays(np.float64, (2, 6), elements=st.floats(-1, 1)))
    req["speed_scale"] = draw(st.floats(0.01, 1.0))
    req["n_segments"] = draw(st.integers(1, 3))
    here = BASES[0] @ kinematics.fkine(START[0])
    for i in range(3):
        req["poses"][i] = here
        req["poses"][i, :3, 3] += draw(hnp.arrays(np.float64, 3, elements=st.floats(-0.05, 0.05)))
    req["grasps"][:2] = np.eye(4)
    req["speed"], req["angular_speed"] = 0.05, 0.5
    req["transition_s"] = draw(st.sampled_from([0.0, 0.05]))
    for _ in range(draw(st.integers(0, 3))):  # then garbage into a few fields
        name = draw(st.sampled_from(["joints", "speed_scale", "poses", "grasps", "speed"]))
        name = draw(st.sampled_from([name, "angular_speed", "transition_s", "config"]))
        flat = req[name].reshape(-1)
        if flat.dtype.kind == "f":
            flat[draw(st.integers(0, flat.size - 1))] = draw(GARBAGE_F8)
        else:
            flat[draw(st.integers(0, flat.size - 1))] = draw(st.integers(0, 255))
    return req


@st.composite
def motion_requests(draw: st.DrawFn) -> np.ndarray:
    """Random bytes as a motion request, or a plausible one with garbage in places."""
    if draw(st.booleans()):
        raw = draw(st.binary(min_size=REQUEST_BYTES, max_size=REQUEST_BYTES))
        return np.frombuffer(raw, layout.MOTION_REQUEST)[0]
    return _plausible(draw)


@settings(FUZZ, max_examples=1000)
@given(req=motion_requests())
def test_any_motion_request_is_planned_or_refused_with_a_motion_error(req: np.ndarray) -> None:
    try:
        kind, robots = check_request(req, NAMES, TYPES, np.ones(2))
        start = START[robots]
        if kind == MotionKind.JOINTS:
            plan = plan_joints(req, robots, start.reshape(-1), TYPES)
            out = np.zeros(6 * len(robots))
            for tau in (0.0, 0.5 * plan.duration, plan.duration):
                plan.sample(tau, out)
                assert np.isfinite(out).all()
        elif kind == MotionKind.PATH:
            path = plan_path(req, robots, NAMES, TYPES, BASES, start, 0.01)
            path.check_some(50)
        event(f"{kind.name}: planned")
    except MotionError as exc:
        event("refused")
        assert str(exc).startswith("motion: ") and len(str(exc)) < 1000


# ------------------------------------------------------------------------------ a live instance


@pytest.fixture(scope="module")
def live(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Kali]:
    """A lockstep instance whose arms stay unpowered, attached; afterwards every process must
    still be alive and ACTIVE with its pid, no fault raised, and nothing left behind."""
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("KALI_LOG_DIR", str(tmp_path_factory.mktemp("logs")))
        name = unique_name("fz")
        try:
            launcher.start(make_config(name), lockstep=True)
            with Kali(name) as kali:
                step_kali_clock(kali.inst, 30)  # SIO reads the pots
                pids = {r["name"]: r["pid"] for r in launcher.describe(kali.inst)}
                yield kali
                step_kali_clock(kali.inst, 100)
                for row in launcher.describe(kali.inst):
                    assert row["pid"] == pids[row["name"]] and pid_alive(row["pid"]), row
                    assert row["state"] == ProcState.ACTIVE.name, row
                assert int(kali.inst.fault["count"]) == 0, kali.inst.fault_text(last=True)
        finally:
            launcher.stop(name)
            assert leftovers(name) == ([], []), f"instance {name} left something behind"


NOT_NUMBERS = st.one_of(
    st.none(),
    st.booleans(),
    st.text(max_size=12).filter(lambda t: t not in NAMES),
    st.binary(max_size=8),
    st.lists(st.floats(), max_size=8),
    st.dictionaries(st.text(max_size=4), st.floats(), max_size=3),
    hnp.arrays(hnp.scalar_dtypes(), hnp.array_shapes(max_dims=3, max_side=5)),
    st.just(object()),
)
ANYTHING = st.one_of(
    NOT_NUMBERS,
    st.integers(min_value=-(2**70), max_value=2**70),
    st.floats(),
    st.sampled_from([0, 1, -1, 2, 7, 0.0, -1.0, 1e300, -1e300, 5e-324, math.nan, math.inf]),
)
NOT_A_ROBOT = st.one_of(st.sampled_from([2, -1, "LEFT", "", "left ", 1.0]), NOT_NUMBERS)
# valid, and never blocking long (None, no limit, only where nothing is waited for: a move
# waited for without a limit may wait forever, queued behind a track that never ends)
TIMEOUTS = st.one_of(st.floats(0.0, 0.02), st.none())

Pick = Callable[[int, st.SearchStrategy[Any]], Any]


def _near(q: np.ndarray) -> st.SearchStrategy[np.ndarray]:
    """Joint targets near ``q``: valid ones, so the TG gets as far as power."""
    return hnp.arrays(np.float64, 6, elements=st.floats(-0.2, 0.2)).map(lambda d: q + d)


def _poses(kali: Kali) -> st.SearchStrategy[np.ndarray]:
    """Poses within 10 cm of the left arm's tool: plausible targets and grasps."""
    here = kali.robot("left").read_pose()

    def moved(d: np.ndarray) -> np.ndarray:
        t = here.copy()
        t[:3, 3] += d
        return t

    return hnp.arrays(np.float64, 3, elements=st.floats(-0.1, 0.1)).map(moved)


def _calls(kali: Kali) -> dict[str, Callable[[Pick], object]]:
    """Every request path of the client library.  Each call takes ``pick(i, valid)``, which
    draws argument ``i`` from ``valid`` unless it is the one argument given garbage."""
    servo = kali.servo
    q = kali.start_point(0)
    poses = _poses(kali)
    robots = st.sampled_from(NAMES)
    joints = st.integers(1, 6)
    algos = st.sampled_from(["pid", "pd"])
    speed = st.floats(0.01, 1.0)
    flags = st.booleans()
    path = st.lists(poses, min_size=1, max_size=3)
    record = servo.get_servo(0, 6, "pd")

    def system(p: Pick) -> Any:
        return kali.motion_system(p(5, st.lists(robots, min_size=1, max_size=2, unique=True)))

    def wait(p: Pick) -> None:
        handle = MotionHandle(kali, p(9, st.integers(0, 2**64 - 1)), [0])
        try:
            handle.wait(p(1, st.floats(0.0, 0.02)))  # never None: this seq may never end
        except TimeoutError:
            event("wait: TimeoutError")  # its documented answer for a request not done

    return {
        "robot": lambda p: kali.robot(p(0, robots)),
        "move_joints": lambda p: kali.robot(p(0, robots)).move_joints(
            p(1, _near(q)), p(2, speed), wait=False
        ),
        "move_joints, wait": lambda p: kali.robot("left").move_joints(
            q, 1.0, wait=p(3, flags), timeout=p(4, st.floats(0.0, 0.02))
        ),
        "move_line": lambda p: kali.robot(p(0, robots)).move_line(
            p(1, poses), p(2, speed), p(3, speed), p(4, st.sampled_from([None, "luf", "ruf"])),
            wait=False,
        ),
        "move_path": lambda p: kali.robot(p(0, robots)).move_path(
            p(1, path), p(2, speed), p(3, speed), p(4, st.floats(0.0, 0.1)), wait=False
        ),
        "system move_path": lambda p: system(p).move_path(
            p(1, path), p(2, speed), p(3, speed), p(4, st.floats(0.0, 0.1)),
            p(6, st.none()), wait=False,
        ),
        "motion_system": lambda p: kali.motion_system(
            p(0, st.lists(robots, min_size=1, max_size=2, unique=True)),
            p(1, st.lists(poses, min_size=1, max_size=2) | st.none()),
        ),
        "set_tool": lambda p: kali.robot(p(0, robots)).set_tool(p(1, poses)),
        "feedforward": lambda p: kali.robot(p(0, robots)).feedforward(
            p(1, st.sampled_from(["off", "gravity", "full", "on"]))
        ),
        "grip": lambda p: kali.robot(p(0, robots)).grip(p(1, flags)),
        "grip, holding": lambda p: kali.robot(p(0, robots)).grip(
            True, 1.0, p(2, st.sampled_from(["bar", "stand", "nothing"]))
        ),
        "distance": lambda p: kali.distance(
            p(0, st.sampled_from(["left", "right", "left/link3", "table", "anvil"])),
            p(1, st.sampled_from(["right", "right/link9", "stand", "bar", "left"])),
        ),
        "set_load": lambda p: kali.robot(p(0, robots)).set_load(
            p(1, st.floats(0.0, 60.0)),
            p(2, hnp.arrays(np.float64, 3, elements=st.floats(-3.0, 3.0))),
            p(3, hnp.arrays(np.float64, (3, 3), elements=st.floats(-0.1, 0.1))),
        ),
        "stop": lambda p: kali.robot(p(0, robots)).stop(),
        "abort": lambda p: kali.robot(p(0, robots)).abort(),
        "cancel": lambda p: MotionHandle(kali, 1, [p(9, st.integers(0, 1))]).cancel(),
        "wait": wait,
        "ready, no robot": lambda p: kali.ready(
            p(9, st.lists(NOT_A_ROBOT, min_size=1, max_size=2)), p(1, TIMEOUTS)
        ),
        "robot_index": lambda p: servo.robot_index(p(0, robots | st.integers(0, 1))),
        "slot": lambda p: servo.slot(p(0, robots), p(1, joints)),
        "algorithm": lambda p: servo.algorithm(p(0, algos)),
        "get_servo": lambda p: servo.get_servo(p(0, robots), p(1, joints), p(2, algos)),
        "put_servo": lambda p: servo.put_servo(
            p(0, robots), p(1, joints), p(2, st.just("pd")), p(3, st.just(record))
        ),
        "put_servo bytes": lambda p: servo.put_servo(
            "left", 6, "pd", np.frombuffer(p(9, st.binary(min_size=112, max_size=112)), "u1")
            .view(servo.level.registry[1].dtype)
            .reshape(())
        ),
        "select": lambda p: servo.select(p(0, robots), p(1, joints), p(2, algos)),
        "set_params": lambda p: servo.set_params(
            p(0, robots), p(1, joints),
            p(2, st.dictionaries(st.sampled_from(["kp", "kv", "fv"]), st.floats(1.0, 100.0))),
            p(3, st.just("pd") | st.none()),
        ),
        "set_params values": lambda p: servo.set_params(
            "right", 6, {"kp": p(0, st.floats(1.0, 100.0)), "fv": p(1, st.floats(1.0, 100.0))}
        ),
        "get_params": lambda p: servo.get_params(p(0, robots), p(1, joints), p(2, st.none())),
        "active": lambda p: servo.active(p(0, robots), p(1, joints)),
        "enable_servo": lambda p: servo.enable_servo(p(0, robots), p(1, joints), p(2, flags)),
        "range_check": lambda p: servo.range_check(p(0, robots), p(1, joints), p(2, flags)),
        "set_safe": lambda p: servo.set_safe(p(0, robots), p(1, joints), p(2, st.floats(0.01, 3))),
        "power off": lambda p: servo.power(p(0, robots), p(9, st.just(False))),
        "power on, no robot": lambda p: servo.power(p(9, NOT_A_ROBOT), p(1, flags)),
        "power_state": lambda p: servo.power_state(p(0, robots)),
        "ff": lambda p: servo.feedforward(p(0, robots), p(1, st.sampled_from(["on", "off"]))),
        "ff_state": lambda p: servo.feedforward_state(p(0, robots)),
        "calibrate": lambda p: servo.calibrate(p(0, robots)),
        "calibration": lambda p: servo.calibration(p(0, robots)),
        "require_calibrated": lambda p: servo.require_calibrated(p(0, robots), "fuzz"),
    }  # fmt: skip


@settings(FUZZ, max_examples=500)
@given(data=st.data())
def test_every_client_call_with_any_argument_is_accepted_or_a_kali_error(
    live: Kali, data: st.DataObject
) -> None:
    calls = _calls(live)
    name = data.draw(st.sampled_from(sorted(calls)), label="call")
    bad = data.draw(st.integers(0, 6), label="garbage in argument")  # past the last: none

    def pick(i: int, valid: st.SearchStrategy[Any]) -> Any:
        return data.draw(ANYTHING if i == bad else valid, label=f"argument {i}")

    try:
        calls[name](pick)
        event(f"{name}: accepted")
    except KaliError as exc:
        event(f"{name}: {type(exc).__name__}")
        assert re.match(r"^[a-z]+: ", str(exc)), str(exc)  # subsystem: message
    except TimeoutError:  # a call that waits for its request: MotionHandle.wait's answer
        assert name.endswith(", wait"), name
        event(f"{name}: TimeoutError")
    step_kali_clock(live.inst, 2)
    assert not int(live.inst.fault["active"]), live.inst.fault_text()


@settings(FUZZ, max_examples=150)
@given(raw=st.binary(min_size=REQUEST_BYTES, max_size=REQUEST_BYTES))
def test_random_bytes_as_queue_entries_are_refused_and_move_nothing(live: Kali, raw: bytes) -> None:
    req = np.frombuffer(raw, layout.MOTION_REQUEST)[0]
    seq = live.queue.put(req)
    step_kali_clock(live.inst, 10)
    rec = live.status[records.find(live.status, seq)]
    assert int(rec["seq"]) == seq
    state = RequestState(int(rec["state"]))
    # refused (nothing is powered), or a stop/abort of nothing (done at once)
    assert state in (RequestState.REFUSED, RequestState.DONE), state
    assert int(live.tg_robots["busy_seq"][0]) == int(live.tg_robots["busy_seq"][1]) == 0


@settings(FUZZ, max_examples=150)
@given(
    slot=st.integers(0, 11),
    op=st.one_of(st.sampled_from(list(SlotOp)), st.integers(0, 2**32 - 1)),
    algo=st.one_of(st.integers(0, 3), st.integers(0, 2**32 - 1)),
    payload=st.binary(max_size=layout.SERVO_STAGING_BYTES),
)
def test_random_mailbox_operations_are_carried_out_or_refused(
    live: Kali, slot: int, op: int, algo: int, payload: bytes
) -> None:
    lv = live.servo.level
    lv.staging[slot, : len(payload)] = np.frombuffer(payload, np.uint8)
    s = lv.slot_structs[slot]
    s.op_algo = algo
    done = int(s.ops_done)
    atomic.store32(lv.op_addr[slot], op)
    step_kali_clock(live.inst, 2)  # SIO feeds only powered joints: no SV takes it yet
    if atomic.load32(lv.op_addr[slot]) != SlotOp.NONE:  # the next client op on it does
        try:
            live.servo.get_params(slot // 6, slot % 6 + 1)
        except KaliError as exc:
            assert "robot" in str(exc)
    assert int(s.ops_done) >= done + (op != SlotOp.NONE)
    assert int(s.op_status) in (0, layout.OP_REFUSED)


# ------------------------------------------------------------------------------ kalictl

WORDS = st.one_of(
    st.sampled_from(
        [
            "start", "stop", "status", "--json", "mem", "top", "--once", "flight", "clock",
            "step", "set", "rate", "estop", "--release", "reset", "enable", "disable",
            "calibrate", "ff", "on", "move", "--joints", "--speed", "run", "servo", "list",
            "select", "get", "left", "tg", "-1", "nan", "1e300", "0,0,0,0,0,0", "kp=nan", "-c",
            "/nonexistent.yaml", "--record", "view", "--url", "BAD NAME", "--help",
        ]
    ),
    st.text(max_size=10).filter(lambda w: not w.startswith("-") and w != "start"),
)  # fmt: skip


@settings(FUZZ, max_examples=150)
@given(words=st.lists(WORDS, max_size=6))
def test_kalictl_with_any_words_exits_with_a_message_never_a_traceback(words: list[str]) -> None:
    words = ["status" if w == "start" else w for w in words]  # never start an instance
    name = unique_name("nx")
    result = CliRunner().invoke(kalictl, ["-i", name, *words], catch_exceptions=True)
    if result.exception is not None and not isinstance(result.exception, SystemExit):
        raise AssertionError(f"kalictl {words}: {result.exception!r}\n{result.output}")
    assert result.exit_code in (0, 1, 2), (words, result.exit_code, result.output)
    assert "Traceback" not in result.output
    assert launcher.shm_objects(name) == []


def test_kalictl_names_an_instance_that_does_not_exist(tmp_path: Path) -> None:
    name = unique_name("nx")
    result = CliRunner().invoke(kalictl, ["-i", name, "status"])
    assert result.exit_code == 1
    assert f"kalictl: arena: no instance '{name}': /kali.{name} does not exist" in result.output


_ = (ChannelError,)  # raw queue records refused on the way in are ChannelErrors (test_hostile)
