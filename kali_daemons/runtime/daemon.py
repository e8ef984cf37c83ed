"""The one daemon base class: lifecycle, real-time settings, the wait/ack loop, statistics.

A Kali process subclasses ``Daemon`` and writes only ``cycle`` (and, outside the cycle,
``on_configure``/``on_activate``/...), after ros2_control's lifecycle nodes: configure →
activate → cycle … → deactivate → shutdown, or error.  The loop is always

    wait for the wall clock's signal → cycle(tick) → record timing → acknowledge

(the interrupt-then-acknowledge protocol of thesis 3.6.2).  A daemon that is self-timed in
real-time mode (the plant, which is the outside world and keeps its own clock, DESIGN 6)
sleeps to its own absolute deadlines instead; in lockstep mode every daemon is clock-driven.

Long on purpose: the one daemon base class with what its loop needs (the compiled clock wait,
the cycle statistics), and ``FunctionDaemon``, a program's periodic function on the same loop.
"""

from __future__ import annotations

import argparse
import ctypes
import gc
import logging
import os
import signal
import sys
import threading
import time
import traceback
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np
import posix_ipc

from ..core import layout, rt
from ..core.errors import DaemonError
from ..core.kernels import WAIT_IDLE, WAIT_INTR, WAIT_SHUTDOWN, WAIT_SIGNAL, Kernel
from ..core.layout import FaultCode, ProcState, RunMode
from ..core.spinlock import pid_alive
from .config import period_ticks
from .flightrec import FlightDumper
from .instance import Instance
from .stalls import ClockWitness

IDLE_WAIT_S = 0.25  # longest semaphore wait before a heartbeat and a shutdown check
SETTLE_POLL_S = 0.001  # a leaving function's wait for the clock to see it leave
CLOCK_WATCH_S = 0.01  # serious, real time: no signal this long → is the wall clock alive?


