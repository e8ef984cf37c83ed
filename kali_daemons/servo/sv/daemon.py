"""The SV daemon: a servo worker that claims fed servo slots and runs them (thesis 3.3.4, 3.3.5).

Signalled by the wall clock with SIO (the SVs are gang-scheduled:
``wallclock.clock.gang_state``), an SV waits until SIO has fed the tick's slots
(``_await_feed``), then claims its work by test-and-set of the slots' ``busy`` words and runs
it (``serve``, which the lockstep executive calls directly): robots fed whole
(``arm.ArmRunner``), then every robot's built-in joints in one compiled call
(``units.Unit``), then every other fed slot one at a time (``_run``).  The SV that finishes
the tick's last slot posts SIO's done semaphore.  ``cycle`` is compiled (``kali_sv_serve``)
and hands back to Python only what needs it (``_serve_event``); ``_await_feed``,
``_learn_feed`` and ``_serve_reference`` are the same in Python, its tests' references.

A servo that raises, returns a bad status or a non-finite torque halts with a SERVO fault
naming robot, joint and algorithm; nothing a client wrote is trusted (DESIGN 7).  An SV on
another CPU than SIO's polls and rests (docs/decisions/0002-sv-polling-and-resting.md); every
other wait sleeps.  How the work is shared and checked: docs/internals/servo-level.md.
"""

from __future__ import annotations

import ctypes
import gc
import math
from typing import Any

import numpy as np
import posix_ipc

from ...core import atomic, layout, rt
from ...core.errors import DaemonError
from ...core.kernels import SV_ARM, SV_DONE, SV_FAULT, SV_FEED, SV_LEFT, SV_SLOT, SV_START, Kernel
from ...core.layout import FaultCode, ShadowState, SlotOp, SlotReset
from ...runtime.config import period_ticks
from ...runtime.daemon import Daemon, drain
from .. import loading, shadow
from ..algorithms.algorithm import Handover, step
from ..level import ServoLevel, apply_op, handover
from . import arm, units

READY_TIMEOUT_S = 30.0  # how long an SV waits at start for SIO to lay out the slots
FEED_HISTORY = 16  # ticks over which a polling SV learns when SIO's feed comes
FEED_MARGIN_NS = 50_000  # it wakes this much before the earliest of them (a timer's lateness)
# A polling SV shares the servos only where they took over SHARE_NS (SIO's feed to every
# servo done, ``sv_served_max_ns``) in SHARE_LOOKS of its last FEED_HISTORY looks, not on a
# single long tick (docs/decisions/0002-sv-polling-and-resting.md); else it wakes once they
# are done, and rests
SHARE_NS = 80_000
SHARE_LOOKS = 4


