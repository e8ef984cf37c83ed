"""The Zenoh bridge (issue 29), on loopback, in lockstep: remote programs, telemetry, events,
refusals, malformed requests, a dead bridge, two instances."""

from __future__ import annotations

import itertools
import json
import os
import re
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh

from kali_daemons.client import Kali, pose
from kali_daemons.client.protocol import BridgeError, Keys
from kali_daemons.client.zenohconfig import client_config
from kali_daemons.core import layout
from kali_daemons.core.errors import KaliError, MotionError
from kali_daemons.runtime.instance import Instance
from kali_daemons.wallclock import step_kali_clock

from .conftest import wait_for

ROOT = Path(__file__).resolve().parent.parent
KALICTL = str(Path(sys.executable).parent / "kalictl")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def bridge_edit(port: int, extra: dict[str, str] | None = None) -> dict[str, str]:
    """Config edits turning the bridge on, listening on loopback ``port``, with the other
    keys of its section ``extra`` sets (YAML values)."""
    lines = {"enabled": "true", "listen": f"[tcp/127.0.0.1:{port}]", **(extra or {})}
    return {
        rf"^(bridge:\n(?:  .*\n)*?)  {key}: .*$": rf"\g<1>  {key}: {value}"
        for key, value in lines.items()
    }


@pytest.fixture
def bridged(kali: Callable[..., str]) -> Callable[..., tuple[str, str]]:
    """Start a lockstep instance with its bridge on: (instance, endpoint)."""

    def start(extra: dict[str, str] | None = None, separate: bool = False) -> tuple[str, str]:
        port = free_port()
        name = kali(lockstep=True, edits=bridge_edit(port, extra), separate=separate)
        return name, f"tcp/127.0.0.1:{port}"

    return start


@pytest.fixture
def listener() -> Iterator[Callable[[str], zenoh.Session]]:
    """Plain Zenoh client sessions (a subscriber's view), closed afterwards."""
    sessions: list[zenoh.Session] = []

    def open_(endpoint: str) -> zenoh.Session:
        s = zenoh.open(client_config(endpoint))
        sessions.append(s)
        return s

    yield open_
    for s in sessions:
        s.close()


def ask(session: zenoh.Session, key: str, value: object) -> dict:
    """One query's answer, as JSON."""
    replies = list(session.get(key, payload=json.dumps(value).encode(), timeout=30.0))
    assert replies, f"no answer to {key}"
    return json.loads(replies[0].ok.payload.to_bytes())


