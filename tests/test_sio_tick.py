"""SIO's tick compiled (``kali_sio_tick``) and an SV's serve compiled
(``kali_sv_serve``, issue 26 item 2) do what their Python references,
``SioCycle._tick_reference`` and ``ServoWorker._serve_reference``, do, tick after tick,
through every event the kernels hand back to Python.

Two copies of the default cell (each arm with robot-level servos allowed) are hosted in this
process, a plant, SIO, both SVs and the dynamics process each, as the lockstep executive hosts
them: one copy runs the compiled tick and serve, the other the references.  Both get the same
story: pots read, power on, set-points streamed into the FIFOs, feed-forward on and off, a
robot-level servo selected and dropped, a tare, a guard reached, the contact limit, a joint's
range, the runaway limit, a motor's current limit and a PID's gain spoilt until each halts, a
halt raised from outside, resets and power cycles, a calibration (its index capture), a
mailbox operation and a disabled servo (single slots), and the gang's words (the SVs' signals
and feeds, as in real time, where SIO acknowledges for them) set at random, with a few random
extras.  After every tick the two arenas must be equal byte for byte, every timing field
aside (latencies, durations, the flight rows' times, a halt's time), and so must SIO's own
arrays and the state it keeps between ticks.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.core.kernels import (
    SIO_CAPTURE,
    SIO_CHECK,
    SIO_CURRENT,
    SIO_ROBOTS,
    SIO_SENSOR,
    SV_ARM,
    SV_FAULT,
    SV_SLOT,
)
from kali_daemons.core.layout import FaultCode, FfMode, GuardState, PowerCmd
from kali_daemons.servo.client import ServoClient
from kali_daemons.sio.cycle import SioCycle
from kali_daemons.sio.gang import GangAcknowledger

from .conftest import HostedCell

TICKS = 2400
ROBOT_SERVOS = {r"^(  - \{name: (left|right).*)\}$": r"\1, robot_servos: true}"}
# timing fields: both copies write them, from their own clocks
TIMES = {
    layout.KEY_SERVO_CTRL: (
        "latency_last_ns",
        "latency_max_ns",
        "latency_hist",
        "sv_exec_last_ns",
        "sv_exec_max_ns",
        "sv_exec_hist",
        "fed_ns",
        "sv_served_max_ns",
    ),
    layout.KEY_SLOTS: ("exec_ns",),
    layout.KEY_FLIGHT_RING: ("t_ns", "latency_ns", "late_ns", "wait_ns", "ran_ns"),
}
PROCESS_FIELDS = ("signal_tick", "ack_tick", "vouched_tick")  # what SIO writes there


class Copy:
    """One hosted cell, SIO's tick compiled or its reference, with a client for the story."""

    def __init__(self, reference: bool) -> None:
        self.cell = HostedCell(("plant", "sio", "sv.0", "sv.1", "dynamics"), ROBOT_SERVOS)
        self.inst = self.cell.inst
        self.plant = self.cell["plant"]
        self.dynamics = self.cell["dynamics"]  # its rows: the feed-forward SIO applies
        self.sio: SioCycle = self.cell["sio"].io  # type: ignore[attr-defined]
        svs = (self.cell["sv.0"], self.cell["sv.1"])
        self.svs = svs
        self.gang = False  # the gang's words at random, as in real time (the story says)
        self.gang_rng = np.random.default_rng(7)  # the same numbers in both copies
        self.centre: list[np.ndarray] = []  # where the set-points go, once the arms are on
        self.sio.serve = self._serve(svs)
        self.client = ServoClient(self.inst)
        self.level = self.client.level
        self.fifos = [self.level.fifo(k) for k in range(self.level.n_robots)]
        self.memory = np.frombuffer(self.inst.arena._mm, dtype=np.uint8)
        sio = self.sio
        # the gang as in real time (sv.0 on SIO's CPU, sv.1 not), SIO's early acknowledgement
        sio._gang = GangAcknowledger(
            self.level.ctrl["sv_fed_tick"],
            self.inst.procs["signal_tick"],
            self.inst.procs["ack_tick"],
            self.inst.procs["vouched_tick"],
            sio.sv_slots,
            [True, False],
        )
        daemon = self.cell["sio"]  # its acknowledgement, which the reference calls
        daemon._ack_early = self.inst.procs["ack_tick"][sio.slot : sio.slot + 1]  # type: ignore[attr-defined]
        sio._bind_tick()
        sio.activate(daemon._ack_early)  # type: ignore[attr-defined]
        self.reference = reference
        self.tick_fn = sio._tick_reference if reference else sio.cycle

    def _serve(self, svs: tuple[object, ...]):
        def serve(tick: int) -> None:
            for sv in svs:
                sv.serve(tick) if not self.reference else sv._serve_reference(tick)  # type: ignore[attr-defined]
            if self.gang:  # the SVs' feeds and signals, as in real time
                rng = self.gang_rng
                for k, slot in enumerate(self.sio.sv_slots):
                    self.level.ctrl["sv_fed_tick"][k] = tick - int(rng.integers(0, 3))
                    self.inst.procs["signal_tick"][slot] = tick - int(rng.integers(0, 2))

        return serve

    def step(self, tick: int) -> None:
        self.plant.cycle(tick)  # type: ignore[attr-defined]
        self.tick_fn(tick)
        if tick % 10 == 0:  # its period
            self.dynamics.cycle(tick)  # type: ignore[attr-defined]

    def state(self) -> list[tuple[str, bytes]]:
        """The arena's blocks (timing fields zeroed), SIO's process words, its own arrays and
        the state it keeps between ticks."""
        arena = self.inst.arena
        ctrl, slots, ring = self.level.ctrl, self.level.slots, self.sio.flight.ring
        for records, key in ((ctrl, layout.KEY_SERVO_CTRL), (slots, layout.KEY_SLOTS)):
            for f in TIMES[key]:
                records[f] = 0
        for f in TIMES[layout.KEY_FLIGHT_RING]:
            ring[f] = 0
        self.inst.fault["time_ns"] = 0  # a halt's wall-clock time
        self.level.robots["arm_exec_ns"] = 0  # a robot-level servo's step
        out = []
        skip = {layout.KEY_PROCESSES, layout.KEY_CONFIG}
        for b in arena.blocks():
            if b.used and b.key not in skip:
                out.append((b.key, self.memory[b.offset : b.offset + b.size].tobytes()))
        procs = self.inst.procs
        out += [(f, procs[f].tobytes()) for f in PROCESS_FIELDS]
        sio = self.sio
        for name in ("q", "q_prev", "qd", "demand", "demand_vel", "demand_acc", "mark", "ff"):
            out.append((name, getattr(sio, name).tobytes()))
        for name in ("torque", "servo_torque", "current", "clamped", "fed_mask", "over"):
            out.append((name, getattr(sio, name).tobytes()))
        a = sio._tick_args
        out.append(("kept", repr((a.faults_seen, a.retrigger_tick, sio._whole.tolist()))))
        out.append(("boards", repr((sio.hw.ticks, sio.hw._state.bit, sio.hw._state.prev_bit))))
        return out

    def close(self) -> None:
        del self.memory
        self.client.close()
        self.cell.close()


