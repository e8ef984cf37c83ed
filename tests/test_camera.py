"""The cell's cameras (issue 56 item 4): a scene's camera rendered by the camera process into
its image ring, read whole by a program (``kali.camera(name).read()``) with its tick, K and
pose; the ring never torn; bad cameras refused at start or at the request."""

from __future__ import annotations

import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.arena import Arena, segment_name, unlink_segment
from kali_daemons.core.errors import ConfigError, HardwareError
from kali_daemons.hardware.camera import CameraRing
from kali_daemons.robots.scene import Camera, load_scene, parse_scene
from kali_daemons.wallclock import step_kali_clock

from .conftest import ROOT, make_config, unique_name

WATCHED = {r"^version: 1$": "version: 1\nscene: scenes/watched.yaml"}
BALL = (0.8, 0.8, 0.2)  # scenes/parts.yaml's ball's colour


def seen(image: np.ndarray, color: tuple[float, float, float]) -> tuple[np.ndarray, int]:
    """The centre (u, v) of the pixels of ``color``'s hue, lit, and how many there are."""
    f = image.astype(float) / 255.0
    hue = f / (f.sum(axis=2, keepdims=True) + 1e-9)
    c = np.asarray(color)
    mask = (np.linalg.norm(hue - c / c.sum(), axis=2) < 0.05) & (f.sum(axis=2) > 0.3)
    v, u = np.nonzero(mask)
    return np.array([u.mean() + 0.5, v.mean() + 0.5]), len(u)


def test_the_camera_shows_an_object_where_its_intrinsics_put_it(
    kali: Callable[..., str],
) -> None:
    """scenes/watched.yaml's camera over the table: its frame shows the ball at the pixel its
    K and pose predict from the simulator's truth (within 2 px), its depth there the ball's
    near surface, and the K and pose the scene's; a frame after a later tick comes."""
    name = kali(edits=WATCHED)
    cam = load_scene(ROOT / "config" / "scenes" / "watched.yaml").camera("table")
    with Kali(name) as k:
        view = k.camera("table")
        first = view.read()
        step_kali_clock(k.inst, 50)
        frame = view.read(since_tick=first.tick + 50)  # the clock stands there: a frame of it
        assert frame.tick == first.tick + 50 and frame.sim_time_s is not None
        assert frame.image.shape == (cam.height, cam.width, 3) and frame.image.dtype == np.uint8
        assert frame.depth.shape == (cam.height, cam.width) and frame.depth.dtype == np.float32
        np.testing.assert_array_equal(frame.K, cam.K)
        np.testing.assert_array_equal(frame.pose, cam.pose)
        ball = k.sim.truth("left").objects["ball"][:3, 3]
        uv = frame.project(ball)
        centre, pixels = seen(frame.image, BALL)
        assert pixels >= 10, "the ball is in view"
        assert np.abs(centre - uv).max() <= 2.0, (centre, uv)
        in_view = np.linalg.solve(frame.pose, np.append(ball, 1.0))[2]
        radius = 0.02
        at = frame.depth[int(uv[1]), int(uv[0])]
        assert abs(at - (in_view - radius)) < 0.005, (at, in_view)
        with pytest.raises(HardwareError, match=r"no camera 'front'; cameras: table"):
            k.camera("front")