class Daemon:
    """Base of every Kali process; subclasses implement ``cycle``.

    Periodic parameters come from the instance's config for daemons that ``kalictl start``
    launched, or from the constructor for functions registered with ``control``.
    """

    kind: ClassVar[str] = ""
    self_timed_in_realtime: ClassVar[bool] = False
    # never signalled by the clock, in lockstep too: an FR3's link (the plant's lockstep turns
    # time it) and its hand (its commands take seconds)
    self_timed_always: ClassVar[bool] = False
    # bind to the config's CPU, lock memory and go SCHED_FIFO; the lockstep executive does
    # not: it runs flat out as long as there are ticks to step, which at SCHED_FIFO would
    # starve the programs it waits for and meet the kernel's real-time throttling
    realtime: ClassVar[bool] = True
    # take the slot kalictl start claimed under this name, if any; False: always claim one,
    # so a name already taken is refused (a program's function must never take a daemon's)
    takes_named_slot: ClassVar[bool] = True

    def __init__(
        self,
        instance: str,
        name: str,
        *,
        period_ms: float | None = None,
        serious: bool | None = None,
        stage: int | None = None,
        cpu: int | None = None,
        priority: int | None = None,
        lock_memory: bool = True,
    ) -> None:
        self.instance_name = instance
        self.name = name
        self.log = logging.getLogger(f"kali.{name}")
        self._overrides: dict[str, Any] = {
            "period_ms": period_ms,
            "serious": serious,
            "stage": stage,
            "cpu": cpu,
            "priority": priority,
        }
        self._lock_memory = lock_memory
        self._leave = False
        self._claimed = False
        self._hosted = False  # configured inside the lockstep executive's process (host)
        self.inst: Instance
        self.slot = -1
        self._rt: rt.RtReport  # what prepare applied; _go_realtime adds the priority
        self._priority = 0  # SCHED_FIFO priority once start-up is over (0: SCHED_OTHER)
        self._nice = 0  # at SCHED_OTHER: its weight against other programs (rt.set_nice)
        self.period_ticks = 1
        self.serious = False
        self.stage = 0
        self._ack_early: np.ndarray | None = None  # acknowledge's view (real time only)
        # real time: wake on this CPU's own timer at each due tick and poll this long for the
        # clock's signal before sleeping on it, so the signal wakes no halted vCPU (an SV on
        # the other CPU, ``processes.sv.poll_us``); 0: sleep on the semaphore
        self.poll_ns = 0
        # polling: wake this long after the due tick (when its work can start: an SV's feed);
        # an array, so a compiled cycle can write it (an SV's ``kali_sv_serve`` learns it)
        self._poll_after = np.zeros(1, np.int64)
        self._clock_wait: ClockWait | None = None  # the base loop's, while it runs

    @property
    def poll_after_ns(self) -> int:
        """Polling: how long after the due tick this process wakes (``poll_ns``)."""
        return int(self._poll_after[0])

    # ------------------------------------------------------------------ hooks

    def on_configure(self) -> None:
        """Outside the cycle: allocate arena records, load models, precompute."""

    def on_activate(self) -> None:
        """Outside the cycle: last preparation before the first tick."""

    def cycle(self, tick: int) -> None:
        """Inside the cycle (no allocation, no I/O, no logging): one period's work."""
        raise NotImplementedError

    def on_deactivate(self) -> None:
        """Outside the cycle: the loop has ended."""

    def on_shutdown(self) -> None:
        """Outside the cycle: release what on_configure took."""

    def on_error(self, exc: BaseException) -> None:
        """Outside the cycle: the daemon failed with ``exc`` (the fault is already raised)."""

    # ------------------------------------------------------------------ driver

    @property
    def period_ns(self) -> int:
        """This daemon's period in ns (whole base ticks); once configured, outside the cycle."""
        return self.period_ticks * int(self.inst.clock["base_tick_ns"])

    def acknowledge(self, tick: int) -> None:
        """Inside the cycle: tell the clock, in real time, that the work ``tick``'s deadline
        is about is done, so what follows in the cycle is bookkeeping it need not wait for
        (SIO, once the boards are written).  The loop acknowledges again at the end; in
        lockstep only that counts, since the next stage reads what the cycle publishes."""
        if self._ack_early is not None:
            self._ack_early[0] = tick

    def leave(self) -> None:
        """Ask the loop to end after the current cycle (signal handlers, ``release``)."""
        self._leave = True

    def main(self) -> int:
        """Run the whole lifecycle as this process's main thread (it takes SIGTERM and
        SIGINT, which only a main thread may); returns the process exit code."""
        signal.signal(signal.SIGTERM, lambda *_: self.leave())
        signal.signal(signal.SIGINT, lambda *_: self.leave())
        try:
            self._configure()
            self.on_activate()
            freeze_heap()
            self._go_realtime()  # after every piece of start-up work (see _go_realtime)
            self._set_state(ProcState.ACTIVE)
            self.inst.bump_registry()  # after ACTIVE: the clock only signals active slots
            self.log.info("active: slot %d, period %d ticks", self.slot, self.period_ticks)
            self._loop()
            self.on_deactivate()
        except Exception as exc:  # the daemon failed: halt the system and say why
            self._fail(exc)
            return 1
        finally:
            self._finish()
        return 0

    def host(self, inst: Instance) -> None:
        """Outside the cycle: configure and activate this daemon inside the lockstep
        executive's process, on its Instance, leaving the process's CPU and scheduling to
        it; the executive then calls ``cycle`` itself (``lockstep.executive``)."""
        self._configure(inst)
        self.on_activate()
        self._set_state(ProcState.ACTIVE)

    def _configure(self, host: Instance | None = None) -> None:
        self._hosted = host is not None
        self.inst = Instance.attach(self.instance_name) if host is None else host
        cfg = self.inst.config
        pcfg = None
        if self.name in {p.name for p in cfg.processes}:
            pcfg = cfg.process(self.name)
        self.slot = self.inst.find_slot(self.name) if self.takes_named_slot else -1
        if self.slot < 0:
            self.slot = self.inst.claim_slot(self.name, os.getpid())
            self._claimed = True
        ov = self._overrides
        base_ms = cfg.clock.base_tick_ms
        period_ms = (
            ov["period_ms"]
            if ov["period_ms"] is not None
            else (pcfg.period_ms if pcfg else base_ms)
        )
        try:
            self.period_ticks = period_ticks(period_ms, base_ms)
        except ValueError:
            raise DaemonError(
                f"{self.name}: period {period_ms} ms must be a multiple of the "
                f"{base_ms} ms base tick"
            ) from None
        self.serious = bool(
            ov["serious"] if ov["serious"] is not None else (pcfg.serious if pcfg else False)
        )
        self.stage = int(ov["stage"] if ov["stage"] is not None else (pcfg.stage if pcfg else 8))
        cpu = ov["cpu"] if ov["cpu"] is not None else (pcfg.cpu if pcfg else None)
        prio = ov["priority"] if ov["priority"] is not None else (pcfg.priority if pcfg else 0)
        realtime = self.realtime and not self._hosted
        self._rt = self._prepare_os(cpu if realtime else None, self._lock_memory and realtime)
        self._priority = prio if realtime else 0
        self._nice = pcfg.nice if pcfg and realtime and not prio else 0
        p = self.inst.procs[self.slot]
        p["pid"] = os.getpid()
        p["cpu"] = self._rt.cpu
        p["priority"] = 0  # SCHED_OTHER until _go_realtime
        p["heartbeat_ns"] = rt.monotonic_ns()
        self._set_state(ProcState.INACTIVE)
        self.on_configure()
        self._register()

    def _prepare_os(self, cpu: int | None, lock_memory: bool) -> rt.RtReport:
        """Outside the cycle, in ``_configure``: bind the process to ``cpu`` and lock its
        memory (``rt.prepare``), still SCHED_OTHER."""
        return rt.prepare(cpu, lock_memory)

    def _go_realtime(self) -> None:
        """SCHED_FIFO at the configured priority, once start-up is over: ``on_configure``,
        ``on_activate`` and ``freeze_heap`` run as SCHED_OTHER.  Tens of ms of set-up or of
        collecting a heap holding MuJoCo and Pinocchio at SCHED_FIFO starve every process of
        lower priority on this CPU, another instance's servo processes included."""
        rt.go_realtime(self._rt, self._priority, self._nice)
        self.inst.procs[self.slot]["priority"] = self._rt.priority
        for w in self._rt.warnings:  # one warning per refusal, at start-up only
            self.log.warning("%s: %s", self.name, w)

    def _register(self) -> None:
        p = self.inst.procs[self.slot]
        p["period_ticks"] = self.period_ticks
        p["serious"] = int(self.serious)
        p["stage"] = self.stage
        p["signal_tick"] = -1
        p["ack_tick"] = -1
        p["vouched_tick"] = -1
        if not self.inst.lockstep:
            self._ack_early = self.inst.procs["ack_tick"][self.slot : self.slot + 1]
        clocked = self.inst.lockstep or not self.self_timed_in_realtime
        p["periodic"] = int(clocked and not self.self_timed_always and self.kind != "wallclock")

    def _set_state(self, state: ProcState) -> None:
        self.inst.procs[self.slot]["state"] = int(state)

    def _fail(self, exc: BaseException) -> None:
        text = f"{type(exc).__name__}: {exc}"
        self.log.error("%s failed: %s\n%s", self.name, text, traceback.format_exc())
        if self.slot >= 0:
            self._set_state(ProcState.ERROR)
            self.inst.raise_fault(FaultCode.DAEMON_ERROR, self.name, text)
        try:
            self.on_error(exc)
        except Exception:
            self.log.exception("%s: on_error failed", self.name)

    def _finish(self) -> None:
        if not self._hosted:  # the executive's scheduling is its own
            rt.leave_realtime()
        self._release_slot()

    def _release_slot(self) -> None:
        """Outside the cycle: ``on_shutdown``, then leave the process table (freeing a slot
        this daemon claimed) and close the Instance it attached."""
        if self.slot < 0:
            return
        try:
            self.on_shutdown()
        finally:
            p = self.inst.procs[self.slot]
            p["periodic"] = 0
            if p["state"] != ProcState.ERROR:
                p["state"] = int(ProcState.FINALIZED)
            self.inst.bump_registry()
            if self._claimed:
                self.inst.free_slot(self.slot)
            if not self._hosted:  # the executive closes the Instance it lent
                self.inst.close()

    # ------------------------------------------------------------------ loops

    def _loop(self) -> None:
        if self.inst.lockstep or not self.self_timed_in_realtime:
            self._clock_driven_loop()
        else:
            self._self_timed_loop()

    def _clock_driven_loop(self) -> None:
        """Wait on this slot's semaphore; the wall clock posts it at each due tick.

        With ``poll_ns`` (real time), while the clock keeps signalling, sleep instead on this
        CPU's own timer to the next due tick (the one after the last signal's ``release_ns``),
        or ``poll_after_ns`` after it, and poll for the post there, then take it: the clock's
        post finds no waiter and wakes nobody across vCPUs.  A signal later than the poll, or
        none (the clock stopped, the gang sat the tick out), is waited for as without it.
        The wait is one compiled call (``ClockWait``).
        """
        inst, i = self.inst, self.slot
        header, heart = inst.arena.header, inst.procs["heartbeat_ns"]
        ack_sem = inst.ack_semaphore() if inst.lockstep else None
        stats = _CycleStats(inst.procs, i)
        now = rt.monotonic_ns
        # a serious process in real time notices a dead wall clock within half the boards'
        # 20 ms watchdog (which cuts the amplifiers anyway); looking costs nothing until then
        self._idle_wait_s = CLOCK_WATCH_S if self.serious and not inst.lockstep else IDLE_WAIT_S
        self._clock_tick, self._clock_waits = -1, 0  # _watch_clock's view of a standing clock
        self._clock_witness: ClockWitness | None = None  # made when the clock first stands
        waiter = ClockWait(
            inst, i, self.period_ticks, 0 if inst.lockstep else self.poll_ns, self._idle_wait_s,
            self._poll_after, stats, ack_sem,
        )  # fmt: skip
        self._clock_wait = waiter
        wait, w = waiter.wait, waiter.args
        try:
            while not self._leave:
                event = wait()  # which first accounts and acknowledges the cycle before
                if event == WAIT_SIGNAL:
                    if self._leave:  # the post may be ``leave``'s wake-up: no cycle runs
                        w.cycled = 0
                        break
                    self.cycle(w.tick)
                elif event == WAIT_IDLE:
                    heart[i] = now()
                    if header["shutdown"]:
                        break
                    self._on_idle()
                elif event == WAIT_SHUTDOWN:
                    break
                # WAIT_INTR: a signal's handler has run (it may have set _leave); wait on
            waiter.settle()  # the last cycle's account, where leaving ended the loop after it
        finally:
            self._clock_wait = None
            waiter.close()
            if self._clock_witness is not None:
                self._clock_witness.close()

    def _set_period(self, ticks: int) -> None:
        """Inside the cycle: be signalled every ``ticks`` base ticks (a polling SV with
        nothing to share rests: ``servo/sv/daemon.py``).  The process record and the clock's
        ``rates_gen`` tell the clock, which re-reads its slots' periods between two of its
        ticks; until then it signals at the old period, and a polling wait sleeps to the
        earlier of its next due tick at the new period and the clock's own (``next_wake``).
        No allocation beyond the record's view; a few times a minute (a change of load)."""
        self.period_ticks = ticks
        self.inst.procs[self.slot]["period_ticks"] = ticks
        self.inst.bump_rates()
        if self._clock_wait is not None:
            self._clock_wait.args.period_ticks = ticks

    def _on_idle(self) -> None:
        """Outside the cycle: no signal for ``_idle_wait_s``; look at the wall clock."""
        self._watch_clock()

    def _watch_clock(self) -> None:
        """Halt naming the wall clock if it is gone or stands still (DESIGN 7): nobody else
        can, and every program waiting for a motion must hear why it stopped.

        Gone: PROCESS_DIED at once.  Alive but not ticking while it should run (real time):
        the boards' watchdog cuts the amplifiers after ``watchdog_ms``, since SIO is not
        signalled either, and this halts with DEADLINE once this process has seen the
        tick stand still through timed-out waits of its own adding up to the serious
        tolerance, and at least two: a stall of the whole machine (the host stops every
        vCPU, DESIGN 10: the clock too, and this process with it) ends one wait late, before
        the clock on its own CPU has ticked again, and never counts, as the clock's
        ``_watch`` rules for the plant (one wait may be longer than the tolerance: 250 ms
        for a non-serious process such as dynamics); nor does a wait through which the
        machine held the clock's CPU alone (``stalls.ClockWitness``)."""
        c, f = self.inst.clock, self.inst.fault
        pid = int(c["pid"])
        if pid <= 0 or f["active"]:
            return
        tick = int(c["tick"])
        if not pid_alive(pid):
            recorded = self.inst.raise_fault(
                FaultCode.PROCESS_DIED,
                "wallclock",
                f"the wall clock (pid {pid}) died at tick {tick}; "
                f"{self.name} noticed: no signal for {self._idle_wait_s * 1e3:g} ms",
            )
            if recorded:  # the wall clock writes every other halt's dump: not this one's
                self._dump_flight()
            return
        if tick != self._clock_tick or self.inst.lockstep or c["mode"] != RunMode.RUNNING:
            self._clock_tick, self._clock_waits = tick, 0
            return
        if self._clock_witness is None:
            self._clock_witness = ClockWitness(self.inst)
        if self._clock_witness.held(rt.monotonic_ns()):
            return
        self._clock_waits += 1
        watched_ms = self._clock_waits * self._idle_wait_s * 1e3
        tolerance_ms = int(c["serious_miss_tolerance_ms"])
        if self._clock_waits >= 2 and watched_ms >= tolerance_ms:
            self.inst.raise_fault(
                FaultCode.DEADLINE,
                "wallclock",
                f"the wall clock (pid {pid}) is alive but stands at tick {tick}: {self.name} "
                f"waited {watched_ms:g} ms more for a signal (tolerance {tolerance_ms} ms)",
                tick=tick,
            )

    def _dump_flight(self) -> None:
        """Write the flight recorder's dump of the halt this process recorded (outside any
        cycle: the system has halted); a failure is logged, never raised.  At normal
        priority: tens of ms of compression and file I/O at SCHED_FIFO would starve the
        plant on this CPU while its brakes come on."""
        policy, param = os.sched_getscheduler(0), os.sched_getparam(0)
        rt.leave_realtime()
        dumper = FlightDumper(self.inst)
        try:
            dumper.dump_if_halted()
        except Exception:  # a failed dump must not take this process down
            self.log.exception("flight recorder dump failed")
        finally:
            dumper.close()
            try:
                os.sched_setscheduler(0, policy, param)
            except OSError:
                pass

    def _self_timed_loop(self) -> None:
        """Sleep to this daemon's own absolute deadlines (the plant in real-time mode)."""
        inst = self.inst
        header = inst.arena.header
        period_ns = self.period_ns
        sleeper = rt.AbsoluteSleeper()
        stats = _CycleStats(inst.procs, self.slot)
        now = rt.monotonic_ns
        t0 = now() + period_ns
        tick = 0
        while not self._leave and not header["shutdown"]:
            due = t0 + tick * period_ns
            sleeper.until(due)
            woke = now()
            planned = due  # lateness is measured against the deadline that was missed
            if woke - due >= period_ns:  # overrun: skip ahead, no burst of catch-up cycles
                tick += (woke - due) // period_ns
            self.cycle(tick)
            stats.record(tick, planned, woke, now())
            tick += 1


