"""One running Kali instance as a process sees it: arena, well-known records, semaphores.

Every Kali process (daemons, kalictl, user programs) attaches through ``Instance.attach``;
only ``kalictl start`` creates (``launcher.create_instance``).  Names:

- segment      ``/kali.<instance>``          (``/dev/shm/kali.<instance>``)
- semaphores   ``/kali.<instance>.s<NN>``    one per process-table slot (thesis 3.6.2)
               ``/kali.<instance>.cmd``      wakes the wall clock for a command
               ``/kali.<instance>.ack``      lockstep acknowledgements to the wall clock

Long on purpose: every process's one view of an instance (its records, semaphores, fault and
process table).
"""

from __future__ import annotations

import os
import re
import time
from dataclasses import dataclass

import numpy as np
import posix_ipc

from ..core import atomic, layout
from ..core.arena import Arena, foreign_object, owner_text, segment_name, shm_path, user_text
from ..core.errors import ClockError, ConfigError, InstanceError
from ..core.joints import JointMap
from ..core.layout import FaultCode, PowerCmd, ProcState, TgPhase
from ..core.spinlock import SpinLock, holder_text
from ..hardware import HardwareKind, Operations, hardware_kind
from .config import KaliConfig, parse_config

_WORD = 0xFFFFFFFF  # the fault word: the low half of the fault record's 64-bit state word
# What the TG is doing in each phase of its tick, for a fault message (Instance.doing)
_DOING: dict[int, str] = {
    TgPhase.REQUESTS: "taking",
    TgPhase.STARTING: "starting",
    TgPhase.CHECKING: "checking",
    TgPhase.ADVANCING: "advancing",
    TgPhase.ENDING: "ending",
}
FAULT_READ_WAIT_S = 0.05  # longest a reader waits for a fault's writer to finish its record
LOCK_STUCK_S = 0.2  # a lock held by one pid this long is reported stuck (kalictl status)

INSTANCE_RE = re.compile(r"^[a-z0-9][a-z0-9_-]{0,23}$")


def check_instance_name(name: str) -> str:
    """Validate an instance name (it becomes part of /dev/shm names)."""
    if not isinstance(name, str) or not INSTANCE_RE.match(name):
        raise InstanceError(
            f"instance name {name!r} is not allowed: 1-24 of a-z 0-9 _ -, starting alphanumeric"
        )
    return name


def slot_semaphore_name(instance: str, slot: int) -> str:
    """POSIX name of the wake-up semaphore of process-table slot ``slot``."""
    return f"{segment_name(instance)}.s{slot:02d}"


def command_semaphore_name(instance: str) -> str:
    """POSIX name of the semaphore that wakes the wall clock for a command."""
    return f"{segment_name(instance)}.cmd"


def ack_semaphore_name(instance: str) -> str:
    """POSIX name of the lockstep acknowledgement semaphore."""
    return f"{segment_name(instance)}.ack"


def feed_semaphore_name(instance: str, sv: int) -> str:
    """POSIX name of the semaphore SIO posts when the servo slots are fed, one per SV."""
    return f"{segment_name(instance)}.feed{sv}"


def done_semaphore_name(instance: str) -> str:
    """POSIX name of the semaphore the SV finishing a tick's last servo posts to SIO."""
    return f"{segment_name(instance)}.done"


def all_semaphore_names(instance: str) -> list[str]:
    """Every semaphore an instance owns."""
    names = [slot_semaphore_name(instance, i) for i in range(layout.MAX_PROCESSES)]
    names += [feed_semaphore_name(instance, k) for k in range(layout.MAX_SV)]
    return [
        *names,
        command_semaphore_name(instance),
        ack_semaphore_name(instance),
        done_semaphore_name(instance),
    ]


@dataclass(frozen=True)
class FaultInfo:
    """The fault record, copied consistently (``Instance.read_fault``)."""

    code: str  # FaultCode name; UNFINISHED while a stopped or dead writer's record is partial
    process: str
    tick: int
    message: str
    time_ns: int
    pid: int
    active: bool
    count: int


@dataclass(frozen=True)
class HeldLock:
    """A lock of the instance held by one process for at least LOCK_STUCK_S."""

    name: str
    pid: int
    holder: str  # holder_text: pid, command, state (stopped, dead, ...)