@pytest.fixture(scope="module")
def twins() -> Iterator[tuple[Copy, Copy]]:
    made: list[Copy] = []
    try:
        made.append(Copy(reference=False))
        made.append(Copy(reference=True))
        yield made[0], made[1]
    finally:
        for c in made:
            c.close()


HALTS = (820, 920, 1200, 1320, 1420, 2255)  # a halt before each: RANGE, RUNAWAY, CURRENT, ...
# (tick, happening, robot, value): the story's spine; random extras come on top of it
SCRIPT = (
    (40, "enable", 0, 0.0),
    (300, "ff", 0, FfMode.FULL),
    (400, "arm", 1, "computed_torque"),
    (500, "tare", 0, 0.0),
    (600, "guard", 0, 0.0),  # reached at once: the arm holds where it touched
    (650, "unguard", 0, 0.0),
    (700, "arm", 1, None),  # back to the joint servos
    (750, "gang", 0, 0.0),
    (800, "range", 0, -0.01),  # a joint's upper limit just below it: RANGE
    (820, "range", 0, np.pi),
    (900, "runaway", 1, 1e-6),  # RUNAWAY
    (920, "runaway", 1, 0.5),
    (1000, "current", 0, 1e-4),  # CURRENT once over for current_fault_ms
    (1200, "current", 0, 10.0),
    (1300, "contact", 1, 1e-3),  # FORCE
    (1320, "contact", 1, 0.0),
    (1400, "halt", 0, 0.0),  # OPERATOR, from outside
    (1500, "disable", 1, 0.0),
    (1520, "enable", 1, 0.0),
    (1600, "calibrate", 0, 0.0),  # index capture: the pulses caught after each read
    (1700, "arm", 0, "impedance"),
    (1800, "gang", 0, 0.0),
    (1900, "ff", 0, FfMode.OFF),
    (2000, "arm", 0, None),
    (2100, "params", 1, 150.0),  # a mailbox operation: the unit leaves the slot to Python
    (2150, "off", 1, 0.0),  # a disabled servo: a single slot
    (2200, "on", 1, 0.0),
    (2250, "nan", 0, np.nan),  # a PID whose torque is not finite: SERVO
    (2251, "nan", 0, 100.0),
    # after each halt: reset, then enable
    *((t + dt, what, 0, 0.0) for t in HALTS for dt, what in ((5, "reset"), (10, "enable"))),
)


