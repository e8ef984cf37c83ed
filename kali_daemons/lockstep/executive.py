"""The lockstep executive: every daemon of a lockstep instance in one process (DESIGN 11).

Lockstep runs the same daemon code in stage order as fast as the CPUs allow, bit for bit
(DESIGN 3); with a process per daemon, the posts, wake-ups and acknowledgements of every
tick cost more than the work.  Here the wall clock configures the daemons in its own process
(``Daemon.host``, in ``HOSTED_ORDER``) and each tick calls the ``cycle`` of every one due,
stage by stage, where it would have posted its semaphore; the SVs run inside SIO's cycle,
where SIO would post their feeds (``SioCycle.serve``).  Everything else is the wall clock's:
commands, process table (each hosted daemon keeps its slot), statistics, halts.  A hosted
daemon that raises fails as its own process would; one that never returns from its cycle is
caught by a watchdog thread (``_watch_cycles``), which halts with DEADLINE naming it.
More: docs/internals/servo-level.md; the user's view: docs/guide/lockstep.md.
"""

from __future__ import annotations

import importlib
import threading

from ..core.errors import DaemonError
from ..core.layout import ProcState
from ..core.rt import monotonic_ns
from ..hardware.registry import hardware_kind
from ..runtime.daemon import Daemon, _CycleStats, run_daemon
from ..runtime.instance import decode
from ..wallclock.clock import LOCKSTEP_SLICE_S, WallClock

# (kind, module, class) in the order hosted daemons are configured: the plant makes the
# boards SIO waits for (or serves the links SIO waits for), SIO lays out the servo level the
# SVs, dynamics and viewer wait for; the plant's module is the hardware kind's simulator
HOSTED_ORDER = (
    ("plant", "plant.daemon", "Plant"),
    ("sio", "sio.daemon", "ServoIO"),
    ("sv", "servo.sv.daemon", "ServoWorker"),
    ("tg", "tg.daemon", "TrajectoryGenerator"),
    ("dynamics", "dynamics.daemon", "Dynamics"),
    ("viewer", "viewer.daemon", "Viewer"),
)


class HostedDaemonError(Exception):
    """A hosted daemon raised out of its cycle (an SV, from inside SIO's)."""

    def __init__(self, daemon: Daemon, exc: Exception) -> None:
        super().__init__(f"{daemon.name}: {exc}")
        self.daemon, self.exc = daemon, exc


