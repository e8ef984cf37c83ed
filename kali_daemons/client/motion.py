"""Motion requests from user programs to the trajectory generator (thesis 3.3.2, DESIGN 5).

    from kali_daemons.client import Kali
    with Kali("default") as kali:
        left = kali.robot("left")
        left.move_joints(np.radians([0, 45, -180, 0, 45, 0]))       # blocks until there
        m = left.move_joints(target, speed=0.3, wait=False)        # a handle
        m.wait(timeout=5.0)
        here = left.read_pose()                                    # tool in the world, 4×4
        left.move_line(pose(here[:3, 3] + [0, 0.1, 0], here), speed=0.05)
        both = kali.motion_system(["left", "right"])               # grasps: as they hold now
        both.move_path([p1, p2, p3], speed=0.05, transition_s=0.3)

Poses are 4×4 transforms in the world frame, metres.  Everything is validated before it is
queued (``MotionError`` naming the argument; nothing moves), a halt wakes every waiting
program with the fault (``MotionFailedError``), and an arm belongs to the first program that
moves it.  The request protocol: docs/internals/motion-client-bridge.md.

Long on purpose: ``Kali``, ``Robot``, ``MotionSystem`` and ``MotionHandle`` share one request
protocol over one instance; what the other client modules share with them is in ``common``.
"""

from __future__ import annotations

import base64
import contextlib
import math
import os
import time
from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ..core import layout
from ..core.channels import RequestQueue
from ..core.errors import ConfigError, KaliError, KinematicsError, QueueFullError, ServoError
from ..core.layout import TERMINAL_STATES, CalibState, MotionKind, PowerState, RequestState
from ..core.spinlock import pid_alive
from ..robots import RobotType
from ..robots.cell import FLANGE_FRAME, base_transform, inverse, load_pinocchio
from ..robots.payload import write_load
from ..robots.scene import Scene
from ..runtime.instance import Instance, decode
from ..runtime.paths import log_dir
from ..servo import schedule
from ..servo.client import ServoClient
from ..servo.shadow import Trial
from ..tg import records
from ..tg.cartesian import CartesianMotion, encode_config, rotation_angle
from ..tg.functions import FunctionRegistry
from ..tg.functions import registry_for as functions_for
from ..tg.profiles import MotionError, check_guard, check_joint_target, rigid_pose
from ..wallclock import step_kali_clock
from . import periodic, remote, streams
from .camera import CameraView
from .common import (
    DEFAULT_INSTANCE,
    FT_FRAMES,
    INSTANCE_ENV,
    Contact,
    MotionFailedError,
    RequestLostError,
    _arcs_arg,
    _config_arg,
    _durations_arg,
    _flag_arg,
    _list_arg,
    _pose_arg,
    _real_array,
    _speed_arg,
    _timeout_arg,
    fault_since,
    program_name,
)
from .periodic import Control
from .remote import RemoteKali
from .state import ArmState, ObjectState, StateReader
from .streams import JointStream, SharedTransform, Stream, TgFunctionHandle
from .together import Together
from .truth import SimTruth

if TYPE_CHECKING:
    from ..robots.collision import CellGeometry
    from ..robots.scene import Clearance

POLL_S = 0.002  # how often a waiting program looks at its request's status
GRIP_TIMEOUT_S = 5.0  # a Franka Hand's grasp or opening takes up to ~2 s
GRIP_POLL_S = 0.005
RECORDED_CHUNK = 1 << 19  # bytes of a recording a remote program fetches per call
_ENDED = frozenset(int(s) for s in TERMINAL_STATES if s != RequestState.LOST)
# a tracking motion's limits unless the program gives its own: m/s, rad/s, m/s², rad/s²
TRACK_LIMITS = (0.25, 1.0, 1.0, 4.0)
LOCKSTEP_STEP = 10  # ticks a waiting program steps a lockstep instance's clock at a time
STOP_LANE_WAIT_S = 1.0  # longest a stop waits for room in the TG's stop lane (emptied every tick)
# Robot.settle: the flange within this of where its demand puts it, this long without a break
SETTLE_M = 2e-4
SETTLE_RAD = 1e-3
SETTLE_HOLD_S = 0.05


