"""The simulated cell's cameras (DESIGN 6): one process rendering every camera of the scene
from the plant's truth into its image ring (``hardware.camera``), each at its own rate.

Non-serious and at normal scheduling on its own CPU share (``processes.camera``): a frame
costs tens of milliseconds of software rendering through EGL, far beyond any tick, so the
process is never signalled by the clock, in lockstep neither, and takes the plant's state as
it finds it (Type 4: the arms' joints of one plant period, give or take one), stamping each
frame with the clock's tick and the plant's time of what it shows.  In lockstep the frames
therefore come at the camera's rate in wall time, not in simulated time.  The process's period
is the fastest camera's; a slower one renders every whole number of periods nearest its rate.
Rendered without shadows: the shadow map costs ~80 ms a frame in software
(docs/decisions/0018-camera.md).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from ..core import layout, rt
from ..core.errors import DaemonError
from ..hardware.camera import CameraRing
from ..robots.model import build_world
from ..runtime.daemon import Daemon

READY_TIMEOUT_S = 30.0  # how long it waits at start for the plant's truth records
IDLE_S = 0.1  # the longest it sleeps before looking at the shutdown again


class SimCamera(Daemon):
    """The scene's cameras rendered from the plant's truth."""

    kind = "camera"
    self_timed_in_realtime = True  # never signalled; the clock watches that it is alive
    self_timed_always = True

    def __init__(self, instance: str, name: str, **kw: Any) -> None:
        kw.setdefault("lock_memory", False)  # not real-time: the renderer's buffers are large
        super().__init__(instance, name, **kw)

    def on_configure(self) -> None:
        """The cell's MuJoCo world (the plant's, built the same way), one renderer per camera,
        and each camera's intrinsics and pose published before its first frame."""
        import mujoco  # with MUJOCO_GL=egl, as the launcher starts it (no display)

        cfg, arena = self.inst.config, self.inst.arena
        deadline = rt.monotonic_ns() + int(READY_TIMEOUT_S * 1e9)
        while arena.lookup(layout.KEY_WORLD_TRUTH) is None or not self._plant_up():
            if rt.monotonic_ns() > deadline:
                raise DaemonError(f"{self.name}: the plant did not lay out its truth records")
            if self.inst.shutting_down:
                return
            time.sleep(0.005)
        world = build_world(cfg.robots, scene=cfg.scene)
        model = world.model
        model.light_castshadow[:] = 0
        self._mujoco, self.model, self.data = mujoco, model, mujoco.MjData(model)
        self.seen = mujoco.MjvOption()
        self.seen.sitegroup[:] = 0  # the grasps' markers are the dashboard's, not the world's
        self.qpos_idx = np.concatenate(world.qpos_adr)
        self.joints = arena.existing(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, cfg.joints.total)
        free = len(world.objects)
        self.objects = arena.existing(layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, free)
        self.object_qpos = self.data.qpos[: 7 * free].reshape(free, 7)
        self.world = arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
        cameras = cfg.scene.cameras
        self.cameras = []
        for i, cam in enumerate(cameras):
            ring = CameraRing(arena, cameras, i)
            renderer = mujoco.Renderer(model, cam.height, cam.width)
            cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, f"camera/{cam.name}")
            every = max(1, round(1e9 / cam.rate_hz / self.period_ns))
            self.cameras.append((ring, renderer, cid, every))
        self._next = [0] * len(cameras)
        for i, (ring, *_) in enumerate(self.cameras):  # a first frame warms every code path
            self.render(i, deliver=False)
            ring.describe(cameras[i].K, cameras[i].pose)

    def _plant_up(self) -> bool:
        """Whether the plant has run a cycle (its truth is the cell's, not zeros)."""
        world = self.inst.arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
        return int(world["ticks"]) > 0

    def _loop(self) -> None:
        """On its own timer always (``Daemon._self_timed_loop``), in lockstep too: its period
        is the fastest camera's (the config gives it), each camera rendered every ``every``
        periods; a loop behind skips the periods it missed rather than rendering a burst."""
        self._self_timed_loop()

    def cycle(self, tick: int) -> None:
        """Each camera whose turn has come: one frame of the plant's state now."""
        for k, (_, _, _, every) in enumerate(self.cameras):
            if tick >= self._next[k]:
                self._next[k] = tick + every
                self.render(k)

    def render(self, k: int, deliver: bool = True) -> None:
        """Camera ``k``'s frame of the plant's state now, delivered to its ring."""
        mj, model, data = self._mujoco, self.model, self.data
        ring, renderer, cid, _ = self.cameras[k]
        cpu = time.process_time_ns()
        tick, sim = int(self.inst.clock["tick"]), int(self.world["sim_time_ns"])
        stamp = rt.monotonic_ns()
        data.qpos[self.qpos_idx] = self.joints["q"]
        self.object_qpos[...] = self.objects["pose"]
        mj.mj_kinematics(model, data)
        mj.mj_camlight(model, data)
        renderer.update_scene(data, camera=cid, scene_option=self.seen)
        image = renderer.render()
        renderer.enable_depth_rendering()
        depth = renderer.render()
        renderer.disable_depth_rendering()
        if not deliver:
            return
        ring.deliver(image, depth, tick, sim, stamp)
        spent = time.process_time_ns() - cpu
        head = ring.head
        head["frame_ns"] = spent
        head["frame_max_ns"] = max(int(head["frame_max_ns"]), spent)

    def on_shutdown(self) -> None:
        for _, renderer, _, _ in getattr(self, "cameras", ()):
            renderer.close()


if __name__ == "__main__":  # python -m kali_daemons.plant.camera --instance NAME --name camera
    from ..runtime.daemon import run_daemon  # run as a program only

    run_daemon(SimCamera)
