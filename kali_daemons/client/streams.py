"""Motion that changes while it runs, from a user program (thesis 3.2.3, 2.7).

    conveyor = kali.shared_transform("conveyor", pose(...), lifetime=0.05)
    h = left.track([conveyor, part, grasp], speed=0.3)   # tool = conveyor · part · grasp
    left.stop()                                           # decelerates on its path
    with left.stream(lifetime=0.1) as s:                  # teleoperation: a pose stream
        for p in hand_controller():
            s.send(p)                                     # the arm follows within limits

A *shared transform* is a record of ``tg.frames`` this program holds and writes, whole or not
at all, at any rate; the TG reads it every tick (``tg.tracking``) and stops the arm on its
path when it is not written within its lifetime.  A *stream* is one shared transform the
arm's tool follows.  Records are free again once the program closes them or exits.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from types import TracebackType
from typing import TYPE_CHECKING

import numpy as np

from ..core import atomic, layout
from ..core.errors import ConfigError, MotionError
from ..core.layout import FrameKind, FunctionStatus, MotionKind
from ..core.spinlock import pid_alive
from ..runtime.instance import decode
from ..tg.cartesian import encode_config
from ..tg.functions import TgFunction, data_of, get_params, set_params
from ..tg.profiles import rigid_pose
from ..tg.tracking import check_limits, check_track_time, rotation, write_frame
from .common import _config_arg, _pose_arg, _real_array

if TYPE_CHECKING:
    from .handle import MotionHandle
    from .motion import Kali
    from .robot import Robot
    from .system import MotionSystem

DEFAULT_LIFETIME_S = 0.1  # a stream not written for this long stops its arm
TWIST = 6  # a twist's values: linear x, y, z (m/s), then angular x, y, z (rad/s)


class SharedTransform:
    """A transform this program writes for the TG to read every tick (a Type 4 record of
    ``tg.frames``).  ``set(pose)`` writes it whole; ``close()`` gives the record back.  One
    another program writes (``Kali.find_transform``) can be named in a loop, not set."""

    def __init__(self, kali: Kali, index: int, name: str, lifetime: float) -> None:
        self.kali = kali
        self.index = index
        self.name = name
        self.lifetime = lifetime
        self._record = kali.frames[index : index + 1].reshape(())

    @property
    def value(self) -> np.ndarray:
        """The pose last written (4×4, a copy)."""
        return self._record["pose"].copy()

    def set(self, pose: np.ndarray) -> None:
        """Write ``pose`` (4×4, a rigid motion) for the TG's next tick, stamped with the wall
        clock's tick; MotionError, nothing written, for a pose that is not finite or rigid."""
        self._check_held("set")
        write_pose(self._record, self.name, int(self.kali.inst.clock["tick"]), pose)

    def set_joints(self, q: np.ndarray) -> None:
        """Write joint targets (a joint stream's), stamped like ``set``; unchecked here: the
        TG stops the arm on a target out of range."""
        self._check_held("set_joints")
        write_frame(
            self._record, int(self.kali.inst.clock["tick"]), None, np.asarray(q, dtype=float)
        )

    def live(self) -> bool:
        """True while a running program holds the record under this name (this one, or the
        one ``Kali.find_transform`` found)."""
        if self.kali.frames is None:
            return False
        pid = int(self._record["owner_pid"])
        if pid <= 0 or decode(self._record["name"]) != self.name:
            return False
        if pid == os.getpid():
            return self.kali.held_frames.get(self.index) is self
        return pid_alive(pid)

    def _check_held(self, what: str) -> None:
        if int(self._record["owner_pid"]) != os.getpid():
            raise MotionError(f"{what}: shared transform '{self.name}' is not held any more")

    def close(self) -> None:
        """Give the record back (a motion tracking it stops once its lifetime passes)."""
        if self.kali.frames is not None and int(self._record["owner_pid"]) == os.getpid():
            self._record["owner_pid"] = 0
        self.kali.held_frames.pop(self.index, None)


def write_pose(record: np.ndarray, name: str, tick: int, pose: object) -> None:
    """Write ``pose`` into shared transform ``name``'s record (0-d), stamped ``tick``;
    MotionError, nothing written, for a pose that is not finite or rigid."""
    write_frame(record, tick, rigid_pose(f"shared transform '{name}'", "pose", pose), None)


