"""The trajectory generator's cycle logic (thesis 3.3.1, 2.2.1; DESIGN 5): one process computes
the set-points of every motion system each TG tick, time-sharing them (``Planner``; its
process shell is ``daemon.TrajectoryGenerator``).

Requests come through the Type 1 queue ``tg.requests`` (3.3.2), stops and aborts through
their own lane ``tg.stops``, emptied first; each request's fate goes to a status record of
``tg.status`` (``records``).  Arms are owned (``tg.leases``) by the first live program that
moves them.  Every request is validated again here (``requests.check_request``): the arena is
never trusted, and a request these checks cannot place is refused, never a halt.  A motion
runs on its path time τ; its set-point goes into each robot's TG → SIO FIFO (Type 2), kept one
set-point ahead of SIO.  A Cartesian path is walked whole before it starts, within a share of
each tick.  Allocation happens only when a request is accepted.  The rules in full:
docs/internals/motion-client-bridge.md.

Long on purpose: the TG's one cycle, every step of it on one class's state; a request's checks
are in ``requests``, the motions' laws in ``profiles``, ``cartesian`` and ``tracking``.
"""

from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from ..core import atomic, layout, rt
from ..core.channels import InterpolatingFifo, RequestQueue
from ..core.errors import KinematicsError
from ..core.layout import (
    CalibState,
    FaultCode,
    GuardState,
    MotionKind,
    PowerState,
    RequestState,
    TgPhase,
)
from ..core.spinlock import pid_alive
from ..robots.cell import base_transform
from ..robots.chain import chain_of, flange_pose
from ..robots.collision import CellClearance, CellGeometry, ClearanceWalk
from ..runtime.config import MAX_PERIOD_MS, ms_to_ns
from ..runtime.instance import Instance, decode
from ..servo.level import FIFO_CAPACITY
from .cartesian import CartesianMotion
from .clearance import JointMoveCheck
from .functions import FUNCTION_SHARE, FunctionSlots, Sensors, registry_for
from .profiles import (
    JointMotion,
    MotionError,
    StopRamp,
)
from .records import StatusRecords, write_status
from .requests import check_request, plan_joints, plan_path, refusal, request_robots
from .tracking import (
    SharedFrames,
    Tracking,
    plan_tracking,
)

MAX_REQUESTS_PER_TICK = 8  # requests taken from the queue per tick (the rest wait a tick)
STOP_TIME_S = 0.3  # a stop ramps the path speed to zero over this long
DEAD_GROUPS = 64  # refused groups remembered, so their late members are refused too
LEAD = 2  # set-points kept in each FIFO ahead of SIO
CALIBRATING = (CalibState.SEARCH, CalibState.SETTLE, CalibState.POTS)
UNCHECKED_CLEARANCE = "KALI_TEST_UNCHECKED_CLEARANCE"  # set: no clearance check (tests only)
CHECK_SHARE = 0.25  # of each TG period spent checking Cartesian paths before they start
# The tick's share (CHECK_SHARE of its period) is spent taking requests, planning paths and
# checking them, in that order; in lockstep it is counted in path samples, not wall time (about
# what a 10 ms tick's share checks in real time): planning a path counts as PLAN_SAMPLES,
# taking a request as REQUEST_WORK (docs/decisions/0009-tg-check-share.md).
LOCKSTEP_CHECK_SAMPLES = 64
PLAN_SAMPLES = 32
REQUEST_WORK = 1  # a request taken costs about what one two-arm path sample does
_TRACKING = (MotionKind.TRACK, MotionKind.TRACK_JOINTS)
MOVES = (MotionKind.JOINTS, MotionKind.PATH, *_TRACKING)  # kinds that move arms (and own them)
_ENDED = frozenset(int(s) for s in layout.TERMINAL_STATES)


@dataclass
class Motion:
    """One accepted request: the robots it moves and its profile.  A joint motion samples
    into ``out`` (its robots' joints one after another); ``rows`` are ``out``'s views of each
    robot's joints, bound once (``joint_rows``) so the cycle slices nothing."""

    seq: int
    robots: list[int]
    profile: JointMotion | CartesianMotion | Tracking
    checking: bool = False  # still being checked (``check``): the arms hold
    check: CartesianMotion | JointMoveCheck | None = None  # what walks it before it starts
    ending: RequestState | None = None  # the last set-point is pushed: DONE/STOPPED when
    ending_message: str = ""  # SIO has taken it (the demand is there), not before
    guard: float = 0.0  # N: the contact force that stops it on any of its arms (0: none)
    tau: float = 0.0
    stop: StopRamp | None = None
    stop_t: float = 0.0
    out: np.ndarray = field(default_factory=lambda: np.zeros(0))
    rows: list[np.ndarray] = field(default_factory=list)
    group: int = 0  # started together with the other motions of this group (0: none)
    group_wait: bool = False  # planned (and checked): waits for the rest of its group
    # continuous motion (3.1): the next request on the same arms, planned from this one's end
    # and started ``overlap`` s before it, the two summed meanwhile (``_blend``)
    successor: Motion | None = None
    predecessor: Motion | None = None  # of a successor: the motion it continues
    overlap: float = 0.0
    blending: bool = False  # a successor whose window has begun: it runs, summed
    stepped: int = -1  # the tick its set-point was last computed (once a tick)
    tracking: bool = False  # a TRACK or TRACK_JOINTS motion (``profile`` a ``Tracking``)


def joint_rows(widths: Sequence[int]) -> tuple[np.ndarray, list[np.ndarray]]:
    """A joint motion's ``out`` for robots of ``widths`` joints, and its per-robot views
    (outside the cycle: when the motion is accepted)."""
    out = np.zeros(sum(widths))
    ends = np.cumsum(widths)
    return out, [out[end - w : end] for w, end in zip(widths, ends, strict=True)]


