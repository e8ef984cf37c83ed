"""A motion system (DESIGN 5): arms holding one object, moving its control frame together
(``Kali.motion_system``)."""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from ..core import layout
from ..core.errors import QueueFullError, ServoError
from ..core.layout import MotionKind
from ..robots.cell import inverse
from ..tg.cartesian import CartesianMotion, encode_config
from ..tg.profiles import MotionError
from . import streams
from .common import (
    _arcs_arg,
    _config_arg,
    _durations_arg,
    _flag_arg,
    _guard_arg,
    _list_arg,
    _pose_arg,
    _speed_arg,
    _timeout_arg,
)
from .handle import MotionHandle
from .state import ObjectState
from .streams import SharedTransform, TgFunctionHandle

if TYPE_CHECKING:
    from .motion import Kali
    from .robot import Robot


# a tracking motion's limits unless the program gives its own: m/s, rad/s, m/s², rad/s²
TRACK_LIMITS = (0.25, 1.0, 1.0, 4.0)


class MotionSystem:
    """Arms holding one object (or one arm): they move its control frame together (DESIGN 5).

    ``grasps[k]`` is arm k's flange in the object's frame, so arm k's T6 = B_k⁻¹ · O · G_k
    for an object pose O; ``holding`` the scene's object they hold, by name, if given.
    ``Kali.motion_system`` makes one.
    """

    def __init__(
        self, kali: Kali, robots: list[Robot], grasps: list[np.ndarray], holding: str | None = None
    ) -> None:
        self.kali = kali
        self.robots = robots
        self.grasps = grasps
        self.holding = holding
        self.names = [r.name for r in robots]
        self.indices = [r.index for r in robots]

    def read_pose(self) -> np.ndarray:
        """The object's pose in the world, from the first arm's measured joints."""
        r = self.robots[0]
        return r.base @ r.read_t6() @ inverse(self.grasps[0])

    def read_state(self) -> ObjectState:
        """The object and its arms at the last servo tick SIO finished, all of that tick
        (``client.state.ObjectState``): its pose from the first arm's measured joints and from
        its demand, and every arm's ``ArmState``."""
        arms = self.kali.state_reader().read([r.index for r in self.robots])
        r, first = self.robots[0], arms[0]
        grasp = inverse(self.grasps[0])  # the first arm's flange to the object
        return ObjectState(
            robots=tuple(r.name for r in self.robots),
            tick=first.tick,
            time_s=first.time_s,
            pose=r.base @ self.kali.flange_pose(first.q, r.index) @ grasp,
            pose_d=r.base @ self.kali.flange_pose(first.q_d, r.index) @ grasp,
            arms=tuple(arms),
        )

    def move_line(
        self,
        target: np.ndarray,
        speed: float = 0.1,
        angular_speed: float = 0.5,
        configs: Sequence[object | str | None] | None = None,
        wait: bool = True,
        timeout: float | None = None,
        guard: float | None = None,
        duration: float | None = None,
        blend: bool = True,
    ) -> MotionHandle:
        """The object in a straight line to ``target`` (world); see ``Robot.move_line``."""
        return self.move_path(
            [target], speed, angular_speed, 0.0, configs, wait, timeout, guard, [duration], blend
        )

    def move_path(
        self,
        targets: Sequence[np.ndarray],
        speed: float = 0.1,
        angular_speed: float = 0.5,
        transition_s: float = 0.2,
        configs: Sequence[object | str | None] | None = None,
        wait: bool = True,
        timeout: float | None = None,
        guard: float | None = None,
        durations: Sequence[float | None] | None = None,
        blend: bool = True,
        arcs: Sequence[Sequence[float] | None] | None = None,
    ) -> MotionHandle:
        """The object along straight lines through ``targets``, blended over
        ``transition_s``; ``configs`` one per arm (None: each keeps its own); ``durations``
        one per segment (s, None: by the speeds), the time for the movement (2.2.1).
        Queued behind another path of this motion system (``wait=False``), with both
        transitions > 0, it continues that one without a stop: the transition of 3.1 between
        its last segment and this one's first (the two summed over the window, which is
        Paul's transition at the junction); ``blend=False`` stops between them.  The window
        is checked before it is taken; failing, it stops between them instead.  Any number of
        targets: past ``layout.MAX_SEGMENTS`` the path goes as several requests, each
        continuing the one before so, put as the queue takes them; the handle is the last
        one's (a stop, or a part that does not arrive, cancels the rest).  Checked
        whole before it is queued when the arms are idle (MotionError says where and why).
        ``guard`` (N): a contact force that stops it on any of its arms, which then all
        hold (``Robot.move_line``)."""
        what = f"move_path: {', '.join(repr(n) for n in self.names)}"
        if isinstance(targets, np.ndarray) and targets.shape == (4, 4):
            raise MotionError(f"{what}: targets is one pose; pass a list ([pose])")
        targets = _list_arg(what, "targets", targets)
        if not targets:
            raise MotionError(f"{what}: no targets; give at least one pose")
        targets = [_pose_arg(f"{what}: targets[{i}]", t) for i, t in enumerate(targets)]
        speed = _speed_arg(what, "speed", speed)
        angular_speed = _speed_arg(what, "angular_speed", angular_speed)
        transition_s = _speed_arg(what, "transition_s", transition_s)
        times = _durations_arg(what, durations, len(targets))
        vias = _arcs_arg(what, arcs, len(targets))
        configs = (
            _list_arg(what, "configs", configs)
            if configs is not None
            else [None] * len(self.robots)
        )
        wait = _flag_arg(what, "wait", wait)
        timeout = _timeout_arg(what, timeout)
        guard_n = _guard_arg(what, guard, self.kali, self.indices)
        if len(configs) != len(self.robots):
            raise MotionError(f"{what}: {len(configs)} configs for {len(self.robots)} arms")
        flags = [
            _config_arg(f"{what}: config", c, r.type.kinematics)
            for c, r in zip(configs, self.robots, strict=True)
        ]
        for r in self.robots:
            self.kali.servo.require_calibrated(r.index, what)
        if self.kali.idle(self.indices):  # the start is known: plan and check it all now
            CartesianMotion(
                self.names,
                [r.type for r in self.robots],
                [r.base for r in self.robots],
                self.grasps,
                [self.kali.start_point(k) for k in self.indices],
                flags,
                targets,
                speed,
                angular_speed,
                transition_s,
                self.kali.tg_dt,
                times,
                vias,
            ).check_all()
        blend = _flag_arg(what, "blend", blend)
        if len(targets) > layout.MAX_SEGMENTS and (guard_n or self.kali.grouping is not None):
            raise MotionError(
                f"{what}: {len(targets)} targets; a guarded path or one in a together() block "
                f"takes at most {layout.MAX_SEGMENTS}"
            )
        codes = [
            encode_config(c, r.type.kinematics) for c, r in zip(flags, self.robots, strict=True)
        ]
        # a long path goes as requests of MAX_SEGMENTS targets, each continuing the one before
        # without a stop (the TG blends them: Paul's transition at each junction, so the arm
        # runs one path); they are put as the queue takes them
        deadline = time.monotonic() + (math.inf if timeout is None else timeout)
        for first in range(0, len(targets), layout.MAX_SEGMENTS):
            part = targets[first : first + layout.MAX_SEGMENTS]
            poses = np.zeros((layout.MAX_SEGMENTS, 4, 4))
            poses[: len(part)] = part
            part_times = times[first : first + layout.MAX_SEGMENTS]
            part_vias = vias[first : first + layout.MAX_SEGMENTS]
            arc_flags = np.zeros(layout.MAX_SEGMENTS, dtype=np.uint8)
            arc_via = np.zeros((layout.MAX_SEGMENTS, 3))
            for i, v in enumerate(part_vias):
                if v is not None:
                    arc_flags[i], arc_via[i] = 1, v
            fields: dict[str, Any] = {  # "flags" is _request's own argument
                "flags": 0 if blend or first else layout.REQUEST_STOP_BETWEEN,
                "n_segments": len(part),
                "poses": poses,
                "grasps": np.array(self.grasps),
                "config": codes,
                "speed": speed,
                "angular_speed": angular_speed,
                "transition_s": transition_s,
                "guard_n": guard_n,
                "durations": np.pad(part_times, (0, layout.MAX_SEGMENTS - len(part_times))),
                "arcs": arc_flags,
                "arc_via": arc_via,
            }
            while True:
                try:
                    handle = self.kali._request(MotionKind.PATH, self.indices, **fields)
                    break
                except QueueFullError:  # the TG takes the earlier parts as they run
                    if time.monotonic() > deadline:
                        raise
                    self.kali.pause()
        if wait and self.kali.grouping is None:  # in a together() block nothing is sent yet
            handle.wait(timeout)
        return handle

    def track(
        self,
        loop: Sequence[SharedTransform | TgFunctionHandle | np.ndarray],
        speed: float = TRACK_LIMITS[0],
        angular_speed: float = TRACK_LIMITS[1],
        accel: float = TRACK_LIMITS[2],
        angular_accel: float = TRACK_LIMITS[3],
        duration: float | None = None,
        configs: Sequence[object | str | None] | None = None,
    ) -> MotionHandle:
        """Let the object's control frame follow the product of ``loop`` (fixed poses and
        shared transforms), read every TG tick, within the limits, for ``duration`` s (None:
        until stopped); ``configs`` one per arm (None: each keeps its own).  The TG refuses
        it if the loop does not close (a shared transform nobody writes, a target out of
        reach) and stops it on its path when a shared transform is not written within its
        lifetime or holds garbage; a target out of reach later holds the arms where they
        are.  Returns the handle at once."""
        what = f"track: {', '.join(repr(n) for n in self.names)}"
        n = len(self.robots)
        configs = [None] * n if configs is None else _list_arg(what, "configs", configs)
        if len(configs) != n:
            raise MotionError(f"{what}: {len(configs)} configs for {n} arms")
        if duration is not None and (
            isinstance(duration, bool) or not isinstance(duration, int | float)
        ):
            raise MotionError(f"{what}: duration {duration!r:.40} is not a time in s")
        limits = (speed, angular_speed, accel, angular_accel)
        return streams.track(self, loop, limits, duration, configs)

    def set_internal_force(self, newtons: float, timeout: float = 5.0) -> None:
        """Squeeze the held object with ``newtons`` along the line between the two arms' tool
        points (0: no squeeze), regulated from their wrist sensors.

        Each arm runs the Cartesian impedance servo (selected, bumplessly, if it runs its
        joint servos; its config needs ``robot_servos: true``) told its partner, the squeeze
        ``fi`` and the line towards the partner in its tool axes (fixed while they hold the
        object): each pushes along the line by ``fi`` plus the squeeze error both compute
        alike from both wrist sensors, times ``kpi`` and integrated (``kii``), so the
        corrections are equal and opposite, squeezing without moving the object.  The squeeze
        then holds through lift, carry and set-down instead of following the two arms' servo
        errors; 0 ends it.  Tare both sensors first, in free air (``Robot.tare``): a
        sensor's offset goes straight into the squeeze.  ServoError for a bad force, an arm
        that cannot run the servo or a sensor never tared."""
        what = f"set_internal_force: {', '.join(repr(n) for n in self.names)}"
        if len(self.robots) != 2:
            raise MotionError(f"{what}: a squeeze needs two arms, not {len(self.robots)}")
        if isinstance(newtons, bool) or not isinstance(newtons, int | float):
            raise ServoError(f"{what}: {newtons!r:.60} is not a force in N")
        if not (math.isfinite(newtons) and newtons >= 0.0):
            raise ServoError(f"{what}: {newtons} N, must be a finite force >= 0")
        if newtons:
            for r in self.robots:
                if int(r._ft(what)["tare_count"]) == 0:
                    raise ServoError(
                        f"{what}: robot '{r.name}''s wrist sensor was never tared: its "
                        f"offset would go into the squeeze (robot.tare() in free air first)"
                    )
        poses = [r.base @ r.read_t6() for r in self.robots]
        tips = [p[:3, 3] + p[:3, 2] * self.kali.inst.config.robots[r.index].ft.tool_tip_m
                for p, r in zip(poses, self.robots, strict=True)]  # fmt: skip
        line = tips[1] - tips[0]
        length = float(np.linalg.norm(line))
        if length < 1e-3:
            raise MotionError(f"{what}: the two tool points are {length * 1000:.2f} mm apart")
        line /= length
        servo = self.kali.servo
        for r in self.robots:  # both asked first: handed over on one tick, then waited for
            if servo.arm_active(r.name) != "impedance":
                servo.select_arm(r.name, "impedance", wait=False)
        limit = _timeout_arg(what, timeout)
        deadline = time.monotonic() + (math.inf if limit is None else limit)
        while any(servo.arm_active(r.name) != "impedance" for r in self.robots):
            if time.monotonic() > deadline:
                raise ServoError(f"{what}: the impedance servo not running within {limit:g} s")
            self.kali.pause()
        pairs = zip((1.0, -1.0), poses, self.robots, self.robots[::-1], strict=True)
        for sign, pose_k, r, other in pairs:
            toward = pose_k[:3, :3].T @ (sign * line)  # towards the other, its tool axes
            params = {f"u{a}": float(v) for a, v in zip("xyz", toward, strict=True)}
            params.update(partner=float(other.index + 1) if newtons else 0.0, fi=float(newtons))
            r.set_servo(params)

    def stop(self) -> int:
        """Decelerate the motion system to rest on its path (ahead of every request); its
        seq, for ``Kali.stopped`` (0 while halted)."""
        return self.kali._order(MotionKind.STOP, self.indices)

    def abort(self) -> int:
        """Drop the motion system's motion at once; its seq, as ``stop``'s."""
        return self.kali._order(MotionKind.ABORT, self.indices)
