"""One arm of the cell as a user program moves it (``Kali.robot(name)``): its reads, its moves
(joints, lines, arcs, paths, tracking and streams), its gripper and load, its wrist sensor and
its servos.  Each move is validated here before it is queued (``MotionError`` naming the
argument; nothing moves) and put through ``Kali._request``."""

from __future__ import annotations

import math
import os
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..core import layout
from ..core.errors import KinematicsError, ServoError
from ..core.layout import MotionKind
from ..robots import RobotType
from ..robots.cell import base_transform, inverse
from ..robots.payload import write_load
from ..servo.shadow import Trial
from ..tg.cartesian import rotation_angle
from ..tg.profiles import MotionError, check_joint_target, rigid_pose
from . import streams
from .common import (
    FT_FRAMES,
    MotionFailedError,
    _config_arg,
    _flag_arg,
    _guard_arg,
    _pose_arg,
    _real_array,
    _speed_arg,
    _timeout_arg,
)
from .handle import MotionHandle
from .state import ArmState
from .streams import JointStream, SharedTransform, Stream, TgFunctionHandle
from .system import TRACK_LIMITS, MotionSystem

if TYPE_CHECKING:
    from .motion import Kali


GRIP_TIMEOUT_S = 5.0  # a Franka Hand's grasp or opening takes up to ~2 s
GRIP_POLL_S = 0.005
# Robot.settle: the flange within this of where its demand puts it, this long without a break
SETTLE_M = 2e-4
SETTLE_RAD = 1e-3
SETTLE_HOLD_S = 0.05


