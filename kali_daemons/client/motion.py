"""``Kali``: a user program's connection to an instance, putting its motion requests to the
trajectory generator (thesis 3.3.2, DESIGN 5).  An arm's moves are ``robot.Robot``'s, a motion
system's ``system.MotionSystem``'s, a request's handle ``handle.MotionHandle``; the protocol
and an example: docs/internals/motion-client-bridge.md.  Long on purpose: ``Kali`` is one
class, the program's whole view of its instance.
"""

from __future__ import annotations

import base64
import contextlib
import math
import os
import time
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, Any, cast

import numpy as np

from ..core import layout
from ..core.channels import RequestQueue
from ..core.errors import ConfigError, KaliError, QueueFullError, ServoError
from ..core.layout import CalibState, MotionKind, PowerState
from ..core.spinlock import pid_alive
from ..robots.cell import FLANGE_FRAME, inverse, load_pinocchio
from ..robots.scene import Scene
from ..runtime.instance import Instance, decode
from ..runtime.paths import log_dir
from ..servo import schedule
from ..servo.client import ServoClient
from ..tg.functions import FunctionRegistry
from ..tg.functions import registry_for as functions_for
from ..tg.profiles import MotionError
from ..wallclock import step_kali_clock
from . import periodic, remote, streams
from .camera import CameraView
from .common import (
    DEFAULT_INSTANCE,
    INSTANCE_ENV,
    MotionFailedError,
    _flag_arg,
    _list_arg,
    _name_arg,
    _pose_arg,
    _timeout_arg,
    fault_since,
    program_name,
)
from .handle import MotionHandle
from .periodic import Control
from .remote import RemoteKali
from .robot import Robot
from .state import StateReader
from .streams import SharedTransform, TgFunctionHandle
from .system import MotionSystem
from .together import Together
from .truth import SimTruth

if TYPE_CHECKING:
    from ..robots.collision import CellGeometry
    from ..robots.scene import Clearance


POLL_S = 0.002  # how often a waiting program looks at its request's status
RECORDED_CHUNK = 1 << 19  # bytes of a recording a remote program fetches per call
LOCKSTEP_STEP = 10  # ticks a waiting program steps a lockstep instance's clock at a time
STOP_LANE_WAIT_S = 1.0  # longest a stop waits for room in the TG's stop lane (emptied every tick)


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
