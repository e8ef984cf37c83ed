"""A camera as a device: its image ring in the arena (``layout.CAMERA``), the interface
between whatever takes the pictures and whoever looks at them (DESIGN 6).

The simulated cell's camera process (``plant.camera``) fills it by rendering the plant's
world; a real camera's driver process would fill it the same way: write its intrinsics and
pose once (``describe``), then ``deliver`` each frame with the clock's tick of the moment it
was taken.  Readers (programs through ``kali.camera(name)``, the dashboard) ``read`` the
latest frame: a writer never blocks on a reader and a reader never sees a torn frame, for the
writer fills the buffer after the latest (of ``CAMERA_BUFFERS``) with that buffer's sequence
odd, and the reader copies the latest and takes it only if its sequence did not change
(the seqlock rule; thesis 3.2.1's Type 4 record, made whole for a large one).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ..core import atomic, layout
from ..core.arena import Arena
from ..core.errors import HardwareError
from ..robots.scene import Camera

READ_TRIES = 8  # a reader overtaken this often by the writer (a frame copied ~3× slower than
# the writer renders) gives up for this call


@dataclass(frozen=True)
class Frame:
    """One picture: ``image`` (height × width × 3, RGB bytes), ``depth`` (height × width, m
    along the view, float32), the clock's ``tick`` and the plant's ``sim_time_s`` of the state
    it shows (None on real hardware), ``stamp_ns`` (CLOCK_MONOTONIC when taken), the
    intrinsics ``K`` (3×3) and the camera's ``pose`` in the world (4×4: x right, y down, z
    along the view, so a world point ``p`` is at pixel ``K @ q / q[2]`` with ``q`` the first
    three of ``inv(pose) @ [p, 1]``)."""

    camera: str
    image: np.ndarray
    depth: np.ndarray
    tick: int
    sim_time_s: float | None
    stamp_ns: int
    K: np.ndarray
    pose: np.ndarray

    def project(self, point: Sequence[float]) -> np.ndarray:
        """Where world point ``point`` (m) falls in the image: (u, v) in pixels, a pixel's
        centre at whole coordinates plus a half."""
        p = np.linalg.solve(self.pose, np.append(np.asarray(point, dtype=float), 1.0))[:3]
        uv = self.K @ p
        return uv[:2] / uv[2]


class CameraRing:
    """Camera ``index`` of the cell's ``cameras`` (the scene's, in order): its header and
    its buffers' views into ``KEY_CAMERA_FRAMES``."""

    def __init__(self, arena: Arena, cameras: Sequence[Camera], index: int) -> None:
        cam = cameras[index]
        self.name = cam.name
        pixels = [c.width * c.height for c in cameras]
        heads = arena.existing(layout.KEY_CAMERAS, layout.CAMERA, len(cameras))
        self.head = heads[index : index + 1].reshape(())
        total = sum(layout.CAMERA_BUFFERS * layout.camera_bytes(n) for n in pixels)
        frames = arena.existing(layout.KEY_CAMERA_FRAMES, np.dtype("u1"), total)
        size, n = layout.camera_bytes(pixels[index]), pixels[index]
        self.offset = sum(layout.CAMERA_BUFFERS * layout.camera_bytes(p) for p in pixels[:index])
        self.depth, self.image = [], []
        for b in range(layout.CAMERA_BUFFERS):
            at = self.offset + b * size
            self.depth.append(frames[at : at + 4 * n].view(np.float32).reshape(cam.height, -1))
            self.image.append(frames[at + 4 * n : at + 7 * n].reshape(cam.height, cam.width, 3))
        self._latest = self.head["latest"].ctypes.data  # the words taken atomically
        seq = self.head["seq"].ctypes.data
        self._seq = [seq + 8 * b for b in range(layout.CAMERA_BUFFERS)]

    # ------------------------------------------------------------------ the writer

    def describe(self, K: np.ndarray, pose: np.ndarray) -> None:  # noqa: N803
        """The writer, before its first frame: the intrinsics and the camera's pose, its
        size and where its buffers are; no frame yet."""
        h = self.head
        h["height"], h["width"] = self.image[0].shape[:2]
        h["K"], h["pose"], h["offset"] = K, pose, self.offset
        atomic.store32(self._latest, -1)
        h["up"] = 1

    def deliver(
        self, image: np.ndarray, depth: np.ndarray, tick: int, sim_time_ns: int, stamp_ns: int
    ) -> None:
        """The writer: one frame into the buffer after the latest, then named latest."""
        h = self.head
        b = (int(h["latest"]) + 1) % layout.CAMERA_BUFFERS
        atomic.fetch_add64(self._seq[b], 1)  # odd: being written
        self.image[b][...] = image
        self.depth[b][...] = depth
        h["tick"][b], h["sim_time_ns"][b], h["stamp_ns"][b] = tick, sim_time_ns, stamp_ns
        atomic.fetch_add64(self._seq[b], 1)
        atomic.store32(self._latest, b)
        h["frames"] += 1

    # ------------------------------------------------------------------ readers

    def stamp(self) -> int:
        """The latest frame's stamp (CLOCK_MONOTONIC), 0 before the first: a reader that has
        that frame skips the copy."""
        b = atomic.load32(self._latest)
        if not 0 <= b < layout.CAMERA_BUFFERS or not self.head["up"]:
            return 0
        return int(self.head["stamp_ns"][b])

    def read(self) -> Frame | None:
        """A copy of the latest frame, whole; None before the first (or when the writer
        overtook this reader READ_TRIES times)."""
        h = self.head
        for _ in range(READ_TRIES):
            b = atomic.load32(self._latest)  # unsigned: the -1 of no frame yet is large
            if not 0 <= b < layout.CAMERA_BUFFERS or not h["up"]:
                return None
            seq = atomic.load64(self._seq[b])
            if seq & 1:
                continue
            image, depth = self.image[b].copy(), self.depth[b].copy()
            tick, sim, stamp = int(h["tick"][b]), int(h["sim_time_ns"][b]), int(h["stamp_ns"][b])
            if atomic.load64(self._seq[b]) != seq:
                continue
            return Frame(
                self.name, image, depth, tick, None if sim < 0 else sim / 1e9, stamp,
                h["K"].copy(), h["pose"].copy(),
            )  # fmt: skip
        return None


def camera_index(cameras: Sequence[Camera], name: str, instance: str) -> int:
    """The index of camera ``name``; HardwareError naming the instance's cameras."""
    for i, c in enumerate(cameras):
        if c.name == name:
            return i
    known = ", ".join(c.name for c in cameras) or "none (its scene declares no cameras)"
    raise HardwareError(f"camera: instance '{instance}' has no camera {name!r}; cameras: {known}")