class Story:
    """What happens to both copies at each tick: the script, a set-point every 10 ticks and
    a few random extras drawn once from one seed."""

    def __init__(self, seed: int) -> None:
        self.rng = np.random.default_rng(seed)
        self.events: dict[str, int] = {}
        self.script: dict[int, list[tuple[str, int, object]]] = {}
        for tick, what, k, value in SCRIPT:
            self.script.setdefault(tick, []).append((what, k, value))

    def plan(self, tick: int) -> list[tuple[str, int, object]]:
        """This tick's happenings."""
        todo = list(self.script.get(tick, ()))
        if tick > 100 and tick % 10 == 0:
            todo.append(("setpoint", 0, 0.0))
        if tick > 100 and self.rng.random() < 0.01:  # an extra, anywhere in the story
            what = str(self.rng.choice(["tare", "ff", "disable", "enable", "gang", "reset"]))
            value = FfMode(int(self.rng.integers(3))) if what == "ff" else 0.0
            todo.append((what, int(self.rng.integers(2)), value))
        return todo

    def apply(self, c: Copy, tick: int, what: str, k: int, value: object) -> None:
        """One happening on one copy."""
        lv, sio = c.level, c.sio
        rs, ft = lv.robots, sio.ft_records
        span = lv.map.span(k)
        stamp = int(c.inst.fault["count"]) & 0xFFFFFFFF
        if what == "enable":
            for r in range(lv.n_robots):
                rs["cmd_faults"][r] = stamp
                rs["power_cmd"][r] = PowerCmd.ENABLE
        elif what == "setpoint":
            if not c.centre:
                c.centre = [sio.q[lv.map.span(r)].copy() for r in range(lv.n_robots)]
            for r, fifo in enumerate(c.fifos):
                if fifo.pending() < 30:
                    wave = 0.05 * np.sin(tick / 300.0 + np.arange(fifo.width))
                    fifo.push(c.centre[r] + wave)
        elif what == "ff":
            sio.ff_records["mode"][k] = value
        elif what == "arm":
            c.client.select_arm(k, value, wait=False)  # type: ignore[arg-type]
        elif what == "tare":
            ft["tare_cmd"][k] = 1
        elif what == "guard":
            ft["guard_n"][k] = value
            ft["guard_state"][k] = GuardState.ARMED
        elif what == "unguard":
            ft["guard_state"][k] = GuardState.IDLE
        elif what == "contact":
            ft["contact_limit"][k] = value
        elif what == "range":
            i = span.start + 1
            sio.driver.q_max[i] = sio.q[i] + value if value < 0 else value
        elif what == "runaway":
            lv.joints["safe"][span] = value
        elif what == "current":
            sio.driver.current_limit[span.start + 1] = value
        elif what == "halt":
            c.inst.raise_fault(FaultCode.OPERATOR, "test", "the story halts", tick=tick)
        elif what == "reset":
            c.inst.clear_fault()
        elif what == "disable":
            rs["cmd_faults"][k] = stamp
            rs["power_cmd"][k] = PowerCmd.DISABLE
        elif what == "calibrate":
            rs["cmd_faults"][k] = stamp
            rs["calib_cmd"][k] = 1
        elif what == "gang":
            c.gang = not c.gang
        elif what == "params":
            c.client.set_params(k, 3, {"kp": value}, wait=False)
        elif what in ("off", "on"):
            c.client.enable_servo(k, 2, what == "on")
        elif what == "nan":
            pid = lv.blocks[lv.registry.index("pid")]
            pid["kp"][span.start + 3] = value
        self.events[what] = self.events.get(what, 0) + 1