class ClockWait:
    """A clocked process's wait for the wall clock's signal on its slot's semaphore (thesis
    3.6.2), polling where ``poll_ns`` asks (``Daemon._clock_driven_loop``).

    ``wait`` is one compiled call (``csrc/clock.c``'s ``kali_clock_wait``, on the C library's
    own opens of the semaphores: ``rt.semaphore_address``); ``wait_reference`` is what it
    does, in Python.  Each first accounts the cycle the last signal ran and acknowledges it
    (``settle``: ``stats``, then, in lockstep, ``ack_sem``), so a tick costs the loop one
    call; then it waits and returns a ``WAIT_*`` event, leaving in ``args`` the tick
    signalled (``tick``), when the post was taken (``woke``) and when the process meant to
    wake (``since``: the signal's release, or ``poll_after`` after it), and whether the clock
    keeps signalling (``signalled``: the next wait polls).  Outside the cycle: ``close``.
    """

    __slots__ = (
        "_ack", "_acks", "_address", "_after", "_due", "_header", "_kernel", "_rel", "_sem",
        "_settle", "_sig", "_stats", "args",
    )  # fmt: skip

    def __init__(
        self,
        inst: Instance,
        slot: int,
        period_ticks: int,
        poll_ns: int,
        idle_s: float,
        after: np.ndarray,
        stats: _CycleStats,
        ack_sem: posix_ipc.Semaphore | None = None,
    ) -> None:
        procs = inst.procs
        self._sem = inst.slot_semaphore(slot)
        self._rel = procs["release_ns"][slot : slot + 1]
        self._sig = procs["signal_tick"][slot : slot + 1]
        self._due = procs["next_due"][slot : slot + 1]
        self._header, self._after = inst.arena.header, after
        shutdown = self._header["shutdown"]
        assert after.dtype == np.int64 and after.shape == (1,), after
        self._stats, self._ack = stats, ack_sem
        self._address = rt.semaphore_address(self._sem)
        self._acks = rt.semaphore_address(ack_sem) if ack_sem is not None else 0
        self._kernel = Kernel(
            "kali_clock_wait",
            (self._rel, self._sig, self._due, after, shutdown, stats),
            stats=ctypes.addressof(stats.args),
            ack_sem=self._acks,
            sem=self._address,
            release=self._rel.ctypes.data,
            signal_tick=self._sig.ctypes.data,
            after=after.ctypes.data,
            shutdown=shutdown.ctypes.data,
            next_due=self._due.ctypes.data,
            base_ns=int(inst.clock["base_tick_ns"]),
            period_ticks=period_ticks,
            poll_ns=poll_ns,
            idle_ns=int(idle_s * 1e9),
        )
        self.args = self._kernel.args
        self._settle = self._kernel.sibling("kali_clock_settle")

    def wait(self) -> int:
        """Inside the cycle: account the last cycle, wait for the next signal (compiled)."""
        return self._kernel()

    def settle(self) -> None:
        """Account and acknowledge the cycle the last signal ran, if not yet (compiled)."""
        self._settle()

    def settle_reference(self) -> None:
        """What ``settle`` does, in Python."""
        a = self.args
        if a.cycled:
            self._stats.record_reference(a.tick, a.since, a.woke, rt.monotonic_ns())
            if self._ack is not None:
                self._ack.release()
            a.cycled = 0

    def wait_reference(self) -> int:
        """What ``wait`` does, in Python (its test's reference)."""
        self.settle_reference()
        a, sem, now = self.args, self._sem, rt.monotonic_ns
        after = 0
        if a.poll_ns and a.signalled:
            after = int(self._after[0])
            nxt = next_wake(a.tick, a.period_ticks, int(self._due[0]))
            due = int(self._rel[0]) + (nxt - a.tick) * a.base_ns + after
            t = now()
            if t < due:
                rt.AbsoluteSleeper().until(due)
                t = due
            rt.poll_semaphore(sem, t + a.poll_ns)
        try:
            sem.acquire(a.idle_ns / 1e9)
        except posix_ipc.BusyError:
            a.signalled = 0
            return WAIT_IDLE
        except posix_ipc.SignalError:
            return WAIT_INTR
        a.woke, a.signalled = now(), 1
        if self._header["shutdown"]:
            return WAIT_SHUTDOWN
        a.tick = int(self._sig[0])
        a.since = int(self._rel[0]) + after
        a.cycled = 1
        return WAIT_SIGNAL

    def close(self) -> None:
        """Give back the C library's opens of the semaphores (outside the cycle)."""
        rt.close_semaphore_address(self._address)
        rt.close_semaphore_address(self._acks)
        self._address = self._acks = 0