def test_a_remote_program_carries_the_bar_through_the_bridge(
    bridged: Callable[..., tuple[str, str]],
) -> None:
    """``kalictl run --remote`` runs example_carry.py here, unchanged, on the instance
    through its bridge: the bar goes up, across and back onto its stand."""
    name, endpoint = bridged()
    r = subprocess.run(
        [KALICTL, "-i", name, "run", "--remote", endpoint, str(ROOT / "scripts/example_carry.py")],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    assert "bar carried and put back at" in r.stdout
    with Instance.attach(name) as inst:
        assert inst.fault_text() is None
        status = inst.arena.record(
            layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING
        )
        done = [int(s) for s in status["state"][status["seq"] > 0]]
        assert done and all(s == layout.RequestState.DONE for s in done)


def test_a_remote_program_moves_reads_and_is_refused_as_a_local_one(
    bridged: Callable[..., tuple[str, str]],
) -> None:
    """Moves, reads and waits as a local program's; every bad request refused with the
    exception and message a local program gets, and nothing queued."""
    name, endpoint = bridged()
    with Kali.connect(endpoint, name) as remote, Kali(name) as local:
        remote.ready(["left"])
        arm = remote.robot("left")
        assert (arm.name, arm.index, arm.n_joints, arm.type.name) == ("left", 0, 6, "puma560")
        np.testing.assert_array_equal(arm.read_joints(), local.robot("left").read_joints())
        q = arm.read_joints() + np.array([0.15, 0, 0, 0, 0, 0])
        handle = arm.move_joints(q, speed=0.5, wait=False)
        assert handle.seq > 0
        handle.wait(timeout=30)
        assert handle.state == layout.RequestState.DONE and handle.done
        np.testing.assert_allclose(arm.read_joints(), q, atol=5e-3)
        here = arm.read_pose()
        np.testing.assert_allclose(here, local.robot("left").read_pose(), atol=1e-9)
        taken = int(local.tg_robots["busy_seq"][0]), len(local.queue)
        bad = [
            lambda a: a.move_joints([float("nan")] * 6),
            lambda a: a.move_joints(q, speed=2.0),
            lambda a: a.move_joints(q[:5]),
            lambda a: a.move_line(np.eye(3)),
            lambda a: a.move_line(pose(here[:3, 3] + [0, 0, 5.0], here)),
            lambda a: a.move_path([here], transition_s=-1),
            lambda a: a.read_wrench("elbow"),
        ]
        for i, request in enumerate(bad):
            with pytest.raises(KaliError) as local_error:
                request(local.robot("left"))
            with pytest.raises(KaliError) as remote_error:
                request(arm)
            assert type(remote_error.value) is type(local_error.value), i
            assert str(remote_error.value) == str(local_error.value), i
        with pytest.raises(KaliError) as local_error:
            local.robot("elbow")
        with pytest.raises(KaliError) as remote_error:
            remote.robot("elbow")
        assert str(remote_error.value) == str(local_error.value)
        assert (int(local.tg_robots["busy_seq"][0]), len(local.queue)) == taken
        with pytest.raises(BridgeError, match="controller's machine"):
            remote.control(lambda tick: None)
        # a wait as in real time: woken by the request's state the bridge publishes (the
        # clock stepped meanwhile by another thread, as real time would advance it)
        remote.inst.lockstep = False
        stepping = threading.Event()

        def step() -> None:
            with Instance.attach(name) as inst:
                while not stepping.is_set():
                    step_kali_clock(inst, 20)
                    time.sleep(0.002)

        stepper = threading.Thread(target=step)
        stepper.start()
        try:
            far = arm.move_joints(q - np.array([0.3, 0, 0, 0, 0, 0]), speed=0.2, wait=False)
            with pytest.raises(TimeoutError, match=rf"request {far.seq} not done within 0.05 s"):
                far.wait(timeout=0.05)
            far.wait(timeout=60)
            assert far.state == layout.RequestState.DONE
        finally:
            stepping.set()
            stepper.join()
        remote.inst.lockstep = True
        with pytest.raises(BridgeError, match="has no '_request'"):
            remote._request  # noqa: B018 — a private method does not cross


def test_telemetry_comes_at_its_rate_with_increasing_ticks(
    bridged: Callable[..., tuple[str, str]], listener: Callable[[str], zenoh.Session]
) -> None:
    """100 Hz (one sample each 10 ticks of 1 ms) for each robot, ticks increasing; the
    timing at 1 Hz; a liveliness token for the instance."""
    name, endpoint = bridged()
    keys = Keys(name)
    s = listener(endpoint)
    samples: dict[str, list[dict]] = {"left": [], "right": []}
    timing: list[dict] = []

    def on_state(sample: zenoh.Sample) -> None:
        doc = json.loads(sample.payload.to_bytes())
        samples[doc["robot"]].append(doc)

    subs = [
        s.declare_subscriber(keys.robots, on_state),
        s.declare_subscriber(
            keys.timing, lambda x: timing.append(json.loads(x.payload.to_bytes()))
        ),
    ]
    assert list(s.liveliness().get(keys.alive, timeout=5.0))
    with Instance.attach(name) as inst:
        step_kali_clock(inst, 2000)
    wait_for(lambda: len(samples["right"]) >= 200 and len(timing) >= 2, 20, "telemetry")
    for robot, docs in samples.items():
        ticks = [d["tick"] for d in docs]
        assert len(docs) in (200, 201), robot
        assert all(b > a for a, b in itertools.pairwise(ticks)), robot
        assert all(b - a == 10 for a, b in itertools.pairwise(ticks[1:])), robot
        assert len(docs[-1]["q"]) == 6 and docs[-1]["power"] == "OFF"
    assert {p["name"] for p in timing[-1]["processes"]} >= {"wallclock", "sio", "bridge"}
    assert len(timing) in (2, 3)
    for sub in subs:
        sub.undeclare()


def test_events_arrive_in_order_and_none_is_lost_across_a_fault_and_reset(
    bridged: Callable[..., tuple[str, str]], listener: Callable[[str], zenoh.Session]
) -> None:
    """Power, calibration, motion, fault and its clearing: numbered 1, 2, 3 ... with no gap,
    in the order they happened; a late subscriber gets the history."""
    import zenoh.ext

    name, endpoint = bridged()
    keys = Keys(name)
    s = listener(endpoint)
    events: list[dict] = []
    sub = zenoh.ext.declare_advanced_subscriber(
        s,
        keys.events,
        lambda x: events.append(json.loads(x.payload.to_bytes())),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
        recovery=zenoh.ext.RecoveryConfig(heartbeat=True),
    )
    time.sleep(0.3)
    with Kali(name) as kali:
        kali.ready(["left", "right"])
        arm = kali.robot("left")
        arm.move_joints(arm.read_joints() + np.array([0.1, 0, 0, 0, 0, 0]), speed=0.5)
        r = subprocess.run([KALICTL, "-i", name, "estop"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        r = subprocess.run([KALICTL, "-i", name, "estop", "--release"], capture_output=True)
        r = subprocess.run([KALICTL, "-i", name, "reset"], capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        kali.sleep(0.1)
    kinds = lambda: [e["kind"] for e in events]  # noqa: E731
    wait_for(lambda: "fault cleared" in kinds(), 20, "the fault cleared event")
    numbers = [e["n"] for e in events]
    assert numbers == list(range(numbers[0], numbers[0] + len(numbers)))
    assert numbers[0] == 1 or len(events) > 1
    order = kinds()
    assert order.index("power") < order.index("calibration") < order.index("motion")
    assert order.index("motion") < order.index("fault") < order.index("fault cleared")
    fault = next(e for e in events if e["kind"] == "fault")
    assert "e-stop" in fault["text"].lower() or "estop" in fault["text"].lower()
    states = [e["state"] for e in events if e["kind"] == "motion"]
    assert states[-1] == "DONE"
    ticks = [e["tick"] for e in events]
    assert ticks == sorted(ticks)
    sub.undeclare()
    late: list[dict] = []  # a subscriber that comes later gets what it missed
    late_sub = zenoh.ext.declare_advanced_subscriber(
        listener(endpoint),
        keys.events,
        lambda x: late.append(json.loads(x.payload.to_bytes())),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True),
    )
    wait_for(lambda: len(late) >= len(events), 10, "the history")
    assert [e["n"] for e in late[: len(events)]] == numbers
    late_sub.undeclare()


def stream_and_track(k: Kali) -> tuple[list[np.ndarray], list[str]]:
    """One program, run locally or through the bridge: a pose stream the left tool follows
    (poses, then twists, then a pose refused), a joint stream, then a shared transform it
    tracks, ``k.sleep`` between sends (the clock stepped in lockstep); the demand after each
    step, and the refusals' words."""
    k.ready(["left"])
    left = k.robot("left")
    start = left.read_pose()
    seen, said = [], []
    with left.stream(lifetime=0.1, accel=5.0) as s:
        p = start.copy()
        for _ in range(20):
            p[2, 3] += 0.002
            s.send(p)
            k.sleep(0.02)
            seen.append(left.read_state().q_d)
        assert s.handle.limited > 0
        for _ in range(5):
            s.send_twist([0.0, 0.02, 0.0, 0.0, 0.0, 0.1])
            k.sleep(0.02)
            seen.append(left.read_state().q_d)
        bent = p.copy()
        bent[0, 0] = 2.0
        for bad, send in ((bent, s.send), ([0.0] * 5, s.send_twist)):
            with pytest.raises(MotionError) as e:
                send(bad)
            said.append(str(e.value))
    with pytest.raises(MotionError) as e:  # closed: the record is not the program's any more
        s.send(p)
    said.append(str(e.value))
    k.sleep(0.2)
    with left.stream_joints(lifetime=0.1) as j:
        q = left.read_joints()
        for _ in range(10):
            q[0] += 0.002
            j.send(q)
            k.sleep(0.02)
            seen.append(left.read_state().q_d)
    k.sleep(0.3)
    frame = k.shared_transform("target", start, lifetime=0.2)
    handle = left.track([frame], speed=0.2)
    for i in range(20):
        p = start.copy()
        p[1, 3] += 0.001 * i
        frame.set(p)
        k.sleep(0.01)
        seen.append(left.read_state().q_d)
    k.sleep(0.3)  # not set for longer than its lifetime: the arm stops on its path
    assert handle.state == layout.RequestState.STOPPED and "not written for" in handle.message
    frame.close()
    return seen, said


def test_a_remote_stream_and_shared_transform_drive_the_arm_as_a_local_program_does(
    kali: Callable[..., str], bridged: Callable[..., tuple[str, str]]
) -> None:
    """Issue 55 item 5: ``robot.stream()``, ``kali.shared_transform`` and ``robot.track``
    through the bridge, unchanged: the remote stream is a shared transform the program's
    session writes, with the same lifetime and stale-stop rule, and the demands tick by tick
    are those of the same program run locally."""
    with Kali(kali(lockstep=True)) as local:
        here, said_here = stream_and_track(local)
    name, endpoint = bridged()
    with Kali.connect(endpoint, name) as remote:
        there, said_there = stream_and_track(remote)
        written = remote.status()["bridge"]["stream_writes"]
    np.testing.assert_array_equal(np.array(there), np.array(here))
    unpid = lambda said: [re.sub(r"\.\d+'", "'", m) for m in said]  # noqa: E731 (the stream's)
    assert unpid(said_there) == unpid(said_here) and "not a rigid pose" in said_here[0]
    assert written == 20 + 5 + 10 + 20  # every send and set written by the bridge itself


def test_verbs_answer_with_kalictls_words(
    bridged: Callable[..., tuple[str, str]],
) -> None:
    """enable, ff, servo get and status through the bridge; kalictl's refusal line for a
    bad one; verbs outside the list refused by name."""
    name, endpoint = bridged()
    with Kali.connect(endpoint, name) as remote:
        out = remote.verb("enable", "left")
        assert "left" in out
        local = subprocess.run(
            [KALICTL, "-i", name, "servo", "get", "left", "9"], capture_output=True, text=True
        )
        with pytest.raises(BridgeError) as e:
            remote.verb("servo", "get", "left", "9")
        assert str(e.value) == "bridge: " + local.stderr.strip()
        with pytest.raises(BridgeError, match="unknown verb 'stop'"):
            remote.verb("stop")
        with pytest.raises(BridgeError, match="not open to remote programs"):
            remote.verb("servo", "load", "/tmp/x.py")
        doc = remote.status()
        assert doc["clock"]["mode"] == "stopped" and doc["bridge"]["sessions"][0]["pid"] > 0


def test_malformed_requests_get_clear_errors_and_never_reach_the_queue(
    bridged: Callable[..., tuple[str, str]], listener: Callable[[str], zenoh.Session]
) -> None:
    """Wrong types, sizes, NaN, unknown methods and verbs, a flood: each answered with an
    error naming it; the TG's queue never sees one."""
    name, endpoint = bridged(extra={"max_requests_per_s": "200"})
    keys = Keys(name)
    with Kali.connect(endpoint, name) as remote:
        s = listener(endpoint)  # the program's own calls, malformed: its name and its secret
        mine = keys.user(remote._conn.mine.name)  # unauthenticated: any client may use it
        call = mine.call(remote._conn.secret)

        def raw(payload: bytes) -> dict:
            replies = list(s.get(call, payload=payload, timeout=10.0))
            return json.loads(replies[0].ok.payload.to_bytes())

        def refused(payload: bytes) -> str:
            return raw(payload)["error"]["message"]

        assert "not JSON" in refused(b"\xff{not json")
        assert "must be a JSON object" in refused(b"[1, 2]")
        assert "bytes (at most" in refused(b" " * (2 << 20))
        assert "no object 99" in refused(json.dumps({"target": 99, "method": "x"}).encode())
        assert "cannot be called from another machine" in refused(
            json.dumps({"target": 0, "method": "close"}).encode()
        )
        assert "__init__" in refused(json.dumps({"target": 0, "method": "__init__"}).encode())
        big = {"__nd__": list(range(100_000))}
        assert "values (at most" in refused(
            json.dumps({"target": 0, "method": "robot", "args": [big]}).encode()
        )
        robot = remote.robot("left")
        nan = json.dumps(
            {"target": robot._oid, "method": "move_joints", "args": [[float("nan")] * 6]}
        )
        assert "must be finite" in refused(nan.encode())
        wrong = json.dumps({"target": robot._oid, "method": "move_joints", "args": ["abc"]})
        assert raw(wrong.encode())["error"]["type"] == "MotionError"
        unknown = mine.verb("format-disk")
        assert "unknown verb" in ask(s, unknown, {"args": []})["error"]["message"]
        assert (
            "not a short string" in ask(s, mine.verb("enable"), {"args": [1]})["error"]["message"]
        )
        assert "no such session" in ask(s, mine.call("0" * 32), {"target": 0})["error"]["message"]
        # a flood: 10,000 requests at once; beyond the rate, or the session's calls waiting,
        # each is refused unread
        answers: list[dict] = []
        lock = threading.Lock()

        def on_reply(reply: zenoh.Reply) -> None:
            with lock:
                answers.append(json.loads(reply.ok.payload.to_bytes()))

        flood = json.dumps({"target": robot._oid, "method": "move_joints", "args": [[1e9] * 6]})
        t0 = time.monotonic()
        for _ in range(10_000):
            s.get(call, on_reply, payload=flood.encode(), timeout=30.0)
        wait_for(lambda: len(answers) == 10_000, 120, "every request of the flood answered")
        rate = 10_000 / (time.monotonic() - t0)
        messages = [a["error"]["message"] for a in answers]
        assert sum("requests a second" in m for m in messages) > 5000, rate
        assert all(
            "requests a second" in m or "wait already" in m or "outside its range" in m
            for m in messages
        )
        with Instance.attach(name) as inst:
            state = inst.arena.record(layout.KEY_TG_STATE, layout.TG_STATE)
            assert int(state["taken_seq"]) == 0  # nothing ever reached the TG


def test_kill_9_of_the_bridge_degrades_without_a_halt(
    bridged: Callable[..., tuple[str, str]],
) -> None:
    """Stalled, then killed: the cell runs on; kalictl status says degraded: bridge; a
    remote program's session worker goes with it."""
    name, endpoint = bridged(separate=False)
    remote = Kali.connect(endpoint, name)
    worker = remote.status()["bridge"]["sessions"][0]["pid"]
    with Instance.attach(name) as inst:
        bridge = int(inst.procs[inst.find_slot("bridge")]["pid"])
        os.kill(bridge, signal.SIGSTOP)  # stalled: said so, nothing else changes
        try:
            time.sleep(2.5)
            r = subprocess.run([KALICTL, "-i", name, "status"], capture_output=True, text=True)
            assert "degraded: bridge (pid" in r.stdout and "stalled: no heartbeat" in r.stdout
        finally:
            os.kill(bridge, signal.SIGCONT)
        assert inst.fault_text() is None
        os.kill(bridge, signal.SIGKILL)
        step_kali_clock(inst, 500)
        assert inst.fault_text() is None
        assert int(inst.clock["tick"]) >= 500
    r = subprocess.run([KALICTL, "-i", name, "status"], capture_output=True, text=True)
    assert "degraded: bridge" in r.stdout and "remote access" in r.stdout
    with pytest.raises(BridgeError, match=r"went away|no answer"):
        remote.robot("left")
    remote.close()
    with Kali(name) as kali:  # a local program still moves the arms
        kali.ready(["left"])
    wait_for(lambda: not os.path.exists(f"/proc/{worker}"), 10, "the session's worker gone")


def test_a_remote_program_that_disappears_is_a_dead_local_program(
    bridged: Callable[..., tuple[str, str]],
) -> None:
    """A remote program killed mid-motion: its session's worker goes, its motion runs out,
    its arm's lease lapses so another program may move it."""
    name, endpoint = bridged()
    code = f"""
import numpy as np, sys, time
from kali_daemons.client import Kali
kali = Kali.connect({endpoint!r}, {name!r})
kali.ready(["left"])
arm = kali.robot("left")
arm.move_joints(arm.read_joints() + np.array([-0.6, 0, 0, 0, 0, 0]), speed=0.2, wait=False)
print(kali.status()["bridge"]["sessions"][0]["pid"], flush=True)
time.sleep(600)
"""
    proc = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        worker = int(proc.stdout.readline())
        with Kali(name) as kali:
            kali.sleep(0.1)  # the TG takes the request
            owner = kali.owner(0)
            assert owner is not None and owner[0] == worker and "remote" in owner[1]
            assert not kali.idle([0])
            proc.kill()
            proc.wait()
            wait_for(lambda: not os.path.exists(f"/proc/{worker}"), 20, "its worker gone")
            assert not kali.idle([0])  # it runs out, as a dead local program's
            for _ in range(300):
                if kali.idle([0]):
                    break
                kali.sleep(0.1)
            assert kali.idle([0]) and kali.owner(0) is None
            arm = kali.robot("left")
            arm.move_joints(arm.read_joints() - np.array([0.1, 0, 0, 0, 0, 0]), speed=0.5)
    finally:
        proc.kill()
        proc.wait()


def test_a_second_instances_keys_are_invisible_to_the_firsts_clients(
    bridged: Callable[..., tuple[str, str]], listener: Callable[[str], zenoh.Session]
) -> None:
    """Each instance's bridge is its own router: a client of the first sees the first's
    keys only, finds no second instance there, and may not even ask for all of ``kali/**``."""
    first, endpoint = bridged()
    second, _ = bridged()
    s = listener(endpoint)
    seen: dict[str, set[str]] = {"first": set(), "second": set(), "all": set()}
    subs = [
        s.declare_subscriber(f"kali/{first}/**", lambda x: seen["first"].add(str(x.key_expr))),
        s.declare_subscriber(f"kali/{second}/**", lambda x: seen["second"].add(str(x.key_expr))),
        s.declare_subscriber("kali/**", lambda x: seen["all"].add(str(x.key_expr))),
    ]
    ask(s, Keys(first).user("reader").status, {})  # the router has the subscriptions by then
    for name in (first, second):
        with Instance.attach(name) as inst:
            step_kali_clock(inst, 100)
    wait_for(lambda: any("/robots/" in k for k in seen["first"]), 10, "the first's telemetry")
    time.sleep(0.2)
    assert all(k.startswith(f"kali/{first}/") for k in seen["first"] | seen["all"])
    assert seen["second"] == set()
    assert not list(s.liveliness().get(Keys(second).alive, timeout=1.0))
    with pytest.raises(BridgeError, match="no Kali instance"):
        Kali.connect(endpoint, second)
    for sub in subs:
        sub.undeclare()


def test_a_reader_cannot_command(
    kali: Callable[..., str], tmp_path: Path, listener: Callable[[str], zenoh.Session]
) -> None:
    """With users: an operator opens a session and moves; a reader gets telemetry and
    status but its session and verbs are refused; no credentials, no connection."""
    users = tmp_path / "users.txt"
    users.write_text("op:secret1\nviewer:secret2\n")
    port = free_port()
    extra = {"users_file": str(users), "operators": "[op]", "readers": "[viewer]"}
    name = kali(lockstep=True, edits=bridge_edit(port, extra))
    endpoint = f"tcp/127.0.0.1:{port}"
    with pytest.raises(BridgeError, match="cannot connect"):
        Kali.connect(endpoint, name)
    with pytest.raises(BridgeError, match="cannot connect"):
        Kali.connect(endpoint, name, user="op", password="wrong")
    with pytest.raises(BridgeError, match="may not ask it"):
        Kali.connect(endpoint, name, user="viewer", password="secret2")
    reader = zenoh.open(client_config(endpoint, "viewer", "secret2"))
    try:
        got: list[bytes] = []
        sub = reader.declare_subscriber(Keys(name).robots, lambda x: got.append(b""))
        mine = Keys(name).user("viewer")
        assert json.loads(next(iter(reader.get(mine.status, timeout=10.0))).ok.payload.to_bytes())
        assert not list(reader.get(mine.verb("enable"), payload=b'{"args": []}', timeout=2.0))
        with Instance.attach(name) as inst:
            step_kali_clock(inst, 100)
        wait_for(lambda: got, 10, "telemetry for the reader")
        sub.undeclare()
    finally:
        reader.close()
    with Kali.connect(endpoint, name, user="op", password="secret1") as remote:
        remote.ready(["left"])
        arm = remote.robot("left")
        assert arm.read_joints().shape == (arm.n_joints,)


def test_ctrl_c_in_a_remote_program_stops_its_arms_on_their_paths(
    bridged: Callable[..., tuple[str, str]],
) -> None:
    """A remote program's ``with Kali()`` block left by Ctrl-C (``kalictl run --remote``
    sends SIGINT) stops the arms it owns before it closes: its move ends STOPPED short of
    its target."""
    name, endpoint = bridged()
    with Kali(name) as local:
        local.ready(["left"])
        start = local.robot("left").read_joints()
        target = start - np.array([0.8, 0, 0, 0, 0, 0])  # away from the right arm
        with pytest.raises(KeyboardInterrupt), Kali.connect(endpoint, name) as remote:
            arm = remote.robot("left")
            arm.move_joints(target, speed=0.2, wait=False)
            remote.sleep(0.5)  # under way
            raise KeyboardInterrupt
        for _ in range(100):
            if local.idle([0]):
                break
            local.sleep(0.1)
        assert local.idle([0])
        q = local.robot("left").read_joints()
        assert 0.02 < start[0] - q[0] < 0.6  # stopped on the way, not at the target
        status = local.status
        ended = status[status["seq"] > 0]
        states = {layout.RequestState(int(s)).name for s in ended["state"]}
        assert "STOPPED" in states


def test_a_remote_run_on_an_instance_not_there_names_the_instances_that_are(
    bridged: Callable[..., tuple[str, str]], tmp_path: Path
) -> None:
    """Issue 52 item 6: ``kalictl run --remote`` to a name the bridge does not serve said
    only that it does not answer; it names the instances that do."""
    name, endpoint = bridged()
    program = tmp_path / "prog.py"
    program.write_text("print('ran')\n")
    r = subprocess.run(
        [sys.executable, "-m", "kali_daemons", "-i", "nothere", "run", "--remote", endpoint,
         str(program)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert r.returncode == 1 and "ran" not in r.stdout, r.stdout
    assert "no Kali instance 'nothere' answers" in r.stderr, r.stderr
    assert f"instances answering there: {name} (-i NAME)" in r.stderr, r.stderr
