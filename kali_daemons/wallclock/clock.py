"""The master wall clock (thesis 3.2.1, 3.6.2; DESIGN section 3): one daemon, on purpose, for
the clock's commands, signals, supervision and halts over one process table.

Each base tick, for every slot due, it checks that the slot acknowledged its previous signal,
then writes the tick and its due time and posts the slot's semaphore
(interrupt-then-acknowledge).  A missing acknowledgement is a missed deadline, counted and
that signal skipped; a serious process halts the system once unacknowledged for longer than
``serious_miss_tolerance_ms`` of the time the machine gave the clock (``_missed``,
``_watch``; docs/decisions/0004-clock-stall-rule.md).  SIO and the SVs are signalled as a
gang (``gang_state``).  Real time sleeps to absolute deadlines and skips ahead after an
overrun; lockstep never sleeps and waits for each stage's acknowledgements.  A process that
has died halts the system if serious and is left out if not (DESIGN 7).  The clock runs above
SIO on its CPU: what it does between ticks delays SIO.  More: docs/internals/servo-level.md.
"""

from __future__ import annotations

import math
import os
import threading

import numpy as np
import posix_ipc

from ..core import futex, layout, rt
from ..core.layout import ClockCommand, FaultCode, ProcState, RunMode
from ..core.spinlock import ProcStat, pid_alive
from ..runtime.config import MAX_PERIOD_MS, ms_to_ns
from ..runtime.daemon import Daemon, _CycleStats, drain
from ..runtime.flightrec import FlightDumper
from ..runtime.instance import decode
from ..runtime.stalls import CpuWitness

STOPPED_WAIT_S = 0.2
MAX_CLOCK_ARG = 1e12  # ticks to step, or ms to set the time to: ~30 years at 1 ms
LOCKSTEP_SLICE_S = 0.05  # lockstep ack waits check for dead processes this often
PACE_SLICE_S = 0.005  # paced by the hardware: with no packet this long, the clock supervises
GANG_RUNS, GANG_SIO_LATE, GANG_SVS_LATE = 0, 1, 2  # gang_state: SIO and the SVs this tick
# A wake-up of the clock later than this was the machine's stall, and the time is not held
# against anyone (_missed); twice the machine's p99.9 wake-up lateness, so on a sound machine
# nothing changes (docs/decisions/0004-clock-stall-rule.md)
STALL_NS = 200_000