def twisted(
    record: np.ndarray, robot: str, twist: object, tick: int, tick_s: float, lifetime: float
) -> np.ndarray:
    """A stream's target moved at ``twist`` (world: vx, vy, vz m/s, then wx, wy, wz rad/s)
    from the pose its record holds, for the time since that was written (at most
    ``lifetime``, so a late send never jumps far), the rotation about the target's point;
    MotionError for a twist that is not 6 finite numbers."""
    t = _real_array(f"stream of '{robot}': twist", twist, "6 numbers")
    if t.shape != (TWIST,):
        raise MotionError(f"stream of '{robot}': twist has shape {t.shape}, not ({TWIST},)")
    dt = min((tick - int(record["stamp_tick"])) * tick_s, lifetime or math.inf)
    pose = record["pose"].copy()
    pose[:3, 3] += t[:3] * dt
    rot = np.empty((3, 3))
    rotation(list(t[3:] * dt), rot)
    pose[:3, :3] = rot @ pose[:3, :3]
    return pose


def claim_slot(records: np.ndarray, name: str, what: str) -> int:
    """Take a free record of ``records`` (``tg.frames`` or ``tg.functions``; free: no holder,
    or a dead one) for ``name`` by a compare-and-swap of its holder's pid, and name it; its
    index.  MotionError if a live program holds ``name`` or none is free."""
    if not isinstance(name, str) or not name or len(name.encode()) > layout.FRAME_NAME_BYTES:
        raise MotionError(f"{what}: name {name!r:.60} must be 1 to {layout.FRAME_NAME_BYTES} bytes")
    me = os.getpid()
    for i in range(len(records)):
        pid = int(records["owner_pid"][i])
        if pid > 0 and pid_alive(pid) and decode(records["name"][i]) == name:
            raise MotionError(f"{what} '{name}' is held by pid {pid}")
    cas = atomic.CompareExchange32()
    for i in range(len(records)):
        pid = int(records["owner_pid"][i])
        if pid > 0 and pid_alive(pid):
            continue
        addr = records["owner_pid"][i : i + 1].ctypes.data
        swapped, _ = cas(addr, pid & 0xFFFFFFFF, me)
        if swapped:  # else another program took it first
            records["name"][i] = name.encode()
            return i
    raise MotionError(f"{what} '{name}': all {len(records)} records are held by running programs")


def find(kali: Kali, name: str) -> SharedTransform:
    """The shared transform ``name`` another running program writes, to name in a loop,
    once it has written it (a motion tracking one never written would be refused);
    MotionError naming those there are if none is."""
    frames = kali.frames
    for i in range(len(frames)):
        pid = int(frames["owner_pid"][i])
        if pid > 0 and pid_alive(pid) and decode(frames["name"][i]) == name:
            if int(frames["writes"][i]) == 0:
                raise MotionError(
                    f"shared transform {name!r:.40}: pid {pid} holds it but has not written it "
                    "yet"
                )
            return SharedTransform(kali, i, name, float(frames["lifetime_s"][i]))
    there = [
        decode(frames["name"][i])
        for i in range(len(frames))
        if int(frames["owner_pid"][i]) > 0 and pid_alive(int(frames["owner_pid"][i]))
    ]
    raise MotionError(
        f"shared transform {name!r:.40}: no running program writes one of that name "
        f"(written now: {', '.join(there) or 'none'})"
    )


def claim(kali: Kali, name: str, lifetime: float) -> SharedTransform:
    """A shared transform ``name`` this program holds (``claim_slot``), stale after
    ``lifetime`` s (0: never); MotionError naming the problem."""
    if isinstance(lifetime, bool) or not isinstance(lifetime, int | float):
        raise MotionError(f"shared transform {name!r:.40}: lifetime {lifetime!r:.40} is not in s")
    check_track_time(float(lifetime))
    i = claim_slot(kali.frames, name, "shared transform")
    rec = kali.frames[i : i + 1].reshape(())
    rec["lifetime_s"] = float(lifetime)
    rec["writes"] = 0
    frame = SharedTransform(kali, i, name, float(lifetime))
    kali.held_frames[i] = frame
    return frame


