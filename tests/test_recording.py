"""Recording a run to MCAP (issue 55 item 2): every servo tick of every arm, lossless in
lockstep, read back by independent readers (the ``mcap`` package's and ``rosbags``)."""

from __future__ import annotations

import os
import subprocess
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from kali_daemons.client import Kali
from kali_daemons.client.state import ArmState
from kali_daemons.core.errors import KaliError
from kali_daemons.recording import log, recorder
from kali_daemons.wallclock import step_kali_clock

from .test_bridge import bridged  # noqa: F401  (the fixture)
from .test_launcher import kalictl
from .test_mcapfile import rosbags_positions

SERVO_FIELDS = ("q", "qd", "q_d", "qd_d", "servo_torque", "ff_torque", "torque", "current")


def by_topic(path: Path) -> dict[str, list]:
    """Every message of the file, decoded, by topic (the mcap package's own reader)."""
    out: dict[str, list] = {}
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, _message, msg in reader.iter_decoded_messages():
            out.setdefault(channel.topic, []).append(msg)
    return out


def test_a_recording_holds_every_servo_tick_of_every_arm(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """``with kali.record(path)`` around a move of both arms, stepped tick by tick: every tick
    of every arm is in the file once, in order, no gap, each message equal to what
    ``read_state`` saw that tick; ``rosbags`` reads the same ticks and joint states."""
    name = kali(lockstep=True)
    path = tmp_path / "run.mcap"
    with Kali(name) as k:
        k.ready()
        left, right = k.robot("left"), k.robot("right")
        seen: dict[str, dict[int, ArmState]] = {"left": {}, "right": {}}
        with k.record(path) as status:
            viewer_cpu = k.inst.config.process("viewer").cpu  # the recorder runs beside it
            assert os.sched_getaffinity(recorder.running(k.inst)) == {viewer_cpu}
            with k.together():
                left.move_joints(left.read_joints() + 0.1, wait=False)
                move = right.move_joints(right.read_joints() - 0.1, wait=False)
            while not move.done:
                step_kali_clock(k.inst, 1)
                for arm in (left, right):
                    s = arm.read_state()
                    seen[arm.name][s.tick] = s
            step_kali_clock(k.inst, 250)  # more than a recorder period after the last read
        assert status["error"] == "" and status["gaps"] == 0, status
        topics = by_topic(path)
        for arm in ("left", "right"):
            servo = topics[f"/kali/{arm}/servo"]
            ticks = np.array([m.tick for m in servo])
            assert (np.diff(ticks) == 1).all(), "every tick once, in order"
            assert ticks[0] <= min(seen[arm]) and ticks[-1] >= max(seen[arm]) + 200
            assert len(ticks) == status["ticks"]
            for m in servo:
                s = seen[arm].get(m.tick)
                if s is not None:
                    for f in SERVO_FIELDS:
                        np.testing.assert_array_equal(getattr(m, f), getattr(s, f), f)
            joints = topics[f"/kali/{arm}/joint_states"]
            assert len(joints) == len(ticks)
            assert list(joints[0].name) == [f"{arm}_joint{j}" for j in range(1, 7)]
            wrench = topics[f"/kali/{arm}/wrench"]
            assert len(wrench) == len(ticks)
        assert "/kali/gaps" not in topics

    positions, _ = rosbags_positions(path, "/kali/left/joint_states")
    assert len(positions) == len(topics["/kali/left/joint_states"])
    first = topics["/kali/left/servo"][0]
    np.testing.assert_array_equal(positions[0], first.q)

    run = log.read(path)  # Kali's own reader: arrays aligned on ticks
    assert set(run.arms) == {"left", "right"} and run.gaps == []
    for arm in ("left", "right"):
        a = run.arms[arm]
        np.testing.assert_array_equal(a.tick, [m.tick for m in topics[f"/kali/{arm}/servo"]])
        assert a.q.shape == (len(a.tick), 6) and a.wrench is not None
        assert a.wrench.shape == (len(a.tick), 6)
        for t, s in seen[arm].items():
            i = int(np.searchsorted(a.tick, t))
            np.testing.assert_array_equal(a.torque[i], s.torque)
            np.testing.assert_array_equal(a.wrench[i], s.wrench)
        np.testing.assert_allclose(np.diff(a.time_s), 1e-3)
    np.testing.assert_array_equal(run.arms["left"].tick, run.arms["right"].tick)


def test_reading_what_is_not_a_recording_says_so(tmp_path: Path) -> None:
    """``log.read`` of a missing file, of one that is not MCAP: each a KaliError naming it."""
    with pytest.raises(KaliError, match="no such file"):
        log.read(tmp_path / "none.mcap")
    junk = tmp_path / "junk.mcap"
    junk.write_bytes(b"not an mcap file at all" * 10)
    with pytest.raises(KaliError, match="not a readable MCAP recording"):
        log.read(junk)


def test_kalictl_records_and_refuses_what_it_cannot_do(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """``kalictl record start|status|stop``: the ticks stepped are in the file; a second
    recording at once, an existing file, a directory that is not there: each refused, naming
    why, and nothing written over."""
    name = kali(lockstep=True)
    path = tmp_path / "cli.mcap"
    r = kalictl("-i", name, "record", "start", str(path))
    assert r.returncode == 0, r.stderr
    again = kalictl("-i", name, "record", "start", str(tmp_path / "other.mcap"))
    assert again.returncode != 0 and "already recording to" in again.stderr, again.stderr
    assert kalictl("-i", name, "clock", "step", "500").returncode == 0
    r = kalictl("-i", name, "record", "status")
    assert "recording recording" in r.stdout, r.stdout
    r = kalictl("-i", name, "record", "stop")
    assert r.returncode == 0 and "no tick lost" in r.stdout, (r.stdout, r.stderr)
    ticks = [m.tick for m in by_topic(path)["/kali/left/servo"]]
    assert len(ticks) >= 500 and (np.diff(ticks) == 1).all()
    size = path.stat().st_size
    r = kalictl("-i", name, "record", "start", str(path))
    assert r.returncode != 0 and "exists" in r.stderr and path.stat().st_size == size
    r = kalictl("-i", name, "record", "start", str(tmp_path / "none" / "x.mcap"))
    assert r.returncode != 0 and "is not a directory" in r.stderr
    with Kali(name) as k, pytest.raises(KaliError, match="is not recording"):
        from kali_daemons.recording import recorder

        recorder.stop(k.inst)


def test_a_recording_survives_a_halt_with_the_halt_in_it(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """An e-stop during a recorded move: the recording ends cleanly after the halt, every
    tick up to it there, with the move's request and the fault (ESTOP) in it."""
    name = kali(lockstep=True)
    path = tmp_path / "halt.mcap"
    with Kali(name) as k:
        k.ready()
        left = k.robot("left")
        with k.record(path) as status:
            move = left.move_joints(left.read_joints() + 0.3, wait=False)
            step_kali_clock(k.inst, 400)
            k.inst.press_estop(None, "test")  # the clock stops: no step until a reset
            halted_at = int(k.inst.clock["tick"])
        assert status["error"] == "" and status["gaps"] == 0, status
        assert k.inst.fault_text() is not None
    topics = by_topic(path)
    ticks = [m.tick for m in topics["/kali/left/servo"]]
    assert (np.diff(ticks) == 1).all() and ticks[-1] >= halted_at - 10
    faults = topics["/kali/faults"]
    assert [f.code for f in faults] == ["ESTOP"], faults
    seqs = {r.seq: r.state for r in topics["/kali/requests"]}
    assert move.seq in seqs, seqs


def test_a_recording_carries_servo_changes_and_the_simulators_truth(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """A gain changed, a servo selected, a joint's servo disabled and enabled, a shadow trial
    begun and stopped, a robot-level servo selected while recording: each is on
    ``/kali/<arm>/servo_changes`` at its tick with the servo's parameters as they then were;
    the plant's truth is on ``/kali/sim/<arm>/truth`` (sampled each recorder period, labelled
    as the simulator's), its joints where the encoders said at that tick.  ``log.read`` gives
    both."""
    name = kali(lockstep=True, base="force.yaml")
    path = tmp_path / "servos.mcap"
    with Kali(name) as k:
        k.ready()
        sv = k.servo
        with k.record(path) as status:
            step_kali_clock(k.inst, 20)
            sv.set_params("left", 2, {"kp": 1234.0})
            step_kali_clock(k.inst, 20)
            sv.select("left", 3, "pd")
            sv.enable_servo("left", 4, False)
            step_kali_clock(k.inst, 20)
            sv.enable_servo("left", 4, True)
            sv.shadow("right", 1, "pd")
            step_kali_clock(k.inst, 30)
            sv.shadow("right", 1, None)
            sv.select_arm("right", "computed_torque")
            step_kali_clock(k.inst, 30)
        assert status["error"] == "" and status["gaps"] == 0, status
    topics = by_topic(path)
    left = [(m.joint, m.kind, m.servo) for m in topics["/kali/left/servo_changes"]]
    right = [(m.joint, m.kind, m.servo) for m in topics["/kali/right/servo_changes"]]
    assert left == [
        (2, "params", "pid"),
        (3, "select", "pd"),
        (4, "disable", "pid"),
        (4, "enable", "pid"),
    ], left
    assert right == [
        (1, "shadow", "pd"),
        (1, "shadow_stopped", "pd"),
        (0, "select", "computed_torque"),
    ], right
    gain = topics["/kali/left/servo_changes"][0]
    assert dict(zip(gain.names, gain.values, strict=True))["kp"] == 1234.0
    ticks = [m.tick for m in topics["/kali/left/servo_changes"]]
    assert ticks == sorted(ticks) and ticks[0] < ticks[1]
    servo = {m.tick: m for m in topics["/kali/left/servo"]}
    truth = topics["/kali/sim/left/truth"]
    assert len(truth) >= 9  # one a recorder period (10 ms) over 100 ticks
    for m in truth:
        np.testing.assert_allclose(m.q, servo[m.tick].q, atol=2e-4)  # an encoder count or so
    run = log.read(path)
    assert [(c.joint, c.kind, c.servo) for c in run.servo_changes["left"]] == left
    np.testing.assert_array_equal(run.truth["left"].tick, [m.tick for m in truth])
    assert run.truth["left"].q.shape == (len(truth), 6)


def test_kalictl_flight_now_dumps_the_ring_without_a_halt(kali: Callable[..., str]) -> None:
    """``kalictl flight --now`` writes the last 2 s as they stand (a ring-*.npz, its fault
    fields saying it was asked for) and sums it up; it is never taken for a halt's dump."""
    name = kali(lockstep=True)
    r = kalictl("-i", name, "clock", "step", "300")
    assert r.returncode == 0, r.stderr
    r = kalictl("-i", name, "flight", "--now")
    assert r.returncode == 0, r.stderr
    first = r.stdout.splitlines()[0]
    assert first.startswith("flight recorder dump ") and "/ring-" in first, r.stdout
    path = Path(first.removeprefix("flight recorder dump "))
    assert path.is_file() and "fault: NONE in kalictl" in r.stdout and "asked for" in r.stdout
    assert "covers ticks" in r.stdout and "300 servo ticks" in r.stdout, r.stdout
    r = kalictl("-i", name, "flight")
    assert r.returncode != 0 and "ring-" not in r.stdout + r.stderr, (r.stdout, r.stderr)


def test_a_remote_program_records_and_gets_the_file(
    bridged: Callable[..., tuple[str, str]], tmp_path: Path  # noqa: F811
) -> None:
    """``kali.record(path)`` through the bridge: the recording is made on the controller's
    machine and fetched to ``path`` here, the same bytes, every tick in it."""
    name, endpoint = bridged()
    path = tmp_path / "remote.mcap"
    with Kali.connect(endpoint, name) as remote:
        remote.ready(["left"])
        left = remote.robot("left")
        with remote.record(path) as status:
            left.move_joints(left.read_joints() + 0.05, speed=0.5)
        assert status["error"] == "" and status["gaps"] == 0, status
    there = Path(status["there"])
    assert there.read_bytes() == path.read_bytes()
    ticks = log.read(path).arms["left"].tick
    assert len(ticks) == status["ticks"] and (np.diff(ticks) == 1).all()
    with Kali.connect(endpoint, name) as remote:
        refused = pytest.raises(KaliError, match="exists")
        with refused:
            remote.record(path).__enter__()


def test_a_disk_that_fills_ends_the_recording_and_the_arms_never_notice(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """Recording onto a 256 KiB file system: the recording ends saying the disk is full,
    nothing halts and the clock steps on."""
    disk = tmp_path / "small"
    disk.mkdir()
    mounted = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=256k", "tmpfs", str(disk)], capture_output=True
    )
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a small file system here: {mounted.stderr.decode()}")
    try:
        name = kali(lockstep=True)
        with Kali(name) as k:
            k.ready()
            left = k.robot("left")
            with k.record(disk / "full.mcap") as status:
                for _ in range(3):
                    left.move_joints(left.read_joints() + 0.2, speed=0.5)
                    left.move_joints(left.read_joints() - 0.2, speed=0.5)
            assert "No space left on device" in status["error"], status
            assert k.inst.fault_text() is None
            tick = int(k.inst.clock["tick"])
            step_kali_clock(k.inst, 100)
            assert int(k.inst.clock["tick"]) == tick + 100
    finally:
        subprocess.run(["umount", str(disk)], check=False)


def test_a_recording_carries_each_cameras_frames(kali: Callable[..., str], tmp_path: Path) -> None:
    """scenes/watched.yaml's camera (issue 56 item 4) in a recording: its new frames as
    sensor_msgs/msg/Image (rgb8, and 32FC1 depth) and CameraInfo, stamped with the tick each
    shows; the last, drained as the recording ends with the clock standing, equal to the
    frame a program read then; rosbags decodes them too."""
    name = kali(lockstep=True, edits={r"^version: 1$": "version: 1\nscene: scenes/watched.yaml"})
    path = tmp_path / "seen.mcap"
    with Kali(name) as k:
        camera = k.camera("table")
        with k.record(path) as status:
            k.ready(["left"])
            left = k.robot("left")
            move = left.move_joints(left.read_joints() + 0.2, wait=False)
            while not move.done:  # the arm in view, moving: frames of many ticks
                step_kali_clock(k.inst, 10)
                time.sleep(0.01)
            tick = int(k.inst.clock["tick"])
            standing = time.monotonic_ns()
            last = camera.read(since_tick=tick)
            while last.stamp_ns <= standing:  # one taken while the clock stands
                last = camera.read(since_tick=tick)
        assert status["error"] == "", status
    topics = by_topic(path)
    images = topics["/kali/cameras/table/image"]
    stamps = [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in images]
    assert len(images) >= 3 and stamps == sorted(stamps), stamps
    for m in images:
        assert (m.height, m.width, m.encoding, m.step) == (240, 320, "rgb8", 960)
        assert m.header.frame_id == "table_optical" and len(m.data) == 240 * 320 * 3
    assert stamps[-1] == tick * 1_000_000
    shown = np.frombuffer(bytes(images[-1].data), np.uint8)
    np.testing.assert_array_equal(shown, last.image.ravel())
    depth = topics["/kali/cameras/table/depth"][-1]
    assert depth.encoding == "32FC1" and depth.step == 4 * 320
    np.testing.assert_array_equal(np.frombuffer(bytes(depth.data), np.float32), last.depth.ravel())
    info = topics["/kali/cameras/table/camera_info"][-1]
    np.testing.assert_array_equal(np.reshape(info.k, (3, 3)), last.K)
    assert info.distortion_model == "plumb_bob" and list(info.d) == [0.0] * 5
    assert len(topics["/kali/cameras/table/camera_info"]) == len(images)

    from rosbags.highlevel import AnyReader

    with AnyReader([path]) as reader:
        seen = [c for c in reader.connections if c.topic == "/kali/cameras/table/image"]
        assert seen and seen[0].msgtype == "sensor_msgs/msg/Image"
        first = next(reader.messages(connections=seen))
        msg = reader.deserialize(first[2], seen[0].msgtype)
        assert (msg.height, msg.width, len(msg.data)) == (240, 320, 240 * 320 * 3)
