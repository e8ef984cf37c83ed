"""Feed-forward dynamics (thesis 3.3.6, 2.2.3): the joint torques the demanded motion needs,
computed with Pinocchio about as often as the TG runs, for SIO to add to the servo torques.

For every set-point in a robot's TG → SIO FIFO it writes one row of ``layout.FEEDFORWARD``,
keyed by the set-point's absolute FIFO index: τ = g(q) in GRAVITY, in FULL
τ = M(q) q̈ + C(q, q̇) q̇ + g(q) + friction(q̇) + k_v q̇ (k_v the active servo's ``kv``: the
PID then damps the velocity error), with q̇ and q̈ beside it for the robot-level servos,
which get FULL rows whatever the mode.  SIO interpolates the rows as it interpolates the
positions, so they stay aligned however late this process runs; a missing or stale row is
SIO's to detect and drop.  Asynchronous and non-serious (3.3.6): Pinocchio's small
allocations are accepted here.  What others write is checked (DESIGN 7): a mode word that is
no FfMode leaves the last valid mode, a set-point that is not finite gets no row, a torque
that is not finite is never published.  More: docs/internals/servo-level.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from fractions import Fraction

import numpy as np

from ..core import layout, rt
from ..core.arena import Arena
from ..core.channels import InterpolatingFifo
from ..core.errors import DaemonError
from ..core.layout import FfMode
from ..robots.inverse import InverseDynamics, central_differences
from ..robots.payload import HeldLoad
from ..runtime.config import KaliConfig, ms_to_ns
from ..runtime.daemon import Daemon
from ..servo import loading
from ..servo.level import FF_MODES, FIFO_CAPACITY, ServoLevel

SIO_WAIT_S = 30.0  # how long the dynamics process waits at start for SIO's servo level
MAX_ROWS_PER_CYCLE = 64  # per robot: a cycle's work stays bounded when a long move arrives


@dataclass
class ArmScratch:
    """One robot's working vectors, its joint count long (allocated at set-up)."""

    n: int
    q_prev: np.ndarray = field(init=False)
    q_i: np.ndarray = field(init=False)
    q_next: np.ndarray = field(init=False)
    qd: np.ndarray = field(init=False)
    qdd: np.ndarray = field(init=False)
    s: np.ndarray = field(init=False)
    kv: np.ndarray = field(init=False)  # the servos' velocity gains now

    def __post_init__(self) -> None:
        for name in ("q_prev", "q_i", "q_next", "qd", "qdd", "s", "kv"):
            setattr(self, name, np.zeros(self.n))