class _CycleStats:
    """Writes one slot's process-side statistics; inside the cycle, no allocation.

    ``record`` is one compiled call (``csrc/clock.c``'s ``kali_cycle_stats``: every process
    makes it every cycle); ``record_reference`` is what it does, in numpy.  Each field is
    viewed once, here: indexing a structured record by field name builds a new view every
    time, which at 1 kHz is most of what the bookkeeping would cost.
    """

    __slots__ = (
        "_ack", "_acks", "_args", "_exec", "_exec_max", "_heart", "_hist", "_kernel", "_late",
        "_late_max",
    )  # fmt: skip

    def __init__(self, procs: np.ndarray, slot: int) -> None:
        def one(field: str) -> np.ndarray:
            return procs[field][slot : slot + 1]

        self._late, self._late_max = one("late_last_ns"), one("late_max_ns")
        self._exec, self._exec_max = one("exec_last_ns"), one("exec_max_ns")
        self._hist = procs["hist"][slot]
        self._heart, self._acks, self._ack = one("heartbeat_ns"), one("acks"), one("ack_tick")
        assert self._hist.flags.c_contiguous and self._hist.dtype == np.uint32
        views = {
            "late": self._late, "late_max": self._late_max, "exec": self._exec,
            "exec_max": self._exec_max, "heart": self._heart, "ack": self._ack,
            "acks": self._acks, "hist": self._hist,
        }  # fmt: skip
        self._kernel = Kernel(
            "kali_cycle_stats",
            (procs, *views.values()),
            **{name: v.ctypes.data for name, v in views.items()},
            linear_us=layout.HIST_LINEAR_US,
            log_bins=layout.HIST_LOG_BINS,
        )
        self._args = self._kernel.args

    @property
    def args(self) -> ctypes.Structure:
        """The kernel's argument block (``ClockWait`` accounts a cycle through it)."""
        return self._args

    def record(self, tick: int, release_ns: int, woke_ns: int, done_ns: int) -> None:
        """Account one cycle, then acknowledge ``tick`` (the last store the clock reads)."""
        a = self._args
        a.tick, a.release, a.woke, a.done = tick, release_ns, woke_ns, done_ns
        self._kernel()

    def record_reference(self, tick: int, release_ns: int, woke_ns: int, done_ns: int) -> None:
        """What ``record`` does, in numpy (its kernel's reference)."""
        late = woke_ns - release_ns
        exe = done_ns - woke_ns
        self._late[0] = late
        if late > self._late_max[0]:
            self._late_max[0] = late
        self._exec[0] = exe
        if exe > self._exec_max[0]:
            self._exec_max[0] = exe
        self._hist[layout.lateness_bin(late)] += 1
        self._heart[0] = done_ns
        self._acks[0] += 1
        self._ack[0] = tick