class WallClock(Daemon):
    """The wall clock process: owns the tick and signals every periodic process."""

    kind = "wallclock"

    def on_configure(self) -> None:
        """Read the clock parameters kalictl start wrote into the clock record."""
        c = self.inst.clock
        self.base_ns = int(c["base_tick_ns"])
        self.busy_ns = int(c["busy_wait_ns"])
        self.tolerance_ns = int(c["serious_miss_tolerance_ms"]) * 1_000_000
        self.lockstep_timeout_s = int(c["lockstep_timeout_ms"]) / 1000.0
        self.lockstep = bool(c["lockstep"])
        # real time paced by the hardware: each state packet a networked robot's link posts on
        # the clock's own semaphore is a base tick (decision 0015); none in a slice: the clock
        # only supervises
        self.paced = bool(c["paced"]) and not self.lockstep
        self._view_table(self.inst.procs)
        log = self.inst.misses
        self._log_entries = log["entries"]
        self._log_count = log["count"].reshape(1)  # a writable one-element view
        self._sems = [self.inst.slot_semaphore(i) for i in range(layout.MAX_PROCESSES)]
        self._pace = self._sems[self.slot]
        self._cmd_sem = self.inst.command_semaphore()
        self._ack_sem = self.inst.ack_semaphore()
        # the words programs wait on (futex.py): a command taken, the clock stopped
        self._cmd_done_addr = c["cmd_done"].ctypes.data
        self._mode_addr = c["mode"].ctypes.data
        self._gen = self._rates_gen = -1
        self._slots: list[int] = []  # periodic slots in (stage, slot) order
        self._serious: list[bool] = []
        self._period: list[int] = []
        self._stages: list[int] = []
        self._watched: list[int] = []  # self-timed slots (real time): watched by heartbeat
        self._watch_ns: list[int] = []  # heartbeat age that makes the clock look them up
        self._watch_next: list[int] = []  # earliest next look-up of a stale, live one
        self._flight = FlightDumper(self.inst)  # dumps the flight recorder after a halt
        self.max_period_ticks = max(1, ms_to_ns(MAX_PERIOD_MS) // self.base_ns)
        self._good_period = np.ones(layout.MAX_PROCESSES, dtype=np.int64)
        procs = self.inst.config.processes
        self._gang_lead = next((q.name for q in procs if q.kind == "sio"), "")
        self._gang_names = {q.name for q in procs if q.kind == "sv"}
        self._lead = -1  # slot of SIO while it is clocked, else -1
        self._members: list[int] = []  # slots of the clocked SVs (SIO's gang)
        self._member: list[bool] = []  # per entry of _slots: an SV
        self._suspect = [0] * layout.MAX_PROCESSES  # a tick's missers (_slots indices)
        self._fresh = [False] * layout.MAX_PROCESSES  # ... each not one at its tick before
        self._suspected = [-1] * layout.MAX_PROCESSES  # per slot: the tick it last was one
        # The time the machine gave the clock (decision 0004): a wake-up over STALL_NS
        # late is time the clock, at the top priority of its CPU, was not run; a serious
        # process is judged only on the rest (_missed, _watch).  Real time only.
        self._lost_ns = 0  # the clock's stalls, summed
        self._sig_lost = [0] * layout.MAX_PROCESSES  # _lost_ns at each slot's last signal
        # the last wake-ups (time, _lost_ns after it), a ring: the stalls since a self-timed
        # process's heartbeat (_lost_since), 4 tolerances and more long
        ring = 4 * (self.tolerance_ns // self.base_ns) + 64
        self._wake_ns, self._wake_lost = [0] * ring, [0] * ring
        self._wakes = 0
        # and the time the machine gave each other CPU a serious process is bound to: a
        # witness of it, started with the clock's loop (real time only)
        own = self.inst.config.process("wallclock").cpu
        cpus = {q.cpu for q in procs if q.serious and q.cpu is not None and q.cpu != own}
        self._witnesses = [] if self.lockstep else [CpuWitness(c, STALL_NS, ring) for c in cpus]
        self._witness_of: list[CpuWitness | None] = [None] * layout.MAX_PROCESSES
        # each slot's process's /proc stat, kept open (_read_table): whether a process late
        # for a tick died is asked every tick it is late, and a path lookup and open each
        # time made the clock's tick three times as long, taking from SIO below it the pieces
        # of its CPU a stall left (issue 58)
        self._stat: list[ProcStat | None] = [None] * layout.MAX_PROCESSES
        # What the clock does after a tick's signals (its accounts, the look-ups of the
        # processes late for it) runs below the serious processes of its CPU, as an
        # interrupt's bottom half: where a stall leaves that CPU in pieces, the clock's work
        # for its late ticks filled them and starved SIO, whose watchdog then cut the arms
        # (issue 58).  A witness of another CPU puts the clock back at its priority if it
        # stands below for a tick (a process spinning there must not stop the clock).  Set
        # in real time when the clock runs at SCHED_FIFO and has a witness (_loop).
        here = [q.priority for q in procs if q.cpu == own and q.serious and q.priority > 0]
        self._bottom = max(1, min(here, default=2) - 1)
        self._top = 0  # the clock's own SCHED_FIFO priority, once it has a bottom half
        self._guard: CpuWitness | None = None  # the witness guarding it; None: no bottom half

    def on_activate(self) -> None:
        """Start the witnesses of the other CPUs; publish the clock as ready (kalictl start
        waits for it)."""
        for w in list(self._witnesses):
            err = w.start()
            if err:
                self._witnesses.remove(w)
                self.log.warning(
                    "wallclock: no witness of CPU %d (%s): a stall of that CPU counts against "
                    "the processes bound to it",
                    w.cpu,
                    os.strerror(err),
                )
        self.inst.clock["pid"] = os.getpid()
        self.inst.clock["ready"] = 1

    def on_shutdown(self) -> None:
        """End the witnesses' threads; close the processes' stat files."""
        for w in self._witnesses:
            w.close()
        for stat in self._stat:
            if stat is not None:
                stat.close()

    def cycle(self, tick: int) -> None:  # pragma: no cover - the clock overrides the loop
        raise AssertionError("the wall clock drives itself")

    # ------------------------------------------------------------------ registry

    def _view_table(self, p: np.ndarray) -> None:
        """View each field of the process table the clock reads or writes once (indexing a
        structured array by field name builds a new view every time)."""
        self._sig, self._rel, self._ack = p["signal_tick"], p["release_ns"], p["ack_tick"]
        self._vouched = p["vouched_tick"]
        self._due, self._signals = p["next_due"], p["signals"]
        self._misses, self._consec = p["misses"], p["consecutive_misses"]
        self._max_consec = p["max_consecutive_misses"]
        self._heart = p["heartbeat_ns"]
        self._periodic, self._state, self._stage = p["periodic"], p["state"], p["stage"]
        self._serious_of, self._pid, self._names = p["serious"], p["pid"], p["name"]
        self._period_of, self._cpu_of = p["period_ticks"], p["cpu"]

    def _rescan(self) -> None:
        """Take up what changed in the process table; at the top of the loop, so after a
        tick's signals but before the clock sleeps: in real time in the clock's bottom half,
        below SIO (it delayed SIO's tick when the clock did it above). A rate change (an SV
        resting or back from it, a few times a minute; ``set_control_rate``) re-reads only
        the periods of the slots the clock has, in place (``_read_rates``); a process
        registering or leaving has the whole table read (``_read_table``): reading it all
        for every rate change delayed SIO's tick
        (docs/decisions/0010-clock-reads-only-rates.md)."""
        c = self.inst.clock
        gen, rates = int(c["registry_gen"]), int(c["rates_gen"])
        if gen != self._gen:
            self._gen, self._rates_gen = gen, rates
            self._read_table()
        elif rates != self._rates_gen:
            self._rates_gen = rates
            self._read_rates()

    def _read_table(self) -> None:
        """Read the periodic slots in (stage, slot) order, whether each is serious, SIO and
        its gang of SVs among them, and the self-timed slots to watch (real time), from the
        whole table at once (numpy); then their periods (``_read_rates``)."""
        active = self._state == ProcState.ACTIVE
        periodic = self._periodic != 0
        live = np.flatnonzero(periodic & active)
        live = live[np.argsort(self._stage[live], kind="stable")]
        names = self._names[live]
        lead = live[names == self._gang_lead.encode()] if self._gang_lead else live[:0]
        member = np.isin(names, [n.encode() for n in self._gang_names]) & (len(lead) > 0)
        self._slots = live.tolist()
        self._serious = (self._serious_of[live] != 0).tolist()
        self._stages = self._stage[live].tolist()
        self._lead = int(lead[0]) if len(lead) else -1
        self._member = member.tolist()
        self._members = live[member].tolist()
        self._period = [1] * len(live)
        by_cpu = {w.cpu: w for w in self._witnesses}
        for i in range(layout.MAX_PROCESSES):
            self._witness_of[i] = by_cpu.get(int(self._cpu_of[i]))
        watched = ~periodic & active & (self._pid > 0)
        watched[self.slot] = False
        self._watched = np.flatnonzero(watched).tolist()
        for i in np.flatnonzero(active & (self._pid > 0)).tolist():
            stat, pid = self._stat[i], int(self._pid[i])
            if stat is None or stat.pid != pid:
                if stat is not None:
                    stat.close()
                self._stat[i] = ProcStat(pid)
        self._watch_ns = [0] * len(self._watched)
        self._watch_next = [0] * len(self._watched)
        self._read_rates()

    def _read_rates(self) -> None:
        """Re-read the periods of the clock's slots in place, no list built: each periodic
        slot's (``_valid_period``; a tick due under a longer period re-aligned to the new
        one, so no process is signalled later than its period says), and the heartbeat age
        that has the clock look a self-timed one up (two of its periods)."""
        tick = int(self.inst.clock["tick"])
        due, period = self._due, self._period
        for k, i in enumerate(self._slots):
            per = self._valid_period(i)
            period[k] = per
            if due[i] > tick + per:
                due[i] = (tick // per + 1) * per
        for k, i in enumerate(self._watched):
            self._watch_ns[k] = 2 * max(1, int(self._period_of[i])) * self.base_ns

    def _valid_period(self, i: int) -> int:
        """Slot ``i``'s period in ticks: the one in its record if ``set_control_rate`` would
        allow it (1 tick .. MAX_PERIOD_MS), else the last valid one (DESIGN 7: the process
        table is written by other processes)."""
        per = int(self._period_of[i])
        if 1 <= per <= self.max_period_ticks:
            self._good_period[i] = per
        return int(self._good_period[i])

    # ------------------------------------------------------------------ loop

    def _loop(self) -> None:
        c = self.inst.clock
        header, fault = self.inst.arena.header, self.inst.fault
        stats = _CycleStats(self.inst.procs, self.slot)
        sleeper = rt.AbsoluteSleeper()
        now = rt.monotonic_ns
        base = self.base_ns
        tick = int(c["tick"])
        t0 = 0
        if not self.lockstep and self._rt.priority > self._bottom and self._witnesses:
            self._top, self._guard = self._rt.priority, self._witnesses[0]
            self._above_param = os.sched_param(self._top)
            self._below_param = os.sched_param(self._bottom)
            self._guard.guard(threading.get_native_id(), self._top, self.base_ns)
        while not self._leave and not header["shutdown"]:
            if c["cmd_seq"] != c["cmd_done"]:
                t0 = self._command(now(), t0)
                tick = int(c["tick"])
            mode = int(c["mode"])
            if mode != RunMode.STOPPED and fault["active"]:
                c["mode"] = mode = RunMode.STOPPED  # halt (DESIGN 7): a fault stops the clock
            if mode == RunMode.STOPPED:
                if self.paced:
                    drain(self._pace)  # packets while stopped are no ticks to catch up on
                self._flight.dump_if_halted()  # once per fault, nothing signalled (DESIGN 7)
                self.inst.procs[self.slot]["heartbeat_ns"] = now()
                futex.wake(self._mode_addr)  # a step done, a halt: whoever waits for it
                try:
                    self._cmd_sem.acquire(STOPPED_WAIT_S)
                except (posix_ipc.BusyError, posix_ipc.SignalError):
                    pass
                continue
            self._rescan()
            if self.lockstep:
                t = now()
                c["tick"] = tick
                if not self._lockstep_tick(tick):
                    continue  # halted inside the tick: it stays unfinished, not counted
                stats.record(tick, t, t, now())
                tick += 1
                c["tick"] = tick
                if mode == RunMode.STEPPING and tick >= int(c["step_target"]):
                    c["mode"] = RunMode.STOPPED
                continue
            if self.paced:
                tick = self._paced_tick(tick, stats)
                continue
            due = t0 + tick * base
            above = self._above()
            if self.busy_ns:
                sleeper.until(due - self.busy_ns)
                rt.spin_until(due)
            else:
                sleeper.until(due)
            woke = now()
            planned = due  # lateness is measured against the deadline that was missed
            # a tick that came while the clock's bottom half was still waiting for the
            # processes above it is theirs, not the machine's: late only from then
            self._count_lost(woke, woke - max(due, above))
            if woke - due >= base:  # overrun: skip ahead, no burst of catch-up ticks
                skip = (woke - due) // base
                c["overruns"] += 1
                c["skipped_ticks"] += skip
                tick += skip
                due += skip * base
            c["tick"] = tick
            if self._tick(tick, due):
                continue
            stats.record(tick, planned, woke, now())
            if self._watched:
                self._watch(now())
            tick += 1

    def _paced_tick(self, tick: int, stats: _CycleStats) -> int:
        """Real time paced by the hardware: wait for the next state packet (a post of the
        clock's semaphore), which is this tick's due time, and signal it; the next tick.
        Packets the clock was too late for are skipped, as an overrun is (no burst of
        catch-up ticks); none within a slice: the clock supervises and asks again."""
        now = rt.monotonic_ns
        self._above()
        try:
            self._pace.acquire(PACE_SLICE_S)
        except (posix_ipc.BusyError, posix_ipc.SignalError):
            self._watch(now())
            return tick
        woke = now()
        c = self.inst.clock
        skip = drain(self._pace)
        if skip:
            c["overruns"] += 1
            c["skipped_ticks"] += skip
            tick += skip
        c["tick"] = tick
        if self._tick(tick, woke):
            return tick + 1
        stats.record(tick, woke, woke, now())
        if self._watched:
            self._watch(now())
        return tick + 1

    def _tick(self, tick: int, due: int) -> bool:
        """A real-time tick: its signals at the clock's priority (``_realtime_tick``) and
        the look-ups of the processes newly late for it (a kill is found at once: a process
        killed at a higher priority than the bottom half frees its memory first), then,
        below the serious processes of its CPU, those of the processes still late; True if
        it halted."""
        suspects = self._realtime_tick(tick, due)
        if suspects and self._look_up(tick, suspects, True):
            return True
        self._below()
        return bool(suspects) and self._look_up(tick, suspects, False)

    def _realtime_tick(self, tick: int, due: int) -> int:
        """Check acknowledgements and signal every slot due at ``tick``; inside the cycle.
        The number of slots to look up (``_look_up``: late for it, or an SV SIO vouched
        for); 0 if it halted.

        SIO and the SVs run as a gang (thesis 3.3.4, ``gang_state``): a tick SIO misses,
        or every SV does, none of them is signalled, and each that missed counts its miss.
        """
        nd, sig, ack, vouched = self._due, self._sig, self._ack, self._vouched
        lead = self._lead
        gang = GANG_RUNS
        if lead >= 0 and tick >= nd[lead]:
            gang = gang_state(lead, self._members, ack, sig, nd, tick)
        member, suspect = self._member, self._suspect
        fresh, suspected = self._fresh, self._suspected
        sig_lost, lost = self._sig_lost, self._lost_ns
        n_suspect = 0
        for k, i in enumerate(self._slots):
            if tick < nd[i]:
                continue
            per = self._period[k]
            nd[i] = (tick // per + 1) * per
            if ack[i] < sig[i] or (i == lead and gang == GANG_SIO_LATE):
                if self._missed(k, i, tick, due):
                    return 0
                fresh[n_suspect] = suspected[i] < tick - per
                suspected[i] = tick
                suspect[n_suspect] = k
                n_suspect += 1
                continue
            if member[k] and vouched[i] == sig[i]:  # SIO acknowledged for an SV not yet fed
                fresh[n_suspect] = suspected[i] < tick - per  # (sio/gang.py): is it alive?
                suspected[i] = tick
                suspect[n_suspect] = k
                n_suspect += 1
            if gang != GANG_RUNS and (i == lead or member[k]):
                continue  # acknowledged, but its gang sits this tick out
            if self._consec[i]:
                self._consec[i] = 0
            sig[i] = tick
            sig_lost[i] = lost
            self._rel[i] = due
            self._signals[i] += 1
            self._sems[i].release()
        return n_suspect

    def _look_up(self, tick: int, n: int, fresh: bool) -> bool:
        """Whether those of the first ``n`` of the tick's suspects that are ``fresh`` (or
        not) died (a /proc read each, after every signal, so none delays one); True if that
        halted the system."""
        suspect, is_fresh = self._suspect, self._fresh
        for j in range(n):
            if is_fresh[j] != fresh:
                continue
            k = suspect[j]
            if self._died(self._slots[k], tick, self._serious[k]) and self.inst.fault["active"]:
                return True
        return False

    def _above(self) -> int:
        """The clock at its own priority, for its wake-up and its signals; when its bottom
        half ended (now), 0 without one."""
        if self._guard is None:
            return 0
        os.sched_setparam(0, self._above_param)
        self._guard.above()
        return rt.monotonic_ns()

    def _below(self) -> None:
        """The clock below the serious processes of its CPU, for what it does after a tick's
        signals (the bottom half)."""
        if self._guard is not None:
            self._guard.below(rt.monotonic_ns())
            os.sched_setparam(0, self._below_param)

    def _missed(self, k: int, i: int, tick: int, due: int) -> bool:
        """Count and log a missed deadline of slot ``i``; halt if it is serious and out of
        tolerance (True), with PROCESS_DIED if it is gone.  Whether a process that missed
        within tolerance died is the caller's to look up (``_died``, a /proc read): in real
        time after the tick's signals.

        Out of tolerance: unacknowledged since its signal for more than
        ``serious_miss_tolerance_ms`` of the time the machine gave the clock, to tell a
        machine stall from a broken process.  The clock outranks everything on its CPU, so a
        wake-up of it over ``STALL_NS`` late is time the machine did not run it, nor, as far
        as anyone can tell, the process.  So: the ticks since its signal (an overrun's
        skipped ones included) less the clock's stalls since (to within the current
        wake-up's fraction of a tick), or, if more, those of the process's own CPU since (its
        witness's, ``_excused``); with the clock's wake-ups within ``STALL_NS``, and in
        lockstep, its consecutive misses times its period.  A process hung for good still
        halts, later by those stalls alone (docs/decisions/0004-clock-stall-rule.md)."""
        self._misses[i] += 1
        n = int(self._consec[i]) + 1
        self._consec[i] = n
        if n > self._max_consec[i]:
            self._max_consec[i] = n
        count = int(self._log_count[0])
        e = self._log_entries[count % layout.MISS_LOG_LEN]
        e["tick"] = tick
        e["signal_ns"] = self._rel[i]
        e["due_ns"] = due
        e["slot"] = i
        e["consecutive"] = n
        self._log_count[0] = count + 1
        lost_ns, held = self._lost_ns - self._sig_lost[i], -1
        overdue_ns = (tick - int(self._sig[i])) * self.base_ns - lost_ns
        if self._serious[k] and overdue_ns > self.tolerance_ns:
            lost_ns, held = self._excused(i, lost_ns, int(self._rel[i]))
            overdue_ns = (tick - int(self._sig[i])) * self.base_ns - lost_ns
            if overdue_ns <= self.tolerance_ns:
                return False
            if self._died(i, tick, True):
                return True
            name = decode(self.inst.procs[i]["name"])
            period_ms = self._period[k] * self.base_ns / 1e6
            self.inst.raise_fault(
                FaultCode.DEADLINE,
                name,
                f"serious process '{name}'{self._doing(name)} missed {n} consecutive deadlines "
                f"at period {period_ms:g} ms ({overdue_ns / 1e6:.1f} ms unacknowledged, tolerance "
                f"{self.tolerance_ns / 1e6:g} ms{self._not_counted(lost_ns, held)}); last "
                f"acknowledged tick {int(self._ack[i])}, signalled tick {int(self._sig[i])}",
                tick=tick,
            )
            self.inst.clock["mode"] = RunMode.STOPPED
            return True
        return False

    def _watch(self, now_ns: int) -> None:
        """Look up self-timed processes whose heartbeat is two periods old (real time): a
        dead one halts (serious) or is left out, and a serious one alive but stalled beyond
        ``serious_miss_tolerance_ms`` halts with DEADLINE, as a clocked one would.  After the
        cycle's signals, so the /proc read of a stale one never delays a signal (it does
        delay SIO, which runs below the clock on its CPU only once the clock sleeps); a live
        but stalled one is looked up again only a watch interval later.

        Stalled counts the time since its heartbeat less the clock's stalls meanwhile, or
        its own CPU's, as ``_missed`` does: when the whole machine stops, the clock stops or
        lags too, so a self-timed process must not halt the system for that time
        (docs/decisions/0004-clock-stall-rule.md)."""
        heart = self._heart
        for k, i in enumerate(self._watched):
            age = now_ns - heart[i]
            if age <= self._watch_ns[k] or now_ns < self._watch_next[k]:
                continue
            self._watch_next[k] = now_ns + self._watch_ns[k]
            tick = int(self.inst.clock["tick"])
            serious = bool(self.inst.procs[i]["serious"])
            if self._died(i, tick, serious) or not serious:
                continue
            lost = self._lost_since(int(heart[i]))
            if age - lost <= self.tolerance_ns:
                continue
            lost, held = self._excused(i, lost, int(heart[i]), now_ns)
            if age - lost <= self.tolerance_ns:
                continue
            p = self.inst.procs[i]
            name = decode(p["name"])
            self.inst.raise_fault(
                FaultCode.DEADLINE,
                name,
                f"serious process '{name}'{self._doing(name)} (pid {int(p['pid'])}, "
                f"self-timed every {int(p['period_ticks']) * self.base_ns / 1e6:g} ms) has not "
                "run for "
                f"{(age - lost) / 1e6:.1f} ms (tolerance {self.tolerance_ns / 1e6:g} ms"
                f"{self._not_counted(lost, held)}): alive but stalled",
                tick=tick,
            )
            self.inst.clock["mode"] = RunMode.STOPPED
            return

    def _doing(self, name: str) -> str:
        """What process ``name`` is stuck in, as its fault message says it after its name:
        " (evaluating tg function 'wave' (sine) for request 12)" for the TG, else ''."""
        doing = self.inst.doing(name)
        return f" ({doing})" if doing else ""

    def _excused(self, i: int, clock_ns: int, since_ns: int, now_ns: int = 0) -> tuple[int, int]:
        """The time slot ``i``'s process is not judged on since ``since_ns``: the clock's
        stalls since (``clock_ns``) or its own CPU's, if that has a witness and lost more
        (``CpuWitness.lost_since``), and that CPU then, else -1.  Outside the common path:
        for a serious process late beyond the tolerance by the clock's stalls alone."""
        witness = self._witness_of[i]
        if witness is None:
            return clock_ns, -1
        cpu_ns = witness.lost_since(since_ns, now_ns or rt.monotonic_ns())
        return (cpu_ns, witness.cpu) if cpu_ns > clock_ns else (clock_ns, -1)

    def _not_counted(self, lost_ns: int, cpu: int = -1) -> str:
        """A fault message's note of the machine's stalls left out of a process's time: the
        clock's, or those of CPU ``cpu``."""
        if lost_ns < self.base_ns:
            return ""
        who = "the clock itself ran late" if cpu < 0 else f"the machine did not run CPU {cpu}"
        return f"; {lost_ns / 1e6:.1f} ms more while {who}, not counted"

    def _count_lost(self, woke: int, late: int) -> None:
        """Account a real-time wake-up at ``woke``, ``late`` ns after its deadline (a stall
        if over ``STALL_NS``): the clock's stalls, and the ring ``_lost_since`` reads (in the
        cycle)."""
        if late > STALL_NS:
            self._lost_ns += late
        j = self._wakes % len(self._wake_ns)
        self._wake_ns[j] = woke
        self._wake_lost[j] = self._lost_ns
        self._wakes += 1

    def _lost_since(self, t_ns: int) -> int:
        """The time the clock lost to stalls since ``t_ns`` (at its wake-ups after it), as
        far back as the ring reaches: older stalls are not counted (the ring holds 4
        tolerances of wake-ups)."""
        n = min(self._wakes, len(self._wake_ns))
        j = self._wakes - 1
        before = self._wake_lost[(self._wakes - n) % len(self._wake_ns)] if n else 0
        for _ in range(n):
            at = j % len(self._wake_ns)
            if self._wake_ns[at] <= t_ns:
                before = self._wake_lost[at]
                break
            j -= 1
        return self._lost_ns - before

    def _lockstep_tick(self, tick: int) -> bool:
        """Signal due slots stage by stage, waiting for every acknowledgement of a stage.

        A non-serious slot still busy with an earlier tick (it timed out) is not signalled:
        a miss, as in real time.  Returns False if the system halted during the tick.
        """
        n = len(self._slots)
        k = 0
        while k < n:
            stage = self._stages[k]
            posted: list[int] = []
            while k < n and self._stages[k] == stage:
                i = self._slots[k]
                if tick >= self._due[i]:
                    per = self._period[k]
                    self._due[i] = (tick // per + 1) * per
                    if self._ack[i] < self._sig[i]:
                        if not self._missed(k, i, tick, rt.monotonic_ns()):
                            self._died(i, tick, self._serious[k])
                    else:
                        self._signal(i, tick)
                        posted.append(k)
                k += 1
            if posted and not self._await_stage(posted, tick):
                return False
        return True

    def _signal(self, i: int, tick: int) -> None:
        """Post slot ``i``'s semaphore for ``tick`` (lockstep), noting when."""
        self._sig[i] = tick
        self._rel[i] = rt.monotonic_ns()
        self._signals[i] += 1
        self._sems[i].release()

    def _await_stage(self, posted: list[int], tick: int) -> bool:
        """Wait until every slot of ``posted`` (indices into the slot lists) acknowledged
        ``tick``; False if the system halted meanwhile.

        The acknowledgement fields decide; the semaphore wakes the clock, one post per
        acknowledgement, all consumed so none is left for the next stage.  Waits in slices
        so a process that died meanwhile is found at once: a serious one halts
        (PROCESS_DIED), a non-serious one is left out.  After the timeout a serious late one
        halts (DEADLINE, as in real time); a non-serious one is skipped with a miss.
        """
        ack, slots, sem = self._ack, self._slots, self._ack_sem
        deadline = rt.monotonic_ns() + int(self.lockstep_timeout_s * 1e9)
        expected, got = len(posted), 0
        waiting = [k for k in posted if ack[slots[k]] < tick]
        while waiting:
            if self.inst.fault["active"]:
                return False  # a process halted the system; the loop stops the clock
            try:
                sem.acquire(LOCKSTEP_SLICE_S)
                got += 1
            except posix_ipc.BusyError:
                dead = [k for k in waiting if self._died(slots[k], tick, self._serious[k])]
                if self.inst.fault["active"]:
                    return False
                expected -= len(dead)
                waiting = [k for k in waiting if k not in dead]
                if rt.monotonic_ns() > deadline:
                    late = [k for k in waiting if ack[slots[k]] < tick]
                    expected -= len(late)
                    return self._lockstep_late(late, tick)
            waiting = [k for k in waiting if ack[slots[k]] < tick]
        while got < expected:  # acknowledgements read before their post arrived
            try:
                sem.acquire(LOCKSTEP_SLICE_S)
                got += 1
            except posix_ipc.BusyError:
                break
        return not self.inst.fault["active"]

    def _lockstep_late(self, late: list[int], tick: int) -> bool:
        """The lockstep timeout passed with ``late`` unacknowledged: halt if one of them is
        serious (False: DEADLINE naming it and what it is busy with, as a missed deadline
        in real time), else count a miss for each and go on (True)."""
        serious = [k for k in late if self._serious[k]]
        if not serious:
            for k in late:
                if not self._missed(k, self._slots[k], tick, rt.monotonic_ns()):
                    self._died(self._slots[k], tick, False)
            return True
        names = [decode(self.inst.procs[self._slots[k]]["name"]) for k in serious]
        who = ", ".join(f"'{n}'{self._doing(n)}" for n in names)
        plural = "es" if len(names) > 1 else ""
        self._lockstep_deadline(", ".join(names), f"serious process{plural} {who}", tick)
        return False

    def _lockstep_deadline(
        self, names: str, who: str, tick: int, what: str = "acknowledge"
    ) -> None:
        """Halt for process(es) ``names`` (``who``: as the message names them) that did not
        ``what`` tick ``tick`` within the lockstep timeout: DEADLINE, as a missed deadline
        in real time, and the clock stops."""
        self.inst.raise_fault(
            FaultCode.DEADLINE,
            names,
            f"lockstep: {who} did not {what} tick {tick} within {self.lockstep_timeout_s:g} s "
            f"(clock.lockstep_ack_timeout_s)",
            tick=tick,
        )
        self.inst.clock["mode"] = RunMode.STOPPED

    def _died(self, i: int, tick: int, serious: bool) -> bool:
        """True if slot ``i``'s process is gone.  A serious one halts the system with
        PROCESS_DIED; a non-serious one is left out (state DIED) and the system runs on."""
        pid = int(self.inst.procs[i]["pid"])
        stat = self._stat[i]
        if pid <= 0 or (stat.alive() if stat is not None and stat.pid == pid else pid_alive(pid)):
            return False
        p = self.inst.procs[i]
        name = decode(p["name"])
        if not serious:
            p["periodic"] = 0  # the owner is gone: the clock writes its state for it
            p["state"] = ProcState.DIED
            self.inst.bump_registry()
            return True
        self.inst.raise_fault(
            FaultCode.PROCESS_DIED,
            name,
            f"process '{name}' (pid {pid}) died; last acknowledged tick {int(self._ack[i])}",
            tick=tick,
        )
        self.inst.clock["mode"] = RunMode.STOPPED
        return True

    # ------------------------------------------------------------------ commands

    def _command(self, now_ns: int, t0: int) -> int:
        """Apply the pending command (start/stop/set/step); returns the new tick-0 time."""
        c = self.inst.clock
        cmd = int(c["cmd"])
        arg = float(c["cmd_arg"])
        status, message = 0, ""
        tick = int(c["tick"])
        base_ms = self.base_ns / 1e6
        if cmd in (ClockCommand.STEP, ClockCommand.SET_TIME) and not (
            math.isfinite(arg) and abs(arg) <= MAX_CLOCK_ARG
        ):  # written by any client (DESIGN 7): refused, nothing changes
            status = -1
            message = f"clock: argument {arg!r} must be finite and at most {MAX_CLOCK_ARG:g}"
        elif cmd == ClockCommand.STEP and (arg < 0 or arg != int(arg)):
            status, message = -1, f"clock step: {arg!r} ticks, must be a whole number >= 0"
        elif cmd in (ClockCommand.START, ClockCommand.STEP) and self.inst.fault["active"]:
            status = -1
            message = f"fault active, kalictl reset first: {self.inst.fault_text()}"
        elif cmd == ClockCommand.START:
            self._drain_acks()
            self._consec[:] = 0
            t0 = now_ns + self.base_ns - tick * self.base_ns
            c["t0_ns"] = t0
            c["mode"] = RunMode.RUNNING
        elif cmd == ClockCommand.STOP:
            c["mode"] = RunMode.STOPPED
        elif cmd == ClockCommand.SET_TIME:
            c["time_offset_ms"] = arg - tick * base_ms
        elif cmd == ClockCommand.STEP:
            if not self.lockstep:
                status, message = -1, "clock step needs lockstep mode (kalictl start --lockstep)"
            else:
                self._drain_acks()
                c["step_target"] = tick + int(arg)
                c["mode"] = RunMode.STEPPING if int(arg) > 0 else RunMode.STOPPED
        else:
            status, message = -1, f"unknown clock command {cmd}"
        c["cmd_status"] = status
        c["cmd_message"] = message.encode()[: layout.MESSAGE_BYTES - 1]
        c["cmd_done"] = c["cmd_seq"]
        futex.wake(self._cmd_done_addr)
        return t0

    def _drain_acks(self) -> None:
        """Forget acknowledgements left over from a timed-out lockstep tick."""
        try:
            while True:
                self._ack_sem.acquire(0)
        except posix_ipc.BusyError:
            pass


def gang_state(
    lead: int, members: list[int], ack: np.ndarray, sig: np.ndarray, due: np.ndarray, tick: int
) -> int:
    """Whether SIO (slot ``lead``) and its SVs (slots ``members``) are signalled this tick.

    They are one gang (thesis 3.3.4): SIO feeds the slots, the SVs run them, SIO waits.
    If SIO has not acknowledged its last signal, signalling the SVs alone would set them
    waiting for a feed that comes only with SIO's next tick: they would miss that tick too,
    after whatever delayed SIO was over (GANG_SIO_LATE).  If no SV has acknowledged, SIO
    signalled alone would feed slots nobody is signalled to run and wait for them until it
    halts (GANG_SVS_LATE); an SV resting (``due`` after ``tick``: a polling SV with nothing
    to share, ``servo/sv/daemon.py``) is not signalled this tick either.  Else the gang runs; an SV
    that is late misses on its own, and the others take its share.  Read once per tick,
    before anyone is signalled.
    """
    if ack[lead] < sig[lead]:
        return GANG_SIO_LATE
    for m in members:
        if ack[m] >= sig[m] and tick >= due[m]:
            return GANG_RUNS
    return GANG_SVS_LATE if members else GANG_RUNS