def test_a_remote_program_reads_the_same_frames_through_the_bridge(
    kali: Callable[..., str],
) -> None:
    """Through the bridge (lockstep, loopback) ``kali.camera(name).read()`` gives the frame a
    local program reads, byte for byte with its tick, stamps, K and pose; a frame of a later
    tick is waited for the same way; an unknown camera is refused in the local words."""
    from .test_bridge import bridge_edit, free_port

    port = free_port()
    name = kali(edits={**WATCHED, **bridge_edit(port)})
    with Kali(name) as k, Kali.connect(f"tcp/127.0.0.1:{port}", name) as remote:
        view, there = k.camera("table"), remote.camera("table")
        first = view.read()
        step_kali_clock(k.inst, 30)
        frame = there.read(since_tick=first.tick + 30)
        same = view.read(since_tick=first.tick + 30)
        assert frame.stamp_ns == same.stamp_ns and frame.tick == same.tick == first.tick + 30
        np.testing.assert_array_equal(frame.image, same.image)
        np.testing.assert_array_equal(frame.depth, same.depth)
        assert frame.depth.dtype == np.float32 and frame.image.dtype == np.uint8
        assert frame.sim_time_s == same.sim_time_s and frame.camera == "table"
        np.testing.assert_array_equal(frame.K, same.K)
        np.testing.assert_array_equal(frame.pose, same.pose)
        with pytest.raises(HardwareError, match=r"no frame of tick \d+ or later within 0.3 s"):
            there.read(since_tick=frame.tick + 1, timeout_s=0.3)  # the clock stands
        with pytest.raises(HardwareError, match=r"no camera 'front'; cameras: table"):
            remote.camera("front")


def test_a_cell_without_cameras_says_so_at_the_request(kali: Callable[..., str]) -> None:
    with Kali(kali()) as k, pytest.raises(HardwareError, match="its scene declares no cameras"):
        k.camera("table")


WRITER = """
import sys, numpy as np
from kali_daemons.core.arena import Arena
from kali_daemons.hardware.camera import CameraRing
from kali_daemons.robots.scene import Camera
cam = Camera("c", (0.0, -1.0, 1.0), (0.0, 0.0, 0.5), 45.0, 640, 480, 30.0)
arena = Arena.attach(sys.argv[1])
ring = CameraRing(arena, [cam], 0)
ring.describe(cam.K, cam.pose)
images = [np.full((480, 640, 3), v, np.uint8) for v in range(256)]
depths = [np.full((480, 640), v, np.float32) for v in range(256)]
n = int(sys.argv[2])
for i in range(n):
    ring.deliver(images[i % 256], depths[i % 256], i, i, i)
"""


def test_a_reader_never_gets_a_torn_frame() -> None:
    """A writer in another process delivering 640×480 frames flat out (each one value
    throughout, its number), a reader copying the latest meanwhile: every frame read is
    whole, its colour, depth and tick of one delivery."""
    cam = Camera("c", (0.0, -1.0, 1.0), (0.0, 0.0, 0.5), 45.0, 640, 480, 30.0)
    name = unique_name("cam")
    need = layout.CAMERA_BUFFERS * layout.camera_bytes(cam.width * cam.height)
    arena = Arena.create(name, layout.header_bytes() + need + (64 << 10))
    try:
        arena.record(layout.KEY_CAMERAS, layout.CAMERA, 1)
        arena.record(layout.KEY_CAMERA_FRAMES, np.dtype("u1"), need)
        ring = CameraRing(arena, [cam], 0)
        writer = subprocess.Popen([sys.executable, "-c", WRITER, name, "3000"], cwd=ROOT)
        read, overtaken = 0, 0
        while writer.poll() is None or read == 0:
            frame = ring.read()
            if frame is None:
                overtaken += int(bool(ring.head["up"]) and int(ring.head["latest"]) >= 0)
                continue
            value = frame.tick % 256
            assert (frame.image == value).all() and (frame.depth == value).all(), frame.tick
            read += 1
        assert writer.wait() == 0
        assert read >= 20, (read, overtaken)
    finally:
        arena.close()
        unlink_segment(segment_name(name))


# ------------------------------------------------------------------ bad cameras

CAMERA = "  - {name: c, at: [0.0, -1.0, 1.0], look_at: [0.0, 0.0, 0.5]"
AT = "  - {name: c, look_at: [0.0, 0.0, 0.5]"