class Robot:
    """One arm of the cell, as a user program moves it."""

    def __init__(self, kali: Kali, index: int) -> None:
        self.kali = kali
        self.index = index
        self.name = kali.names[index]
        cfg = kali.inst.config.robots[index]
        self.type = cfg.type  # its robot type: joints, limits, kinematics
        self.n_joints = cfg.n_joints
        self.span = kali.inst.config.joints.span(index)  # its joints in the flat records
        self.base = base_transform(cfg.base_xyz, cfg.base_yaw_deg)  # base in the world
        self.tool = np.eye(4)  # tool in the flange frame

    def read_joints(self) -> np.ndarray:
        """The measured joint angles (rad, one per joint of its type), a copy."""
        return self.kali.servo.level.joints["q"][self.span].copy()

    def read_state(self) -> ArmState:
        """The arm at the last servo tick SIO finished, every value of that one tick: joints,
        velocities, demand, torques, currents, wrench; with its power, calibration and
        servos as they stand (``client.state.ArmState``)."""
        return self.kali.state_reader().read([self.index])[0]

    def read_t6(self, demand: bool = False) -> np.ndarray:
        """T6: the flange in the robot's base frame (4×4, thesis 3.3.1), by Pinocchio's
        forward kinematics of the arm model, from the measured joints or, with ``demand``,
        from where the arm is servoed to (``Kali.start_point``: where its next motion
        starts)."""
        q = self.kali.start_point(self.index) if demand else self.read_joints()
        return self.kali.flange_pose(q, self.index)

    def read_pose(self, demand: bool = False) -> np.ndarray:
        """The tool's pose in the world, B · T6 · Tool: from the measured joints, or with
        ``demand`` from the demand (exact, where the measured pose is a few encoder counts
        off it once settled)."""
        return self.base @ self.read_t6(demand) @ self.tool

    def settle(
        self,
        within_m: float = SETTLE_M,
        within_rad: float = SETTLE_RAD,
        hold_s: float = SETTLE_HOLD_S,
        timeout: float = 5.0,
    ) -> None:
        """Wait until the arm is where it is told to be: its flange (from the measured joints)
        within ``within_m`` and ``within_rad`` of the flange at SIO's demand, without a break,
        for ``hold_s`` of the clock's time (a *fine point*, as VAL's FINE or RAPID's ``fine``).

        A motion is DONE once its last set-point is demanded; the arm closes its servo error
        after that, for some ms, longer while a feed-forward row is late.  Wait for it before
        what needs the arm there: a gripper closed on the way welds the object where the arm
        happens to be, and the arms' servos then fight through it until their next motion.
        MotionError, naming the offset, if
        not settled within ``timeout`` s of the clock's time; MotionFailedError at a halt."""
        what = f"settle: robot '{self.name}'"
        limit = _timeout_arg(what, timeout)
        for name, v in (("within_m", within_m), ("within_rad", within_rad), ("hold_s", hold_s)):
            if isinstance(v, bool) or not isinstance(v, int | float) or not v >= 0:
                raise MotionError(f"{what}: {name} {v!r:.60}, must be a number >= 0")
        inst = self.kali.inst
        tick_s = inst.config.clock.base_tick_ms / 1000.0
        start = int(inst.clock["tick"])
        since, off_m, off_rad = start, math.inf, math.inf
        while True:
            if inst.fault["active"]:
                raise MotionFailedError(f"{what}: the system halted: {inst.fault_text()}")
            if inst.shutting_down:
                raise MotionFailedError(f"{what}: instance '{inst.name}' was stopped")
            now = int(inst.clock["tick"])
            demand = self.kali.servo.level.joints["demand"][self.span].copy()
            there = self.kali.flange_pose(demand, self.index)
            here = self.read_t6()
            off_m = float(np.linalg.norm(here[:3, 3] - there[:3, 3]))
            off_rad = rotation_angle(there[:3, :3].T @ here[:3, :3])
            if off_m > within_m or off_rad > within_rad:
                since = now
            elif (now - since) * tick_s >= hold_s:
                return
            if limit is not None and (now - start) * tick_s > limit:
                raise MotionError(
                    f"{what}: its flange is {off_m * 1000:.2f} mm and {off_rad * 1000:.2f} "
                    f"mrad from its demand after {limit:g} s (within {within_m * 1000:g} mm "
                    f"and {within_rad * 1000:g} mrad for {hold_s * 1000:g} ms asked)"
                )
            self.kali.pause()

    def grip(
        self,
        close: bool = True,
        timeout: float | None = GRIP_TIMEOUT_S,
        holding: str | None = None,
    ) -> None:
        """Close (or open) the gripper, through the robot's hardware: on the McGill board its
        output line, set at once (the plant welds a closing gripper to the object if the
        flange is within reach of its grasp); on an FR3 its Franka Hand, waited for until
        it reports its outcome (MotionFailedError if it failed, or ``timeout`` s passed).
        ``holding``: the scene's object it closes on, whose mass and inertia the arm's model
        then carries (``set_load``, at the arm's grasp of it); opening lets go of any load."""
        what = f"grip: robot '{self.name}'"
        close = _flag_arg(what, "close", close)
        limit = _timeout_arg(what, timeout)
        if holding is not None and not close:
            raise MotionError(f"{what}: holding {holding!r} names what it closes on; open alone")
        load = None if holding is None else self.kali.held_load(what, holding, [self])[0][0]
        hw = self.kali.inst.hardware(self.index)
        ticket = hw.grip(self.index, close)
        deadline = time.monotonic() + (math.inf if limit is None else limit)
        while ticket and (ok := hw.grip_result(self.index, ticket)) is None:
            if time.monotonic() > deadline:
                raise MotionFailedError(f"{what}: the gripper did not finish within {timeout} s")
            if self.kali.inst.lockstep:
                self.kali.pause()  # nothing else steps its clock
            else:
                time.sleep(GRIP_POLL_S)
        if ticket and not ok:
            verb = "closing" if close else "opening"
            raise MotionFailedError(f"{what}: the gripper reports its {verb} failed")
        if load is not None:
            self.set_load(*load, holding=holding)
        elif not close:
            self.set_load(0.0)

    def set_load(
        self,
        mass: float,
        com: Sequence[float] | np.ndarray = (0.0, 0.0, 0.0),
        inertia: np.ndarray | None = None,
        holding: str | None = None,
    ) -> None:
        """What this arm holds beyond its configured tool (libfranka's ``setLoad``): ``mass``
        (kg) at ``com`` (its centre of mass in the flange frame, m) with ``inertia`` about it
        (flange axes, kg·m²; None: a point mass).  The dynamics process's feed-forward and
        the robot-level servos' model carry it from their next cycle; 0 kg: nothing held.
        ``holding``: the scene's object it is, held at the arm's grasp of it (``grip`` and
        ``motion_system`` name it): the TG's clearance check then carries its shape.
        ServoError, nothing changed, for a value out of bounds or an object no arm can hold."""
        what = f"set_load: robot '{self.name}'"
        held = 0  # the record's: the object's index + 1, 0 none
        if holding is not None:
            scene = self.kali.scene
            can = [o.name for o in scene.graspable]
            if holding not in can:
                raise ServoError(
                    f"{what}: holding {holding!r}: not an object of the scene an arm can hold; "
                    f"those are {can}"
                )
            held = [o.name for o in scene.objects].index(holding) + 1
        kg = _speed_arg(what, "mass", mass)
        at = _real_array(f"{what}: com", com, "3 numbers (m)")
        spread = (
            np.zeros((3, 3))
            if inertia is None
            else _real_array(f"{what}: inertia", inertia, "a 3×3 inertia (kg·m²)")
        )
        record = self.kali.loads[self.index : self.index + 1].reshape(())
        write_load(record, kg, at, spread, what, held)

    def read_wrench(self, frame: str = "world") -> np.ndarray:
        """The arm's wrist force/torque sensor in Newtons (SIO's, this tick), a copy
        of 6 values [Fx, Fy, Fz, Tx, Ty, Tz] (N, N·m).  ``frame``: ``"world"`` (default) or
        ``"tool"`` give the contact wrench, what the environment applies to the tool (its own
        weight removed, low-pass filtered), about the tool point in world or tool axes;
        ``"sensor"`` the wrench the tool exerts on the sensor (its weight included,
        unfiltered), sensor frame.  ServoError for an arm without a sensor."""
        if frame not in FT_FRAMES:
            raise ServoError(
                f"read_wrench: robot '{self.name}': frame {frame!r:.40}; "
                f"one of: {', '.join(FT_FRAMES)}"
            )
        return self._ft(f"read_wrench({frame!r})")[frame].copy()

    def tare(self, timeout: float = 5.0) -> None:
        """Zero the wrist sensor: SIO averages its next 0.1 s of readings less the tool's
        weight and takes that as the sensor's offset.  Keep the arm still and touching
        nothing.  Waits until done; ServoError if the system halts or ``timeout`` (s) passes."""
        ft = self._ft("tare")
        limit = _timeout_arg("tare", timeout)
        deadline = time.monotonic() + (math.inf if limit is None else limit)
        count = int(ft["tare_count"])
        ft["tare_cmd"] = 1
        while int(ft["tare_count"]) == count:
            if self.kali.inst.fault["active"]:
                raise ServoError(
                    f"tare: robot '{self.name}': the system halted: {self.kali.inst.fault_text()}"
                )
            if time.monotonic() > deadline:
                raise ServoError(f"tare: robot '{self.name}': not done within {limit:g} s")
            self.kali.pause()

    def _ft(self, what: str) -> np.ndarray:
        """The arm's FT_STATE record (0-d); ServoError if it has no wrist sensor."""
        if self.kali.inst.config.robots[self.index].ft.sheet is None:
            raise ServoError(f"{what}: robot '{self.name}' has no wrist force/torque sensor")
        return self.kali.ft[self.index : self.index + 1].reshape(())

    def joints_at(self, target: np.ndarray, config: object | str) -> np.ndarray:
        """The joint angles putting the tool at ``target`` (world pose) in configuration
        ``config`` (e.g. ``"run"``: its robot type's ``kinematics.configs``), for a
        ``move_joints`` into a configuration a straight line cannot change to; MotionError
        if out of reach or limits."""
        what = f"joints_at: robot '{self.name}'"
        kin = self.type.kinematics
        flags = _config_arg(what, config, kin)
        t6 = inverse(self.base) @ _pose_arg(what, target) @ inverse(self.tool)
        try:
            return kin.ikine(t6, flags)
        except KinematicsError as exc:
            raise MotionError(f"{what}: {str(exc).removeprefix('kinematics: ')}") from None

    def set_tool(self, tool: np.ndarray) -> None:
        """The tool frame in the flange frame (4×4) for this program's Cartesian moves: a
        rigid pose (``rigid_pose``: finite, a rotation, within ``MAX_POSE_M``), else
        MotionError naming the value and the rule, the tool unchanged.  A scaled or mirrored
        tool would turn every pose read through it into one no move may target."""
        self.tool = rigid_pose(f"set_tool: robot '{self.name}'", "tool", tool)

    def move_line(
        self,
        target: np.ndarray,
        speed: float = 0.1,
        angular_speed: float = 0.5,
        config: object | str | None = None,
        wait: bool = True,
        timeout: float | None = None,
        guard: float | None = None,
        duration: float | None = None,
        blend: bool = True,
    ) -> MotionHandle:
        """A straight line of the tool to ``target`` (world), at ``speed`` m/s and
        ``angular_speed`` rad/s at most, or taking ``duration`` s (thesis 2.2.1: the time
        for the movement), keeping the arm's configuration (``config``, e.g. 'ruf', must be
        the one it is in if given).  Blocks unless ``wait`` is False.

        ``guard`` (N) makes it a guarded move: once the wrist sensor's contact force reaches
        it, SIO holds the arm where it is that servo tick and the motion ends CONTACT
        (``handle.contact`` says where; ``wait`` returns).  Tare the sensor first."""
        return self.move_path(
            [target], speed, angular_speed, 0.0, config, wait, timeout, guard, [duration], blend
        )

    def move_arc(
        self,
        via: Sequence[float],
        target: np.ndarray,
        speed: float = 0.1,
        angular_speed: float = 0.5,
        wait: bool = True,
        timeout: float | None = None,
        duration: float | None = None,
    ) -> MotionHandle:
        """A circular arc of the tool to ``target`` (world) through the point ``via`` (world,
        m), at ``speed`` along it (or taking ``duration`` s), its orientation turning as a
        line's; refused if ``via`` is on the line between the ends.  See ``move_line``."""
        return self.move_path(
            [target], speed, angular_speed, 0.0, None, wait, timeout, None, [duration],
            arcs=[via],
        )  # fmt: skip

    def move_path(
        self,
        targets: Sequence[np.ndarray],
        speed: float = 0.1,
        angular_speed: float = 0.5,
        transition_s: float = 0.2,
        config: object | str | None = None,
        wait: bool = True,
        timeout: float | None = None,
        guard: float | None = None,
        durations: Sequence[float | None] | None = None,
        blend: bool = True,
        arcs: Sequence[Sequence[float] | None] | None = None,
    ) -> MotionHandle:
        """Straight lines of the tool through ``targets`` (world poses), blended over
        ``transition_s`` at each via point (Paul's method; the path starts and ends at
        rest); ``durations`` gives segments a time instead of the speeds (None: by them);
        ``arcs`` makes segments circular arcs through the points given (None: a line).
        See ``move_line``."""
        system = MotionSystem(self.kali, [self], [inverse(self.tool)])
        configs = [config]
        return system.move_path(
            targets, speed, angular_speed, transition_s, configs, wait, timeout, guard, durations,
            blend, arcs,
        )  # fmt: skip

    def move_joints(
        self,
        q: np.ndarray,
        speed: float = 0.5,
        wait: bool = True,
        timeout: float | None = None,
        guard: float | None = None,
        blend: bool = True,
    ) -> MotionHandle:
        """A smooth joint move to ``q`` (rad, one value per joint of the arm's type:
        ``n_joints``), every joint arriving together, at ``speed`` (0, 1] of the joint speed
        and acceleration limits.  Blocks until there unless ``wait`` is False; returns the
        request's handle either way.  ``guard``: see ``move_line``.  Queued behind another
        joint move of this arm (``wait=False``), it continues that one without a stop, the
        two summed over the overlap of its deceleration and this one's acceleration, unless
        ``blend`` is False (thesis 3.1)."""
        what = f"move_joints: robot '{self.name}'"
        target = _joints(self.name, q, self.type)
        if not (
            isinstance(speed, int | float)
            and not isinstance(speed, bool)
            and math.isfinite(speed)
            and 0.0 < speed <= 1.0
        ):
            raise MotionError(f"{what}: speed {speed!r:.60}, must be in (0, 1]")
        wait = _flag_arg(what, "wait", wait)
        timeout = _timeout_arg(what, timeout)
        guard_n = _guard_arg(what, guard, self.kali, [self.index])
        handle = self.kali._request(
            MotionKind.JOINTS,
            [self.index],
            flags=0 if _flag_arg(what, "blend", blend) else layout.REQUEST_STOP_BETWEEN,
            joints=[target],
            speed_scale=float(speed),
            guard_n=guard_n,
        )
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
        config: object | str | None = None,
    ) -> MotionHandle:
        """Let the tool follow the product of ``loop`` (a position equation, thesis 3.2.3:
        fixed 4×4 poses and ``SharedTransform``s, e.g. ``[conveyor, part, grasp]``), read
        every TG tick, within ``speed`` (m/s), ``angular_speed`` (rad/s), ``accel`` (m/s²)
        and ``angular_accel`` (rad/s²), for ``duration`` s (None: until ``stop``).  Returns
        the handle at once; it ends STOPPED, with the reason, when a shared transform goes
        stale or bad or the target leaves the arm's reach (``MotionSystem.track``)."""
        system = MotionSystem(self.kali, [self], [inverse(self.tool)])
        return system.track(loop, speed, angular_speed, accel, angular_accel, duration, [config])

    def stream(
        self,
        lifetime: float = streams.DEFAULT_LIFETIME_S,
        speed: float = TRACK_LIMITS[0],
        angular_speed: float = TRACK_LIMITS[1],
        accel: float = TRACK_LIMITS[2],
        angular_accel: float = TRACK_LIMITS[3],
    ) -> Stream:
        """Start following a stream of tool poses this program sends (``Stream.send``) at
        any rate, within the limits (see ``track``); not sent for ``lifetime`` s, the arm
        decelerates to rest and the motion ends.  The stream starts where the tool is."""
        tool = self.base @ self.type.kinematics.fkine(self.kali.start_point(self.index))
        frame = self.kali.shared_transform(
            f"stream.{self.name}.{os.getpid()}", tool @ self.tool, lifetime
        )
        try:
            handle = self.track([frame], speed, angular_speed, accel, angular_accel)
        except BaseException:
            frame.close()
            raise
        return Stream(self, frame, handle)

    def stream_joints(
        self,
        lifetime: float = streams.DEFAULT_LIFETIME_S,
        speed: float = 0.5,
        duration: float | None = None,
    ) -> JointStream:
        """Start following a stream of joint targets (``JointStream.send(q)``), each joint
        within ``speed`` (0, 1] of its speed and acceleration limits; see ``stream``."""
        return streams.start_joint_stream(self, lifetime, speed, duration)

    def feedforward(self, mode: str) -> None:
        """This arm's feed-forward from the dynamics process (thesis 3.3.6): ``"full"`` (the
        inverse dynamics of the demanded motion), ``"gravity"`` or ``"off"``; it fades in or
        out over ``feedforward.ramp_ms``."""
        self.kali.servo.feedforward(self.name, mode)

    def select_servo(self, name: str) -> None:
        """Run this whole arm with robot-level servo ``name`` (``"computed_torque"``,
        ``"impedance"``, a plugin's), or with ``"joints"`` its joint servos again; handed
        over bumplessly at the next servo tick, while it moves or not (thesis 3.3.4)."""
        self.kali.servo.select_arm(self.name, name)

    def select_joint_servos(
        self,
        name: str,
        params: Sequence[Mapping[str, float]] | Mapping[str, float] | None = None,
    ) -> None:
        """Every joint of this arm onto joint servo ``name`` with its own parameters
        (``params[j]`` for joint j + 1, or one mapping for all), handed over together on one
        servo tick, bumplessly; every joint's parameters checked before any changes."""
        self.kali.servo.select_joints(self.name, name, params)

    def set_servo(self, params: Mapping[str, float], servo: str | None = None) -> None:
        """Change parameters of this arm's robot-level servo (default: the active one) on
        line, e.g. ``set_servo({"kz": 500, "fz": 15})``; ServoError, nothing changed, for a
        bad value."""
        self.kali.servo.set_arm_params(self.name, params, servo)

    def shadow_servo(self, name: str | None, joint: int | None = None) -> None:
        """Run servo ``name`` in shadow beside this arm's active servos — a robot-level one,
        or with ``joint`` (1..n) that joint's: stepped every tick on the same inputs, its
        torque compared and never applied; None ends the trial.  ``trials()`` reads the
        figures; selecting it afterwards goes on from its own state."""
        if joint is None:
            self.kali.servo.shadow_arm(self.name, name)
        else:
            self.kali.servo.shadow(self.name, joint, name, wait=not self.kali.inst.lockstep)

    def trials(self) -> list[Trial]:
        """This arm's joints' figures from their last shadow trial: (shadow − active)
        torque RMS and peak, N·m, over the ticks compared."""
        return self.kali.servo.trials(self.name)

    def servo_params(self, servo: str | None = None) -> dict[str, float]:
        """The parameters of this arm's robot-level servo (default: the active one)."""
        return self.kali.servo.get_arm_params(self.name, servo)

    def stop(self) -> int:
        """Decelerate this arm's motion to rest on its path; queued ones are cancelled.  It
        goes ahead of every request; its seq, for ``Kali.stopped`` (0 while halted)."""
        return self.kali._order(MotionKind.STOP, [self.index])

    def abort(self) -> int:
        """Drop this arm's motion at once: it holds at the last set-point.  Its seq, as
        ``stop``'s."""
        return self.kali._order(MotionKind.ABORT, [self.index])


def _joints(robot: str, q: np.ndarray, rtype: RobotType) -> np.ndarray:
    """A joint target for robot ``robot`` of type ``rtype``: its ``n_joints`` angles, finite
    and within range; MotionError naming the robot, its type and joint count otherwise."""
    n = rtype.n_joints
    what = f"move_joints: robot '{robot}' ({rtype.name}, {n} joints)"
    target = _real_array(what, q, f"{n} numbers")
    if target.shape != (n,):
        raise MotionError(
            f"{what}: {target.size} values given, shape {target.shape}, expected ({n},)"
        )
    check_joint_target(robot, target, rtype)
    return target