def estop_pressed(robots: list[str]) -> str:
    """What ``kalictl estop`` says once it has pressed the buttons of ``robots`` (the
    bridge's e-stop says the same)."""
    return f"e-stop pressed: {', '.join(robots)}; amplifiers off, system halted"


def decode(raw: bytes | np.bytes_ | np.ndarray) -> str:
    """A fixed-width arena string (bytes, or a record's field viewed) as text."""
    return bytes(raw).split(b"\0", 1)[0].decode("utf-8", "replace")


def _check_kind(instance: str, name: str, version: int) -> None:
    """InstanceError unless this Kali has hardware kind ``name`` with records of ``version``
    (the digest ``kalictl start`` stored): a process of another Kali must not misread, or
    write, a register."""
    try:
        kind = hardware_kind(name)
    except ConfigError as exc:
        raise InstanceError(f"instance '{instance}': {exc}") from None
    if kind.version != version:
        raise InstanceError(
            f"instance '{instance}': its {name} hardware records are version {version}, this "
            f"Kali's {kind.version}; stop the instance with the Kali that started it"
        )


@dataclass(frozen=True)
class Cell:
    """The cell as ``kalictl start`` wrote it into the arena (``layout.CELL``): what the
    safety path and the status tools need, without parsing the config or running user code.
    Per robot in config order: name, robot type name, hardware kind, each joint's encoder
    resolution (rad a count) and motor current limit (A)."""

    names: tuple[str, ...]
    models: tuple[str, ...]
    hardware: tuple[str, ...]
    joints: JointMap
    rad_per_count: tuple[np.ndarray, ...]
    max_current: tuple[np.ndarray, ...]
    n_svs: int

    @property
    def n_robots(self) -> int:
        return len(self.names)

    @staticmethod
    def read(rec: np.ndarray, instance: str) -> Cell:
        """The cell from its record; InstanceError if it holds what no start writes (the
        arena is not trusted: a bad count must not become an index)."""
        n = int(rec["n_robots"])
        robots = rec["robots"][: max(0, min(n, layout.MAX_ROBOTS))].copy()
        counts = tuple(int(c) for c in robots["n_joints"])
        if not 1 <= n <= layout.MAX_ROBOTS or not all(1 <= c <= layout.MAX_JOINTS for c in counts):
            raise InstanceError(
                f"instance '{instance}': its cell record holds {n} robots of {list(counts)} "
                f"joints, not 1..{layout.MAX_ROBOTS} robots of 1..{layout.MAX_JOINTS} joints "
                f"(written outside kalictl start)"
            )
        names = tuple(decode(r) for r in robots["name"])
        kinds = tuple(decode(r) for r in robots["hardware"])
        for kind_name, version in zip(kinds, robots["hardware_version"], strict=True):
            _check_kind(instance, kind_name, int(version))
        per_joint = list(zip(robots, counts, strict=True))
        return Cell(
            names=names,
            models=tuple(decode(r) for r in robots["model"]),
            hardware=kinds,
            joints=JointMap(names, counts),
            rad_per_count=tuple(r["rad_per_count"][:c] for r, c in per_joint),
            max_current=tuple(r["max_current"][:c] for r, c in per_joint),
            n_svs=max(0, min(int(rec["n_svs"]), layout.MAX_SV)),
        )