def test_the_compiled_tick_equals_the_reference(twins: tuple[Copy, Copy]) -> None:
    compiled, reference = twins
    story = Story(2626)
    step = compiled.sio._step
    handed: list[int] = []

    def counted(fn: Callable[[], int]) -> Callable[[], int]:
        def call() -> int:
            handed.append(fn())
            return handed[-1]

        return call

    compiled.sio._step = counted(step)
    served: list[int] = []
    for sv in compiled.svs:
        kernel = sv._serve_kernel  # type: ignore[attr-defined]

        def serve(kernel: Callable[[], int] = kernel) -> int:
            served.append(kernel())
            return served[-1]

        sv._serve_kernel = serve  # type: ignore[attr-defined]
    halts, count = set(), 0
    for tick in range(TICKS):
        for what, k, value in story.plan(tick):
            for c in (compiled, reference):
                story.apply(c, tick, what, k, value)
        compiled.step(tick)
        reference.step(tick)
        got, want = compiled.state(), reference.state()
        assert [k for k, _ in got] == [k for k, _ in want]
        for (key, a), (_, b) in zip(got, want, strict=True):
            assert a == b, f"tick {tick}: {key} differs (story so far {story.events})"
        if int(compiled.inst.fault["count"]) != count:
            count = int(compiled.inst.fault["count"])
            halts.add(FaultCode(int(compiled.inst.fault["code"])))
    # every event the passes hand back happened, and every halt of the story
    kinds = {e: handed.count(e) for e in (SIO_CAPTURE, SIO_SENSOR, SIO_ROBOTS, SIO_CHECK)}
    kinds[SIO_CURRENT] = handed.count(SIO_CURRENT)
    assert all(kinds.values()), kinds
    # (a unit leaves a slot it claimed to Python, SV_LEFT, only when a client's operation
    # comes between its two looks at the slot: a race one process cannot stage; what it then
    # runs is the single slots' path, SV_SLOT)
    sv_kinds = {e: served.count(e) for e in (SV_ARM, SV_FAULT, SV_SLOT)}
    assert all(sv_kinds.values()), sv_kinds
    want = {FaultCode.SERVO, FaultCode.RANGE, FaultCode.RUNAWAY, FaultCode.CURRENT, FaultCode.FORCE}
    assert want | {FaultCode.OPERATOR} <= halts, (halts, story.events)