class ServoWorker(Daemon):
    """One SV: claims fed servo slots by test-and-set and runs them."""

    kind = "sv"

    def on_configure(self) -> None:
        """Attach to the slots SIO lays out; find this worker's number and feed semaphore."""
        inst = self.inst
        try:
            self.index = int(self.name.split(".", 1)[1])
        except (IndexError, ValueError):
            raise DaemonError(f"{self.name}: an SV is named sv.<n>") from None
        deadline = rt.monotonic_ns() + int(READY_TIMEOUT_S * 1e9)
        while inst.arena.lookup(layout.KEY_SERVO_CTRL) is None or not int(
            inst.arena.existing(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)["ready"]
        ):
            if rt.monotonic_ns() > deadline:
                raise DaemonError(f"{self.name}: SIO did not lay out the servo slots in time")
            if inst.shutting_down:
                return
            rt.AbsoluteSleeper().until(rt.monotonic_ns() + 5_000_000)
        self.level = ServoLevel(inst)
        self.me = self.index + 1  # the value this worker writes into a claimed busy word
        self.feed = inst.feed_semaphore(self.index)
        self.done_sem = inst.done_semaphore()
        n = self.level.n
        # claim order: worker k starts k/N of the way round, so workers rarely collide
        count = max(1, int(self.level.ctrl["sv_count"]) or 1)
        start = (self.index * n) // count
        self.order = [(start + m) % n for m in range(n)]
        self.busy = self.level.slots["busy"]
        registry = self.level.registry
        self._setup_units(count)
        self.n_algos = len(registry)
        self._loads_gen = self.level.loads["generation"].reshape(1)  # plugins loaded so far
        # per slot: the algorithm its robot starts with, what an invalid index is restored to
        self.configured = [
            registry.index(robot.servo)
            for robot in inst.config.robots
            for _ in range(robot.n_joints)
        ]
        self.cas = atomic.CompareExchange32()
        c = self.level.ctrl
        self._fed = c["fed"]
        self._tick = c["tick"]
        self._exec_last = c["sv_exec_last_ns"][self.index : self.index + 1]
        self._exec_max = c["sv_exec_max_ns"][self.index : self.index + 1]
        self._servos = c["sv_servos"][self.index : self.index + 1]
        self._exec_hist = c["sv_exec_hist"][self.index]
        self._fed_tick = c["sv_fed_tick"][self.index : self.index + 1]
        lockstep = inst.lockstep
        self.feed_timeout_s = (
            inst.config.clock.lockstep_ack_timeout_s
            if lockstep
            else inst.config.clock.serious_miss_tolerance_ms / 1000.0
        )
        me, sio = inst.config.process(self.name), inst.config.process("sio")
        if not lockstep and me.cpu is not None and me.cpu != sio.cpu:
            # poll at most half a servo period (a short servo period, a long poll_us)
            self.poll_ns = min(me.poll_us * 1000, self.period_ns // 2)
        # a polling SV rests while an SV on SIO's CPU, which never does, runs every servo
        self.servo_ticks = self.rest_ticks = self.period_ticks
        sv_cpus = [p.cpu for p in inst.config.processes if p.kind == "sv"]
        if self.poll_ns and me.rest_ms and sio.cpu in sv_cpus:
            self.rest_ticks = period_ticks(me.rest_ms, inst.config.clock.base_tick_ms)
        # when SIO's feed came in the last ticks, in ns after the tick's due time, and how long
        # the servos took from it (_learn_feed)
        self._release = inst.procs["release_ns"][self.slot : self.slot + 1]
        self._fed_ns = c["fed_ns"]
        self._served_max = c["sv_served_max_ns"][self.index : self.index + 1]
        self._feed_seen = np.zeros(FEED_HISTORY, np.int64)
        self._served = np.zeros(FEED_HISTORY, np.int64)
        self._feed_cap = self.period_ns // 2  # never wake later than half a tick in
        self._bind_serve()

    def _setup_units(self, count: int) -> None:
        """The robots' units in this worker's order, each bound to its slots and the
        built-ins' blocks (``units.Unit``; the kernels' library loaded, built first if this
        source has none yet).  Outside the cycle."""
        lv = self.level
        registry = lv.registry
        spans = [lv.map.span(k) for k in range(lv.n_robots)]
        first = (self.index * lv.n_robots) // count
        pid_a, pd_a = (registry.index(name) for name in units.ALGORITHMS)
        self._left = np.zeros(max(lv.map.counts, default=1), np.int64)
        pid, pd = lv.blocks[pid_a], lv.blocks[pd_a]
        self.units = []
        for k in ((first + m) % lv.n_robots for m in range(lv.n_robots)):
            lo, hi = spans[k].start, spans[k].stop
            unit = units.Unit(
                lv.slots, pid, pd, lo, hi, pid_a, pd_a, self.me, self.index, self._left
            )
            self.units.append(unit)
        # each robot as one unit when SIO feeds it whole (a robot-level servo: arm.py)
        self.arms = [
            arm.ArmRunner(self, k) for k in ((first + m) % lv.n_robots for m in range(lv.n_robots))
        ]
        self._arm_addr = [lv.busy_addr[a.lo] for a in self.arms]
        self._arm_busy = [lv.slots["busy"][a.lo : a.lo + 1] for a in self.arms]

    def _bind_serve(self) -> None:
        """``serve`` compiled (``kali_sv_serve``; ``_serve_reference`` is what it does), on the
        units and the order above; outside the cycle."""
        lv, c = self.level, self.level.ctrl
        units = (ctypes.c_void_p * max(1, len(self.units)))(
            *(ctypes.addressof(u.args) for u in self.units)
        )
        self._arm_lo = np.array([a.lo for a in self.arms], dtype=np.int64)
        self._order = np.array(self.order, dtype=np.int64)
        self._done_address = rt.semaphore_address(self.done_sem)
        self._feed_address = rt.semaphore_address(self.feed)
        keep = (self._fed_ns, self._served_max, self._release, self._feed_seen, self._served)
        self._serve_kernel = Kernel(
            "kali_sv_serve",
            (units, self.units, self._arm_lo, self._order, lv.slots, c, *keep, self._poll_after),
            n=lv.n,
            n_arms=len(self.arms),
            n_units=len(self.units),
            slots=lv.slots.ctypes.data,
            fed_tick_out=self._fed_tick.ctypes.data,
            ctrl_fed=self._fed.ctypes.data,
            ctrl_done=lv.done_addr,
            ctrl_tick=self._tick.ctypes.data,
            arm_lo=self._arm_lo.ctypes.data,
            units=ctypes.addressof(units),
            order=self._order.ctypes.data,
            done_sem=self._done_address,
            feed_sem=self._feed_address,
            poll_ns=self.poll_ns,
            feed_wait_ns=int(self.feed_timeout_s * 1e9),
            learn=1 if self.poll_ns else 0,
            fed_ns=self._fed_ns.ctypes.data,
            served_max=self._served_max.ctypes.data,
            release=self._release.ctypes.data,
            feed_seen=self._feed_seen.ctypes.data,
            served=self._served.ctypes.data,
            history=FEED_HISTORY,
            margin_ns=FEED_MARGIN_NS,
            share_ns=SHARE_NS,
            share_looks=SHARE_LOOKS,
            cap_ns=self._feed_cap,
            servo_ticks=self.servo_ticks,
            rest_ticks=self.rest_ticks,
            want_ticks=self.servo_ticks,
            poll_after=self._poll_after.ctypes.data,
            me=self.me,
            arm_free=layout.ARM_FREE,
            exec_last=self._exec_last.ctypes.data,
            exec_max=self._exec_max.ctypes.data,
            servos=self._servos.ctypes.data,
            exec_hist=self._exec_hist.ctypes.data,
            linear_us=layout.HIST_LINEAR_US,
            log_bins=layout.HIST_LOG_BINS,
        )
        self._serve_args = self._serve_kernel.args

    def on_shutdown(self) -> None:
        """Give back the compiled serve's opens of the done and feed semaphores."""
        rt.close_semaphore_address(getattr(self, "_done_address", 0))
        rt.close_semaphore_address(getattr(self, "_feed_address", 0))
        self._done_address = self._feed_address = 0

    def cycle(self, tick: int) -> None:
        """Inside the cycle: wait for the feed, then claim and run slots until none is left.
        Compiled: ``kali_sv_serve`` from its stage ``SV_FEED`` (``_await_feed``; SIO did not
        feed ``tick`` in time, halted or itself late: nothing to run), then as ``serve``."""
        self._serve_args.wanted = tick
        self._serve_from(SV_FEED)
        self._follow_learnt_period()
        if self._loads_gen[0] != self.level.taken:
            self.take_loads()

    def cycle_reference(self, tick: int) -> None:
        """What ``cycle`` does, with the feed awaited in Python (``_await_feed``)."""
        fed_tick = self._await_feed(tick)
        if fed_tick >= 0:
            self.serve(fed_tick)
        self._follow_learnt_period()
        if self._loads_gen[0] != self.level.taken:
            self.take_loads()

    def take_loads(self) -> None:
        """Take the servo plugins loaded since the last cycle (``servo.loading``), the tick
        acknowledged first: after the cycle, in the gap before the next (what a load may
        cost was checked by the loading client).  Called by the lockstep executive after
        this SV's share of SIO's tick."""
        wait = getattr(self, "_clock_wait", None)
        if wait is not None:
            wait.settle()
        if loading.take(self.level, self.index):
            self.n_algos = len(self.level.registry)
            for runner in self.arms:
                runner.bind_loaded()
            gc.freeze()  # what it made joins the frozen heap (decision 0007); no collection

    def _follow_learnt_period(self) -> None:
        """Inside the cycle: to rest, or back from it, where the feed's learning chose
        another period (``_learn_feed``'s ``want_ticks``); one field read otherwise."""
        want = self._serve_args.want_ticks
        if want != self.period_ticks:
            self._set_period(want)

    def serve(self, fed_tick: int) -> None:
        """Inside the cycle: claim and run fed slots of SIO's tick ``fed_tick`` until none is
        left.  Called in the lockstep executive by SIO itself where it would post the feeds
        (``SioCycle.serve``); ``cycle`` does the same once its feed came."""
        self._serve_args.fed_tick = fed_tick
        self._serve_from(SV_START)

    def _serve_from(self, stage: int) -> None:
        """``kali_sv_serve`` from ``stage`` until it is done; what runs Python, it hands back
        here (``_serve_event``)."""
        self._serve_args.stage = stage
        while (event := self._serve_kernel()) != SV_DONE:
            self._serve_event(event)

    def _serve_event(self, event: int) -> None:
        """What ``kali_sv_serve`` hands back: a robot fed whole it claimed (its model and
        robot-level servo), a unit's non-finite torque (a halt), the slots a unit left and
        a single slot it claimed (a plugin, a mailbox operation, a reset, a disabled servo)."""
        a = self._serve_args
        if event == SV_ARM:
            runner = self.arms[a.at - 1]
            runner.run(a.tick_now)
            a.count = runner.n
        elif event == SV_FAULT:
            unit = self.units[a.unit]
            fault = unit.fault()
            name = self.level.registry[self.level.slot_structs[fault].algo].name
            self._servo_fault(fault, name, f"returned torque {unit.bad()!r} N·m, status 0")
        elif event == SV_LEFT:
            structs = self.level.slot_structs
            for m in range(self.units[a.unit].left()):
                i = int(self._left[m])
                self._run(i, structs[i], a.tick_now)
                self._done(1, a.fed)
        elif event == SV_SLOT:
            i = int(self._order[a.at - 1])
            self._run(i, self.level.slot_structs[i], a.tick_now)
            a.count = 1
        else:
            raise DaemonError(f"{self.name}: the compiled serve returned event {event}")

    def _serve_reference(self, fed_tick: int) -> None:
        """``serve`` in Python, step for step what ``kali_sv_serve`` does (its test's
        reference)."""
        self._fed_tick[0] = fed_tick  # before any slot: SIO may acknowledge for it now
        lv = self.level
        t0 = rt.monotonic_ns()
        fed = int(self._fed)
        if fed == 0:
            return
        cas = self.cas
        busy, addr, structs, me = self.busy, lv.busy_addr, lv.slot_structs, self.me
        tick_now = int(self._tick)
        ran = 0
        for m, runner in enumerate(self.arms):  # robots fed whole: one SV runs each
            if self._arm_busy[m][0] == layout.ARM_FREE:
                ok, _ = cas(self._arm_addr[m], layout.ARM_FREE, me)
                if ok:
                    runner.run(tick_now)
                    ran += runner.n
                    self._done(runner.n, fed)
        for unit in self.units:
            ran += self._serve_unit(unit, tick_now, fed)
        for i in self.order:
            if busy[i] != 0:
                continue  # not fed, or another worker has it
            ok, _ = cas(addr[i], 0, me)
            if not ok:
                continue
            self._run(i, structs[i], tick_now)
            ran += 1
            self._done(1, fed)
        if ran:
            exe = rt.monotonic_ns() - t0
            self._exec_last[0] = exe
            if exe > self._exec_max[0]:
                self._exec_max[0] = exe
            self._servos[0] += ran
            self._exec_hist[layout.lateness_bin(exe)] += 1

    def _serve_unit(self, unit: units.Unit, tick: int, fed: int) -> int:
        """Claim and run one robot's unit (``units.Unit``), then any slot it claimed for the
        per-slot path; the number of slots done.  Inside the cycle."""
        ran = unit.run(tick)
        left = unit.left()
        if ran:
            fault = unit.fault()
            if fault >= 0:
                s = self.level.slot_structs[fault]
                name = self.level.registry[s.algo].name
                self._servo_fault(fault, name, f"returned torque {unit.bad()!r} N·m, status 0")
            self._done(ran, fed)
        structs = self.level.slot_structs
        for m in range(left):
            i = int(self._left[m])
            self._run(i, structs[i], tick)
            self._done(1, fed)
        return ran + left

    def _done(self, count: int, fed: int) -> None:
        """Count ``count`` slots done; the tick's last one posts SIO's done semaphore."""
        if atomic.fetch_add32(self.level.done_addr, count) + count == fed:
            self.done_sem.release()  # the tick's last servo: wake SIO

    def _await_feed(self, tick: int) -> int:
        """Sleep until SIO has fed ``tick`` (or a later tick); the tick fed, -1 on the timeout.
        The reference of ``kali_sv_serve``'s stage ``SV_FEED`` (``cycle``).

        SIO's fed tick (``ctrl.tick``, written before it posts) says whether ``tick`` is fed;
        its posts on the feed semaphore only wake.  SIO posts every SV's each tick it runs, so
        ticks this SV missed or rested through leave posts behind: each look takes every post
        there is first, then reads the fed tick.  (A post taken as this tick's would find the
        last tick's slots all claimed and leave this SV's share to the others.)

        Not fed yet, an SV on another CPU than SIO's first polls the feed for ``poll_ns`` (it
        is awake anyway, having woken on its timer shortly before the feed is due and polled
        for the clock's signal: ``Daemon._clock_driven_loop``, ``_learn_feed``), so SIO's post
        wakes nobody: a post that wakes a halted vCPU can stall the poster's vCPU, SIO's
        (docs/decisions/0002-sv-polling-and-resting.md).
        """
        now = rt.monotonic_ns()
        end, poll_end = now + int(self.feed_timeout_s * 1e9), now + self.poll_ns
        feed = self.feed
        while True:
            drain(feed)
            fed = int(self._tick)
            if fed >= tick:
                if self.poll_ns:
                    self._learn_feed()
                return fed
            if self.poll_ns:
                rt.poll_semaphore(feed, poll_end)
            while True:
                try:
                    feed.acquire(max(0.0, (end - rt.monotonic_ns()) / 1e9))
                    break  # then the fed tick again, with any other post
                except posix_ipc.BusyError:  # on the wall-time clock: judged on ours
                    if rt.monotonic_ns() >= end:
                        return -1
                except posix_ipc.SignalError:  # a handler ran: wait on for what is left
                    continue

    def _learn_feed(self) -> None:
        """A polling SV, once it has this tick's feed: note when SIO fed it (``fed_ns``),
        after the tick's due time, and the longest the servos took from a feed since it last
        looked (``sv_served_max_ns``, which SIO raises each tick and this takes), and choose
        when to wake from now on (``poll_after_ns``) and how often (``want_ticks``).

        Worth sharing (over ``SHARE_NS`` in ``SHARE_LOOKS`` of the last ``FEED_HISTORY``
        looks; half that while shared): wake ``FEED_MARGIN_NS`` before the earliest feed of
        those looks and claim servos beside the SV on SIO's CPU.  Otherwise wake after the
        latest feed plus ``SHARE_NS``, only to acknowledge, and rest: signalled every
        ``rest_ticks`` (``processes.sv.rest_ms``) until a look sees a tick worth sharing.
        The measurements behind these choices: docs/decisions/0002-sv-polling-and-resting.md."""
        a = self._serve_args  # the history's place is the compiled serve's (its feed_k)
        k = a.feed_k
        self._feed_seen[k] = int(self._fed_ns) - int(self._release[0])
        self._served[k] = int(self._served_max[0])
        self._served_max[0] = 0
        a.feed_k = (k + 1) % FEED_HISTORY
        limit = SHARE_NS // 2 if a.sharing else SHARE_NS  # shared, they take ~half
        share = int((self._served > limit).sum()) >= SHARE_LOOKS
        a.sharing = int(share)
        if share:
            after = int(self._feed_seen.min()) - FEED_MARGIN_NS
        else:
            after = int(self._feed_seen.max()) + SHARE_NS
        self._poll_after[0] = max(0, min(after, self._feed_cap))
        a.want_ticks = self.servo_ticks if share else self.rest_ticks

    def _run(self, i: int, s: Any, tick: int) -> None:
        """Run slot ``i``'s servo once (mailbox first, then a reset, then the step)."""
        lv = self.level
        op = s.op
        if op != SlotOp.NONE:
            apply_op(lv, i, op)
            atomic.store32(lv.op_addr[i], SlotOp.NONE)
        if s.algo >= self.n_algos:  # not an SV's write: back to the configured servo
            handover(lv, i, self.configured[i])
        if s.reset:
            a = int(s.algo)
            if s.reset == SlotReset.SHIFT:  # new coordinates, same motion: bumpless
                handover(lv, i, a)
            else:  # power on: at rest, no torque yet
                pos = s.position
                lv.registry[a].handover(lv.structs[i][a], Handover(pos, 0.0, pos, 0.0, 0.0))
                s.torque = 0.0
            s.reset = SlotReset.NONE
        if not s.enabled:
            s.torque = 0.0
            s.ran_tick = tick
            return
        a = s.algo
        alg = lv.registry[a]
        t0 = rt.monotonic_ns()
        try:
            torque, error, status = step(alg, lv.structs[i][a], s.demand, s.position, s.demand_vel)
        except Exception as exc:  # the user's servo: halt and say which
            self._servo_fault(i, alg.name, f"raised {type(exc).__name__}: {exc}")
            return
        s.exec_ns = rt.monotonic_ns() - t0
        if status != 0 or not math.isfinite(torque):
            self._servo_fault(i, alg.name, f"returned torque {torque!r} N·m, status {status!r}")
            return
        s.torque = torque
        s.error = error
        s.status = status
        s.ran_tick = tick
        s.sv = self.index
        if s.shadow_state == ShadowState.RUNNING:
            self.shadow_step(i, s, 0.0)

    def shadow_step(self, i: int, s: Any, ff: float) -> None:
        """Step slot ``i``'s shadow trial (``kali_daemons.servo.shadow``) on the inputs its active
        servo just had and compare: (shadow + ``ff``) − the slot's torque, ``ff`` being the
        feed-forward SIO adds to a joint servo's torque and not to the active one's (0.0
        under a joint servo, whose torque gets it too).  A shadow that raises or returns a
        bad status or a non-finite torque ends its trial, never halts: nothing applied it.
        Inside the cycle."""
        lv = self.level
        b = s.shadow
        if not 0 <= b < self.n_algos or b == s.algo:  # not an SV's write: end it
            shadow.end_joint(lv, i, ShadowState.STOPPED)
            return
        try:
            alg = lv.registry[b]
            torque, _, status = step(alg, lv.structs[i][b], s.demand, s.position, s.demand_vel)
        except Exception:
            shadow.end_joint(lv, i, ShadowState.RAISED)
            return
        if status != 0 or not math.isfinite(torque):
            s.shadow_torque = torque
            shadow.end_joint(lv, i, ShadowState.FAILED)
            return
        shadow.record(s, torque, torque + ff - s.torque)

    def _servo_fault(self, i: int, algo: str, what: str) -> None:
        s = self.level.slot_structs[i]
        s.torque = 0.0
        self.inst.raise_fault(
            FaultCode.SERVO, self.name, f"servo '{algo}' on {self.level.map.label(i)} {what}"
        )