# A program's functions claim and free their process-table slots one at a time (the table's
# spinlock excludes threads too; this keeps a program's own threads from spinning on it).
_TABLE_GUARD = threading.Lock()
RETURNED_FALSE = "the function returned False"
RELEASED_ELSEWHERE = "released by another process (wallclock.release)"


class FunctionDaemon(Daemon):
    """A plain function run periodically on the wall clock: ``control`` of thesis 3.6.2.

    Run two ways.  ``main``: the calling process's main thread becomes the periodic process
    until the function is released (``wallclock.control``, blocking, as in the thesis); any
    exception halts the system.  ``start_thread``: a thread of the calling program runs it
    while the program goes on (``client.Kali.control``); the slot carries the program's pid,
    so the clock watches the program, and the function shares the program's objects (a
    shared transform the program holds, owned by its pid).  A thread takes only what is its
    own: its CPU and priority (on Linux ``sched_setaffinity`` and ``sched_setscheduler`` of
    pid 0 act on the calling thread) and its timer slack; locking memory, freezing the heap
    and signal handlers are the whole program's, and stay the program's business.  A
    non-serious function run in a thread that raises is released with its error; a serious
    one halts the system.
    """

    kind = "function"
    takes_named_slot = False

    def __init__(self, instance: str, name: str, func: Callable[[int], object], **kw) -> None:
        super().__init__(instance, name, **kw)
        self._func = func
        self.ticks = np.zeros(1, dtype=np.int64)  # calls so far; a view: no allocation a call
        self.reason = ""  # why it ended: a release message, its return or its error
        self.error: str | None = None  # what it raised, as text
        self.thread: threading.Thread | None = None  # the thread running it (start_thread)
        self._thread_cpu: int | None = None  # the CPU that thread binds itself to
        self._wake: posix_ipc.Semaphore | None = None  # its slot's semaphore, while it runs
        self._wake_lock = threading.Lock()  # release posts _wake only while it is open

    def cycle(self, tick: int) -> None:
        """Inside the cycle: call the user's function with the tick; it returning False
        releases it."""
        self.ticks[0] += 1
        if self._func(tick) is False:
            self.release(RETURNED_FALSE)

    def release(self, reason: str) -> None:
        """From any thread: end the loop after the current cycle (thesis ``release``); the
        first reason given is kept.  A thread waiting for its signal is woken for it."""
        if not self.reason:
            self.reason = reason
        self.leave()
        if threading.current_thread() is not self.thread:
            with self._wake_lock:
                if self._wake is not None:
                    self._wake.release()

    def start_thread(self) -> None:
        """Outside the cycle, in the calling thread: configure (claim the slot, register;
        anything wrong raises here and leaves nothing), then run the loop in a new daemon
        thread of this process.  Returns once the slot is ACTIVE, so the clock signals it
        from its next tick on (or once the thread has already ended: ``error`` says why)."""
        started = threading.Event()
        self.thread = threading.Thread(
            target=self._thread_main, args=(started,), name=f"kali {self.name}", daemon=True
        )
        try:
            with _TABLE_GUARD:
                self._configure()
            self.on_activate()
        except BaseException:
            if self.slot >= 0:
                self._finish()
            elif hasattr(self, "inst"):  # attached, but no slot claimed: close it
                self.inst.close()
            raise
        self._wake = self.inst.slot_semaphore(self.slot)
        self.thread.start()
        started.wait()

    def _thread_main(self, started: threading.Event) -> None:
        """The thread's life: its own CPU and priority, ACTIVE, the loop, then leave."""
        try:
            self._bind_thread()
            self._go_realtime()  # sched_setscheduler(0): this thread only
            self._set_state(ProcState.ACTIVE)
            self.inst.bump_registry()  # after ACTIVE: the clock only signals active slots
            started.set()
            self._loop()
            self.on_deactivate()
        except Exception as exc:
            self._raised(exc)
        finally:
            try:
                self._finish()
            finally:
                started.set()

    def _raised(self, exc: Exception) -> None:
        """Outside the cycle, in the thread: the function raised ``exc``.  Serious: halt the
        system naming it (DAEMON_ERROR), as a failing Kali process does.  Else only this
        function is released, its error kept and logged; the system runs on."""
        text = f"{type(exc).__name__}: {exc}"
        self.error = text
        if not self.reason:
            self.reason = text
        if self.serious:
            self._fail(exc)
            return
        self.log.error("%s released: it raised %s\n%s", self.name, text, traceback.format_exc())
        self._set_state(ProcState.ERROR)

    def _prepare_os(self, cpu: int | None, lock_memory: bool) -> rt.RtReport:
        """As every daemon's in ``main``; in a thread nothing yet: ``_configure`` runs in the
        program's thread, whose CPU and memory are the program's.  The thread binds itself
        (``_bind_thread``)."""
        if self.thread is None:
            return super()._prepare_os(cpu, lock_memory)
        self._thread_cpu = cpu
        return rt.RtReport(-1, 0, 0, False, [])

    def _bind_thread(self) -> None:
        """In the thread, outside the cycle: timer slack 1 ns and, given a CPU, bind to it;
        on Linux both act on the calling thread alone (``rt.prepare`` would also bind every
        other thread of the program, and lock the whole program's memory)."""
        report = rt.prepare(None, lock_memory=False)  # timer slack only: per thread
        cpu = self._thread_cpu
        if cpu is not None:
            try:
                os.sched_setaffinity(0, {cpu})
                report.cpu = cpu
            except OSError as exc:
                report.warnings.append(f"cannot bind to CPU {cpu}: {exc.strerror}")
        self._rt = report
        self.inst.procs[self.slot]["cpu"] = report.cpu

    def _on_idle(self) -> None:
        """Outside the cycle: a slot another process released (``wallclock.release``) is
        signalled no more: leave instead of waiting for ever."""
        if not self.inst.procs[self.slot]["periodic"]:
            self.release(RELEASED_ELSEWHERE)
            return
        super()._on_idle()

    def on_configure(self) -> None:
        """Outside the cycle: take any post an earlier holder of this slot left on its
        semaphore (a signal it never took), so the first wake-up is the clock's."""
        drain(self.inst.slot_semaphore(self.slot))

    def _finish(self) -> None:
        """Outside the cycle: leave the clock (``_unregister``), then the process table."""
        if self.thread is None or threading.current_thread() is self.thread:
            rt.leave_realtime()  # never the program's thread: its scheduling is its own
        with self._wake_lock:
            self._wake = None
        if self.slot >= 0:
            self._unregister()
        with _TABLE_GUARD:
            self._release_slot()

    def _unregister(self) -> None:
        """Outside the cycle: stop the clock signalling this slot, then acknowledge whatever
        it signalled before it saw that, until it can signal no more: the clock rescans its
        slots at the start of each tick, so once it has begun the tick after next, or stands
        (stopped, halted, shut down).  A process that leaves may leave that to its exit (the
        clock finds its pid dead); a thread's pid lives on, and a signal it never took would
        hold a lockstep tick until the timeout (a serious one: DEADLINE)."""
        inst, i = self.inst, self.slot
        c, procs, header = inst.clock, inst.procs, inst.arena.header
        procs[i]["periodic"] = 0
        inst.bump_registry()
        since = int(c["tick"])
        sig, ack = procs["signal_tick"][i : i + 1], procs["ack_tick"][i : i + 1]
        sem = inst.slot_semaphore(i)
        ack_sem = inst.ack_semaphore() if inst.lockstep else None
        limit_s = int(c["lockstep_timeout_ms"]) / 1000.0 + 1.0
        deadline = time.monotonic() + limit_s
        while True:
            seen = int(sig[0])
            if seen > int(ack[0]):  # signalled, and it will not run: acknowledged unrun
                ack[0] = seen
                if ack_sem is not None:
                    ack_sem.release()
            stands = int(c["mode"]) == RunMode.STOPPED or inst.fault["active"] or header["shutdown"]
            if (stands or int(c["tick"]) > since + 1) and int(sig[0]) == seen:
                break
            if time.monotonic() > deadline:
                self.log.warning(
                    "%s: the wall clock stayed in tick %d for %g s after the release",
                    self.name,
                    int(c["tick"]),
                    limit_s,
                )
                break
            try:
                sem.acquire(SETTLE_POLL_S)
            except posix_ipc.BusyError:
                pass
        drain(sem)


