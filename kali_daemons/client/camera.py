"""``kali.camera(name)``: a program's view of one of the cell's cameras (``hardware.camera``),
in simulation the camera process's renders, on real hardware its driver's frames.  A remote
program's (``RemoteCamera``) fetches the same frames through the bridge and waits for one by
the same rule (``wait_for_frame``)."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

from ..core.errors import HardwareError
from ..hardware.camera import CameraRing, Frame, camera_index
from ..robots.scene import Camera
from . import protocol
from .protocol import BridgeError

if TYPE_CHECKING:
    from ..runtime.instance import Instance
    from .remote import Connection

POLL_S = 0.005  # how often a wait for a newer frame looks
FRAME_POLL_S, REMOTE_POLL_S = 0.01, 0.05  # a remote camera's wait looks within these


def wait_for_frame(
    name: str,
    fetch: Callable[[Frame | None], Frame | None],
    since_tick: int | None,
    timeout_s: float,
    poll_s: float = POLL_S,
) -> Frame:
    """Camera ``name``'s latest frame, or with ``since_tick`` the first showing that tick or a
    later one, waiting up to ``timeout_s``; ``fetch(last)`` gives the latest frame if it is
    newer than ``last`` (the last one fetched, or None), else ``last``.  HardwareError naming
    the camera if none comes in time."""
    deadline = time.monotonic() + timeout_s
    frame = None
    while True:
        frame = fetch(frame)
        if frame is not None and (since_tick is None or frame.tick >= since_tick):
            return frame
        if time.monotonic() >= deadline:
            what = "no frame yet" if frame is None else f"the latest shows tick {frame.tick}"
            wanted = "" if since_tick is None else f" of tick {since_tick} or later"
            raise HardwareError(
                f"camera {name!r}: no frame{wanted} within {timeout_s:g} s ({what}); "
                f"is the camera process running? (kalictl status)"
            )
        time.sleep(poll_s)


class CameraView:
    """Camera ``name`` of ``inst``'s scene: ``read`` its latest frame."""

    def __init__(self, inst: Instance, name: str) -> None:
        cameras = inst.config.scene.cameras
        self.name = name
        self.ring = CameraRing(inst.arena, cameras, camera_index(cameras, name, inst.name))

    def read(self, since_tick: int | None = None, timeout_s: float = 5.0) -> Frame:
        """The latest frame, whole (never torn); with ``since_tick``, the first one showing
        that tick or a later one (``kali.inst.clock["tick"]``: a frame of the present), waiting
        up to ``timeout_s`` (wall time, in lockstep too: the camera renders on its own timer).
        HardwareError naming the camera if none comes in time."""
        return wait_for_frame(self.name, self.fetch, since_tick, timeout_s)

    def fetch(self, last: Frame | None) -> Frame | None:
        """The latest frame if it is newer than ``last``, else ``last`` (it looks at the
        frame's stamp before copying a frame that has not changed)."""
        if last is not None and self.ring.stamp() == last.stamp_ns:
            return last
        return self.ring.read() or last


class RemoteCamera:
    """A remote program's ``kali.camera(name)``: ``read`` as a local program's, each look a
    query the bridge answers with the ring's latest frame (``protocol.encode_frame``; nothing
    when the asker has it already), looking twice a frame period."""

    def __init__(self, conn: Connection, name: str, camera: Camera) -> None:
        self.name = name
        self._conn = conn
        self._key = conn.mine.camera(name)
        self._poll_s = min(REMOTE_POLL_S, max(FRAME_POLL_S, 0.5 / camera.rate_hz))

    def read(self, since_tick: int | None = None, timeout_s: float = 5.0) -> Frame:
        """As ``CameraView.read``: the latest frame, or the first of ``since_tick`` or later,
        waiting up to ``timeout_s``."""
        return wait_for_frame(self.name, self.fetch, since_tick, timeout_s, self._poll_s)

    def fetch(self, last: Frame | None) -> Frame | None:
        """The latest frame if it is newer than ``last``, else ``last``."""
        what = f"camera {self.name!r}"
        since = None if last is None else last.stamp_ns
        data = self._conn.ask_bytes(self._key, protocol.dumps({"since_stamp": since}), 30.0, what)
        if data.startswith(protocol.FRAME_MAGIC):
            return protocol.decode_frame(data, what)
        answer = protocol.loads(data, what)
        if not isinstance(answer, dict):
            raise BridgeError(f"{what}: a malformed answer")
        protocol.raise_reply(answer)
        return last