class Instance:
    """An attached instance: views of the clock, process table and fault record."""

    def __init__(self, name: str, arena: Arena) -> None:
        self.name = name
        self.arena = arena
        self.clock = arena.existing(layout.KEY_CLOCK, layout.CLOCK)
        self.procs = arena.existing(layout.KEY_PROCESSES, layout.PROCESS, layout.MAX_PROCESSES)
        self.fault = arena.existing(layout.KEY_FAULT, layout.FAULT)
        self.misses = arena.existing(layout.KEY_MISSES, layout.MISS_LOG)
        self._config: KaliConfig | None = None
        self._cell: Cell | None = None
        self._sems: dict[str, posix_ipc.Semaphore] = {}
        self._ops: dict[str, Operations] = {}  # each hardware kind's, once asked for
        clock_off = arena.lookup(layout.KEY_CLOCK)[0]  # type: ignore[index]
        fault_off = arena.lookup(layout.KEY_FAULT)[0]  # type: ignore[index]
        self.table_lock = SpinLock(
            arena.address_of_field(clock_off, layout.CLOCK, "table_lock"), "process table"
        )
        self.cmd_lock = SpinLock(
            arena.address_of_field(clock_off, layout.CLOCK, "cmd_lock"), "clock command"
        )
        # the fault word and its sequence count, read and swapped as one 64-bit state word
        self._fault_state = arena.address_of_field(fault_off, layout.FAULT, "active")
        self._fault_count = arena.address_of_field(fault_off, layout.FAULT, "count")
        self._fault_cas = atomic.CompareExchange64()
        self.registry_gen_addr = arena.address_of_field(clock_off, layout.CLOCK, "registry_gen")
        self.rates_gen_addr = arena.address_of_field(clock_off, layout.CLOCK, "rates_gen")

    @classmethod
    def attach(cls, name: str) -> Instance:
        """Attach to the running instance ``name``."""
        return cls(check_instance_name(name), Arena.attach(name))

    def close(self) -> None:
        """Close semaphores and unmap; safe to call twice."""
        for sem in self._sems.values():
            sem.close()
        self._sems.clear()
        self._ops.clear()  # their record views pin the mapping
        self.arena.close()

    def __enter__(self) -> Instance:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- shared objects

    @property
    def config(self) -> KaliConfig:
        """The configuration the instance was started with (its text is in the arena), its
        user files loaded from the copies taken at start (``kali_daemons.tools.snapshot``): this
        runs the robot types' and plugins' code, so the safety path never asks for it
        (``cell`` holds what that needs)."""
        if self._config is None:
            text = self._text(layout.KEY_CONFIG)
            base = self._text(layout.KEY_CONFIG_DIR)
            files = self._text(layout.KEY_CONFIG_FILES)
            source = f"{self.arena.name}:config"
            self._config = parse_config(text, source, base or None, files, instance=self.name)
        return self._config

    @property
    def cell(self) -> Cell:
        """The arms as ``kalictl start`` found them (``layout.CELL``), from the arena alone:
        no config to parse, no user code to run."""
        if self._cell is None:
            self._cell = Cell.read(self.arena.existing(layout.KEY_CELL, layout.CELL), self.name)
        return self._cell

    def _text(self, key: str) -> str:
        found = self.arena.lookup(key)
        if found is None:
            return ""
        off, size = found
        raw = self.arena.view(off, np.dtype("u1"), size)
        return bytes(raw).split(b"\0", 1)[0].decode()

    @property
    def lockstep(self) -> bool:
        """True when the instance runs in lockstep mode."""
        return bool(self.clock["lockstep"])

    @property
    def shutting_down(self) -> bool:
        """True once kalictl stop has asked every process to leave."""
        return bool(self.arena.header["shutdown"])

    def robot_index(self, robot: str) -> int:
        """Index of ``robot`` in the config (and in every per-robot array); InstanceError."""
        names = self.cell.names
        if robot not in names:
            raise InstanceError(
                f"no robot {robot!r:.40} in instance '{self.name}' (robots: {', '.join(names)})"
            )
        return names.index(robot)

    def hardware(self, k: int) -> Operations:
        """The operations of the hardware behind robot ``k``, outside any cycle and without
        a lock (``hardware.Operations``), from the arena alone."""
        return self._operations(self.cell.hardware[k])

    def all_hardware(self) -> list[Operations]:
        """The operations of every hardware kind in the cell, each once."""
        return [self._operations(name) for name in dict.fromkeys(self.cell.hardware)]

    def hardware_kind(self, name: str) -> HardwareKind:
        """The hardware kind ``name`` behind some of this cell's robots, its records the
        version they were laid out with (``Cell.read`` checks it)."""
        if name not in self.cell.hardware:
            raise InstanceError(f"instance '{self.name}': no robot of hardware kind {name!r}")
        return hardware_kind(name)

    def _operations(self, name: str) -> Operations:
        ops = self._ops.get(name)
        if ops is None:
            kind = self.hardware_kind(name)
            ops = self._ops[name] = kind.operations(self.arena, self.cell.n_robots)
        return ops

    def robot_states(self) -> np.ndarray:
        """SIO's record of each robot (``layout.ROBOT_STATE``), config order."""
        return self.arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, self.cell.n_robots)

    def command_power(self, k: int, on: bool) -> None:
        """Ask SIO to power robot ``k``'s amplifiers on (off): the command word stamped with
        the faults raised so far, read before the fault check, so a halt after the check
        voids it (SIO takes a command only while the stamp is the count and no fault is
        active; LinuxCNC: a halt forgets every pending command).  InstanceError for an
        enable while a fault is active."""
        stamp = int(self.fault["count"]) & 0xFFFFFFFF
        if on and self.fault["active"]:
            raise InstanceError(
                f"cannot enable '{self.cell.names[k]}' while a fault is active "
                f"({self.fault_text()}); kalictl reset first"
            )
        robots = self.robot_states()
        robots["cmd_faults"][k] = stamp
        robots["power_cmd"][k] = PowerCmd.ENABLE if on else PowerCmd.DISABLE

    def push(self, k: int, force: np.ndarray, seconds: float) -> None:
        """Ask the plant to push robot ``k``'s tool with ``force`` (N, world frame, at the
        tool's centre of mass) for ``seconds`` of simulated time (``kalictl push``; tests and
        demos of force control).  A push replaces the one in progress."""
        pushes = self.arena.existing(layout.KEY_PUSHES, layout.PUSH, self.cell.n_robots)
        pushes["force"][k] = force
        pushes["duration_ns"][k] = round(seconds * 1e9)
        pushes["seq"][k] = int(pushes["seq"][k]) + 1  # last: the plant starts the push

    def semaphore(self, posix_name: str) -> posix_ipc.Semaphore:
        """Open (once) one of the instance's semaphores."""
        sem = self._sems.get(posix_name)
        if sem is None:
            path = shm_path(posix_name, semaphore=True)
            why = foreign_object(path, semaphore=True, any_owner=True)
            if why is not None:
                raise InstanceError(f"instance '{self.name}': semaphore {why}; not opened")
            try:
                sem = posix_ipc.Semaphore(posix_name)
            except posix_ipc.ExistentialError as exc:
                raise InstanceError(f"instance '{self.name}': no semaphore {posix_name}") from exc
            except posix_ipc.PermissionsError:
                raise InstanceError(
                    f"instance '{self.name}': semaphore {posix_name} "
                    f"{owner_text(posix_name, semaphore=True)}; {user_text()} may not use it"
                ) from None
            self._sems[posix_name] = sem
        return sem

    def slot_semaphore(self, slot: int) -> posix_ipc.Semaphore:
        """The wake-up semaphore of process-table slot ``slot``."""
        return self.semaphore(slot_semaphore_name(self.name, slot))

    def command_semaphore(self) -> posix_ipc.Semaphore:
        """The semaphore that wakes the wall clock for a command."""
        return self.semaphore(command_semaphore_name(self.name))

    def feed_semaphore(self, sv: int) -> posix_ipc.Semaphore:
        """The semaphore that tells SV ``sv`` the servo slots are fed."""
        return self.semaphore(feed_semaphore_name(self.name, sv))

    def done_semaphore(self) -> posix_ipc.Semaphore:
        """The semaphore that tells SIO every fed servo has run."""
        return self.semaphore(done_semaphore_name(self.name))

    def ack_semaphore(self) -> posix_ipc.Semaphore:
        """The lockstep acknowledgement semaphore."""
        return self.semaphore(ack_semaphore_name(self.name))

    # ---------------------------------------------------------------- process table

    def find_slot(self, name: str) -> int:
        """Index of the slot holding process ``name``, or -1."""
        raw = name.encode()
        for i in range(layout.MAX_PROCESSES):
            if self.procs[i]["state"] != ProcState.FREE and self.procs[i]["name"] == raw:
                return i
        return -1

    def slot_of(self, name: str) -> int:
        """Index of the slot holding process ``name``; ClockError naming the known ones."""
        i = self.find_slot(name)
        if i < 0:
            known = ", ".join(self.process_names()) or "none"
            raise ClockError(f"no process '{name}' in instance '{self.name}' (known: {known})")
        return i

    def process_names(self) -> list[str]:
        """Names of every occupied slot, in slot order."""
        return [decode(p["name"]) for p in self.procs if p["state"] != ProcState.FREE]

    def claim_slot(self, name: str, pid: int) -> int:
        """Reserve a free slot for a new process ``name`` (unique among occupied slots)."""
        if not name or len(name.encode()) >= layout.NAME_BYTES:
            raise ClockError(f"process name {name!r} must be 1..{layout.NAME_BYTES - 1} bytes")
        with self.table_lock:
            if self.find_slot(name) >= 0:
                raise ClockError(f"process '{name}' already exists in instance '{self.name}'")
            free = np.flatnonzero(self.procs["state"] == ProcState.FREE)
            if free.size == 0:
                raise ClockError(
                    f"process table of instance '{self.name}' is full "
                    f"({layout.MAX_PROCESSES} slots) for '{name}'"
                )
            i = int(free[0])
            self.procs[i] = 0
            self.procs[i]["name"] = name.encode()
            self.procs[i]["pid"] = pid
            self.procs[i]["cpu"] = -1
            self.procs[i]["signal_tick"] = -1
            self.procs[i]["ack_tick"] = -1
            self.procs[i]["vouched_tick"] = -1
            self.procs[i]["state"] = ProcState.SPAWNED
            return i

    def free_slot(self, slot: int) -> None:
        """Return a slot to the table (the process left)."""
        with self.table_lock:
            self.procs[slot]["periodic"] = 0
            self.procs[slot]["state"] = ProcState.FREE
        self.bump_registry()

    def bump_registry(self) -> None:
        """Tell the wall clock the set of periodic or self-timed slots changed (it reads the
        process table again)."""
        atomic.fetch_add32(self.registry_gen_addr, 1)

    def bump_rates(self) -> None:
        """Tell the wall clock a slot's ``period_ticks`` changed, after writing it (it
        re-reads only its slots' periods: ``WallClock._rescan``)."""
        atomic.fetch_add32(self.rates_gen_addr, 1)

    # ---------------------------------------------------------------- faults (DESIGN 7)

    def raise_fault(
        self, code: FaultCode, process: str, message: str, tick: int | None = None
    ) -> bool:
        """Record a fault and so halt the system; the first uncleared fault wins.

        A halt disables every robot's amplifiers through its board first (DESIGN 7: bit 7 of
        the command/status register low cuts them at once; the brakes follow in the plant),
        whoever raises it.  Lock-free: one compare-and-swap of the record's 64-bit state word,
        from (fault word 0, even sequence count) to (this pid, odd count), decides the winner
        and opens the record in one step; the winner alone writes the rest and then makes the
        count even.  So no process holding anything, stopped or dead, can keep a halt from
        being recorded, and no reader sees the fault word set beside an earlier fault's
        fields.  The fault count goes up once the record is written (the loser's at once), so
        whoever sees a halt counted (SIO and the TG each tick) reads its record whole.  The
        wall clock stops itself when it sees the fault word set.  Returns True if this call
        recorded the fault, False if one was already active (still counted).
        """
        self.power_off_all()
        pid = os.getpid()
        state = atomic.load64(self._fault_state)
        while True:
            if state & _WORD:
                atomic.fetch_add64(self._fault_count, 1)  # counted too
                return False  # an uncleared fault is active: it stands
            # win and open the record in one step: the word becomes this pid and the sequence
            # count odd (a writer that died half-way left it odd already: step past it)
            seq = (state >> 32) + 1 + (state >> 32 & 1)
            won, state = self._fault_cas(self._fault_state, state, (seq & _WORD) << 32 | pid)
            if won:
                break
        f = self.fault
        f["code"] = int(code)
        f["pid"] = pid
        f["tick"] = int(self.clock["tick"]) if tick is None else tick
        f["time_ns"] = time.time_ns()
        f["process"] = process.encode()[: layout.NAME_BYTES - 1]
        f["message"] = message.encode()[: layout.MESSAGE_BYTES - 1]
        atomic.fetch_add64(self._fault_state, 1 << 32)  # even: written (whether reset or not)
        atomic.fetch_add64(self._fault_count, 1)  # last: a halt counted is a halt written
        try:
            self.command_semaphore().release()  # a stopped-but-waiting clock notices at once
            if self.lockstep:
                self.ack_semaphore().release()  # a clock waiting for lockstep acks too
        except InstanceError:  # squatted or gone: the clock sees the fault word at its next look
            pass
        return True

    def press_estop(self, robot: str | None, process: str) -> list[str]:
        """Press the emergency-stop button of ``robot`` (None: every robot's) and halt the
        system (a fault ESTOP raised by ``process``): each board cuts its amplifiers at once,
        the brakes follow.  Lock-free, so from any process whoever holds what (``kalictl
        estop``, the bridge), from the arena alone (no config parsed, no user code run).  The
        robots pressed (``estop_pressed`` says so); InstanceError for an unknown robot, with
        nothing pressed."""
        targets = [robot] if robot is not None else list(self.cell.names)
        indices = [self.robot_index(name) for name in targets]
        for k in indices:
            self.hardware(k).press_estop(k, True)
        self.raise_fault(FaultCode.ESTOP, process, f"emergency stop pressed: {', '.join(targets)}")
        return targets

    def power_off_all(self) -> None:
        """Cut every robot's drive through its hardware (safe from any process; takes no
        lock, so it works whoever holds what)."""
        for ops in self.all_hardware():
            ops.cut()

    def clear_fault(self) -> bool:
        """Clear the active fault (kalictl reset); False if none was active.

        Every power and calibration command still pending is voided first: one written
        during the halt carries the halt's own fault count, and SIO, stopped with the clock,
        has not seen it; a halt forgets every pending command, so nothing powers on at reset
        by itself."""
        state = atomic.load64(self._fault_state)
        if state & _WORD and self.arena.lookup(layout.KEY_ROBOTS) is not None:
            robots = self.robot_states()
            robots["power_cmd"] = PowerCmd.NONE
            robots["calib_cmd"] = 0
            del robots
        while state & _WORD:  # clear the word, keep the sequence count (a writer may be busy)
            cleared, state = self._fault_cas(self._fault_state, state, state & ~_WORD)
            if cleared:
                for ops in self.all_hardware():
                    ops.reset()  # the hardware's own recovery (an FR3's), power still off
                return True
        return False

    def read_fault(self) -> FaultInfo:
        """A consistent copy of the fault record (the latest fault, even if cleared).

        Copied between two equal even values of its sequence count.  If the winner of a
        fault stops or dies before its record is written, the copy says so (code UNFINISHED,
        naming the writer) after FAULT_READ_WAIT_S: the halt itself stands all the same.
        """
        f = self.fault
        deadline = time.monotonic() + FAULT_READ_WAIT_S
        while True:
            state = atomic.load64(self._fault_state)
            seq, word = state >> 32, state & _WORD
            if not seq & 1:
                info = FaultInfo(
                    code=_code_name(int(f["code"])),
                    process=decode(f["process"]),
                    tick=int(f["tick"]),
                    message=decode(f["message"]),
                    time_ns=int(f["time_ns"]),
                    pid=int(f["pid"]),
                    active=word != 0,
                    count=int(atomic.load64(self._fault_count)),
                )
                if atomic.load64(self._fault_state) >> 32 == seq:
                    return info
            elif time.monotonic() > deadline:
                writer = word or int(f["pid"])
                return FaultInfo(
                    code="UNFINISHED",
                    process=f"pid {writer}",
                    tick=int(self.clock["tick"]),
                    message=f"the record of this halt was left unfinished by {holder_text(writer)}",
                    time_ns=0,
                    pid=writer,
                    active=word != 0,
                    count=int(atomic.load64(self._fault_count)),
                )
            time.sleep(0.0005)

    def doing(self, process: str) -> str:
        """What process ``process`` is busy with, for a fault naming it ('' when it does not
        say): the TG's phase of its tick and request (``TG_STATE.phase``), or the TG function
        it is evaluating: "evaluating tg function 'wave' (sine) for request 12"; a link's
        robot connection, as its hardware says it (``Operations.link_text``).  Read
        lock-free while the TG may be writing: it words a fault, it decides nothing."""
        kinds = {p.name: p.kind for p in self.config.processes}
        if kinds.get(process) == "link":  # a networked robot's: what its hardware says
            k = self.robot_index(process.partition(".")[2])
            return self.hardware(k).link_text(k)
        if kinds.get(process) != "tg" or self.arena.lookup(layout.KEY_TG_STATE) is None:
            return ""
        state = self.arena.existing(layout.KEY_TG_STATE, layout.TG_STATE)
        verb = _DOING.get(int(state["phase"]), "")
        seq, slot = int(state["phase_seq"]), int(state["phase_function"])
        if not verb:
            return ""  # between ticks
        request = f" request {seq}" if seq else " requests"
        if not (0 < slot <= layout.MAX_FUNCTIONS and self.arena.lookup(layout.KEY_TG_FUNCTIONS)):
            return verb + request
        slots = self.arena.existing(
            layout.KEY_TG_FUNCTIONS, layout.TG_FUNCTION, layout.MAX_FUNCTIONS
        )
        label, function = decode(slots[slot - 1]["name"]), decode(slots[slot - 1]["function"])
        return f"evaluating tg function '{label}' ({function})" + (f" for{request}" if seq else "")

    def fault_text(self, last: bool = False) -> str | None:
        """The active fault as one line, or None; ``last``: the latest fault even if cleared
        (None if there never was one)."""
        active = atomic.load64(self._fault_state) & _WORD
        if not (active or (last and atomic.load64(self._fault_count))):
            return None
        f = self.read_fault()
        return f"{f.code} in {f.process} at tick {f.tick}: {f.message}"

    # ---------------------------------------------------------------- locks

    def lock_words(self) -> list[tuple[str, int]]:
        """Every spinlock of the instance as (name, address): the arena directory, the
        process table, the clock's command, the motion queue's producers and each servo
        slot's mailbox (those not laid out yet are left out)."""
        clock_off = self.arena.lookup(layout.KEY_CLOCK)[0]  # type: ignore[index]
        a = self.arena
        words = [
            ("arena directory", a.address_of_field(0, layout.HEADER, "dir_lock")),
            ("process table", a.address_of_field(clock_off, layout.CLOCK, "table_lock")),
            ("clock command", a.address_of_field(clock_off, layout.CLOCK, "cmd_lock")),
        ]
        queue = a.lookup(layout.KEY_MOTION_QUEUE)
        if queue is not None:
            words.append(
                (
                    f"queue {layout.KEY_MOTION_QUEUE}",
                    a.address_of_field(queue[0], layout.QUEUE_HEADER, "lock"),
                )
            )
        slots = a.lookup(layout.KEY_SLOTS)
        if slots is not None:
            joints = self.cell.joints
            for k, robot in enumerate(joints.names):
                for j in range(joints.counts[k]):
                    i = joints.index(k, j)
                    if (i + 1) * layout.SERVO_SLOT.itemsize <= slots[1]:
                        addr = a.address_of_field(slots[0], layout.SERVO_SLOT, "op_lock", i)
                        words.append((f"servo mailbox {robot} joint {j + 1}", addr))
        return words

    def held_locks(self, hold_s: float = LOCK_STUCK_S) -> list[HeldLock]:
        """The locks one process has held for at least ``hold_s`` (sampled at both ends of
        that time): a holder that is stopped, hung or dead.  Never in a cycle (it sleeps)."""
        words = self.lock_words()
        first = [atomic.load32(addr) for _, addr in words]
        if not any(first):
            return []
        time.sleep(hold_s)
        held = []
        for (name, addr), pid in zip(words, first, strict=True):
            if pid and atomic.load32(addr) == pid:
                held.append(HeldLock(name, pid, holder_text(pid)))
        return held


def _code_name(code: int) -> str:
    """A fault code's name; the number itself if the record holds no FaultCode."""
    try:
        return FaultCode(code).name
    except ValueError:
        return f"code {code}"


def time_ms(clock: np.ndarray) -> float:
    """Running time of the wall clock in ms (thesis: total running time in milliseconds)."""
    return float(clock["time_offset_ms"]) + int(clock["tick"]) * int(clock["base_tick_ns"]) / 1e6