class LockstepExecutive(WallClock):
    """The wall clock of a lockstep instance, hosting every other daemon of its config."""

    realtime = False  # runs flat out while stepping: never SCHED_FIFO, never bound

    def on_configure(self) -> None:
        """The clock's own set-up, then every hosted daemon's, in ``HOSTED_ORDER``."""
        super().on_configure()
        if not self.lockstep:
            raise DaemonError(f"{self.name}: the lockstep executive runs lockstep instances only")
        self.hosted: dict[int, Daemon] = {}  # slot -> daemon, called by the executive
        self.stats: dict[int, _CycleStats] = {}
        self.gang: list[tuple[int, Daemon]] = []  # (slot, SV): run inside SIO's cycle
        self.every: list[Daemon] = []  # in the order configured, failed ones too
        self._cycling: list[int] = []  # the hosted slots the watchdog watches
        self._watch_stop = threading.Event()
        self._watchdog = threading.Thread(
            target=self._watch_cycles, name=f"{self.name}.watchdog", daemon=True
        )
        order = {kind: n for n, (kind, _, _) in enumerate(HOSTED_ORDER)}
        procs = [p for p in self.inst.config.processes if p.kind in order]
        procs.sort(key=lambda p: order[p.kind])
        # the plant: the cell's hardware's simulator (franky-sim for an FR3 cell)
        simulator = hardware_kind(self.inst.config.hardware_kinds[0]).simulator
        modules = {kind: (mod, cls) for kind, mod, cls in HOSTED_ORDER}
        modules["plant"] = tuple(simulator.split(":"))  # type: ignore[assignment]
        classes = {
            kind: getattr(importlib.import_module(f"kali_daemons.{mod}"), cls)
            for kind, (mod, cls) in modules.items()
        }
        sio: Daemon | None = None
        for p in procs:
            daemon = classes[p.kind](self.instance_name, p.name)
            self.every.append(daemon)
            try:
                daemon.host(self.inst)
            except Exception as exc:
                daemon._fail(exc)  # names it, as its own process would
                raise DaemonError(f"{p.name} failed to start: {exc}") from exc
            slot = daemon.slot
            self.stats[slot] = _CycleStats(self.inst.procs, slot)
            if p.kind == "sv":
                self.gang.append((slot, daemon))
            else:
                self.hosted[slot] = daemon
            if p.kind == "sio":
                sio = daemon
        if sio is not None:
            sio.io.serve = self._serve  # type: ignore[attr-defined]
        self._cycling = sorted([*self.hosted, *(i for i, _ in self.gang)])

    def on_activate(self) -> None:
        """The clock's activation, and the watchdog over the hosted daemons' cycles."""
        super().on_activate()
        self._watchdog.start()

    def on_deactivate(self) -> None:
        """Every hosted daemon's loop has ended with the executive's."""
        for daemon in self.every:
            if self.inst.procs[daemon.slot]["state"] == ProcState.ACTIVE:
                daemon.on_deactivate()

    def on_shutdown(self) -> None:
        """Stop the watchdog; release every hosted daemon, last configured first, then the
        clock's own."""
        self._watch_stop.set()
        if self._watchdog.is_alive():
            self._watchdog.join()
        for daemon in reversed(self.every):
            if daemon.slot >= 0:
                try:
                    daemon._finish()
                except Exception:
                    self.log.exception("%s: shutdown failed", daemon.name)
        super().on_shutdown()

    # ------------------------------------------------------------------ the tick

    def _lockstep_tick(self, tick: int) -> bool:
        """Run due slots stage by stage: a hosted daemon's cycle here, a program's periodic
        function (its own process) by semaphore, waiting for its acknowledgement.  False if
        the system halted during the tick (the tick stays unfinished, as with processes)."""
        slots, stages, due, hosted = self._slots, self._stages, self._due, self.hosted
        n = len(slots)
        k = 0
        while k < n:
            stage = stages[k]
            posted: list[int] = []
            while k < n and stages[k] == stage:
                i = slots[k]
                if tick >= due[i]:
                    per = self._period[k]
                    due[i] = (tick // per + 1) * per
                    daemon = hosted.get(i)
                    if daemon is not None:
                        if not self._run(i, daemon, tick):
                            return False
                    elif self._member[k]:
                        pass  # an SV: it runs inside SIO's cycle
                    elif self._ack[i] < self._sig[i]:
                        if not self._missed(k, i, tick, monotonic_ns()):
                            self._died(i, tick, self._serious[k])
                    else:
                        self._signal(i, tick)
                        posted.append(k)
                k += 1
            if posted and not self._await_stage(posted, tick):
                return False
        return True

    def _run(self, i: int, daemon: Daemon, tick: int) -> bool:
        """Call hosted slot ``i``'s cycle for ``tick`` and account it as its acknowledgement;
        False if the system halted meanwhile.  Its signal is written after its release
        time: the watchdog reads a signal ahead of the acknowledgement as a cycle running
        since the release time (``_watch_cycles``)."""
        t = monotonic_ns()
        self._rel[i] = t
        self._sig[i] = tick
        self._signals[i] += 1
        try:
            daemon.cycle(tick)
        except HostedDaemonError as failure:  # an SV inside SIO's cycle
            self._failed(failure.daemon, failure.exc)
            return False
        except Exception as exc:
            self._failed(daemon, exc)
            return False
        self.stats[i].record(tick, t, t, monotonic_ns())
        return not self.inst.fault["active"]

    def _serve(self, tick: int) -> None:
        """SIO's feed (``SioCycle.serve``): every SV takes its share of the slots fed for
        ``tick`` now, in SV order, and is accounted as signalled and acknowledged."""
        for i, sv in self.gang:
            t = monotonic_ns()
            self._rel[i] = t
            self._sig[i] = tick  # after its release time, as in _run
            self._signals[i] += 1
            try:
                sv.serve(tick)  # type: ignore[attr-defined]
            except Exception as exc:
                raise HostedDaemonError(sv, exc) from exc
            self.stats[i].record(tick, t, t, monotonic_ns())
        for _, sv in self.gang:  # plugins loaded meanwhile, after the tick's servos
            if sv._loads_gen[0] != sv.level.taken:  # type: ignore[attr-defined]
                sv.take_loads()  # type: ignore[attr-defined]

    def _watch_cycles(self) -> None:
        """The watchdog thread: every ``LOCKSTEP_SLICE_S``, while no fault is active, find
        the hosted daemons inside their cycle (signalled, not acknowledged; an SV inside
        SIO's), and once one of them has been in it longer than ``lockstep_timeout_s`` halt
        with DEADLINE naming the innermost (the latest released: the one running) and what
        it is busy with.  A reset clears the fault; a daemon still in its cycle is named
        again, as a hung process in real time misses its deadline again.  Reads the process
        table only; the executive's thread decides everything else."""
        limit_ns = int(self.lockstep_timeout_s * 1e9)
        sig, ack, rel, state = self._sig, self._ack, self._rel, self._state
        while not self._watch_stop.wait(LOCKSTEP_SLICE_S):
            if self.inst.fault["active"]:
                continue
            inside = [i for i in self._cycling if sig[i] > ack[i] and state[i] == ProcState.ACTIVE]
            now = monotonic_ns()
            if not inside or now - min(int(rel[i]) for i in inside) <= limit_ns:
                continue
            i = max(inside, key=lambda j: int(rel[j]))
            name = decode(self.inst.procs[i]["name"])
            who = f"serious process '{name}'{self._doing(name)}"
            if not self.inst.procs[i]["serious"]:
                who = f"process '{name}' (not serious, but every daemon here waits for it)"
            self._lockstep_deadline(name, who, int(sig[i]), "finish its cycle of")

    def _failed(self, daemon: Daemon, exc: Exception) -> None:
        """A hosted daemon raised: it fails as its own process would (DAEMON_ERROR naming
        it, state ERROR, not periodic any more), and the executive carries on."""
        daemon._fail(exc)
        self.hosted.pop(daemon.slot, None)
        self.gang = [(i, sv) for i, sv in self.gang if sv is not daemon]
        p = self.inst.procs[daemon.slot]
        p["periodic"] = 0
        self.inst.bump_registry()


if __name__ == "__main__":
    run_daemon(LockstepExecutive)