class TgFunctionHandle:
    """A TG function this program set up (``Kali.tg_function``): name it in a ``track``
    loop; ``set(**params)`` changes its parameters on line (the TG skips it while they are
    written: its last transform stands that tick); ``close()`` frees the slot."""

    def __init__(self, kali: Kali, index: int, name: str, fn: TgFunction) -> None:
        self.kali = kali
        self.index = index
        self.name = name
        self.function = fn
        self._slot = kali.functions[index : index + 1].reshape(())
        self._data = data_of(self._slot, fn)

    def set(self, **params: float) -> None:
        """Change parameters (the others keep their values); MotionError naming the bad one,
        nothing changed.  Outside any cycle: the TG sees them whole at its next tick."""
        self._write(params, fresh=False)

    def _write(self, params: Mapping[str, float], fresh: bool) -> None:
        if int(self._slot["owner_pid"]) != os.getpid():
            raise MotionError(f"tg function '{self.name}' is not held any more")
        addr = self._slot["seq"].ctypes.data
        seq = atomic.load32(addr)
        saved = bytes(self._slot["data"])
        atomic.store32(addr, (seq + 1) | 1)
        try:
            set_params(self.function, self._data, params, fresh)
        except ConfigError as exc:
            self._slot["data"] = np.frombuffer(saved, dtype=np.uint8)
            raise MotionError(str(exc).removeprefix(f"{exc.subsystem}: ")) from None
        finally:
            atomic.store32(addr, ((seq + 1) | 1) + 1)

    def params(self) -> dict[str, float]:
        """Every parameter's current value."""
        return get_params(self.function, self._data)

    @property
    def status(self) -> FunctionStatus:
        """RUNNING once a motion used it; RAISED or TOO_LONG once it failed there."""
        return FunctionStatus(int(self._slot["status"]))

    @property
    def worst_s(self) -> float:
        """Its longest evaluation in the TG, s."""
        return int(self._slot["worst_ns"]) * 1e-9

    @property
    def over_budget(self) -> int:
        """Its evaluations that took longer than its budget (``FUNCTION_SHARE`` of the TG
        period): in real time the first holds its motions (TOO_LONG); in lockstep, which
        never holds one for its time, a count above 0 says real time would have."""
        return int(self._slot["over_budget"])

    def restart(self) -> None:
        """Its time t counts from now again."""
        self._slot["start_tick"] = int(self.kali.inst.clock["tick"])

    def close(self) -> None:
        """Free the slot (a motion still using it holds its last transform)."""
        if self.kali.functions is not None and int(self._slot["owner_pid"]) == os.getpid():
            self._slot["owner_pid"] = 0
        self.kali.held_functions.pop(self.index, None)


def set_up_function(
    kali: Kali, function: str, name: str | None, params: Mapping[str, float]
) -> TgFunctionHandle:
    """Claim a ``tg.functions`` slot for TG function ``function`` (a built-in or a config
    plugin's) with ``params`` (the rest at their defaults), its time t from now."""
    registry = kali.function_registry()
    try:
        fn = registry[registry.index(function)]
    except ConfigError as exc:
        raise MotionError(str(exc).removeprefix(f"{exc.subsystem}: ")) from None
    label = name if name is not None else f"{function}.{os.getpid()}.{len(kali.held_functions)}"
    i = claim_slot(kali.functions, label, "tg function")
    slot = kali.functions[i : i + 1].reshape(())
    slot["algo"] = 0
    handle = TgFunctionHandle(kali, i, label, fn)
    kali.held_functions[i] = handle
    try:
        slot["data"] = 0
        slot["status"] = FunctionStatus.IDLE
        slot["evaluations"] = 0
        slot["over_budget"] = 0
        slot["worst_ns"] = 0
        handle._write(params, fresh=True)
    except BaseException:
        handle.close()
        raise
    handle.restart()
    slot["algo"] = registry.index(function) + 1
    return handle


def track(
    system: MotionSystem,
    loop: Sequence[SharedTransform | TgFunctionHandle | np.ndarray],
    limits: tuple[float, float, float, float],
    duration: float | None,
    configs: Sequence[object | None],
) -> MotionHandle:
    """Put a TRACK request: ``system``'s control frame follows the product of ``loop``
    within ``limits`` (m/s, rad/s, m/s², rad/s²) for ``duration`` s (None: until stopped);
    MotionError naming the argument."""
    what = f"track: {', '.join(repr(n) for n in system.names)}"
    factors = list(loop) if isinstance(loop, list | tuple) else None
    if factors is None or not 1 <= len(factors) <= layout.MAX_LOOP:
        raise MotionError(f"{what}: loop must be a list of 1 to {layout.MAX_LOOP} transforms")
    poses = np.zeros((layout.MAX_SEGMENTS, 4, 4))
    entries = np.zeros((layout.MAX_LOOP, 2), dtype=np.uint8)
    fixed = 0
    for i, f in enumerate(factors):
        if isinstance(f, SharedTransform):
            if f.kali is not system.kali or not f.live():
                raise MotionError(
                    f"{what}: loop[{i}]: shared transform '{f.name}' is closed (no program "
                    f"writes it)"
                )
            entries[i] = (FrameKind.SHARED, f.index)
        elif isinstance(f, TgFunctionHandle):
            if f.kali is not system.kali or f.kali.held_functions.get(f.index) is not f:
                raise MotionError(f"{what}: loop[{i}]: tg function '{f.name}' is closed")
            entries[i] = (FrameKind.FUNCTION, f.index)
        else:
            poses[fixed] = _pose_arg(f"{what}: loop[{i}]", f)
            entries[i] = (FrameKind.FIXED, fixed)
            fixed += 1
    req = np.zeros((), dtype=layout.MOTION_REQUEST)
    names = ("speed", "angular_speed", "accel", "angular_accel")
    for name, value in zip(names, limits, strict=True):
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise MotionError(f"{what}: {name} {value!r:.40} is not a number")
        req[name] = value
    req["track_s"] = 0.0 if duration is None else duration
    try:
        check_limits(req)
    except MotionError as exc:
        raise MotionError(f"{what}: {exc}") from None
    flags = [
        _config_arg(f"{what}: config", c, r.type.kinematics)
        for c, r in zip(configs, system.robots, strict=True)
    ]
    for r in system.robots:
        system.kali.servo.require_calibrated(r.index, what)
    return system.kali._request(
        MotionKind.TRACK,
        system.indices,
        n_loop=len(factors),
        loop=entries,
        poses=poses,
        grasps=np.array(system.grasps),
        config=[
            encode_config(c, r.type.kinematics) for c, r in zip(flags, system.robots, strict=True)
        ],
        speed=float(limits[0]),
        angular_speed=float(limits[1]),
        accel=float(limits[2]),
        angular_accel=float(limits[3]),
        track_s=float(req["track_s"]),
    )