class Planner:
    """The TG's cycle logic: takes requests, plans and checks them, and feeds the FIFOs every
    tick (``cycle``).  Plain state over the arena's records, laid over them outside the
    cycle (``__init__``, from the process's ``Instance``, its name and its process-table
    slot); the process shell (``daemon.TrajectoryGenerator``), the lockstep executive
    through it, and the tests drive the same ``cycle``."""

    def __init__(self, inst: Instance, name: str, slot: int) -> None:
        self.inst, self.name, self.slot = inst, name, slot
        cfg = inst.config
        arena = inst.arena
        self.names = [r.name for r in cfg.robots]
        self.n_robots = len(self.names)
        self.joint_map = cfg.joints  # robot k's joints: flat base[k] .. + counts[k]
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
        self.status = arena.record(
            layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING
        )
        self.records = StatusRecords(self.status)
        self._pending: tuple[int, np.void] | None = None  # taken, waiting for a record
        self.stop_request = np.zeros(1, dtype=layout.STOP_REQUEST)
        self.tg_robots = arena.record(layout.KEY_TG_ROBOTS, layout.TG_ROBOT, self.n_robots)
        # per robot: requests put in the queue before this seq are cancelled (a stop lane's)
        self._cancel_below = [0] * self.n_robots
        self.state = arena.record(layout.KEY_TG_STATE, layout.TG_STATE)
        self._longest = self.state["longest_ns"].reshape(1)
        self._phase = self.state["phase"].reshape(1)
        self._phase_seq = self.state["phase_seq"].reshape(1)
        self._phase_ns = self.state["phase_ns"].reshape(1)
        self.leases = arena.record(layout.KEY_TG_LEASES, layout.LEASE, self.n_robots)
        self._lease_pid = self.leases["pid"]
        self.lockstep = inst.lockstep
        self._work = 0  # lockstep: path samples checked (and plans) this tick
        self._now = 0  # this tick
        # field views taken once: indexing a record by name builds a new view every time
        # each robot's set-point: as many of the record's MAX_JOINTS columns as it has joints
        setpoints = self.tg_robots["setpoint"]
        self._setpoint_of = [setpoints[k, :n] for k, n in enumerate(self.joint_map.counts)]
        self._demand_of: list[np.ndarray] = []  # SIO's demands per robot, once attached
        self._q_of: list[np.ndarray] = []  # SIO's measured joints per robot, once attached
        self._progress = self.status["progress"]
        self._tick = self.tg_robots["tick"]
        ratio = Fraction(ms_to_ns(cfg.clock.tg_period_ms), ms_to_ns(cfg.clock.servo_period_ms))
        self.fifos = [
            InterpolatingFifo(arena, layout.KEY_FIFO.format(robot=name), n, FIFO_CAPACITY, ratio)
            for name, n in zip(self.names, self.joint_map.counts, strict=True)
        ]
        # SIO's records, once SIO has created them: None before, while every tick returns at
        # once (so the methods it calls take them as laid out)
        self.robots: np.ndarray = None  # type: ignore[assignment]
        self.dt = cfg.clock.tg_period_ms / 1000.0
        self.check_ns = int(CHECK_SHARE * ms_to_ns(cfg.clock.tg_period_ms))
        self._check_until = 0  # monotonic ns: when this tick's check share ends (cycle)
        # kalictl rate tg MS changes the period in the registry slot: _follow_rate reads it
        self._own_period = inst.procs["period_ticks"][self.slot, ...]  # 0-d view
        self._period_followed = 0  # none yet: the first cycle sets the FIFOs' ratio
        self._base_ns = int(inst.clock["base_tick_ns"])
        self._servo_ns = ms_to_ns(cfg.clock.servo_period_ms)
        self._max_period_ns = ms_to_ns(MAX_PERIOD_MS)
        self.bases = [base_transform(r.base_xyz, r.base_yaw_deg) for r in cfg.robots]
        self.request = np.zeros(1, dtype=layout.MOTION_REQUEST)
        self.types = [r.type for r in cfg.robots]
        # guarded moves: each arm's wrist-sensor record, where SIO trips the TG's guard
        self.contact_limits = [
            None if r.ft.sheet is None else r.ft.contact_limit_n for r in cfg.robots
        ]
        self.ft = arena.record(layout.KEY_FT, layout.FT_STATE, self.n_robots)
        self._guard_state = self.ft["guard_state"]
        self._cas = atomic.CompareExchange32()
        self._chains = [chain_of(t) for t in self.types]  # where a guarded move touched
        self._tips = [r.ft.tool_tip_m for r in cfg.robots]
        self.frames = SharedFrames(
            arena.record(layout.KEY_TG_FRAMES, layout.SHARED_FRAME, layout.MAX_FRAMES),
            self._base_ns,
        )
        self.functions = FunctionSlots(
            arena.record(layout.KEY_TG_FUNCTIONS, layout.TG_FUNCTION, layout.MAX_FUNCTIONS),
            registry_for(cfg.tg_functions, cfg.base_dir, cfg.files),
            Sensors(self.names, [], []),  # SIO's records once it has laid them out
            self._base_ns,
            self.lockstep,
        )
        self.functions.evaluating = self.state["phase_function"].reshape(1)
        self._limited = self.status["limited"]
        # a blend's scratch: each path's pose, the sum, two rotations
        self._blend_poses = (np.eye(4), np.eye(4), np.eye(4), np.eye(3), np.eye(3))
        self.motions: list[Motion] = []
        self.waiting: list[tuple[int, np.void]] = []  # accepted, robots still busy
        self._groups: dict[int, tuple[int, set[int]]] = {}  # group -> (size, its robots)
        self._dead_groups: dict[int, str] = {}  # refused groups (the latest DEAD_GROUPS)
        self._faults_seen = int(inst.fault["count"])
        # the cell's bodies, for each motion's clearance check before it starts (None: no
        # check, a test's switch only: the plant's crash, driven on purpose)
        self.clearance: CellClearance | None = None
        if not os.environ.get(UNCHECKED_CLEARANCE):
            self.clearance = CellClearance(CellGeometry(cfg.robots, cfg.scene))
        # what each arm holds (its load record names the scene object) and the clearances
        # with those objects' shapes on the arms, one model per set of them, made once
        self._held = inst.arena.existing(layout.KEY_LOADS, layout.LOAD, self.n_robots)["held"]
        self._clearances: dict[tuple[int, ...], CellClearance] = {}
        self._robots, self._scene = cfg.robots, cfg.scene
        self._warm_up()

    def _warm_up(self) -> None:
        """Plan, check and sample one short Cartesian path and one joint move (outside the
        cycle): numpy's first matrix product starts its BLAS, which under ``mlockall`` faults
        in and locks its buffers, 20-30 ms, once; the first real motion must not pay that."""
        for t in {t.name: t for t in self.types}.values():
            q = t.q_home.copy()
            start = t.kinematics.fkine(q)
            target = start.copy()
            target[2, 3] += 0.01
            plan = CartesianMotion(
                ["warm-up"], [t], [np.eye(4)], [np.eye(4)], q[None], [None], [target], 0.1, 0.5,
                0.0, self.dt,
            )  # fmt: skip
            plan.check_all()
            plan.sample(0.5 * plan.duration)
            JointMotion(q, q + 0.01, t.qd_max, t.qdd_max).sample(0.01, np.zeros(t.n_joints))

    # ------------------------------------------------------------------ status records

    def _say(self, seq: int, state: RequestState, message: str = "") -> None:
        """Request ``seq``'s state into its record; an ended one's record is its program's
        from here on (``StatusRecords.release``), and another request's once read, so a
        request that has ended already is never written again."""
        if not self.records.holds(seq):
            return
        write_status(self.records[seq], seq, state, message)
        if int(state) in _ENDED:
            self.records.release(seq)

    # ------------------------------------------------------------------ the tick

    def cycle(self, tick: int) -> None:
        """Halts first, then new requests, then every running motion's next set-point; the
        tick's parts timed, and kept if it is the longest yet (``TG_STATE.longest_*``)."""
        t0, c0 = rt.monotonic_ns(), rt.thread_time_ns()
        self._at(TgPhase.REQUESTS, 0, t0)
        self._follow_rate()  # first: a changed period's share is this tick's
        self._check_until = t0 + self.check_ns  # the whole tick's share (_spent)
        self._work = 0
        self._now = tick
        if self.robots is None:
            self.robots = self._attach_robots()
            if self.robots is None:
                return  # SIO has not laid the servo level out yet
        count = int(self.inst.fault["count"])
        if int(self.inst.fault["active"]) or count != self._faults_seen:
            self._faults_seen = count
            self._halt_all()
        self._take_stops()  # first: a stop never waits behind other requests
        taken = 0
        for _ in range(MAX_REQUESTS_PER_TICK):
            if taken and self._spent():  # the rest wait in the queue: at least one a tick
                break
            if self._pending is None:
                seq = self.queue.get_into(self.request)
                if seq is None:
                    break
                self._pending = (seq, self.request[0].copy())
            seq, req = self._pending
            if self.records.allocate(seq, int(req["client_pid"])) is None:
                self._blocked(seq)  # every record holds a live request: the queue pushes back
                break
            self._pending = None
            self._phase_seq[0] = seq & 0xFFFFFFFF
            self._take(seq, req)
            self.state["taken_seq"] = seq  # after its record holds it (clients look there)
            self._work += REQUEST_WORK
            taken += 1
        if self._pending is None and int(self.state["blocked_seq"]):
            self.state["blocked_seq"] = 0
        self.state["evicted"] = self.records.evicted
        t1 = rt.monotonic_ns()
        self._at(TgPhase.STARTING, 0, t1)
        self._start_waiting()
        if self._groups:
            self._release_groups()
        t2 = rt.monotonic_ns()
        for m in list(self.motions):
            why = self._cannot_move(m.robots)
            if m.guard and self._tripped(m) >= 0:  # SIO holds its arms where they touched
                self._at(TgPhase.ENDING, m.seq, rt.monotonic_ns())
                self._end_motion(m, RequestState.CONTACT)
            elif why:  # SIO holds the arm or its demand follows it: the motion cannot go on
                self._at(TgPhase.ENDING, m.seq, rt.monotonic_ns())
                self._end_motion(m, RequestState.ABORTED, why)
            elif m.group_wait and not m.checking:
                pass  # planned: it starts with its group (_release_groups)
            elif m.predecessor is not None and not m.checking:
                pass  # a successor: its predecessor blends into it, or it runs once that ends
            elif m.checking:
                self._at(TgPhase.CHECKING, m.seq, rt.monotonic_ns())
                self._check(m)
                if not (m.checking or m.group_wait or m.predecessor) and m in self.motions:
                    self._at(TgPhase.ADVANCING, m.seq, rt.monotonic_ns())
                    self._advance(m)  # started: its first tick's set-point, as any motion's
            elif m.ending is not None:
                if not any(self.fifos[k].pending() for k in m.robots):
                    self._at(TgPhase.ENDING, m.seq, rt.monotonic_ns())
                    self._end_motion(m, m.ending, m.ending_message)
            elif m.stepped != tick:
                self._at(TgPhase.ADVANCING, m.seq, rt.monotonic_ns())
                self._advance(m)
        self._tick[...] = tick
        t3 = rt.monotonic_ns()
        self._at(TgPhase.IDLE, 0, t3)
        if t3 - t0 > self._longest[0]:
            self._note_longest(tick, (t0, t1, t2, t3), rt.thread_time_ns() - c0, taken)

    def _at(self, phase: TgPhase, seq: int, now_ns: int) -> None:
        """Say where the TG is (``TG_STATE.phase``), for a reader at a halt; in the cycle."""
        self._phase_ns[0] = now_ns
        self._phase_seq[0] = seq & 0xFFFFFFFF
        self._phase[0] = phase  # last: its time and request are there before it

    def _note_longest(
        self, tick: int, t: tuple[int, int, int, int], cpu_ns: int, taken: int
    ) -> None:
        """Keep tick ``tick`` as the TG's longest: its parts from its times ``t`` (start,
        requests taken, waiting ones started, motions done).  Inside the cycle, rarely."""
        s = self.state
        s["longest_tick"] = tick
        s["longest_take_ns"] = t[1] - t[0]
        s["longest_start_ns"] = t[2] - t[1]
        s["longest_motions_ns"] = t[3] - t[2]
        s["longest_cpu_ns"] = cpu_ns
        s["longest_requests"] = taken
        s["longest_motions"] = len(self.motions)
        self._longest[0] = t[3] - t[0]  # last: a reader sees the parts of this one or before

    def _follow_rate(self) -> None:
        """Follow this TG's own period, changed on line by ``kalictl rate``: τ's step, the
        check slice and the ratio of the set-points pushed from this tick on.  In the cycle;
        allocates only when the period has changed (the first cycle counts as a change: a
        restarted TG may find the FIFOs at the ratio it set before).

        A period ``set_control_rate`` would refuse (shorter than the servo period, longer than
        ``config.MAX_PERIOD_MS``: written into the process table by something else) is not
        followed: τ's step and the FIFOs' ratio stay as they were."""
        ticks = int(self._own_period)
        if ticks == self._period_followed:
            return
        self._period_followed = ticks
        period_ns = ticks * self._base_ns
        if not self._servo_ns <= period_ns <= self._max_period_ns:
            return
        self.dt = period_ns / 1e9
        self.check_ns = int(CHECK_SHARE * period_ns)
        self.functions.budget_ns = int(FUNCTION_SHARE * period_ns)
        ratio = Fraction(period_ns, self._servo_ns)
        for fifo in self.fifos:
            fifo.set_ratio(ratio)

    def _attach_robots(self) -> np.ndarray | None:
        """SIO's per-robot records once it has laid them and the per-joint ones out (None
        before); binds each robot's view of the joints' demands."""
        arena = self.inst.arena
        if arena.lookup(layout.KEY_ROBOTS) is None or arena.lookup(layout.KEY_JOINTS) is None:
            return None
        joints = arena.existing(layout.KEY_JOINTS, layout.JOINT_STATE, self.joint_map.total)
        self._demand_of = self.joint_map.split(joints["demand"])
        self._q_of = self.joint_map.split(joints["q"])
        self.functions.sensors = Sensors(self.names, self._q_of, list(self.ft["world"]))
        return arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, self.n_robots)

    def _halt_all(self) -> None:
        """Tell every motion and waiting request the fault (readers have said HALTED since it
        was raised: ``MotionHandle``).  Requests still in the queue are judged when taken, by
        their ``fault_epoch``: those put before the fault are HALTED, later ones run."""
        text = self._halt_text()
        for m in self.motions:
            self._say(m.seq, RequestState.HALTED, text)
            for k in m.robots:
                self.tg_robots["busy_seq"][k] = 0
        self.motions.clear()
        self._groups.clear()
        self._guard_state[:] = GuardState.IDLE  # SIO powers the arms off: nothing to hold
        for seq, _ in self.waiting:
            self._say(seq, RequestState.HALTED, text)
        self.waiting.clear()

    def _halt_text(self) -> str:
        return f"halted: {self.inst.fault_text(last=True) or 'the system halted'}"

    # ------------------------------------------------------------------ admission

    def _blocked(self, seq: int) -> None:
        """Request ``seq`` waits for a record (every one holds a request queued or running):
        counted, and named with the tick it began for ``kalictl status``."""
        self.state["record_waits"] += 1
        if int(self.state["blocked_seq"]) != seq:
            self.state["blocked_seq"] = seq
            self.state["blocked_tick"] = self._now

    def _take_stops(self) -> None:
        """Carry out every request in the stop lane (``tg.stops``), before any other: a stop
        or abort of its arms (claimed as any request: refused on an arm another live program
        owns, unless forced), which also cancels their requests put in the request queue
        before it.  No status record: nobody waits on its outcome; each robot's
        ``stop_seq`` says it was carried out.  One put before the latest fault is dropped
        (the halt stopped everything)."""
        faults = int(self.inst.fault["count"])
        while (seq := self.stops.get_into(self.stop_request)) is not None:
            req = self.stop_request[0]
            if int(req["fault_epoch"]) < faults:
                continue
            kind = int(req["kind"])
            try:
                robots = request_robots(req, self.n_robots)
            except MotionError:  # nobody reads its outcome: counted, and nothing moves
                robots = []
            if kind not in (MotionKind.STOP, MotionKind.ABORT) or not robots:
                self.state["stops_refused"] += 1
                continue
            if self._claim(robots, req):
                self.state["stops_refused"] += 1
                continue
            self._stop(robots, abort=kind == MotionKind.ABORT)
            below = int(req["before_seq"])
            if self._pending is not None and self._pending[0] < below:
                pending, self._pending = self._pending, None
                self._cancel_pending(pending, robots)
            for k in robots:
                self._cancel_below[k] = max(self._cancel_below[k], below)
                self.tg_robots["stop_seq"][k] = seq
            self.state["stops_taken"] += 1

    def _cancel_pending(self, pending: tuple[int, np.void], robots: list[int]) -> None:
        """A stop came for request ``pending``'s arms while it waited for a record: it is
        taken as usual and then cancelled (``_take`` sees ``_cancel_below``), or, if it is for
        other arms, waits on."""
        seq, req = pending
        try:
            mine = set(request_robots(req, self.n_robots)) & set(robots)
        except Exception:
            mine = set()
        if not mine:
            self._pending = pending
            return
        if self.records.allocate(seq, int(req["client_pid"])) is None:
            self._pending = pending  # still no record: cancelled once it has one
            return
        self._take(seq, req)
        self.state["taken_seq"] = seq

    def _claim(self, robots: list[int], req: np.void) -> str:
        """Give ``robots`` to the request's program, or say who owns them ('' when given).

        An arm is free when no pid holds it or its holder is dead; REQUEST_FORCE takes it
        from a live owner and stops that owner's motions on it.  A request with no pid (0:
        not from a client) neither claims nor takes over, and neither does a STOP or ABORT
        without REQUEST_FORCE: stopping an arm moves nothing, so it gives no ownership (it
        is still refused on an arm another program owns)."""
        pid = int(req["client_pid"])
        force = bool(int(req["flags"]) & layout.REQUEST_FORCE)
        moves = int(req["kind"]) in MOVES
        taken = []
        for k in robots:
            held = int(self._lease_pid[k])
            if held in (0, pid) or not pid_alive(held):
                continue
            if not force:
                lease = self.leases[k]
                return (
                    f"robot '{self.names[k]}' is owned by pid {held} "
                    f"({decode(lease['name']) or 'a program'}) since tick {int(lease['tick'])}; "
                    f"another program's requests for it are refused until that one exits "
                    f"(kalictl move --force takes it over)"
                )
            taken.append(k)
        if pid <= 0:
            return ""
        if taken:
            self._stop(taken, abort=False)
        if not (moves or force):
            return ""
        for k in robots:
            if int(self._lease_pid[k]) != pid:
                lease = self.leases[k]
                lease["pid"] = pid
                lease["tick"] = self._now
                lease["name"] = req["client_name"]
        return ""

    # ------------------------------------------------------------------ requests

    def _robots_of(self, req: np.void) -> list[int]:
        """The robots of a request already checked by ``check_request``."""
        return request_robots(req, self.n_robots)

    def _take(self, seq: int, req: np.void) -> None:
        """Check a new request; queue, refuse, or act on it (stop, abort).  Nothing a request
        holds raises out of here: whatever is wrong with it refuses it (``refusal``)."""
        calibrated = None if self.robots is None else self.robots["calibrated"]
        rec = self.records[seq]
        write_status(rec, seq, RequestState.FREE)  # this request's from here on
        rec["client_pid"] = pid = int(req["client_pid"])
        rec["read"] = 1 if int(req["flags"]) & layout.REQUEST_UNWATCHED else 0
        if int(req["fault_epoch"]) < int(self.inst.fault["count"]):  # put before a fault
            self._say(seq, RequestState.HALTED, self._halt_text())
            return
        try:
            kind, robots = check_request(
                req, self.names, self.types, calibrated, self.contact_limits
            )
        except Exception as exc:  # a request never halts the cell
            self._refuse(seq, req, refusal(exc))
            return
        if kind not in (MotionKind.STOP, MotionKind.ABORT):
            cancelled = [k for k in robots if seq < self._cancel_below[k]]
            if cancelled:
                self._refuse(seq, req, f"cancelled: a stop of robot '{self.names[cancelled[0]]}'"
                             " was put after it")  # fmt: skip
                return
        if pid > 0 and self.records.live(pid) > layout.LIVE_SHARE:
            self._refuse(
                seq,
                req,
                f"program pid {pid} already has {layout.LIVE_SHARE} requests queued or running "
                f"(layout.LIVE_SHARE); wait for some to end",
            )
            return
        owner = self._claim(robots, req)
        if owner:
            self._refuse(seq, req, owner)
            return
        g = int(req["group"])
        if g:
            why = self._dead_groups.get(g) or self._join_group(g, req, robots)
            if why:
                self._refuse(seq, req, why)
                return
        if kind in (MotionKind.STOP, MotionKind.ABORT):
            self._stop(robots, abort=kind == MotionKind.ABORT)
            self._say(seq, RequestState.DONE, kind.name.lower())
            return
        self._say(seq, RequestState.QUEUED)
        self.waiting.append((seq, req))

    def _require_calibrated(self, k: int) -> None:
        if not int(self.robots["calibrated"][k]):
            raise MotionError(
                f"robot '{self.names[k]}' is not calibrated; Cartesian motion needs its true "
                f"joint angles (kalictl calibrate {self.names[k]})"
            )

    def _start_waiting(self) -> None:
        """Start each waiting request whose robots are idle, in order of arrival.

        Planning a Cartesian path (milliseconds of CPU) counts against the tick's check share
        like the checks: a path is planned only while that share lasts, so a tick plans at
        most the paths it has time for; the rest wait a tick in order
        (docs/decisions/0009-tg-check-share.md)."""
        busy = {k for m in self.motions for k in m.robots}
        queued: set[int] = set()  # robots an earlier waiting request waits for
        still = []
        for seq, req in self.waiting:
            robots = self._robots_of(req)
            if int(req["group"]) and not self._group_here(req):  # its partners are not in yet
                still.append((seq, req))
                busy |= set(robots)
                queued |= set(robots)
                continue
            before = self._blend_into(req, robots) if not queued & set(robots) else None
            if before is not None and not (int(req["kind"]) == MotionKind.PATH and self._spent()):
                self._plan_successor(seq, req, robots, before)
                queued |= set(robots)  # later requests wait behind it
                continue
            if busy & set(robots) or (
                int(req["kind"]) == MotionKind.PATH and self._spent()
            ):  # robots busy, or this tick's share of planning and checks is spent
                still.append((seq, req))
                busy |= set(robots)  # keep the order: later requests wait behind this one
                queued |= set(robots)
                continue
            why = self._cannot_move(robots)
            if why:
                self._refuse(seq, req, why)
                continue
            self._start(seq, req, robots)
            busy |= set(robots)
        self.waiting = still

    def _blend_into(self, req: np.void, robots: list[int]) -> Motion | None:
        """The motion request ``req`` may continue without a stop (thesis 3.1: the
        transition between one request's last segment and the next one's first), or None.

        It may when one motion moves exactly its robots, of the same kind (joint moves, or
        paths of one motion system: the same first grasp), running (not checking, stopping,
        ending, grouped or already followed), both unguarded, the path's transition windows
        both > 0, and the request does not ask to stop first (REQUEST_STOP_BETWEEN)."""
        kind = int(req["kind"])
        if int(req["flags"]) & layout.REQUEST_STOP_BETWEEN or int(req["group"]):
            return None
        if kind not in (MotionKind.JOINTS, MotionKind.PATH) or float(req["guard_n"]):
            return None
        movers = [m for m in self.motions if set(m.robots) & set(robots)]
        if len(movers) != 1:
            return None
        m = movers[0]
        if m.robots != robots or m.checking or m.group_wait or m.guard or m.predecessor:
            return None
        if m.successor is not None or m.stop is not None or m.ending is not None:
            return None
        p = m.profile
        if kind == MotionKind.JOINTS:
            return m if isinstance(p, JointMotion) else None
        if not isinstance(p, CartesianMotion):
            return None
        same_grasp = np.allclose(p.request_grasp, req["grasps"][0], atol=1e-12)
        windows = p.path.transition_s > 0.0 and float(req["transition_s"]) > 0.0
        return m if same_grasp and windows else None

    def _plan_successor(self, seq: int, req: np.void, robots: list[int], a: Motion) -> None:
        """Plan request ``req`` from where motion ``a`` ends, to follow it without a stop
        (``_blend``); a path is checked from there first, while ``a`` runs.  Refused with the
        reason as any request would be."""
        profile: JointMotion | CartesianMotion
        try:
            check: CartesianMotion | JointMoveCheck | None
            if isinstance(a.profile, JointMotion):
                start = a.profile.target.copy()
                profile = plan_joints(req, robots, start, self.types)
                overlap = min(a.profile.law.accel_time, profile.law.accel_time)
                check = self._joint_check(profile, robots, start)
            else:
                assert isinstance(a.profile, CartesianMotion)
                self._work += PLAN_SAMPLES
                begin = a.profile.end_q()
                profile = plan_path(req, robots, self.names, self.types, self.bases, begin, self.dt)
                overlap = min(a.profile.path.transition_s, profile.path.transition_s)
                profile.clearance = self._walk(robots, begin)
                check = profile
        except Exception as exc:  # a request never halts the cell
            self._refuse(seq, req, refusal(exc))
            return
        out, rows = joint_rows([self.joint_map.counts[k] for k in robots])
        b = Motion(seq, robots, profile, out=out, rows=rows, check=check)
        b.checking = check is not None
        b.predecessor, b.overlap = a, overlap
        a.successor = b
        self.motions.append(b)
        self._say(seq, RequestState.QUEUED, f"to follow request {a.seq} without a stop")

    def _group_here(self, req: np.void) -> bool:
        """True when every request of ``req``'s group has been taken (waiting or planned)."""
        g = int(req["group"])
        have = sum(1 for _, r in self.waiting if int(r["group"]) == g)
        have += sum(1 for m in self.motions if m.group == g)
        return have >= int(req["group_size"])

    def _release_groups(self) -> None:
        """Run together every group whose motions are all planned and checked: each gets
        its first set-point this tick (thesis 3.1: synchronisation of motion systems)."""
        waiting = [m for m in self.motions if m.group_wait]
        for g in {m.group for m in waiting}:
            members = [m for m in self.motions if m.group == g]
            ready = [m for m in members if m.group_wait and not m.checking]
            if len(ready) == len(members) == self._groups[g][0]:
                for m in members:
                    m.group_wait = False
                    self._run(m)
                del self._groups[g]

    def _join_group(self, g: int, req: np.void, robots: list[int]) -> str:
        """Count request ``req`` into group ``g``; why it cannot be one of it, or ''."""
        size = int(req["group_size"])
        have, arms = self._groups.setdefault(g, (size, set()))
        if size != have or not 2 <= size <= layout.MAX_ROBOTS:
            return f"group of {size} requests; its first said {have}, and 2 to {layout.MAX_ROBOTS}"
        if arms & set(robots):
            names = ", ".join(f"'{self.names[k]}'" for k in sorted(arms & set(robots)))
            return f"robot {names} is moved by two requests of one group (kali.together)"
        arms |= set(robots)
        return ""

    def _refuse_group(self, g: int, seq: int, why: str) -> None:
        """A request of group ``g`` was refused: the rest of it is cancelled, unstarted,
        and its members still to come are refused when taken (``_dead_groups``)."""
        text = f"cancelled: request {seq} of its group (kali.together) was refused: {why}"
        for m in [m for m in self.motions if m.group == g and m.seq != seq]:
            self._end_motion(m, RequestState.REFUSED, text)
        for s, r in [(s, r) for s, r in self.waiting if int(r["group"]) == g and s != seq]:
            self.waiting.remove((s, r))
            self._say(s, RequestState.REFUSED, text)  # (one ended this tick is left as it is)
        self._groups.pop(g, None)
        self._dead_groups[g] = text
        while len(self._dead_groups) > DEAD_GROUPS:
            del self._dead_groups[next(iter(self._dead_groups))]

    def _spent(self) -> bool:
        """True once this tick's share of path checks and planning is used up: wall time in
        real time, a count of path samples in lockstep (so a run there depends on simulated
        time only, bit for bit whatever the host's load).  In the cycle."""
        if self.lockstep:
            return self._work >= LOCKSTEP_CHECK_SAMPLES
        return time.monotonic_ns() > self._check_until

    def _cannot_move(self, robots: list[int]) -> str:
        """Why SIO will not move one of ``robots`` now (unpowered, calibrating, guided by
        hand: it holds the arm or lets its demand follow it), or ''."""
        for k in robots:
            if int(self.robots["power"][k]) != PowerState.ON:
                return f"robot '{self.names[k]}' is not powered (kalictl enable {self.names[k]})"
            if int(self.robots["calib_state"][k]) in CALIBRATING:
                return f"robot '{self.names[k]}' is calibrating"
            if int(self.robots["guided"][k]):
                return (
                    f"robot '{self.names[k]}' is guided by hand (the guiding servo); select "
                    f"another to move it (kalictl servo select {self.names[k]} joints)"
                )
        return ""

    def _start(self, seq: int, req: np.void, robots: list[int]) -> None:
        if int(req["kind"]) == MotionKind.PATH:
            self._plan_path(seq, req, robots)
            return
        if int(req["kind"]) in _TRACKING:
            self._plan_tracking(seq, req, robots)
            return
        start = np.concatenate([self._start_point(k) for k in robots])
        try:
            profile = plan_joints(req, robots, start, self.types)
        except Exception as exc:  # a request never halts the cell
            self._refuse(seq, req, refusal(exc))
            return
        out, rows = joint_rows([self.joint_map.counts[k] for k in robots])
        m = Motion(seq, robots, profile, guard=float(req["guard_n"]), out=out, rows=rows)
        m.check = self._joint_check(profile, robots, start)
        if m.check is not None:
            self._say(seq, RequestState.QUEUED, "checking the move")
        self._begin(m, req, checking=m.check is not None)  # checked from this tick

    def _plan_tracking(self, seq: int, req: np.void, robots: list[int]) -> None:
        """Start a TRACK or TRACK_JOINTS request from where its arms are, its loop checked
        to close now; refused with the reason otherwise."""
        try:
            if int(req["kind"]) == MotionKind.TRACK:
                for k in robots:
                    self._require_calibrated(k)
            start = [self._start_point(k) for k in robots]
            plan = plan_tracking(
                req, robots, self.names, self.types, self.bases, start, self.frames, self.dt,
                self._now, self.functions, self._measured_at_rest(robots),
            )  # fmt: skip
        except Exception as exc:  # a request never halts the cell
            self._refuse(seq, req, refusal(exc))
            return
        walk = self._walk(robots, plan.q_ref)
        if walk is not None:
            plan.keep_clear(walk)
        self._begin(Motion(seq, robots, plan, tracking=True), req)

    def _begin(self, m: Motion, req: np.void, checking: bool = False) -> None:
        """Motion ``m`` of request ``req`` is planned: its arms are busy with it from now;
        it runs this tick, or (one of a group) once the whole group is planned and checked,
        or (``checking``, a path) once its check is through."""
        m.group = int(req["group"])
        m.group_wait = m.group != 0
        m.checking = checking
        for k in m.robots:
            self.tg_robots["busy_seq"][k] = m.seq
        self.motions.append(m)
        if not (checking or m.group_wait):
            self._run(m)

    def _refuse(self, seq: int, req: np.void, why: str) -> None:
        """Refuse request ``seq``; one of a group takes the rest of its group with it."""
        self._say(seq, RequestState.REFUSED, why)
        g = int(req["group"])
        if g:
            self._refuse_group(g, seq, why)

    def _run(self, m: Motion) -> None:
        """Motion ``m`` is planned (and checked): it runs from this tick."""
        rec = self.records[m.seq]
        rec["limited"] = 0
        rec["duration_s"] = m.profile.duration if math.isfinite(m.profile.duration) else 0.0
        rec["progress"] = 0.0
        self._say(m.seq, RequestState.RUNNING)
        if m.guard:  # SIO watches each arm's contact force from its next tick
            for k in m.robots:
                ft = self.ft[k]
                ft["guard_seq"] = m.seq
                ft["guard_n"] = m.guard
                ft["guard_state"] = GuardState.ARMED  # last
        for _ in range(LEAD - 1):  # run ahead of SIO by LEAD set-points
            if isinstance(m.profile, Tracking):  # from rest: where the arms are (its target
                for i, k in enumerate(m.robots):  # is read once a tick, its speed kept)
                    self.fifos[k].push(m.profile.q_ref[i])
            else:
                self._advance(m)

    def _plan_path(self, seq: int, req: np.void, robots: list[int]) -> None:
        """Plan a Cartesian request from where its arms are; its check starts this tick."""
        try:
            for k in robots:
                self._require_calibrated(k)
            start = [self._start_point(k) for k in robots]
            self._work += PLAN_SAMPLES
            plan = plan_path(
                req, robots, self.names, self.types, self.bases, start, self.dt,
                self._measured_at_rest(robots),
            )  # fmt: skip
        except Exception as exc:  # a request never halts the cell
            self._refuse(seq, req, refusal(exc))
            return
        plan.clearance = self._walk(robots, start)
        self._say(seq, RequestState.QUEUED, "checking the path")
        m = Motion(seq, robots, plan, guard=float(req["guard_n"]), check=plan)
        self._begin(m, req, checking=True)  # the cycle checks its first slice this tick

    def _check(self, m: Motion) -> None:
        """Walk a slice of ``m``'s path; run or refuse it at the end.

        The slice ends ``CHECK_SHARE`` of a period after the tick began, not after the slice
        did: planning the path in the same tick, or checking another motion, uses the same
        share, so a tick stays within it (a plan and a whole slice on top once took the TG
        7.5 ms of its 10, and with the plant and sv.1 on its CPU it missed).  The time is looked
        at after each sample (a numerically solved arm's, the FR3's, is costly), and
        at least one sample is checked each tick, so every check ends."""
        plan = m.check
        assert plan is not None
        try:
            while not plan.check_some(1):
                self._progress[self.records.index(m.seq)] = plan.progress
                self._work += 1
                if self._spent():
                    return
        except Exception as exc:  # nothing has moved: refuse, never halt
            self._end_motion(m, RequestState.REFUSED, refusal(exc))
            if m.group:
                self._refuse_group(m.group, m.seq, refusal(exc))
            return
        m.checking = False
        if not (m.group_wait or m.predecessor is not None):  # a successor waits for its turn
            self._run(m)

    def _start_point(self, k: int) -> np.ndarray:
        """Where robot ``k``'s next motion starts: its last set-point while the FIFO still
        holds some, else SIO's present demand (where the FIFO holds)."""
        if self.fifos[k].pending():
            return self._setpoint_of[k].copy()
        return self._demand_of[k].copy()

    def _walk(self, robots: list[int], start: Sequence[np.ndarray]) -> ClearanceWalk | None:
        """A clearance walk along a motion of ``robots`` starting at ``start`` (one row a
        robot), the other arms where their motions so far take them (``_start_point``): an
        arm moved by another request meanwhile is checked against where it was then (move
        arms that pass near each other as one motion system, or one after the other)."""
        if self.clearance is None:
            return None
        qs = [self._start_point(k) for k in range(self.n_robots)]
        for k, q in zip(robots, start, strict=True):
            qs[k] = np.asarray(q, dtype=float)
        return self._holding().walk(robots, qs)

    def _holding(self) -> CellClearance:
        """The cell's clearances with each arm's held object on it (its load record's: a grip
        or a motion system naming a scene object), made the first time that set is held
        (a few ms: two arms' collision models and the pairs)."""
        assert self.clearance is not None
        objects = self._scene.objects
        held = tuple(  # the object each holds (a record naming none it can hold: nothing)
            int(h) - 1 if 0 < h <= len(objects) and objects[int(h) - 1].grasps else -1
            for h in self._held
        )
        if all(h < 0 for h in held):
            return self.clearance
        cell = self._clearances.get(held)
        if cell is None:
            holding = {
                k: (objects[h].name, self._scene.grasp_for(objects[h].name, self._robots[k]))
                for k, h in enumerate(held)
                if h >= 0
            }
            cell = CellClearance(CellGeometry(self._robots, self._scene, holding))
            self._clearances[held] = cell
        return cell

    def _joint_check(
        self, profile: JointMotion, robots: list[int], start: np.ndarray
    ) -> JointMoveCheck | None:
        """The clearance check of joint move ``profile`` of ``robots`` from ``start`` (their
        joints one after another); None where nothing is checked."""
        widths = [self.joint_map.counts[k] for k in robots]
        ends = np.cumsum(widths)
        walk = self._walk(robots, [start[e - w : e] for w, e in zip(widths, ends, strict=True)])
        if walk is None:
            return None
        return JointMoveCheck(profile, walk, [self.names[k] for k in robots], widths)

    def _measured_at_rest(self, robots: list[int]) -> list[np.ndarray] | None:
        """Where the arms of a motion system starting at rest are (SIO's measured joints): a
        held object's grasps are taken from where the arms really hold it
        (``cartesian.held_object``).  None if one still has set-points to run (a moving arm's
        measured joints lag them) or runs a robot-level servo: joint servos close their
        errors, so arms on them that stand off their set-points are held there by the
        object, but an impedance servo's arm stands off by its springs' deflection on purpose,
        its squeeze regulated from the wrist sensors (``set_internal_force``)."""
        for k in robots:
            if self.fifos[k].pending() or int(self.robots["arm_algo"][k]) != layout.ARM_NONE:
                return None
        return [self._q_of[k].copy() for k in robots]

    def _stop(self, robots: list[int], abort: bool) -> None:
        for m in list(self.motions):
            if m not in self.motions or not set(m.robots) & set(robots):
                continue  # (ended with a group cancelled below)
            if m.checking or m.group_wait or (m.predecessor and not m.blending):  # not moved
                state = RequestState.ABORTED if abort else RequestState.STOPPED
                self._end_motion(m, state, "cancelled before it started")
                if m.group:  # its group cannot start together any more
                    self._refuse_group(m.group, m.seq, "it was cancelled before it started")
            elif abort:
                self._end_motion(m, RequestState.ABORTED, "aborted")
            elif isinstance(m.profile, Tracking):
                m.profile.stop("stopped on request")
            elif m.stop is None and m.ending is None:  # not once it is arriving
                m.stop = StopRamp(m.tau, STOP_TIME_S)
                m.stop_t = 0.0
        for seq, req in list(self.waiting):
            if not any(s == seq for s, _ in self.waiting):
                continue  # cancelled with its group
            if set(self._robots_of(req)) & set(robots):
                self.waiting.remove((seq, req))
                self._say(seq, RequestState.ABORTED if abort else RequestState.STOPPED, "cancelled")
                if int(req["group"]):
                    self._refuse_group(int(req["group"]), seq, "it was cancelled")

    # ------------------------------------------------------------------ running motions

    def _advance(self, m: Motion) -> None:
        """One TG tick of motion ``m``: the next set-point of each of its robots.

        A FIFO with no room left (the TG signalled faster than its period: a period in the
        process table that no ``set_control_rate`` wrote) holds the motion for a tick instead
        of overflowing; SIO goes on taking set-points at the servo rate."""
        for k in m.robots:
            if self.fifos[k].pending() >= FIFO_CAPACITY - 1:
                return
        p = m.profile
        if m.tracking:  # (a flag: isinstance of an ABC costs the joint motions ~0.3 µs)
            self._track(m, p)  # type: ignore[arg-type]
            return
        b = m.successor
        if b is not None and (b.blending or self._blend_due(m, b)):
            self._blend(m, b)
            return
        self._next_tau(m)
        # the motion's last set-point, where it stops: marked, so the dynamics process
        # writes its resting row at once, not once SIO has drained the FIFO
        last = m.tau >= p.duration or (m.stop is not None and m.stop.sigma(m.stop_t) == 0.0)
        if isinstance(p, CartesianMotion):
            try:
                rows = p.sample(m.tau)
            except KinematicsError as exc:  # the check let it through: stop and halt (2.2.1)
                self._kinematics_halt(m, p, str(exc))
                return
            for i, k in enumerate(m.robots):
                self.fifos[k].push(rows[i], last)
                np.copyto(self._setpoint_of[k], rows[i])
        else:
            p.sample(m.tau, m.out)  # type: ignore[union-attr]  # not tracking: a joint motion
            for i, k in enumerate(m.robots):
                q = m.rows[i]
                self.fifos[k].push(q, last)
                np.copyto(self._setpoint_of[k], q)
        self._progress[self.records.index(m.seq)] = m.tau / p.duration
        if last and m.stop is not None:
            m.ending, m.ending_message = RequestState.STOPPED, "stopped on the path"
        elif last:
            m.ending = RequestState.DONE

    def _next_tau(self, m: Motion) -> None:
        """Motion ``m``'s path time one tick on: dt, or σ·dt while it stops (in the cycle)."""
        if m.stop is not None:
            m.stop_t += self.dt
            m.tau = min(m.stop.tau(m.stop_t), m.profile.duration)
        else:
            m.tau = min(m.tau + self.dt, m.profile.duration)

    def _blend_due(self, a: Motion, b: Motion) -> bool:
        """True when successor ``b`` of ``a`` starts this tick: it is planned and checked,
        ``a`` runs on (no stop) and the next tick of ``a`` is inside the last ``overlap`` s
        of it, and the window's summed set-points pass the checks (else ``b`` starts after
        ``a`` at rest: ``_end_motion``).  In the cycle; the check allocates, once a blend."""
        if b.checking or b.overlap <= 0.0 or a.stop is not None:
            return False
        if a.tau + self.dt <= a.profile.duration - b.overlap + 1e-9:
            return False
        why = self._blend_fault(a, b)
        if why:
            b.overlap = 0.0  # not blended: it starts at rest once a has arrived
            self._say(b.seq, RequestState.QUEUED, f"after request {a.seq} at rest: {why}")
            return False
        b.blending = True
        rec = self.records[b.seq]
        rec["duration_s"] = b.profile.duration
        rec["progress"] = 0.0
        self._say(b.seq, RequestState.RUNNING)
        if isinstance(b.profile, CartesianMotion):
            assert isinstance(a.profile, CartesianMotion)
            for qb, qa in zip(b.profile.q_ref, a.profile.q_ref, strict=True):
                np.copyto(qb, qa)  # IK near where the arms are
        return True

    def _blend_fault(self, a: Motion, b: Motion) -> str:
        """Why the summed set-points of ``a``'s last ``b.overlap`` s and ``b``'s first would
        not do (a joint too fast; for paths, also out of reach or near a singularity), or ''.
        Outside the cycle's usual work: once, as the blend begins (it allocates)."""
        ta, tb = a.tau, 0.0
        samples = []
        while ta < a.profile.duration:
            ta, tb = min(ta + self.dt, a.profile.duration), tb + self.dt
            samples.append(self._summed(a, b, ta, tb).copy())
        try:
            if isinstance(b.profile, CartesianMotion):
                assert isinstance(a.profile, CartesianMotion)
                b.profile.check_poses(samples, a.profile.q_ref)
            else:
                limits = np.concatenate([self.types[k].qd_max for k in b.robots])
                prev = np.concatenate([self._setpoint_of[k] for k in a.robots])
                for q in samples:
                    fast = np.abs(q - prev) / self.dt > limits * (1.0 + 1e-9)
                    if fast.any():
                        j = int(np.flatnonzero(fast)[0])
                        return f"joint {j + 1} of the blend would go faster than its limit"
                    prev = q
        except MotionError as exc:
            return str(exc)
        return ""

    def _summed(self, a: Motion, b: Motion, ta: float, tb: float) -> np.ndarray:
        """The blend's set-point at path times ``ta`` of ``a`` and ``tb`` of ``b``: joint
        moves summed less their junction (``b.out``), paths' object poses composed so
        (``_blend_obj``: p_a + p_b − p_j, R_a · R_jᵀ · R_b, Paul's transition at the
        junction when the windows match).  In the cycle."""
        if isinstance(b.profile, JointMotion):
            assert isinstance(a.profile, JointMotion)
            a.profile.sample(ta, a.out)
            b.profile.sample(tb, b.out)
            np.add(b.out, a.out, out=b.out)
            np.subtract(b.out, a.profile.target, out=b.out)
            return b.out
        assert isinstance(a.profile, CartesianMotion) and isinstance(b.profile, CartesianMotion)
        oa, ob, obj, tmp, rot = self._blend_poses
        a.profile.path.sample(ta, oa)
        b.profile.path.sample(tb, ob)
        junction = b.profile.path.poses[0]
        np.matmul(oa[:3, :3], junction[:3, :3].T, out=tmp)
        np.matmul(tmp, ob[:3, :3], out=rot)
        obj[:3, :3] = rot
        np.add(oa[:3, 3], ob[:3, 3], out=obj[:3, 3])
        np.subtract(obj[:3, 3], junction[:3, 3], out=obj[:3, 3])
        return obj

    def _blend(self, a: Motion, b: Motion) -> None:
        """One tick of ``a`` ending and ``b`` beginning at once (thesis 3.1: the transition
        between one request's last segment and the next one's first): the summed set-point.
        ``a`` ends DONE as its path time reaches its end, and ``b`` goes on alone; stopped
        meanwhile, both decelerate on their paths and end STOPPED together.  In the cycle."""
        self._next_tau(a)
        self._next_tau(b)
        b.stepped = self._now  # the loop does not step it again this tick once a has ended
        out = self._summed(a, b, a.tau, b.tau)
        if isinstance(b.profile, CartesianMotion):
            try:
                rows = b.profile.solve(out)
            except KinematicsError as exc:  # its window was checked: stop and halt (2.2.1)
                self._kinematics_halt(b, b.profile, str(exc))
                return
        else:
            rows = b.rows
        for i, k in enumerate(b.robots):
            self.fifos[k].push(rows[i])
            np.copyto(self._setpoint_of[k], rows[i])
        self._progress[self.records.index(a.seq)] = a.tau / a.profile.duration
        self._progress[self.records.index(b.seq)] = b.tau / b.profile.duration
        if a.tau >= a.profile.duration:  # a has arrived: b goes on alone from here
            a.successor, b.predecessor, b.blending = None, None, False
            self._end_motion(a, RequestState.DONE)
            for k in b.robots:
                self.tg_robots["busy_seq"][k] = b.seq
            if isinstance(a.profile, JointMotion):  # b's own samples from the next tick
                # a joint motion's successor is one (_plan_successor)
                b.profile.sample(b.tau, b.out)  # type: ignore[union-attr, call-arg]
        elif a.stop is not None and a.stop.sigma(a.stop_t) == 0.0:
            assert b.stop is not None
            a.successor, b.predecessor, b.blending = None, None, False
            self._end_motion(a, RequestState.STOPPED, "stopped on the path")
            b.ending, b.ending_message = RequestState.STOPPED, "stopped on the path"

    def _track(self, m: Motion, p: Tracking) -> None:
        """One tick of tracking motion ``m``: its arms' next set-points, or its end."""
        rows = p.step(self._now)
        self._limited[self.records.index(m.seq)] = p.limited
        if rows is None:  # held at the last set-points: nothing more to push
            m.ending = RequestState.ABORTED if p.aborted else RequestState.STOPPED
            m.ending_message = p.why
            return
        for i, k in enumerate(m.robots):
            self.fifos[k].push(rows[i])
            np.copyto(self._setpoint_of[k], rows[i])
        self._progress[self.records.index(m.seq)] = min(1.0, p.t / p.duration)
        if p.done:
            if p.why:
                m.ending, m.ending_message = RequestState.STOPPED, f"stopped on its path: {p.why}"
            else:
                m.ending = RequestState.DONE

    def _kinematics_halt(self, m: Motion, plan: CartesianMotion, why: str) -> None:
        """No joint solution at run time: the arms hold at their last set-points and the
        system halts, naming the motion system, the segment and the reason."""
        names = ", ".join(f"'{self.names[k]}'" for k in m.robots)
        text = (
            f"motion system {names}, request {m.seq}: no joint solution at "
            f"{plan.segment_label(m.tau)}, {m.tau:.2f} s into the motion: {why}"
        )
        self._end_motion(m, RequestState.HALTED, text)
        self.inst.raise_fault(FaultCode.SINGULARITY, self.name, text)

    def _tripped(self, m: Motion) -> int:
        """The first of guarded motion ``m``'s robots whose guard SIO has tripped, else -1.
        In the cycle: one word per arm."""
        for k in m.robots:
            if int(self._guard_state[k]) == GuardState.TRIPPED:
                return k
        return -1

    def _contact(self, m: Motion, k: int) -> str:
        """Guarded motion ``m`` touched on robot ``k``: SIO holds its arms where they were
        then.  Write where into its status record (the tool point from the joints SIO
        noted, the contact wrench) and return the message.  Once per guarded move (it
        allocates)."""
        ft = self.ft[k]
        n = self.joint_map.counts[k]
        tool = self.bases[k] @ flange_pose(self._chains[k], ft["guard_q"][:n].copy())
        xyz = tool[:3, 3] + tool[:3, 2] * self._tips[k]
        rec = self.records[m.seq]
        rec["contact_robot"] = k
        rec["contact_xyz"] = xyz
        rec["contact_force"] = ft["guard_force"]
        rec["contact_wrench"] = ft["guard_wrench"]
        x, y, z = (float(v) for v in xyz)
        return (
            f"contact: robot '{self.names[k]}' felt {float(ft['guard_force']):.1f} N "
            f"(guard {m.guard:g} N) with its tool at ({x:.4f}, {y:.4f}, {z:.4f}) m, "
            f"{m.tau:.2f} s into the motion; held there"
        )

    def _disarm(self, m: Motion) -> int:
        """Guarded motion ``m`` ends: its arms' guards go idle, each armed one by a
        compare-and-swap (SIO may be tripping it); returns the first arm SIO had tripped
        (its hold ends too), else -1."""
        tripped = -1
        for k in m.robots:
            addr = self._guard_state[k : k + 1].ctypes.data
            swapped, seen = self._cas(addr, GuardState.ARMED, GuardState.IDLE)
            if not swapped and seen == GuardState.TRIPPED:
                tripped = k if tripped < 0 else tripped
                self._guard_state[k] = GuardState.IDLE
        return tripped

    def _end_motion(self, m: Motion, state: RequestState, message: str = "") -> None:
        """End motion ``m`` with ``state``; a guarded one that touched, even as it arrived
        or stopped, ends as CONTACT saying where."""
        if m.guard and not m.checking:
            k = self._disarm(m)
            if k >= 0 and state in (RequestState.DONE, RequestState.STOPPED, RequestState.CONTACT):
                state, message = RequestState.CONTACT, self._contact(m, k)
        self.motions.remove(m)
        for k in m.robots:
            self.tg_robots["busy_seq"][k] = 0
        self._say(m.seq, state, message)
        if m.predecessor is not None:  # a successor ended before it began
            m.predecessor.successor = None
            m.predecessor = None
        b = m.successor
        if b is not None:  # planned from m's end: it runs from there if m arrived
            m.successor, b.predecessor = None, None
            if state != RequestState.DONE:
                why = f"cancelled: request {m.seq}, which it was to follow, did not arrive"
                self._end_motion(b, RequestState.STOPPED, why)
                return
            for k in b.robots:
                self.tg_robots["busy_seq"][k] = b.seq
            if not b.checking:  # else it runs once its check is through (_check)
                self._run(b)