class MotionHandle:
    """One request: ``done``, ``state``, ``wait(timeout)``, ``cancel()``."""

    def __init__(self, kali: Kali, seq: int, robots: list[int], epoch: int | None = None) -> None:
        self.kali = kali
        self.seq = seq
        self.robots = robots
        # the fault count when it was put (None: now); a fault counted after it halts it
        self.epoch = int(kali.inst.fault["count"]) if epoch is None else epoch
        self._final: tuple[RequestState, str] | None = None  # the TG's last word, once read
        self._contact: Contact | None = None  # where a guarded move touched, once read
        self._released = False  # the TG was told it may reuse the status record
        self._rec = -1  # its status record, once found (the TG gives it one: tg/records.py)

    def _record(self) -> np.void | None:
        """This request's status record, or None: not taken by the TG yet, or given to
        another request since."""
        status = self.kali.status
        if self._rec < 0:
            self._rec = records.find(status, self.seq)
            if self._rec < 0:
                return None
        rec = status[self._rec]
        return rec if int(rec["seq"]) == self.seq else None

    def _read(self) -> tuple[RequestState, str]:
        """(state, message) as the TG wrote them, or HALTED with the fault when one has been
        raised since the request was put and the TG has not ended it yet (the TG cannot tick
        while halted; the process raising the fault does not know the requests)."""
        if self._final is not None:
            return self._final
        if self.seq == 0:  # made in a together() block that has not ended
            return RequestState.QUEUED, "not sent yet: its together() block has not ended"
        # the TG writes a request's record, then counts it taken: read in the other order, so
        # a request it takes between the two reads is not taken for one whose record is gone
        taken = int(self.kali.tg_state["taken_seq"])
        rec = self._record()
        state = RequestState.QUEUED  # still in the queue, or taken and not yet written
        if rec is not None:
            raw = int(rec["state"])
            message = decode(rec["message"])  # the TG writes the message before the state
            if raw in _ENDED and int(rec["seq"]) == self.seq:
                if raw == RequestState.CONTACT:  # read before the record is released
                    k = int(rec["contact_robot"])
                    self._contact = Contact(
                        self.kali.names[k],
                        rec["contact_xyz"].copy(),
                        float(rec["contact_force"]),
                        rec["contact_wrench"].copy(),
                    )
                self._final = (RequestState(raw), message)
                self._release()
                return self._final
            if raw in (RequestState.QUEUED, RequestState.RUNNING):
                state = RequestState(raw)
        elif self._rec >= 0 or self.seq <= taken:
            self._final = (
                RequestState.LOST,
                f"its outcome was not kept: the TG gave its status record to another request "
                f"(a program keeps at most {layout.STATUS_SHARE} outcomes unread, and when "
                f"every record is needed the oldest unread ones give way); read outcomes "
                f"(handle.state, wait) or drop the handles",
            )
            return self._final
        fault = fault_since(self.kali.inst, self.epoch)
        if fault is not None:
            return RequestState.HALTED, f"halted: {fault}"
        return state, ""

    def _release(self) -> None:
        """Tell the TG this program is done with the status record (once, and only while the
        record still holds this request: the TG cannot have reused it before)."""
        if self._released or self.seq == 0:
            return
        self._released = True
        if self.kali.status is not None:
            rec = self._record()
            if rec is not None:
                rec["read"] = 1

    def __del__(self) -> None:
        try:
            self._release()  # nobody can read it any more
        except Exception:
            pass

    @property
    def state(self) -> RequestState:
        """Where the request is (QUEUED until the TG has taken it; HALTED at once on a halt;
        LOST if its record was reused)."""
        return self._read()[0]

    @property
    def message(self) -> str:
        """Why it was refused, stopped or halted ('' otherwise)."""
        return self._read()[1]

    @property
    def contact(self) -> Contact | None:
        """Where a guarded move touched (it ended CONTACT), else None."""
        self._read()
        return self._contact

    @property
    def limited(self) -> int:
        """A tracking motion's ticks so far whose target moved faster than its limits allow
        (rate-limited); 0 for other motions."""
        rec = self._record()
        return 0 if rec is None else int(rec["limited"])

    @property
    def done(self) -> bool:
        """True once the request is over, however it ended."""
        return self.state in TERMINAL_STATES

    def wait(self, timeout: float | None = None) -> None:
        """Block until the motion has arrived, or a guarded one touched (``contact`` says
        where); MotionFailedError if it ended any other way (refused, stopped, aborted,
        halted: the message says why), TimeoutError after ``timeout`` s."""
        timeout = _timeout_arg(f"wait: request {self.seq}", timeout)
        if self.seq == 0:
            raise MotionError("wait: the request is sent when its together() block ends")
        deadline = None if timeout is None else time.monotonic() + timeout
        inst = self.kali.inst
        while (state := self.state) not in TERMINAL_STATES:  # one read: judged as it was seen
            if inst.shutting_down:  # nothing is left to finish it, or to say so
                raise MotionFailedError(
                    f"request {self.seq} {state.name.lower()}: instance '{inst.name}' was "
                    f"stopped (kalictl stop)"
                )
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(
                    f"motion: request {self.seq} not done within {timeout:g} s "
                    f"({state.name.lower()})"
                )
            self.kali.pause()
        if state == RequestState.LOST:
            raise RequestLostError(f"request {self.seq} lost: {self.message}")
        if state not in (RequestState.DONE, RequestState.CONTACT):
            raise MotionFailedError(f"request {self.seq} {state.name.lower()}: {self.message}")

    def cancel(self) -> None:
        """Stop the motion smoothly on its path (a queued one never starts)."""
        self.kali._order(MotionKind.STOP, self.robots)


