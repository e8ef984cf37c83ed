"""``kali.camera(name)``: a program's view of one of the cell's cameras (``hardware.camera``),
in simulation the camera process's renders, on real hardware its driver's frames."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

from ..core.errors import HardwareError
from ..hardware.camera import CameraRing, Frame, camera_index

if TYPE_CHECKING:
    from ..runtime.instance import Instance

POLL_S = 0.005  # how often a wait for a newer frame looks


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
        deadline = time.monotonic() + timeout_s
        frame, looked = None, -1
        while True:
            if self.ring.stamp() != looked:  # a new frame: copy it (else keep the last copy)
                frame = self.ring.read()
                looked = -1 if frame is None else frame.stamp_ns
            if frame is not None and (since_tick is None or frame.tick >= since_tick):
                return frame
            if time.monotonic() >= deadline:
                what = "no frame yet" if frame is None else f"the latest shows tick {frame.tick}"
                wanted = "" if since_tick is None else f" of tick {since_tick} or later"
                raise HardwareError(
                    f"camera {self.name!r}: no frame{wanted} within {timeout_s:g} s ({what}); "
                    f"is the camera process running? (kalictl status)"
                )
            time.sleep(POLL_S)
