"""The viewer (issue 6, thesis 3.3.7): the live rerun dashboard.

A lockstep instance records its dashboard to a file, which is read back (the arms, joints,
timing and faults; a push on a tool in the wrist sensor's series and the contact arrow, issue
27); a headless chromium
opens the web viewer of another and its screenshot must show the arms and the plots; a
real-time instance keeps drawing after a halt, and its viewer dying halts nothing and leaves
no process or port behind.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import os
import select
import shutil
import signal
import socket
import subprocess
import time
import urllib.parse
from collections import Counter
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pinocchio as pin
import pytest
import rerun as rr

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.core.errors import ConfigError
from kali_daemons.core.joints import per_joint
from kali_daemons.core.layout import FaultCode, RunMode
from kali_daemons.robots.cell import base_transform
from kali_daemons.runtime.config import DashboardConfig, KaliConfig
from kali_daemons.runtime.instance import Instance, time_ms
from kali_daemons.servo.client import ServoClient
from kali_daemons.tools import launcher
from kali_daemons.viewer.dashboard import CONTACT_M_PER_N, Dashboard, blueprint
from kali_daemons.viewer.sinks import pick_port, reachable, rerun_binary
from kali_daemons.wallclock import start_kali_clock, step_kali_clock

from .conftest import make_config, unique_name, wait_for
from .test_launcher import kalictl
from .test_servo_level import power_all
from .test_tg import MIXED

DASHBOARD = r"^dashboard:\n(?:  .*\n?)*"  # the section in config/default.yaml
NO_SENSOR_LEFT = {r"^(  - \{name: left.*)\}$": r"\1, ft: {sensor: none}}"}


def dashboard(**fields: object) -> dict[str, str]:
    """A config edit replacing the ``dashboard`` section by ``dashboard: {fields}``."""
    text = ", ".join(f"{k}: {json.dumps(v)}" for k, v in fields.items())
    return {DASHBOARD: f"dashboard: {{{text}}}\n"}


@contextmanager
def moving(name: str) -> Iterator[tuple[Instance, ServoClient]]:
    """Attach, power both arms and send each a one-second move of two joints."""
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            power_all(inst, client, 200)
            for k, moves in enumerate(({1: 0.5, 2: -0.4}, {0: 0.4, 4: 0.5})):
                fifo = client.level.fifo(k)
                start = client.level.joints["demand"][inst.config.joints.span(k)].copy()
                for m in range(1, 101):  # 100 TG set-points: 1 s
                    target = start.copy()
                    for j, delta in moves.items():
                        target[j] += delta * m / 100
                    fifo.push(target)
            yield inst, client
        finally:
            client.close()


# ---------------------------------------------------------------------------- configuration


def test_dashboard_config_and_record_path(tmp_path: Path) -> None:
    cfg = make_config("cfgonly")  # default.yaml, but the tests' instances serve no web viewer
    assert cfg.dashboard == dataclasses.replace(DashboardConfig(), web="off")
    assert launcher._record_path(cfg, None) == ""
    cfg = make_config("cfgonly", dashboard(record="runs/a.rrd", web=False, connect=None))
    assert (cfg.dashboard.record, cfg.dashboard.web, cfg.dashboard.connect) == (
        "runs/a.rrd",
        "off",
        None,
    )
    with pytest.raises(ConfigError, match=r"dashboard.record .*/config/runs/a\.rrd: no directory"):
        launcher._record_path(cfg, None)  # relative to the config's directory
    assert launcher._record_path(cfg, tmp_path / "b.rrd") == str(tmp_path / "b.rrd")  # --record
    with pytest.raises(ConfigError, match=r"--record .*: is a directory"):
        launcher._record_path(cfg, tmp_path)
    for fields, message in (
        ({"web": "maybe"}, "dashboard.web = 'maybe': must be one of: auto, on, off"),
        ({"connect": "http://x:1"}, "dashboard.connect = 'http://x:1': must be a rerun gRPC"),
        ({"web_port": 9000, "grpc_port": 9000}, "dashboard.grpc_port = 9000: must differ"),
        ({"web_port": 70000}, "dashboard.web_port = 70000: must be an integer >= 0"),
        ({"record": ""}, "dashboard.record = '': must be null or a file path"),
        ({"port": 1}, "dashboard.port: unknown key"),
    ):
        with pytest.raises(ConfigError, match=message):
            make_config("cfgonly", dashboard(**fields))


# ---------------------------------------------------------------------------- the recording


def read_rrd(path: Path) -> tuple[Counter[str], dict[str, list[float]], dict[str, list], int]:
    """Rows per entity, kali_time (s) of the temporal rows, TextLog texts, blueprints."""
    from rerun.chunk import RrdReader

    reader = RrdReader(path)
    rows: Counter[str] = Counter()
    times: dict[str, list[float]] = {}
    texts: dict[str, list] = {}
    for chunk in reader.stream():
        rows[chunk.entity_path] += chunk.num_rows
        batch = chunk.to_record_batch()
        if "kali_time" in chunk.timeline_names:
            t = batch.column("kali_time").to_pylist()
            times.setdefault(chunk.entity_path, []).extend(x.total_seconds() for x in t)
        if "TextLog:text" in batch.schema.names:
            texts.setdefault(chunk.entity_path, []).extend(
                (level[0], text[0])
                for level, text in zip(
                    batch.column("TextLog:level").to_pylist(),
                    batch.column("TextLog:text").to_pylist(),
                    strict=True,
                )
            )
        if chunk.entity_path == "/robots/left/q" and "Scalars:scalars" in batch.schema.names:
            texts.setdefault("q", []).extend(batch.column("Scalars:scalars").to_pylist())
    return rows, times, texts, len(reader.blueprints())


def test_recording_has_the_arms_joints_timing_and_faults_at_25_hz(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    rrd = tmp_path / "run.rrd"
    name = kali(lockstep=True, edits=dashboard(web="off", connect=None, record=str(rrd)))
    with moving(name) as (inst, _):
        step_kali_clock(inst, 2000)
        d = launcher.dashboard(inst)
        assert d is not None and d.record == str(rrd) and not d.web_url and not d.web_pid
        assert d.frames == 2230 // 40 + 1 and d.errors == 0, d
        inst.raise_fault(FaultCode.OPERATOR, "test", "halted by the viewer test")
        inst.clear_fault()
        step_kali_clock(inst, 80)
        assert inst.fault_text() is None
    launcher.stop(name)  # flushes the recording
    rows, times, texts, blueprints = read_rrd(rrd)

    assert blueprints == 1
    for robot in ("left", "right"):
        for part in ("links/boxes", "links/cylinders", "flange"):
            assert rows[f"/world/{robot}/{part}"] > 50, (robot, part)
        for q in ("q", "demand", "error", "torque", "ff_torque", "current"):
            assert rows[f"/robots/{robot}/{q}"] > 50, (robot, q)
        assert rows[f"/robots/{robot}/flange/position"] > 50
    for entity in ("exec_us", "late_us", "misses", "sio_latency_us"):
        assert rows[f"/timing/{entity}"] > 50, entity
    assert rows["/world/bar"] > 50 and rows["/world/stand"] == 1 and rows["/world/table"] == 1

    # 25 frames per second of Kali time: a frame every 40 ticks of 1 ms, in lockstep exactly
    t = np.array(sorted(times["/robots/left/q"]))
    assert t[-1] >= 2.2
    inside = t[(t >= 0.5) & (t < 2.5)]
    assert 20 <= len(inside) / 2.0 <= 30, len(inside)
    assert np.allclose(np.diff(t[t < 2.3]), 0.04)

    # the left arm's joint 2 went 0.5 rad (28.6°) up, joint 3 0.4 rad down
    q = np.array(texts["q"])
    assert q[-1][1] - q[0][1] == pytest.approx(28.6, abs=1.0)
    assert q[-1][2] - q[0][2] == pytest.approx(-22.9, abs=1.0)

    faults = texts["/events/faults"]
    assert ("ERROR", "OPERATOR in test at tick 2230: halted by the viewer test") in faults
    assert ("INFO", "fault cleared") in faults
    assert ("INFO", "left: on") in texts["/events/left"]
    assert ("INFO", "process 'sio': ACTIVE") in texts["/events/processes"]


def components(path: Path) -> dict[tuple[str, str], list[tuple[float | None, np.ndarray]]]:
    """Every logged component of a recording: per entity and column (``Scalars:scalars``,
    ``Arrows3D:vectors`` ...) its rows as (kali_time in s, None if static; value)."""
    from rerun.chunk import RrdReader

    found: dict[tuple[str, str], list[tuple[float | None, np.ndarray]]] = {}
    for chunk in RrdReader(path).stream():
        batch = chunk.to_record_batch()
        times: list = [None] * batch.num_rows
        if "kali_time" in chunk.timeline_names:
            times = [t.total_seconds() for t in batch.column("kali_time").to_pylist()]
        for column in batch.schema.names:
            if ":" not in column or column == "kali_time":
                continue
            rows = found.setdefault((chunk.entity_path, column), [])
            for t, v in zip(times, batch.column(column).to_pylist(), strict=True):
                if v is not None:
                    rows.append((t, v if isinstance(v[0], str) else np.array(v, dtype=float)))
    return found


def test_the_dashboard_shows_a_push_on_a_tool_in_its_wrench_series_and_contact_arrow(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """The right arm (braked) is pushed for 0.6 s: its force series (tool axes) has the push's
    size, the arrow (base coordinates under the base's transform) starts at the tool point
    and turned into world axes is the push at 1 cm per newton, and the torque about the tool
    point is that of a force at the sensor; before and after, ~0.  The left arm has no
    sensor: no wrench series, no arrow, no plot."""
    rrd = tmp_path / "wrench.rrd"
    name = kali(
        lockstep=True,
        edits=dashboard(web="off", connect=None, record=str(rrd)) | NO_SENSOR_LEFT,
    )
    push = np.array([20.0, -15.0, 25.0])  # N, world axes: 35.4 N
    with Kali(name) as k:
        step_kali_clock(k.inst, 200)
        k.robot("right").tare()
        step_kali_clock(k.inst, 200)
        t_push = time_ms(k.inst.clock) / 1000.0
        k.inst.push(1, push, 0.6)
        step_kali_clock(k.inst, 900)
        assert not int(k.inst.fault["active"]), k.inst.fault_text()
        cfg = k.inst.config
    launcher.stop(name)
    logged = components(rrd)

    def series(entity: str, column: str = "Scalars:scalars") -> dict[float, np.ndarray]:
        return {round(t, 3): v for t, v in logged.get((entity, column), []) if t is not None}

    assert logged[("/robots/right/wrench/force", "SeriesLines:names")] == [
        (None, ["fx", "fy", "fz"])
    ]
    assert logged[("/robots/right/wrench/torque", "SeriesLines:names")] == [
        (None, ["tx", "ty", "tz"])
    ]
    for entity in (
        "/robots/left/wrench/force",
        "/robots/left/wrench/torque",
        "/world/left/contact",
    ):
        assert not [c for e, c in logged if e == entity], entity
    frames = len(series("/robots/right/q"))
    assert frames > 30 and len(series("/robots/left/q")) == frames  # drawn all the same
    force, torque = series("/robots/right/wrench/force"), series("/robots/right/wrench/torque")
    origins = series("/world/right/contact", "Arrows3D:origins")
    vectors = series("/world/right/contact", "Arrows3D:vectors")
    position, rpy = series("/robots/right/flange/position"), series("/robots/right/flange/rpy")
    assert (
        len(force) > frames - 5
        and force.keys() == torque.keys() == vectors.keys() == origins.keys()
    )

    right = cfg.robots[1]
    base = base_transform(right.base_xyz, right.base_yaw_deg)
    tip = right.ft.tool_tip_m
    pushed = [t for t in force if t_push + 0.2 <= t <= t_push + 0.55]
    still = [t for t in force if t_push - 0.15 <= t <= t_push or t >= t_push + 0.75]
    assert len(pushed) >= 8 and len(still) >= 6, (pushed, still)
    for t in force:
        flange = pin.rpy.rpyToMatrix(np.radians(rpy[t]))  # the flange's (tool's) axes in the world
        # the arrow starts at the tool point: tool_tip_m out along the flange's z
        start = base[:3, :3] @ origins[t][0] + base[:3, 3]
        np.testing.assert_allclose(start, position[t] + tip * flange[:, 2], atol=1e-6)
        contact = base[:3, :3] @ vectors[t][0] / CONTACT_M_PER_N  # world axes, N
        # the tool-axes series and the world-axes arrow are the same force (SIO turns it with
        # the angles it read that tick, the viewer's frame with the angles of its own moment)
        assert np.linalg.norm(flange @ force[t] - contact) < 0.02 * np.linalg.norm(contact) + 0.1
        if t in pushed:
            # uncalibrated: SIO's sensor frame is right to a degree or so (test_wrench)
            assert np.linalg.norm(contact - push) < 0.05 * np.linalg.norm(push) + 0.3, (t, contact)
            fx, fy, _ = force[t]
            # a force at the sensor, tip_m behind the tool point: about that point r × f
            np.testing.assert_allclose(torque[t], [tip * fy, -tip * fx, 0.0], atol=0.05)
        elif t in still:
            assert np.linalg.norm(force[t]) < 1.0 and np.linalg.norm(torque[t]) < 0.1, t

    plots = {
        v.name: v.contents
        for v in blueprint(["left", "right"], [False, True])
        .root_container.contents[1]
        .contents[0]
        .contents
    }
    assert plots["right: contact force, torque (N, N·m)"] == [
        "robots/right/wrench/force",
        "robots/right/wrench/torque",
    ]
    assert not [p for p in plots if p.startswith("left: contact")]


def one_frame(cfg: KaliConfig, arena: Arena, rrd: Path) -> tuple[Path, Dashboard]:
    """A dashboard over records laid out by hand (no processes): its static part and one
    frame, recorded into ``rrd``."""
    inst = SimpleNamespace(
        config=cfg,
        arena=arena,
        clock=np.zeros((), layout.CLOCK),
        procs=np.zeros(layout.MAX_PROCESSES, layout.PROCESS),
        fault=np.zeros((), layout.FAULT),
    )
    rec = rr.RecordingStream("kali-test")
    rec.set_sinks(rr.FileSink(str(rrd)))
    board = Dashboard(inst, rec)
    board.log_static()
    board.frame()
    rec.flush(timeout_sec=5.0)
    rec.disconnect()
    return rrd, board


def test_a_mixed_cell_draws_and_plots_each_arm_over_its_own_joints(
    arena: Arena, tmp_path: Path
) -> None:
    """A PUMA 560 (6 joints) and a Panda (7): the viewer's frame, over records laid out by
    hand (no processes), plots each arm's joints j1..jN from the per-joint records and
    draws each arm with its own type's shapes at those angles; the Panda's wrench and contact
    arrow at its tool point, none for the PUMA, whose sensor has not answered yet."""
    cfg = make_config("mixed", MIXED)
    jm = cfg.joints
    robots = arena.record(layout.KEY_ROBOTS, layout.ROBOT_STATE, 2)
    robots["pots_read"] = 1
    joints = arena.record(layout.KEY_JOINTS, layout.JOINT_STATE, jm.total)
    joints["q"] = per_joint([r.type.q_home for r in cfg.robots])
    joints["demand"] = joints["q"] + 0.01
    joints["torque"] = np.arange(jm.total)
    arena.record(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
    arena.record(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
    arena.record(layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, len(cfg.scene.free))
    ft = arena.record(layout.KEY_FT, layout.FT_STATE, 2)
    ft["present"] = [0, 1]
    ft["tool"] = [[9.0] * 6, [1.0, 2.0, 3.0, 0.1, 0.2, 0.3]]
    ft["world"] = [[9.0] * 6, [10.0, 0.0, -5.0, 0.0, 0.0, 0.0]]
    rrd, board = one_frame(cfg, arena, tmp_path / "mixed.rrd")
    assert [a.model.nq for a in board.arms] == [6, 7]
    del robots, joints, ft

    from rerun.chunk import RrdReader

    scalars: dict[str, list] = {}
    series: dict[str, list] = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        if "Scalars:scalars" in batch.schema.names:
            scalars[chunk.entity_path] = batch.column("Scalars:scalars").to_pylist()[0]
        if "SeriesLines:names" in batch.schema.names:
            series[chunk.entity_path] = batch.column("SeriesLines:names").to_pylist()[0]
        for column in ("Arrows3D:origins", "Arrows3D:vectors"):
            if column in batch.schema.names and "kali_time" in chunk.timeline_names:
                scalars[column] = batch.column(column).to_pylist()[0][0]
    assert series["/robots/left/q"] == [f"j{j}" for j in range(1, 7)]
    assert series["/robots/right/q"] == [f"j{j}" for j in range(1, 8)]
    assert series["/robots/right/ff_torque"] == [f"j{j} ff" for j in range(1, 8)]
    left, right = (r.type for r in cfg.robots)
    np.testing.assert_allclose(scalars["/robots/left/q"], np.degrees(left.q_home))
    np.testing.assert_allclose(scalars["/robots/right/q"], np.degrees(right.q_home))
    np.testing.assert_allclose(scalars["/robots/right/error"], [np.degrees(0.01)] * 7)
    assert scalars["/robots/right/torque"] == list(range(6, 13))
    flange = base_transform((0.6, 0.0, 0.0), 180.0) @ right.kinematics.fkine(right.q_home)
    np.testing.assert_allclose(scalars["/robots/right/flange/position"], flange[:3, 3], atol=1e-9)
    assert "/robots/left/wrench/force" not in scalars  # not present: not shown
    assert scalars["/robots/right/wrench/force"] == [1.0, 2.0, 3.0]
    assert scalars["/robots/right/wrench/torque"] == [0.1, 0.2, 0.3]
    # the arrow is under world/right, the base's frame: yawed 180° at x = 0.6
    base = base_transform((0.6, 0.0, 0.0), 180.0)
    tool_point = flange @ [0.0, 0.0, cfg.robots[1].ft.tool_tip_m, 1.0]
    # (rerun keeps an arrow's coordinates as float32)
    np.testing.assert_allclose(base @ [*scalars["Arrows3D:origins"], 1.0], tool_point, atol=1e-6)
    arrow = base[:3, :3] @ scalars["Arrows3D:vectors"]
    np.testing.assert_allclose(
        arrow, [10.0 * CONTACT_M_PER_N, 0.0, -5.0 * CONTACT_M_PER_N], atol=1e-8
    )


def test_the_dashboard_draws_every_object_of_the_scene(arena: Arena, tmp_path: Path) -> None:
    """The parts' scene (issue 56): each fixed object drawn once, in its shape, where the
    file puts it; each free one's shape once and its pose every frame, from its truth record
    (here a block moved by hand: the frame draws it there)."""
    cfg = make_config("scene-draw", {r"^version: 1$": "version: 1\nscene: scenes/parts.yaml"})
    jm = cfg.joints
    arena.record(layout.KEY_ROBOTS, layout.ROBOT_STATE, 2)
    joints = arena.record(layout.KEY_JOINTS, layout.JOINT_STATE, jm.total)
    joints["q"] = per_joint([r.type.q_home for r in cfg.robots])
    arena.record(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
    arena.record(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
    objects = arena.record(layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, len(cfg.scene.free))
    for obj, truth in zip(cfg.scene.free, objects, strict=True):
        truth["pose"] = [*obj.xyz, *obj.quat]
    objects["pose"][1, 0] += 0.1  # the block, 10 cm along x
    arena.record(layout.KEY_FT, layout.FT_STATE, 2)
    rrd, _ = one_frame(cfg, arena, tmp_path / "scene.rrd")
    del joints, objects

    from rerun.chunk import RrdReader

    shapes: dict[str, str] = {}
    where: dict[str, list] = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        for column in batch.schema.names:
            kind = column.split(":")[0]
            if kind in ("Boxes3D", "Cylinders3D", "Ellipsoids3D", "Capsules3D"):
                shapes[chunk.entity_path] = kind
        if "Transform3D:translation" in batch.schema.names:
            where[chunk.entity_path] = batch.column("Transform3D:translation").to_pylist()[0][0]
    assert {k: v for k, v in shapes.items() if k.count("/") == 2} == {
        "/world/stand": "Boxes3D",
        "/world/table": "Boxes3D",
        "/world/bar": "Boxes3D",
        "/world/block": "Boxes3D",
        "/world/can": "Cylinders3D",
        "/world/ball": "Ellipsoids3D",
    }
    np.testing.assert_allclose(where["/world/table"], [0.0, -0.38, 0.2], atol=1e-6)
    np.testing.assert_allclose(where["/world/block"], [-0.05, -0.33, 0.42], atol=1e-6)
    np.testing.assert_allclose(where["/world/ball"], [-0.15, -0.43, 0.42], atol=1e-6)


@pytest.mark.filterwarnings("ignore:RRD file has no footer")  # what rerun --save writes
def test_a_live_viewer_listening_gets_the_dashboard_and_no_web_viewer_starts(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    port, _ = pick_port(0)
    saved = tmp_path / "live.rrd"
    # a stand-in for a native viewer: rerun's gRPC server, saving what it receives
    live = subprocess.Popen(
        [str(rerun_binary()), "--bind", "127.0.0.1", "--port", str(port), "--save", str(saved)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    try:
        deadline = time.monotonic() + 10.0
        while not reachable("127.0.0.1", port):
            assert time.monotonic() < deadline and live.poll() is None
            time.sleep(0.05)
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        name = kali(lockstep=True, edits=dashboard(connect=url, web_port=0, grpc_port=0))
        with Instance.attach(name) as inst:
            d = launcher.dashboard(inst)
            assert d is not None and d.live_url == url and not d.web_url and not d.web_pid, d
            assert kalictl("-i", name, "view").stdout == (
                f"dashboard: streaming to the rerun viewer at {url}\n"
            )
            step_kali_clock(inst, 400)
        launcher.stop(name)
    finally:
        live.terminate()
        live.wait(5.0)
    rows, _, _, _ = read_rrd(saved)
    assert rows["/world/left/links/boxes"] >= 10 and rows["/robots/right/current"] >= 10


def test_a_port_held_by_something_not_a_viewer_is_said_and_not_streamed_to(
    kali: Callable[..., str],
) -> None:
    """Issue 52 item 6: something else listening at ``dashboard.connect`` (here a socket
    that accepts and never answers) was taken for a live viewer: the viewer streamed to it,
    blocked, and ``kalictl start`` took 44 s and said "streaming to the rerun viewer"."""
    port, _ = pick_port(0)
    with socket.socket() as squatter:
        squatter.bind(("127.0.0.1", port))
        squatter.listen()
        url = f"rerun+http://127.0.0.1:{port}/proxy"
        t0 = time.monotonic()
        name = kali(lockstep=True, edits=dashboard(connect=url, web="off"))
        assert time.monotonic() - t0 < 20
        with Instance.attach(name) as inst:
            d = launcher.dashboard(inst)
            assert d is not None and not d.live_url, d
            assert f"port {port} is in use by something that is not a rerun viewer" in d.message
            out = kalictl("-i", name, "view").stdout
            assert "not a rerun viewer" in out and "streaming to" not in out, out


# ---------------------------------------------------------------------------- the web viewer


class Chromium:
    """Headless chromium driven over the DevTools protocol on a pipe (fds 3 and 4), so no
    port and no websocket library are needed."""

    def __init__(self, profile: Path, size: tuple[int, int] = (1600, 1000)) -> None:
        to_r, self._to_w = os.pipe()
        self._from_r, from_w = os.pipe()
        os.set_inheritable(to_r, True)
        os.set_inheritable(from_w, True)

        def fds() -> None:  # in the child: the browser reads fd 3 and writes fd 4
            a, b = os.dup(to_r), os.dup(from_w)
            os.dup2(a, 3)
            os.dup2(b, 4)

        self.proc = subprocess.Popen(
            [
                "chromium",
                "--headless=new",
                "--no-sandbox",  # root, in a VM
                "--remote-debugging-pipe",
                "--use-angle=swiftshader",  # no GPU: WebGPU/WebGL in software
                "--enable-unsafe-swiftshader",
                "--ignore-gpu-blocklist",
                f"--window-size={size[0]},{size[1]}",
                f"--user-data-dir={profile}",
                "about:blank",
            ],
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=fds,  # the test process runs no threads of its own
            close_fds=False,
            start_new_session=True,
        )
        os.close(to_r)
        os.close(from_w)
        self._buf = b""
        self._id = 0
        self.session = ""

    def send(self, method: str, params: dict | None = None, timeout: float = 20.0) -> dict:
        """One DevTools command; its result."""
        self._id += 1
        msg: dict = {"id": self._id, "method": method, "params": params or {}}
        if self.session:
            msg["sessionId"] = self.session
        os.write(self._to_w, json.dumps(msg).encode() + b"\0")
        deadline = time.monotonic() + timeout
        while True:
            while b"\0" in self._buf:
                raw, self._buf = self._buf.split(b"\0", 1)
                reply = json.loads(raw)
                if reply.get("id") == self._id:
                    if "error" in reply:
                        raise RuntimeError(f"{method}: {reply['error']}")
                    return reply["result"]
            ready, _, _ = select.select([self._from_r], [], [], deadline - time.monotonic())
            if not ready:
                raise TimeoutError(f"chromium did not answer {method} within {timeout:g} s")
            data = os.read(self._from_r, 1 << 20)
            if not data:
                raise EOFError("chromium closed the DevTools pipe")
            self._buf += data

    def open(self, url: str) -> None:
        """Open ``url`` in a new page and talk to that page from now on."""
        target = self.send("Target.createTarget", {"url": url})["targetId"]
        self.session = self.send("Target.attachToTarget", {"targetId": target, "flatten": True})[
            "sessionId"
        ]

    def screenshot(self) -> bytes:
        """The page as PNG."""
        return base64.b64decode(self.send("Page.captureScreenshot", {"format": "png"})["data"])

    def close(self) -> None:
        """Close the browser and reap it; kill its session if it does not leave."""
        try:
            self.session = ""
            self.send("Browser.close", timeout=5.0)
        except (OSError, RuntimeError, TimeoutError, EOFError):
            pass
        try:
            self.proc.wait(5.0)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        deadline = time.monotonic() + 5.0
        while self.left() and time.monotonic() < deadline:  # its renderer, GPU and zygote
            time.sleep(0.05)
        if self.left():
            os.killpg(self.proc.pid, signal.SIGKILL)  # the session it was started in
        os.close(self._to_w)
        os.close(self._from_r)

    def left(self) -> list[int]:
        """Pids still running in the browser's session (it leads one of its own)."""
        pids = []
        for stat in Path("/proc").glob("[0-9]*/stat"):
            try:
                fields = stat.read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if int(fields[3]) == self.proc.pid and fields[0] != "Z":  # session id, state
                pids.append(int(stat.parent.name))
        return pids


def alive(pid: int) -> bool:
    """True while ``pid`` runs (a zombie waiting for its reaper does not count)."""
    try:
        return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


def listening(port: int) -> list[str]:
    """Local addresses (hex, as /proc/net/tcp* shows them) listening on ``port``."""
    found = []
    for table in ("/proc/net/tcp", "/proc/net/tcp6"):
        for line in Path(table).read_text().splitlines()[1:]:
            local, state = line.split()[1], line.split()[3]
            addr, hexport = local.rsplit(":", 1)
            if state == "0A" and int(hexport, 16) == port:  # 0A: LISTEN
                found.append(addr)
    return found


def looks(png: bytes) -> dict[str, int]:
    """Pixel counts that tell a drawn dashboard from a blank or loading page.

    The left 2/5 of the page is the 3D view (above the event log), the rest the plots.
    """
    from io import BytesIO

    from PIL import Image

    img = np.asarray(Image.open(BytesIO(png)).convert("RGB")).astype(int)
    h, w, _ = img.shape
    r, g, b = img[..., 0], img[..., 1], img[..., 2]
    view = np.zeros((h, w), bool)
    view[int(0.05 * h) : int(0.6 * h), : int(0.38 * w)] = True
    plots = np.zeros((h, w), bool)
    plots[int(0.05 * h) : int(0.6 * h), int(0.42 * w) :] = True
    cream = (r > 150) & (r - b > 15) & (r - b < 60) & (g > 0.85 * r)  # the PUMA's links
    brown = (r > 70) & (r < 160) & (r - b > 40) & (g < 0.85 * r) & (g > 0.5 * r)  # the stand
    orange = (r > 200) & (g > 90) & (g < 170) & (b < 80)  # joint 2's lines
    blue = (b > 150) & (r < 110) & (g > 90) & (g < 160)  # joint 5's lines
    coarse = (img[plots] // 32) @ np.array([64, 8, 1])
    return {
        "cream in 3D": int((cream & view).sum()),
        "brown in 3D": int((brown & view).sum()),
        "orange in plots": int((orange & plots).sum()),
        "blue in plots": int((blue & plots).sum()),
        "colours in plots": len(np.unique(coarse)),
    }


def drawn(counts: dict[str, int]) -> bool:
    """The arms, the stand and the joint series are all there."""
    return (
        counts["cream in 3D"] > 2000
        and counts["brown in 3D"] > 500
        and counts["orange in plots"] > 300
        and counts["blue in plots"] > 100
        and counts["colours in plots"] > 40
    )


@pytest.mark.skipif(shutil.which("chromium") is None, reason="needs Debian's chromium")
def test_web_dashboard_shows_the_arms_and_plots_in_a_browser(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    name = kali(lockstep=True, edits=dashboard(web="on", web_port=0, grpc_port=0, connect=None))
    with moving(name) as (inst, _):
        step_kali_clock(inst, 1500)
        d = launcher.dashboard(inst)
        assert d is not None and d.ready and d.web_url and d.web_pid > 0, d
        url = urllib.parse.urlsplit(d.web_url)
        grpc = urllib.parse.urlsplit(urllib.parse.parse_qs(url.query)["url"][0])
        assert url.hostname == grpc.hostname == "127.0.0.1"
        ports = (url.port, grpc.port)
        for port in ports:
            assert listening(port) == ["0100007F"], port  # 127.0.0.1 only
        view = kalictl("-i", name, "view", "--url")
        assert view.returncode == 0 and view.stdout.strip() == d.web_url, view.stderr

        browser = Chromium(tmp_path / "chromium")
        try:
            browser.open(d.web_url)
            deadline = time.monotonic() + 40.0
            seen = 0
            while seen < 2 and time.monotonic() < deadline:
                time.sleep(1.5)  # the wasm viewer loads, connects, draws, then settles
                png = browser.screenshot()
                counts = looks(png)
                seen = seen + 1 if drawn(counts) else 0
        finally:
            browser.close()
        assert browser.left() == []
        shot = tmp_path / "dashboard.png"
        shot.write_bytes(png)
        assert drawn(counts), f"{counts}: see {shot}"
        web_pid = d.web_pid
    launcher.stop(name)
    assert not alive(web_pid)
    for port in ports:
        assert listening(port) == [], port


# ---------------------------------------------------------------------------- real time


@pytest.mark.serial
def test_realtime_viewer_draws_through_a_halt_and_its_death_halts_nothing(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=False, edits=dashboard(web="on", web_port=0, grpc_port=0, connect=None))
    with Instance.attach(name) as inst:
        rec = inst.arena.existing(layout.KEY_DASHBOARD, layout.DASHBOARD)
        viewer = inst.procs[inst.find_slot("viewer")]
        assert not viewer["periodic"]  # self-timed in real time, like the plant
        # frames as the viewer can draw them: a CI run's busy machine drew 1 in 0.3 s
        frames = rec["frames"]  # a live view (``rec`` itself is dropped before the stop)
        wait_for(lambda f=frames: int(f) >= 3, timeout=10, what="three frames drawn")
        inst.raise_fault(FaultCode.OPERATOR, "test", "halt")
        wait_for(lambda: int(inst.clock["mode"]) == RunMode.STOPPED, what="the clock stopped")
        drawn, tick = int(frames), int(inst.clock["tick"])
        # still drawing: the arms fall, brakes bite
        wait_for(lambda f=frames: int(f) >= drawn + 5, timeout=10, what="drawing halted")
        assert int(inst.clock["tick"]) == tick
        inst.clear_fault()
        start_kali_clock(inst)
        pid, web_pid = int(viewer["pid"]), int(rec["web_pid"])
        count = int(inst.fault["count"])
        os.kill(pid, signal.SIGKILL)
        time.sleep(0.5)
        assert not alive(web_pid)  # the web server died with it
        # nothing halted for it (a host stall may halt a serious process meanwhile: not ours)
        assert int(inst.fault["count"]) == count or "viewer" not in inst.fault_text(last=True)
        del rec, viewer, frames


def test_the_dashboard_shows_each_cameras_latest_frame_where_the_camera_stands(
    tmp_path: Path,
) -> None:
    """scenes/watched.yaml's camera (issue 56 item 4): the dashboard places a pinhole of its
    K at its pose and logs its latest frame, colour and depth, under it."""
    cfg = make_config("camera-draw", {r"^version: 1$": "version: 1\nscene: scenes/watched.yaml"})
    name = unique_name("a")
    arena = Arena.create(name, 4 << 20)  # the fixture's 1 MiB holds no 320×240 ring
    try:
        _camera_frame(cfg, arena, tmp_path)
    finally:
        arena.close()
        launcher.stop(name)


def _camera_frame(cfg: KaliConfig, arena: Arena, tmp_path: Path) -> None:
    from kali_daemons.hardware.camera import CameraRing

    cam = cfg.scene.camera("table")
    arena.record(layout.KEY_ROBOTS, layout.ROBOT_STATE, 2)
    arena.record(layout.KEY_JOINTS, layout.JOINT_STATE, cfg.joints.total)
    arena.record(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
    arena.record(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
    arena.record(layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, len(cfg.scene.free))
    arena.record(layout.KEY_FT, layout.FT_STATE, 2)
    arena.record(layout.KEY_CAMERAS, layout.CAMERA, 1)
    need = layout.CAMERA_BUFFERS * layout.camera_bytes(cam.width * cam.height)
    arena.record(layout.KEY_CAMERA_FRAMES, np.dtype("u1"), need)
    ring = CameraRing(arena, cfg.scene.cameras, 0)
    ring.describe(cam.K, cam.pose)
    image = np.zeros((cam.height, cam.width, 3), np.uint8)
    image[10:20, 30:40] = (200, 30, 40)
    ring.deliver(image, np.full((cam.height, cam.width), 1.25, np.float32), 7, 7_000_000, 1)
    rrd, _ = one_frame(cfg, arena, tmp_path / "camera.rrd")
    del ring

    from rerun.chunk import RrdReader

    columns: dict[str, dict[str, object]] = {}
    for chunk in RrdReader(rrd).stream():
        batch = chunk.to_record_batch()
        for column in batch.schema.names:
            if column.split(":")[0] in ("Image", "DepthImage", "Pinhole", "Transform3D"):
                got = batch.column(column).to_pylist()[0]
                columns.setdefault(chunk.entity_path, {})[column] = got
    placed = columns["/world/cameras/table"]
    np.testing.assert_allclose(placed["Transform3D:translation"][0], cam.xyz, atol=1e-6)
    np.testing.assert_allclose(
        np.reshape(placed["Pinhole:image_from_camera"][0], (3, 3)).T, cam.K, atol=1e-4
    )
    shown = columns["/world/cameras/table/image"]
    pixels = np.frombuffer(bytes(shown["Image:buffer"][0]), np.uint8)
    np.testing.assert_array_equal(pixels.reshape(cam.height, cam.width, 3), image)
    depth = columns["/world/cameras/table/depth"]
    assert np.frombuffer(bytes(depth["DepthImage:buffer"][0]), np.float32).max() == 1.25