def _guard_arg(what: str, guard: object, kali: Kali, robots: list[int]) -> float:
    """A guarded move's contact force (N; None: unguarded, 0.0), checked as the TG will
    (``check_guard``): every arm with a wrist sensor, the force below its contact limit."""
    if guard is None:
        return 0.0
    if isinstance(guard, bool) or not isinstance(guard, int | float):
        raise MotionError(f"{what}: guard {guard!r:.60}, must be a force in N")
    cfg = kali.inst.config
    limits = [None if r.ft.sheet is None else r.ft.contact_limit_n for r in cfg.robots]
    try:
        check_guard(float(guard), robots, kali.names, limits)
    except MotionError as exc:
        raise MotionError(f"{what}: {str(exc).removeprefix('motion: ')}") from None
    return float(guard)


def _name_arg(name: str, value: object) -> str:
    """A body's name for ``Kali.distance``; MotionError for anything but a string."""
    if not isinstance(value, str):
        raise MotionError(f"distance: {name} {value!r:.60} is not a body's name")
    return value


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


class Kali:
    """A user program's connection to a running instance (attach by name), or, with
    $KALI_REMOTE set (``kalictl run --remote``) or through ``Kali.connect``, to one on another
    machine through its Zenoh bridge (``remote.RemoteKali``: the same API)."""

    def __new__(cls, instance: str | None = None, force: bool = False) -> Kali:
        endpoint = os.environ.get(remote.REMOTE_ENV)
        if cls is Kali and endpoint:
            return remote.connect(endpoint, instance, force=force)  # type: ignore[return-value]
        return super().__new__(cls)

    @staticmethod
    def connect(endpoint: str, instance: str | None = None, **options: Any) -> RemoteKali:
        """Attach to ``instance`` on another machine through its bridge at Zenoh
        ``endpoint`` (``tcp/HOST:7447``); ``options``: force, user, password, root_ca,
        certificate, private_key (``remote.connect``)."""
        return remote.connect(endpoint, instance, **options)

    def __init__(self, instance: str | None = None, force: bool = False) -> None:
        """Attach to ``instance`` (default: $KALI_INSTANCE, set by ``kalictl run``, else
        'default').  ``force``: every request takes its arms over from the program owning
        them (``kalictl move --force``)."""
        self.force = force
        self.program = program_name()
        name = os.environ.get(INSTANCE_ENV, DEFAULT_INSTANCE) if instance is None else instance
        self.inst = Instance.attach(name)  # an empty name is refused, never the default
        try:
            self.servo = ServoClient(self.inst, pause=self._servo_tick, guard=self._schedule)
            arena = self.inst.arena
            self.queue = RequestQueue(
                arena,
                layout.KEY_MOTION_QUEUE,
                layout.MOTION_REQUEST,
                layout.MOTION_QUEUE_CAPACITY,
                share=("client_pid", layout.MOTION_QUEUE_SHARE),
            )
            self.stops = RequestQueue(
                arena,
                layout.KEY_STOP_QUEUE,
                layout.STOP_REQUEST,
                layout.STOP_QUEUE_CAPACITY,
                share=("client_pid", layout.STOP_QUEUE_SHARE),
            )
            self.tg_state = arena.record(layout.KEY_TG_STATE, layout.TG_STATE)
            self.status = arena.record(
                layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING
            )
            self.tg_robots = arena.record(
                layout.KEY_TG_ROBOTS, layout.TG_ROBOT, len(self.servo.names)
            )
            self.leases = arena.record(layout.KEY_TG_LEASES, layout.LEASE, len(self.servo.names))
            self.ft = arena.record(layout.KEY_FT, layout.FT_STATE, len(self.servo.names))
            self.loads = arena.record(layout.KEY_LOADS, layout.LOAD, len(self.servo.names))
            self.frames = arena.record(layout.KEY_TG_FRAMES, layout.SHARED_FRAME, layout.MAX_FRAMES)
            self.functions = arena.record(
                layout.KEY_TG_FUNCTIONS, layout.TG_FUNCTION, layout.MAX_FUNCTIONS
            )
            self.fifos = [self.servo.level.fifo(k) for k in range(len(self.servo.names))]
        except KaliError:
            self.inst.close()
            raise
        self.names = self.servo.names
        self.held_frames: dict[int, SharedTransform] = {}  # the shared transforms it writes
        self.held_functions: dict[int, TgFunctionHandle] = {}  # the TG functions it set up
        self._functions: FunctionRegistry | None = None  # loaded on first use
        self._state_reader: StateReader | None = None  # made at the first read_state
        self._recording: Path | None = None  # this program's last recording
        self.sim = SimTruth(self)  # the simulator's truth (kali.sim.truth(robot))
        self.grouping: Together | None = None  # a together() block being written
        self.tg_dt = self.inst.config.clock.tg_period_ms / 1000.0
        self._pin: dict[str, tuple] = {}  # per robot type: Pinocchio model, data, flange frame
        self._geometry: CellGeometry | None = None  # the collision model, made at first use
        self.controls: list[Control] = []  # the periodic functions it started (control)

    def robot(self, name: str) -> Robot:
        """The arm called ``name``; ServoError naming the robots otherwise."""
        return Robot(self, self.servo.robot_index(name))

    def camera(self, name: str) -> CameraView:
        """The cell's camera called ``name`` (its scene's ``cameras``): ``read()`` gives its
        latest frame (image, depth, tick, K, pose); HardwareError naming the cameras otherwise."""
        return CameraView(self.inst, name)

    def pause(self) -> None:
        """Let time pass while waiting: a short sleep, or in a lockstep instance a few ticks
        of its clock (nothing else steps it), so programs run there unchanged."""
        if self.inst.lockstep:
            step_kali_clock(self.inst, LOCKSTEP_STEP)
        else:
            time.sleep(POLL_S)

    def _schedule(self, what: str, step_us: float) -> None:
        """The schedulability check of a servo about to be loaded (``servo.load``): in real
        time, ScheduleError if a joint running it would not fit the servo tick."""
        if not self.inst.lockstep:
            schedule.guard(self.inst, schedule.Change(what, step_us), False, lambda _text: None)

    def _servo_tick(self) -> None:
        """Let one servo tick pass for a servo call waiting on it: in a lockstep instance
        one step of its clock (as ``pause`` steps it, finer), else a short sleep."""
        if self.inst.lockstep:
            step_kali_clock(self.inst, 1)
        else:
            time.sleep(POLL_S)

    def sleep(self, seconds: float) -> None:
        """Let ``seconds`` pass: a sleep, or in a lockstep instance its clock stepped that long
        (nothing else steps it), so a program that waits for something to settle runs there
        unchanged.  MotionError for a time that is not finite and >= 0."""
        if isinstance(seconds, bool) or not isinstance(seconds, int | float):
            raise MotionError(f"sleep: {seconds!r:.60} is not a time in s")
        if not (math.isfinite(seconds) and seconds >= 0.0):
            raise MotionError(f"sleep: {seconds} s, must be a finite time >= 0")
        if self.inst.lockstep:
            tick_ms = self.inst.config.clock.base_tick_ms
            step_kali_clock(self.inst, round(seconds * 1000.0 / tick_ms))
        else:
            time.sleep(seconds)

    def ready(self, names: Sequence[str] | None = None, timeout: float = 30.0) -> None:
        """Power the robots ``names`` (default: all) and calibrate those not calibrated yet,
        waiting until they are; ServoError with the reason otherwise (thesis 3.5.1)."""
        names = list(self.names) if names is None else _list_arg("ready", "names", names)
        for n in names:
            self.servo.robot_index(n)  # ServoError naming the robots for any other
        limit = _timeout_arg("ready", timeout)
        deadline = time.monotonic() + (math.inf if limit is None else limit)

        def wait_until(done: Callable[[], bool], what: str, why: Callable[[], str]) -> None:
            while not done():
                if self.inst.fault["active"]:
                    raise ServoError(f"{what}: the system halted: {self.inst.fault_text()}")
                if self.inst.shutting_down:
                    raise ServoError(
                        f"{what}: instance '{self.inst.name}' was stopped (kalictl stop)"
                    )
                if time.monotonic() > deadline:
                    raise ServoError(f"{what}: not done within {timeout:g} s ({why()})")
                self.pause()

        for n in names:
            if self.servo.power_state(n) != PowerState.ON:
                self.servo.power(n, True)
        wait_until(
            lambda: all(self.servo.power_state(n) == PowerState.ON for n in names),
            f"power {', '.join(names)}",
            lambda: "; ".join(self.servo.power_text(n) for n in names),
        )
        todo = [n for n in names if not self.servo.calibrated(n)]
        for n in todo:
            self.servo.calibrate(n)

        def calibrated() -> bool:
            states = [self.servo.calibration(n) for n in todo]
            failed = [
                f"{n}: {m}"
                for n, (s, _, m) in zip(todo, states, strict=True)
                if s == CalibState.FAILED
            ]
            if failed:
                raise ServoError(f"calibration failed: {'; '.join(failed)}")
            return all(s == CalibState.DONE for s, _, _ in states)

        wait_until(
            calibrated,
            f"calibrate {', '.join(todo)}",
            lambda: "; ".join(f"{n}: {self.servo.calibration(n)[2]}" for n in todo),
        )

    def distance(self, a: str, b: str) -> Clearance:
        """The clearance between two bodies of the cell with the arms at their measured
        joints: an arm (``"left"``), one of its links (``"left/link3"``) or a scene object
        (``"table"``), from the controller's collision model (``robots.collision``: the URDFs'
        collision shapes, the scene's objects where they were built).  MotionError naming the
        bodies for one the cell does not have."""
        if self._geometry is None:
            from ..robots.collision import CellGeometry  # here: coal, on first use only

            self._geometry = CellGeometry(self.inst.config.robots, self.scene)
        qs = [self.servo.level.arm("q", k).copy() for k in range(len(self.names))]
        try:
            return self._geometry.distance(_name_arg("a", a), _name_arg("b", b), qs)
        except ConfigError as exc:
            raise MotionError(str(exc).removeprefix("config: ")) from None

    @property
    def scene(self) -> Scene:
        """The cell's world (``robots.scene``): its objects, where they were built, their
        grasps."""
        return self.inst.config.scene

    def held_load(
        self, what: str, holding: str, robots: Sequence[Robot]
    ) -> list[tuple[tuple[float, np.ndarray, np.ndarray], np.ndarray]]:
        """Per arm of ``robots`` holding the scene's object ``holding`` together: its share
        of the object's load (mass, centre of mass, inertia: ``set_load``'s arguments) and its
        grasp (the flange in the object's frame).  MotionError naming the scene's objects for
        one it does not have."""
        try:
            obj = self.scene.object(holding) if isinstance(holding, str) else None
            if obj is None:
                raise ConfigError(f"{holding!r} is not an object's name")
            cfgs = self.inst.config.robots
            grasps = [self.scene.grasp_for(holding, cfgs[r.index]) for r in robots]
        except ConfigError as exc:
            reason = str(exc).removeprefix("config: ")
            raise MotionError(f"{what}: holding {holding!r}: {reason}") from None
        share = 1.0 / len(robots)
        return [(obj.load_on(grasp, share), grasp) for grasp in grasps]

    def motion_system(
        self,
        names: Sequence[str],
        grasps: Sequence[np.ndarray] | None = None,
        holding: str | None = None,
    ) -> MotionSystem:
        """Arms ``names`` holding one object.  ``grasps[k]`` is arm k's flange in the
        object's frame; ``holding`` (an object of the scene, by name) takes each arm's from the
        scene (``Scene.grasp_for``) and sets each arm's load to its share of the object's mass
        and inertia (``Robot.set_load``: the arms hold it now); neither takes them from where
        the arms are now (their set-points), with the object's frame at the first arm's tool."""
        robots = [self.robot(n) for n in _list_arg("motion_system", "names", names)]
        if not robots or len({r.index for r in robots}) != len(robots):
            raise MotionError(f"motion_system: {list(names)}: name each arm once, at least one")
        if holding is not None:
            if grasps is not None:
                raise MotionError("motion_system: give grasps or the object held, not both")
            loads = self.held_load("motion_system", holding, robots)
            for robot, (load, _) in zip(robots, loads, strict=True):
                robot.set_load(*load, holding=holding)  # each its share: they hold it together
            return MotionSystem(self, robots, [grasp for _, grasp in loads], holding)
        if grasps is None:  # from the set-points the TG starts from, not the sagging arms
            flanges = [r.base @ r.type.kinematics.fkine(self.start_point(r.index)) for r in robots]
            obj = flanges[0] @ robots[0].tool
            grasps = [inverse(obj) @ f for f in flanges]
        else:
            grasps = _list_arg("motion_system", "grasps", grasps)
            grasps = [_pose_arg(f"motion_system: grasps[{i}]", g) for i, g in enumerate(grasps)]
            if len(grasps) != len(robots):
                raise MotionError(f"motion_system: {len(grasps)} grasps for {len(robots)} arms")
        return MotionSystem(self, robots, list(grasps))

    def run_conveyor(self, run: bool = True) -> None:
        """Start (or stop) the cell's conveyor belt (the simulated cell's
        ``plant.conveyor_m_s``): its motor line on the first arm's hardware."""
        self.inst.hardware(0).run_conveyor(_flag_arg("run_conveyor", "run", run))

    def together(self, *moves: Callable[[], object]) -> Together:
        """Motion requests that start together, on one TG tick (thesis 3.1): a block,
        ``with kali.together() as g: a.move_line(...); b.move_joints(...)``, or the moves as
        functions, ``g = kali.together(lambda: a.move_line(...), lambda: b.move_joints(...))``
        (Python runs a call's arguments first, so a move given as a plain call would be sent
        before ``together`` could hold it back); then ``g.wait()`` (all) or
        ``g.wait(any=True)`` (the first over).  Moves in the group do not wait; they are
        sent when the block ends, or at once for the functional form."""
        group = Together(self)
        if not moves:
            return group
        for i, move in enumerate(moves):
            if not callable(move):
                raise MotionError(
                    f"together: moves[{i}] is {move!r:.60}; give functions (lambda: a.move_"
                    f"line(...)), or use the block form (with kali.together() as g: ...)"
                )
        with group:
            for move in moves:
                move()
        return group

    def shared_transform(
        self,
        name: str,
        pose: np.ndarray | None = None,
        lifetime: float = streams.DEFAULT_LIFETIME_S,
    ) -> SharedTransform:
        """A shared transform ``name`` this program writes (``set``) for tracking motions
        to read every TG tick (thesis 3.2.3), first set to ``pose`` if given; a motion
        tracking it stops on its path once it is older than ``lifetime`` s (0: never
        stale).  MotionError if a live program holds ``name`` or all records are held."""
        frame = streams.claim(self, name, lifetime)
        if pose is not None:
            try:
                frame.set(pose)
            except BaseException:
                frame.close()
                raise
        return frame

    def find_transform(self, name: str) -> SharedTransform:
        """The shared transform ``name`` another running program writes (a hand controller,
        a sensor process), to name in a ``track`` loop; MotionError if none is written."""
        return streams.find(self, name)

    def tg_function(
        self, function: str, name: str | None = None, **params: float
    ) -> TgFunctionHandle:
        """Set up TG function ``function`` (``conveyor``, ``line``, ``sine`` or a config
        plugin's ``tg_functions``) with ``params`` (the rest at their defaults), its time t
        from now; name the handle in a ``track`` loop and the TG evaluates it there every
        tick (thesis 3.2.3).  ``name``: this program's label for it (messages name it)."""
        return streams.set_up_function(self, function, name, params)

    def function_registry(self) -> FunctionRegistry:
        """The TG functions this instance knows: the built-ins and the config's plugins
        (loaded on first use, as the TG loaded them)."""
        if self._functions is None:
            cfg = self.inst.config
            self._functions = functions_for(cfg.tg_functions, cfg.base_dir, cfg.files)
        return self._functions

    def control(
        self,
        func: Callable[[int], object],
        period_ms: float = 10.0,
        serious: bool = False,
        name: str | None = None,
        *,
        cpu: int | None = None,
        priority: int = 0,
    ) -> Control:
        """Run ``func(tick)`` every ``period_ms`` on the wall clock while this program goes
        on (thesis 3.6.2 ``control``), in a thread of this program (``periodic``): returns
        its handle at once, registered (the clock signals it from its next tick; in lockstep
        the clock steps, as the program waits, only with it acknowledged).  It ends on
        ``release(message)``, when it returns False, when it raises (a serious one halts the
        system naming it; another is released, ``error`` saying why) and at ``close``.
        ``name``: its process-table name (default ``prog.<pid>.<n>``); ``cpu`` and
        ``priority`` (SCHED_FIFO, 0: none) are the thread's own.  ClockError for a bad
        argument (a period not a whole number of base ticks, a name taken)."""
        control = periodic.start(self, func, period_ms, serious, name, cpu, priority)
        self.controls = [c for c in self.controls if c.running] + [control]
        return control

    def release_controls(self, message: str = "") -> None:
        """Release every function this program's ``control`` started that still runs, each
        with ``message`` (``Control.release``).  Never raises (``close`` calls it): one
        still inside its call is logged, and ends when that call returns."""
        for control in self.controls:
            try:
                control.release(message)
            except KaliError as exc:  # a ClockError
                periodic.log.warning("%s", exc)
        self.controls = []

    def flange_pose(self, q: np.ndarray, robot: int = 0) -> np.ndarray:
        """T6 (flange in the base frame) of robot ``robot``'s joints ``q``, by Pinocchio's
        model of its type (loaded on first use)."""
        import pinocchio as pin  # here: a program that never asks pays nothing for it

        rcfg = self.inst.config.robots[robot]
        if rcfg.model not in self._pin:  # by model: two type files may share a ROBOT.name
            model = load_pinocchio(rcfg.type)
            self._pin[rcfg.model] = (model, model.createData(), model.getFrameId(FLANGE_FRAME))
        model, data, frame = self._pin[rcfg.model]
        pin.framesForwardKinematics(model, data, np.asarray(q, dtype=np.float64))
        return np.array(data.oMf[frame].homogeneous)

    def idle(self, robots: Sequence[int]) -> bool:
        """True when no motion is running or waiting for any of ``robots`` (and the queue
        is empty), so a new request's start is where they are now."""
        busy = self.tg_robots["busy_seq"]
        return all(int(busy[k]) == 0 for k in robots) and len(self.queue) == 0

    @contextlib.contextmanager
    def record(self, path: str | os.PathLike[str]) -> Iterator[dict[str, object]]:
        """Record every servo tick of every arm to the new MCAP file ``path`` while the block
        runs (``kali_daemons.recording``: joint states, wrenches and every servo quantity as
        ROS 2 messages any MCAP tool opens); the dict it gives is filled with the recording's
        final status when the block ends (``ticks``, ``gaps``, ``bytes``, ``error``)."""
        self.start_recording(path)
        status: dict[str, object] = {}
        try:
            yield status
        finally:
            status.update(self.stop_recording())

    def start_recording(self, path: str | os.PathLike[str] | None = None) -> str:
        """Start recording to the new file ``path`` (None: a new ``rec-*.mcap`` in the
        instance's log directory); its path.  ``record`` is the block form."""
        from ..recording import recorder  # here: mcap only when recording

        if path is None:
            stamp = time.strftime("%Y%m%d-%H%M%S")
            path = log_dir(self.inst.name) / f"rec-{self.inst.name}-{stamp}.mcap"
        self._recording = Path(path).absolute()
        recorder.start(self.inst, self._recording)
        return str(self._recording)

    def record_in_log_dir(self) -> str:
        """``start_recording`` into the log directory: what a remote program asks for (it
        names no path on this machine), fetching the file with ``recorded_bytes``."""
        return self.start_recording(None)

    def stop_recording(self) -> dict[str, object]:
        """Stop the recording: what is left is drained and the file finished; its status."""
        from ..recording import recorder  # here: mcap only when recording

        return recorder.stop(self.inst)

    def recorded_bytes(self, offset: int, size: int = RECORDED_CHUNK) -> str:
        """Up to ``size`` bytes of this program's last recording from ``offset``, base64 (a
        remote program fetches its recording so); '' at the end."""
        if self._recording is None:
            raise KaliError("recorded_bytes: this program has made no recording")
        if isinstance(offset, bool) or not isinstance(offset, int) or offset < 0:
            raise KaliError(f"recorded_bytes: offset {offset!r:.40} is not a byte count")
        size = max(1, min(int(size), RECORDED_CHUNK))
        with open(self._recording, "rb") as f:
            f.seek(offset)
            return base64.b64encode(f.read(size)).decode()

    def state_reader(self) -> StateReader:
        """The reader of the arms' states (``Robot.read_state``), made at the first read."""
        if self._state_reader is None:
            self._state_reader = StateReader(self)
        return self._state_reader

    def start_point(self, k: int) -> np.ndarray:
        """Where robot ``k``'s next motion starts when it is idle: the TG's last set-point
        while SIO is still interpolating towards it, else SIO's demand (as the TG does); one
        angle per joint of its type."""
        span = self.inst.config.joints.span(k)
        if self.fifos[k].pending():
            return self.tg_robots["setpoint"][k, : span.stop - span.start].copy()
        return self.servo.level.joints["demand"][span].copy()

    def owner(self, k: int) -> tuple[int, str] | None:
        """(pid, program name) of the live program owning robot ``k``, or None."""
        lease = self.leases[k]
        pid = int(lease["pid"])
        return (pid, decode(lease["name"])) if pid_alive(pid) else None

    def owned_by(self, pid: int) -> list[int]:
        """The robots program ``pid`` owns."""
        return [k for k in range(len(self.names)) if int(self.leases["pid"][k]) == pid]

    def _order(self, kind: MotionKind, robots: list[int], force: bool = False) -> int:
        """A STOP or ABORT of ``robots`` through the TG's stop lane (``tg.stops``): taken
        before any other request, it also cancels their requests this program or another put
        before it; nobody waits on its outcome (``stopped`` tells when it is carried out).
        Its seq in the lane, or 0 while the system is halted: nothing moves then, and the TG
        ends every motion.  A full lane (it is emptied every TG tick) is waited for, ~1 s at
        most, then QueueFullError."""
        epoch = int(self.inst.fault["count"])
        if fault_since(self.inst, epoch) is not None:
            return 0
        req = np.zeros((), dtype=layout.STOP_REQUEST)
        req["kind"] = kind
        req["flags"] = layout.REQUEST_UNWATCHED | (
            layout.REQUEST_FORCE if force or self.force else 0
        )
        req["n_robots"] = len(robots)
        req["robots"][: len(robots)] = robots
        req["client_pid"] = os.getpid()
        req["client_name"] = self.program
        req["fault_epoch"] = epoch
        req["before_seq"] = self.queue.put_seq()
        deadline = time.monotonic() + STOP_LANE_WAIT_S
        while True:
            try:
                return self.stops.put(req)
            except QueueFullError:
                if time.monotonic() > deadline:
                    raise
                self.pause()

    def stop_own(self) -> int:
        """Stop the arms this program owns on their paths (a remote program's ``with`` block
        does as it ends on Ctrl-C); the stop's seq (``stopped``), 0 if none."""
        return self.stop_robots(self.owned_by(os.getpid()))

    def stop_robots(self, robots: Sequence[int], force: bool = False) -> int:
        """Stop ``robots`` (indices) on their paths; ``force`` takes them over from the
        program that owns them (``kalictl run`` on Ctrl-C).  The stop's seq in the stop
        lane, for ``stopped`` (0: nothing to stop, or halted)."""
        return self._order(MotionKind.STOP, list(robots), force) if robots else 0

    def stopped(self, robots: Sequence[int], seq: int) -> bool:
        """Whether the stop ``seq`` (``stop_robots``) has been carried out on ``robots`` and
        they are at rest: no motion left on them.  True at once while halted (the
        amplifiers are cut)."""
        if self.inst.fault["active"] or seq == 0:
            return True
        done = self.tg_robots["stop_seq"]
        busy = self.tg_robots["busy_seq"]
        return all(int(done[k]) >= seq and int(busy[k]) == 0 for k in robots)

    def _request(
        self, kind: MotionKind, robots: list[int], flags: int = 0, **fields: object
    ) -> MotionHandle:
        """Put one request; MotionFailedError while the system is halted (it would only be
        halted: the TG is stopped), QueueFullError when the TG cannot take more yet."""
        epoch = int(self.inst.fault["count"])
        fault = fault_since(self.inst, epoch)
        if fault is not None:
            raise MotionFailedError(
                f"{kind.name.lower()} request refused: the system is halted ({fault}); "
                f"kalictl reset first"
            )
        req = np.zeros((), dtype=layout.MOTION_REQUEST)
        req["kind"] = kind
        req["flags"] = flags | (layout.REQUEST_FORCE if self.force else 0)
        req["n_robots"] = len(robots)
        req["robots"][: len(robots)] = robots
        req["client_pid"] = os.getpid()
        req["client_name"] = self.program
        req["fault_epoch"] = epoch
        for name, value in fields.items():
            if name == "joints":  # one row per robot, its joint count of the record's columns
                for i, row in enumerate(cast("Sequence[np.ndarray]", value)):
                    req["joints"][i, : len(row)] = row
            elif name in ("grasps", "config"):  # one per robot of the request
                req[name][: len(robots)] = value
            else:
                req[name] = value
        if self.grouping is not None:  # sent with its group when the block ends
            handle = MotionHandle(self, 0, robots, epoch)
            self.grouping.add(req, handle)
            return handle
        seq = self.queue.put(req)
        return MotionHandle(self, seq, robots, epoch)

    def close(self) -> None:
        """Detach (the motions already requested go on; those tracking this program's
        shared transforms stop once their lifetime passes); its periodic functions are
        released first."""
        self.release_controls()
        for frame in list(self.held_frames.values()):
            frame.close()
        for function in list(self.held_functions.values()):
            function.close()
        self.frames = None  # type: ignore[assignment]
        self.functions = None  # type: ignore[assignment]
        self.servo.close()
        self.tg_robots = None  # type: ignore[assignment]
        self.fifos = []
        self.status = None  # type: ignore[assignment]
        self.tg_state = None  # type: ignore[assignment]
        self.stops = None  # type: ignore[assignment]
        self.leases = None  # type: ignore[assignment]
        self.ft = None  # type: ignore[assignment]
        self.queue = None  # type: ignore[assignment]
        self.inst.close()

    def __enter__(self) -> Kali:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()