class Dynamics(Daemon):
    """Writes every robot's feed-forward rows; SIO applies them."""

    kind = "dynamics"

    def on_configure(self) -> None:
        """Load the models, then wait for SIO to lay the servo level out (FIFOs, records)."""
        inst = self.inst
        cfg = inst.config
        self.load(cfg)
        deadline = rt.monotonic_ns() + int(SIO_WAIT_S * 1e9)
        while not self._sio_ready():
            if rt.monotonic_ns() > deadline:
                raise DaemonError(f"{self.name}: SIO did not lay out the servo level")
            rt.AbsoluteSleeper().until(rt.monotonic_ns() + 5_000_000)
        self.attach(cfg, inst.arena)
        self.level = level = ServoLevel(inst)
        self._arm_algo = level.robots["arm_algo"]
        self._algo = level.slots["algo"]
        self._enabled = level.slots["enabled"]
        self._loads_gen = level.loads["generation"].reshape(1)
        self._view_gains()

    def _view_gains(self) -> None:
        """Per slot, per algorithm: a view of its kv parameter, or None if it has none
        (again after a servo plugin was loaded while running; outside the cycle)."""
        self._kv_views = [
            [rec["kv"].reshape(-1) if "kv" in (rec.dtype.names or ()) else None for rec in row]
            for row in self.level.data
        ]

    def load(self, cfg: KaliConfig) -> None:
        """Each robot type's model and each robot's scratch, its joint count wide (outside
        the cycle)."""
        self.inverse = []  # one per robot: each carries its own load
        for r in cfg.robots:
            tool = (r.ft.tool_mass_kg, r.ft.tool_com_m)
            self.inverse.append(InverseDynamics(r.type, tool, gravity=not r.holds_gravity))
        self.held = [HeldLoad(inverse.model) for inverse in self.inverse]
        self.n_robots = len(cfg.robots)
        self.joint_map = cfg.joints  # robot k's joint j: flat index (servo slot) base[k] + j
        self.servo_period_s = cfg.clock.servo_period_ms / 1000.0
        self.arms = [ArmScratch(n) for n in self.joint_map.counts]

    def attach(self, cfg: KaliConfig, arena: Arena) -> None:
        """Each robot's FIFO (its joint count wide) and its columns of the ``FEEDFORWARD``
        rows, once SIO has laid the record out (outside the cycle)."""
        ratio = Fraction(ms_to_ns(cfg.clock.tg_period_ms), ms_to_ns(cfg.clock.servo_period_ms))
        self.fifos = [
            InterpolatingFifo(
                arena, layout.KEY_FIFO.format(robot=r.name), r.n_joints, FIFO_CAPACITY, ratio
            )
            for r in cfg.robots
        ]
        self.ff = arena.existing(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, self.n_robots)
        loads = arena.existing(layout.KEY_LOADS, layout.LOAD, self.n_robots)
        self.loads = [loads[k : k + 1].reshape(()) for k in range(self.n_robots)]
        # per robot: its columns of every row's q and tau, (FF_ROWS, n_joints) views
        counts = self.joint_map.counts
        self._ff_q = [self.ff["q"][k, :, :n] for k, n in enumerate(counts)]
        self._ff_tau = [self.ff["tau"][k, :, :n] for k, n in enumerate(counts)]
        self._ff_qd = [self.ff["qd"][k, :, :n] for k, n in enumerate(counts)]
        self._ff_qdd = [self.ff["qdd"][k, :, :n] for k, n in enumerate(counts)]
        # per robot: the first FIFO index without a row, and the mode the rows are in
        self.next_row = [fifo.indices()[0] for fifo in self.fifos]
        self.mode_seen = [FfMode.OFF] * self.n_robots

    def _sio_ready(self) -> bool:
        arena = self.inst.arena
        if arena.lookup(layout.KEY_FEEDFORWARD) is None:
            return False
        if arena.lookup(layout.KEY_SERVO_CTRL) is None:
            return False
        return bool(arena.existing(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)["ready"])

    # ------------------------------------------------------------------ the cycle

    def cycle(self, tick: int) -> None:
        """Rows for every set-point pushed since the last cycle, for every robot that wants
        feed-forward; then the heartbeat SIO checks."""
        ff = self.ff
        for k in range(self.n_robots):
            word = int(ff["mode"][k])
            mode = FfMode(word) if word in FF_MODES else self.mode_seen[k]
            if int(self._arm_algo[k]) != layout.ARM_NONE:
                mode = FfMode.FULL  # a robot-level servo takes the demand's q̇, q̈ from the rows
            loaded = self.held[k].follow(self.loads[k])  # what the program says it holds
            if mode != self.mode_seen[k] or loaded:  # recompute what SIO has not used yet
                self.mode_seen[k] = mode
                self.next_row[k] = self.fifos[k].indices()[0] - 1
            if mode != FfMode.OFF:
                self._servo_gains(k)
                self._robot(k, mode)
                ff["computed_mode"][k] = mode
        ff["heartbeat_tick"][:] = tick
        if self._loads_gen[0] != self.level.taken and loading.take(self.level):
            self._view_gains()  # after the tick's rows: a plugin loaded while running

    def _servo_gains(self, k: int) -> None:
        """Robot ``k``'s velocity gains k_v now (0 where a servo has none or is disabled)."""
        kv = self.arms[k].kv
        base = self.joint_map.base[k]
        for j in range(len(kv)):
            i = base + j
            views = self._kv_views[i]
            algo = int(self._algo[i])
            view = views[algo] if algo < len(views) else None
            kv[j] = float(view[0]) if view is not None and self._enabled[i] else 0.0

    def _robot(self, k: int, mode: FfMode) -> None:
        """Robot ``k``'s new rows (in the cycle): each set-point's once its successor is
        pushed (central differences), a motion's last one's (``rests_at``) at once, with the
        arm at rest there: waiting for SIO to drain the FIFO left the moving row's torques,
        its Coulomb friction among them, on an arm at rest for as long as this process ran
        late."""
        fifo = self.fifos[k]
        a = self.arms[k]
        head, tail = fifo.indices()
        if head == tail:  # drained: SIO holds at B, set-point head - 1's place
            fifo.held(a.q_i)
            if fifo.indices() == (head, tail):
                a.qd.fill(0.0)
                a.qdd.fill(0.0)
                self._write(k, head - 1, mode)
            self.next_row[k] = head
            return
        first = max(self.next_row[k], head - 1)
        for i in range(first, min(tail, first + MAX_ROWS_PER_CYCLE)):
            if not fifo.read(i, a.q_i):
                continue  # overwritten: SIO is long past it
            if not np.isfinite(a.q_i).all():
                self.next_row[k] = i + 1
                continue  # garbage SIO refuses as well: no row
            if mode == FfMode.GRAVITY or not (i + 1 < tail and fifo.read(i + 1, a.q_next)):
                if mode != FfMode.GRAVITY and not fifo.rests_at(i):
                    break  # its successor is not pushed yet: next cycle
                a.qd.fill(0.0)  # gravity only, or a motion's last: the arm rests there (SIO's
                a.qdd.fill(0.0)  # demand reaches it over the segment, from the row before)
            else:
                self._previous(k, i)
                t_in = fifo.ratio_of(i) * self.servo_period_s  # segment ending at i
                t_out = fifo.ratio_of(i + 1) * self.servo_period_s  # segment leaving i
                central_differences(a.q_prev, a.q_i, a.q_next, t_in, t_out, a.qd, a.qdd, a.s)
            self._write(k, i, mode)
            self.next_row[k] = i + 1

    def _previous(self, k: int, i: int) -> None:
        """q_{i-1} into ``q_prev``: where SIO held if set-point ``i`` is the first after a
        reset (the FIFO publishes it: a row this process wrote while the FIFO was drained may
        predate the reset, as calibration re-bases the angles), else the position its own row
        was written for (the hold), else the ring's set-point, else q_i itself (a start)."""
        a = self.arms[k]
        if self.fifos[k].held_before(i, a.q_prev):
            return
        key = i  # 1 + (i - 1)
        row = key % layout.FF_ROWS
        if int(self.ff["key"][k, row]) == key:
            np.copyto(a.q_prev, self._ff_q[k][row])
        elif not self.fifos[k].read(i - 1, a.q_prev):
            np.copyto(a.q_prev, a.q_i)

    def _write(self, k: int, index: int, mode: FfMode) -> None:
        """Compute and publish robot ``k``'s row for set-point ``index`` (its scratch's q_i,
        qd, qdd and kv), in the row's first n_joints columns."""
        ff = self.ff
        a = self.arms[k]
        key = index + 1
        row = key % layout.FF_ROWS
        tau = self.inverse[k].torque(mode, a.q_i, a.qd, a.qdd, a.kv)
        if not np.isfinite(tau).all():
            return  # never publish a torque SIO could not use (a neighbour's covers it)
        keys = ff["key"][k]
        keys[row] = layout.FF_NO_KEY  # SIO ignores the row while it changes
        self._ff_q[k][row] = a.q_i
        self._ff_tau[k][row] = tau
        self._ff_qd[k][row] = a.qd
        self._ff_qdd[k][row] = a.qdd
        keys[row] = key
        ff["rows_written"][k] += 1