@pytest.mark.parametrize(
    ("entry", "expected"),
    [
        (AT + ", at: [0.0, -4.0, 1.0]}", r"at = \[0.0, -4.0, 1.0\]: outside the cell"),
        (
            "  - {name: c, at: [0.0, 0.0, -0.5], look_at: [0.0, 1.0, 0.5]}",
            r"outside the cell \(within ±3 m of the origin in x and y, above the floor",
        ),
        (
            "  - {name: c, at: [0.0, 0.0, 2.0], look_at: [0.0, 0.0, 1.995]}",
            r"look_at = \[0.0, 0.0, 1.995\]: must lie 1 cm from it or more",
        ),
        (CAMERA + ", width: 2000}", r"width = 2000: whole pixels, 16 .. 1280"),
        (CAMERA + ", rate_hz: 0}", r"rate_hz = 0: frames a second, > 0 and at most 30"),
        (CAMERA + ", fovy_deg: 200}", r"fovy_deg = 200"),
        (CAMERA + ", zoom: 2}", r"'zoom' is not a key of a camera"),
        (
            CAMERA + ", width: 640, height: 480, rate_hz: 10}",
            r"cameras: would take 37% of a core \('c' 37 %\), more than the camera process's "
            r"budget of 30%",
        ),
    ],
)
def test_a_bad_camera_is_refused_naming_the_file_the_camera_and_the_rule(
    entry: str, expected: str
) -> None:
    text = f"version: 1\nobjects: []\ncameras:\n{entry}\n"
    with pytest.raises(ConfigError, match=expected) as err:
        parse_scene(text, "cell.yaml")
    assert str(err.value).startswith("config: cell.yaml: cameras"), err.value


def test_a_camera_looking_straight_down_has_the_worlds_y_up_in_its_image() -> None:
    """Its image's x is the world's x, its image's down the world's -y; a point straight
    below it falls on the image's centre."""
    cam = parse_scene(
        "version: 1\ncameras:\n  - {name: c, at: [0.1, -0.4, 1.0], look_at: [0.1, -0.4, 0.4]}\n",
        "down.yaml",
    ).camera("c")
    np.testing.assert_allclose(cam.pose[:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    p = np.linalg.solve(cam.pose, [0.1, -0.4, 0.4, 1.0])[:3]
    np.testing.assert_allclose((cam.K @ p)[:2] / p[2], [cam.width / 2, cam.height / 2])


def test_two_cameras_share_the_budget() -> None:
    """Each within the budget, together beyond it: refused naming both."""
    two = "".join(
        f"  - {{name: c{i}, at: [0.0, -1.0, 1.0], look_at: [0.0, 0.0, 0.5], rate_hz: 12}}\n"
        for i in range(2)
    )
    parse_scene(f"version: 1\ncameras:\n{two.splitlines()[0]}\n", "one.yaml")
    with pytest.raises(ConfigError, match=r"'c0' 16 %, 'c1' 16 %"):  # 12 Hz of 13.5 ms
        parse_scene(f"version: 1\ncameras:\n{two}", "two.yaml")


def test_a_camera_process_is_placed_by_its_entry_and_only_for_kalis_own_plant(
    tmp_path: Path,
) -> None:
    """A scene with cameras runs the camera process at normal scheduling where
    ``processes.camera`` puts it; an FR3 cell (franky-sim simulates its world) refuses them."""
    cfg = make_config("cam", WATCHED)
    camera = cfg.process("camera")
    assert (camera.cpu, camera.priority, camera.nice, camera.serious) == (1, 0, 0, False)
    placed = make_config(
        "cam", {**WATCHED, r"^  viewer: (.*)$": r"  viewer: \1\n  camera: {cpu: 0, nice: 5}"}
    )
    assert (placed.process("camera").cpu, placed.process("camera").nice) == (0, 5)
    assert not any(p.kind == "camera" for p in make_config("cam").processes)
    with pytest.raises(ConfigError, match=r"camera.priority: unknown key"):
        make_config(
            "cam", {**WATCHED, r"^  viewer: (.*)$": r"  viewer: \1\n  camera: {priority: 5}"}
        )
    scene = tmp_path / "watched.yaml"
    scene.write_text("version: 1\ncameras:\n" + CAMERA + "}\n")
    with pytest.raises(ConfigError, match=r"declares cameras, which render the cell Kali's own "
                       r"plant simulates; robot 'arm' is on franka hardware"):  # fmt: skip
        make_config("cam", {r"^scene: .*$": f"scene: {scene}"}, base="fr3.yaml")