def next_wake(tick: int, period: int, clock_due: int) -> int:
    """The tick a polling process signalled for ``tick`` sleeps to: the wall clock's next due
    tick for it (``clock_due``, the process record's) where that is within one ``period``
    ahead, else the next multiple of the period (the clock's rule).  A process that changed
    its own period (``Daemon._set_period``) is signalled at the old one until the clock
    re-reads the table, which keeps a due tick within the new period and moves a later one
    (a shorter period) to the new period's next multiple after its own tick: so the wake is
    never after the next signal, and early only once, after a change to a shorter period
    the clock had not yet read.  Kept equal to ``kali_clock_wait``'s."""
    if tick < clock_due <= tick + period:
        return clock_due
    return (tick // period + 1) * period


def drain(sem: posix_ipc.Semaphore) -> int:
    """Take every post ``sem`` holds, without waiting (outside the cycle, or in a cycle's
    Python reference: ``ServoWorker._await_feed``); how many it held."""
    taken = 0
    try:
        while True:
            sem.acquire(0)
            taken += 1
    except posix_ipc.BusyError:
        pass
    return taken


def freeze_heap() -> None:
    """Outside the cycle, just before the loop: collect, then move every object left (the
    imports, models, arena views: most of the heap) into the collector's permanent
    generation, so no later collection walks them.

    A daemon allocates after start-up (the TG plans each motion as it comes, a program's
    function may build objects), so the cyclic collector still runs now and then; a full
    collection of an unfrozen heap took the TG long enough to halt the cell.  Frozen, a full
    collection walks only what was made since (docs/decisions/0007-freeze-the-heap.md)."""
    gc.collect()
    gc.freeze()


def run_daemon(cls: type[Daemon], argv: list[str] | None = None) -> None:
    """Entry point of ``python -m kali_daemons.<kind> --instance NAME --name NAME``."""
    ap = argparse.ArgumentParser(prog=f"kali_daemons.{cls.kind}")
    ap.add_argument("--instance", required=True)
    ap.add_argument("--name", default=cls.kind)
    args = ap.parse_args(argv)
    logging.basicConfig(
        level=logging.INFO,
        format=f"%(asctime)s {args.name}[%(process)d] %(levelname)s %(message)s",
        stream=sys.stderr,
    )
    sys.exit(cls(args.instance, args.name).main())