class Stream:
    """A pose stream (teleoperation): ``send(pose)`` as often as the program likes, the tool
    follows within the limits; not sent within ``lifetime`` s, the arm decelerates to rest
    and the motion ends.  ``close()`` (or leaving ``with``) stops the arm and frees the
    record.  ``handle`` is the tracking motion's."""

    def __init__(self, robot: Robot, frame: SharedTransform, handle: MotionHandle) -> None:
        self.robot = robot
        self.frame = frame
        self.handle = handle

    def send(self, pose: np.ndarray) -> None:
        """The tool's next target (world pose, 4×4)."""
        self.frame.set(pose)

    def send_twist(self, twist: Sequence[float]) -> None:
        """Move the target at ``twist`` (world: vx, vy, vz m/s, then wx, wy, wz rad/s) since
        the last send (``twisted``): a spacemouse's or a joystick's velocity command; the TG
        keeps the arm in its limits.  MotionError for a twist that is not 6 finite numbers."""
        self.frame._check_held("send_twist")
        inst = self.robot.kali.inst
        tick_s = inst.config.clock.base_tick_ms / 1000.0
        rec = self.frame._record
        now = int(inst.clock["tick"])
        self.send(twisted(rec, self.robot.name, twist, now, tick_s, self.frame.lifetime))

    def close(self) -> None:
        """Stop the arm on its path (if the motion still runs) and free the record."""
        if not self.handle.done:
            self.handle.cancel()
        self.frame.close()

    def __enter__(self) -> Stream:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class JointStream(Stream):
    """A joint-target stream: ``send(q)`` (rad, one per joint); see ``Stream``."""

    def send(self, q: np.ndarray) -> None:
        """The arm's next joint targets."""
        self.frame.set_joints(q)

    def send_twist(self, twist: Sequence[float]) -> None:
        """Not for joints: MotionError."""
        raise MotionError(f"joint stream of '{self.robot.name}': send joint targets, not twists")


def start_joint_stream(
    robot: Robot, lifetime: float, speed: float, duration: float | None
) -> JointStream:
    """A TRACK_JOINTS request of ``robot`` from where it is, fed by a new shared record."""
    what = f"stream_joints: robot '{robot.name}'"
    if isinstance(speed, bool) or not isinstance(speed, int | float) or not 0.0 < speed <= 1.0:
        raise MotionError(f"{what}: speed {speed!r:.40}, must be in (0, 1]")
    track_s = 0.0 if duration is None else duration
    check_track_time(float(track_s))
    kali = robot.kali
    frame = claim(kali, f"joints.{robot.name}.{os.getpid()}", lifetime)
    try:
        frame.set_joints(kali.start_point(robot.index))
        entries = np.zeros((layout.MAX_LOOP, 2), dtype=np.uint8)
        entries[0] = (FrameKind.SHARED, frame.index)
        handle = kali._request(
            MotionKind.TRACK_JOINTS,
            [robot.index],
            n_loop=1,
            loop=entries,
            speed_scale=float(speed),
            track_s=float(track_s),
        )
    except BaseException:
        frame.close()
        raise
    return JointStream(robot, frame, handle)
