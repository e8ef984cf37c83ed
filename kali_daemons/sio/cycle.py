"""Servo I/O's cycle logic (thesis 3.3.3, 3.3.5, figure 3.2), ``SioCycle``: the servo level's
bottleneck, once per servo tick, as a plain class its process (``daemon.ServoIO``), the
lockstep executive and a test drive alike.  (a) Read every joint through the hardware
(``hardware.Hardware``) and estimate velocities; (b) take each robot's demand from its
TG → SIO FIFO (or hold), check range and tracking error, take the feed-forward
(``feedforward.py``) and feed the servo slots, then post the SVs; (c) sleep until the servos
are done, acknowledge for the SVs it can vouch for (``gang.py``), add the feed-forward, write
the torques, and drive power and the keep-alive.

The common tick is one compiled call (``kali_sio_tick``); what it hands back (an index pulse,
a sensor's trip, a robot powering or calibrating, a fault) SIO does in Python, and
``_tick_reference`` is the whole tick in Python, the call's test reference.  Range, runaway,
current, amplifiers and servos not done each halt the system naming the robot, joint, value
and limit (DESIGN 7).  More: docs/internals/sio-viewer-core.md.

Long on purpose: SIO's one cycle; its tick is a compiled call (``kali_sio_tick``), and what
is here is that tick's binding and the steps around it (power, calibration, checks, faults, the
wait for the servos) on one state.
"""

from __future__ import annotations

import ctypes
import math
from collections.abc import Callable

import numpy as np
import posix_ipc

from ..core import layout, rt
from ..core.errors import DaemonError
from ..core.kernels import (
    NO_FAULT,
    SIO_CAPTURE,
    SIO_CHECK,
    SIO_CURRENT,
    SIO_DONE,
    SIO_FED,
    SIO_ROBOTS,
    SIO_SENSOR,
    SIO_WAIT,
    ST_BACK,
    ST_READ,
    WRENCH_OK,
    Kernel,
    copies,
)
from ..core.layout import FaultCode, FfMode, GuardState, PowerCmd, PowerState, SlotReset
from ..core.spinlock import pid_alive
from ..hardware import Hardware
from ..runtime.config import DEFAULT_SAFE_RAD, ms_to_ns, period_ticks
from ..runtime.flightrec import FlightRecorder
from ..runtime.instance import Instance
from ..servo.level import ServoLevel
from .calibration import ACTIVE, Absolute, Calibration
from .feedforward import RobotFeedforward
from .gang import GangAcknowledger
from .wrench import ArmSensor, sensors_of

POWER_ON_TIMEOUT_MS = 300.0  # amplifiers and brakes must report on within this
VELOCITY_FILTER_HZ = 25.0  # low-pass on encoder velocities, as the PID's (figure 3.4)
STAMP = 0xFFFFFFFF  # a command's ``cmd_faults`` stamp holds the fault count's low 32 bits


class SioCycle:
    """SIO's cycle over the instance's records: encoders in, servos fed, torques out, every
    safety check of the servo level.  Built outside the cycle (the servo level laid out, the
    boards attached, the driver and the kernels bound); ``cycle`` is the tick.
    ``acknowledge`` is the process's acknowledgement of a tick (``Daemon.acknowledge``), which
    the Python reference calls where the compiled tick acknowledges early."""

    # ------------------------------------------------------------------ set-up

    def __init__(
        self,
        inst: Instance,
        name: str,
        slot: int,
        acknowledge: Callable[[int], None],
    ) -> None:
        """Lay out the servo level, attach to the boards and build the driver."""
        self.inst, self.name, self.slot = inst, name, slot
        self.acknowledge = acknowledge
        cfg = inst.config
        kinds = cfg.hardware_kinds
        if len(kinds) != 1:
            raise DaemonError(
                f"{self.name}: a cell of {' and '.join(kinds)} hardware; SIO drives one kind "
                "of hardware per cell"
            )
        lv = self.level = ServoLevel(inst, create=True)
        ctrl = lv.ctrl
        first = not int(ctrl["ready"])
        if first:
            lv.initialise()
        nr, n = lv.n_robots, lv.n
        rs = lv.robots
        js = lv.joints
        self._driver_state = (js["acc"], js["prev"], js["offset"])
        self.fifos = [lv.fifo(k) for k in range(nr)]
        self.ff_records = inst.arena.record(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, nr)
        if first:
            self.ff_records["key"] = layout.FF_NO_KEY
            for k, robot in enumerate(cfg.robots):
                self.ff_records["mode"][k] = FfMode[robot.ff.upper()]
        period_s = lv.servo_period_s
        self.rate = 1.0 / period_s
        period_ns = ms_to_ns(cfg.clock.servo_period_ms)

        def servo_ticks(ms: float) -> int:  # at least ``ms`` of servo ticks, at least one
            return max(1, -(-ms_to_ns(ms) // period_ns))

        self.power_timeout_ticks = servo_ticks(POWER_ON_TIMEOUT_MS)
        self.hw: Hardware = inst.hardware_kind(kinds[0]).drive(
            inst.arena, cfg, servo_ticks, lambda name: inst.slot_semaphore(inst.slot_of(name))
        )
        self.driver = self.hw.driver  # conversions and calibration offsets (thesis 3.5)
        if not first:
            self.driver.load(*self._driver_state)
        self._clock = inst.clock  # a record: its fields are read afresh each time
        self.watchdog_ms = cfg.plant.watchdog_ms
        self.base_ms = cfg.clock.base_tick_ms
        self.current_ticks = np.array(
            [servo_ticks(r.current_fault_ms) for r in cfg.robots for _ in range(r.n_joints)],
            dtype=np.int64,
        )
        sv_names = [p.name for p in cfg.processes if p.kind == "sv"]
        ctrl["sv_count"] = len(sv_names)
        self.feeds = [inst.feed_semaphore(k) for k in range(len(sv_names))]
        # the lockstep executive hosting SIO and the SVs in one process sets this: called
        # with the tick where the feeds would be posted, it runs every SV's share at once
        self.serve: Callable[[int], None] | None = None
        self.done_sem = inst.done_semaphore()
        # How long the servos may take: inside the clock's own limit for SIO, so a late servo
        # is named here rather than SIO by the clock.  Waited in slices of a servo period,
        # after each of which an SV that died holding a slot halts at once (PROCESS_DIED).
        if inst.lockstep:
            self.wait_s = 0.8 * cfg.clock.lockstep_ack_timeout_s
        else:
            tolerance_s = cfg.clock.serious_miss_tolerance_ms / 1000.0
            self.wait_s = max(period_s, tolerance_s - 2 * period_s)
        self.slice_s = period_s
        self.slice_ns, self.wait_ns = int(period_s * 1e9), int(self.wait_s * 1e9)
        self.sv_slots = [inst.slot_of(name) for name in sv_names]
        ctrl["sv_fed_tick"] = -1
        # lockstep has no deadlines, and its clock counts one acknowledgement post per
        # process: there every SV acknowledges for itself
        sio_cpu = cfg.process("sio").cpu
        self._gang = GangAcknowledger(
            ctrl["sv_fed_tick"],
            inst.procs["signal_tick"],
            inst.procs["ack_tick"],
            inst.procs["vouched_tick"],
            [] if inst.lockstep else self.sv_slots,
            []
            if inst.lockstep
            else [sio_cpu is not None and cfg.process(sv).cpu == sio_cpu for sv in sv_names],
        )
        # private, preallocated arrays: flat over all joints (robot k joint j at base[k] + j)
        self.q = np.zeros(n)
        self.q_prev = np.zeros(n)
        self.qd = np.zeros(n)
        a = period_s * 2.0 * math.pi * VELOCITY_FILTER_HZ
        self.vel_a, self.vel_b = a, 1.0 / (1.0 + a)
        self.demand = np.zeros(n)
        self.demand_vel = np.zeros(n)  # the demand's velocity and acceleration (feedforward.py)
        self.demand_acc = np.zeros(n)
        # a fed slot's busy value: 0, or ARM_FREE / ARM_HELD for a robot fed whole (servo/sv/arm.py)
        self.mark = np.zeros(n, dtype=np.uint32)
        self._whole = np.zeros(nr, dtype=np.uint8)  # fed whole last tick (_arm_robot)
        self._arm_algo = rs["arm_algo"]
        self._arm_op = rs["arm_op"]
        self._shadows = rs["shadows"]
        self._spans = [lv.map.span(k) for k in range(nr)]
        self.torque = np.zeros(n)
        self.servo_torque = np.zeros(n)
        self.current = np.zeros(n)
        self.clamped = np.zeros(n, dtype=bool)
        self.fed_mask = np.zeros(n, dtype=bool)
        self.over = np.zeros(n, dtype=np.int64)
        # the checks' arrays: every joint at once (_checks)
        self._range_check = js["range_check"]  # written by clients: nonzero = checked
        self._safe = js["safe"]  # written by clients (ServoClient.set_safe)
        ok = np.asarray(self._safe, dtype=np.float64)  # SIO's own copy, only valid limits
        self._safe_ok = np.where((ok > 0) & (ok <= math.pi), ok, DEFAULT_SAFE_RAD)
        self.ff = np.zeros(n)
        self._slot_demand = lv.slots["demand"]
        self._slot_position = lv.slots["position"]
        self._slot_velocity = lv.slots["velocity"]
        self._slot_torque = lv.slots["torque"]
        self._slot_busy = lv.slots["busy"]
        self._q_min = self.driver.q_min
        self._q_max = self.driver.q_max
        self._fault_active = inst.fault["active"]
        self._fault_count = inst.fault["count"]
        self._pub = [
            (js[f], src)
            for f, src in (
                ("q", self.q),
                ("qd", self.qd),
                ("demand", self.demand),
                ("servo_torque", self.servo_torque),
                ("ff_torque", self.ff),
                ("torque", self.torque),
                ("current", self.current),
            )
        ]
        self._hist = ctrl["latency_hist"]
        self._ctrl_tick, self._ctrl_fed, self._ctrl_done = ctrl["tick"], ctrl["fed"], ctrl["done"]
        self._lat_last, self._lat_max = ctrl["latency_last_ns"], ctrl["latency_max_ns"]
        self._robots_tick, self._robots_faults = rs["tick"], rs["faults_seen"]
        self._r = [_RobotViews(self, k) for k in range(nr)]
        self._capture = np.zeros(nr, dtype=np.uint8)  # index capture on (calibration.py)
        self._calib: list[Calibration | Absolute] = [
            Absolute(self, k) if r.type.absolute_encoders else Calibration(self, k)
            for k, r in enumerate(cfg.robots)
        ]
        ffc = cfg.feedforward
        self._ff_reference = [  # their kernels run in the cycle (_bind_kernels: self._ff)
            RobotFeedforward(
                self.ff_records,
                k,
                self.fifos[k],
                self.ff[lv.map.span(k)],
                heartbeat_limit=period_ticks(ffc.stale_ms, cfg.clock.base_tick_ms, round_up=True),
                missing_limit=servo_ticks(ffc.stale_ms),
                step=cfg.clock.servo_period_ms / ffc.ramp_ms,
                vel=self.demand_vel[lv.map.span(k)],
                acc=self.demand_acc[lv.map.span(k)],
            )
            for k in range(nr)
        ]
        # the wrist force/torque sensors, read in Newtons every tick (wrench.py)
        self.ft_records = inst.arena.record(layout.KEY_FT, layout.FT_STATE, nr)
        self._sensors = [
            ArmSensor(
                cfg,
                k,
                self.hw.gauges(k) if gauged else None,
                self.ft_records[k : k + 1].reshape(()),
                self.q[lv.map.span(k)],
                period_s,
                None if gauged else self.hw.wrench(k),
                self.hw.gauge_cycles(k) if gauged else None,
            )
            for k in sensors_of(cfg)
            for gauged in [cfg.robots[k].ft.sheet.source == "gauges"]  # type: ignore[union-attr]
        ]
        self._guard_state = self.ft_records["guard_state"]
        self._guard_q = [
            self.ft_records["guard_q"][k, :n] for k, n in enumerate(lv.map.counts)
        ]  # views, bound once
        if first:
            self.hw.start()
        for sensor in self._sensors:
            sensor.start()
        for k in range(nr):
            if int(rs[k]["calib_state"]) in ACTIVE:  # a restarted SIO does not resume one
                self._calib[k].fail("SIO restarted during calibration")
        self.driver.angles(self.q)
        self.q_prev[:] = self.q
        for k in range(nr):
            self.fifos[k].reset(self.q[lv.map.span(k)])
        self.flight = FlightRecorder(inst, n, create=True, slot=self.slot)  # DESIGN 7
        self.flight.bind(
            self.q,
            self.qd,
            self.demand,
            self.demand_vel,
            self.servo_torque,
            self.ff,
            self.torque,
            self.current,
            lv.slots["shadow_torque"],  # the SVs' (kali_daemons.servo.shadow), done by the record
            self.ft_records["tool"],
        )
        self._bind_kernels()
        ctrl["ready"] = 1

    def _bind_kernels(self) -> None:
        """The tick's arithmetic as compiled kernels (``kali_daemons.core.kernels``), bound to the
        arrays above; the library is built here if missing (~0.2 s), never in the cycle."""
        lv, n = self.level, self.level.n
        js = lv.joints
        self.driver.bind(self.q, self.torque, self.current, self.clamped)
        self._velocity = Kernel(
            "kali_velocity",
            n=n,
            q=self.q,
            q_prev=self.q_prev,
            qd=self.qd,
            gain=self.rate * self.vel_a,
            b=self.vel_b,
        )
        self._check = Kernel(
            "kali_checks",
            n=n,
            n_robots=lv.n_robots,
            bounds=np.array([*lv.map.base, n], dtype=np.int64),
            q=self.q,
            demand=self.demand,
            q_min=self._q_min,
            q_max=self._q_max,
            range_check=self._range_check,
            fed=self.fed_mask,
            safe=self._safe,
            safe_ok=self._safe_ok,
            pi=math.pi,
        )
        self._feed = Kernel(
            "kali_feed",
            (self._ctrl_fed, self._ctrl_done),
            n=n,
            demand=self.demand,
            q=self.q,
            qd=self.qd,
            fed=self.fed_mask,
            slot_demand=self._slot_demand,
            slot_position=self._slot_position,
            slot_velocity=self._slot_velocity,
            slot_busy=self._slot_busy,
            not_fed=layout.SLOT_NOT_FED,
            ctrl_fed=self._ctrl_fed.ctypes.data,
            ctrl_done=self._ctrl_done.ctypes.data,
            demand_vel=self.demand_vel,
            demand_acc=self.demand_acc,
            ff=self.ff,
            slot_demand_vel=lv.slots["demand_vel"],
            slot_demand_acc=lv.slots["demand_acc"],
            slot_ff=lv.slots["ff"],
            mark=self.mark,
        )
        self._torques = Kernel(
            "kali_torques",
            n=n,
            slot_torque=self._slot_torque,
            fed=self.fed_mask,
            servo_torque=self.servo_torque,
            ff=self.ff,
            torque=self.torque,
        )
        self._current = Kernel(
            "kali_current_check",
            n=n,
            torque=self.torque,
            fed=self.fed_mask,
            clamped=self.clamped,
            over=self.over,
            current_ticks=self.current_ticks,
        )
        self._ff = [ff.compiled() for ff in self._ff_reference]  # kali_feedforward
        # each robot's demand from its FIFO (kali_fifo_pop): _robot's common path
        self._pops = [f.compiled_pop(r.demand) for f, r in zip(self.fifos, self._r, strict=True)]
        # every robot's step where nothing but its motion happens to it: the demand popped,
        # its joints fed, the fed mask cleared first; any other robot is _robot's
        rs = lv.robots
        amps, amps_bit = self.hw.amps_register()
        pops = (ctypes.c_void_p * lv.n_robots)(*(ctypes.addressof(p.args) for p in self._pops))
        self._robots = Kernel(
            "kali_sio_robots",
            (pops, self._pops),
            n=n,
            n_robots=lv.n_robots,
            bounds=np.array([*lv.map.base, n], dtype=np.int64),
            fed=self.fed_mask,
            **{f: rs[f] for f in ("pots_read", "power", "power_cmd", "calib_cmd", "calib_state")},
            guided=rs["guided"],
            guard_state=self._guard_state,
            amps=amps,
            amps_bit=amps_bit,
            on=PowerState.ON,
            tripped=GuardState.TRIPPED,
            calib_active=sum(1 << state for state in ACTIVE),
            pops=ctypes.addressof(pops),
        )
        self._robots_args = self._robots.args
        d = self.driver  # the joint records: SIO's arrays, then the driver's state (store)
        self._publish = copies(
            [(src, dst) for dst, src in self._pub]
            + [(d.acc, js["acc"]), (d.prev, js["prev"]), (d.offset, js["offset"])]
        )
        self._bind_tick()

    def _bind_tick(self) -> None:
        """SIO's tick as one compiled call over the kernels above (``kali_sio_tick``: the passes
        ``kali_sio_front`` and ``kali_sio_back`` with the wait between them;
        ``_tick_reference`` is what it does), the boards' kernels called through their
        addresses.  Their block also holds what SIO keeps between ticks: the
        fault count seen and the tick of the last retrigger."""
        lv, n, nr = self.level, self.level.n, self.level.n_robots
        rs, procs, ctrl = lv.robots, self.inst.procs, lv.ctrl
        read, dac, control = self.hw.tick_kernels(
            rs["power"], rs["enable_ticks"], self._capture, self._fault_active
        )
        sensors = (ctypes.c_void_p * max(1, len(self._sensors)))(
            *(ctypes.addressof(s.args) for s in self._sensors)
        )
        guard_state = (ctypes.c_void_p * max(1, len(self._sensors)))(
            *(s.state["guard_state"].ctypes.data for s in self._sensors)
        )
        guard_n = (ctypes.c_void_p * max(1, len(self._sensors)))(
            *(s.state["guard_n"].ctypes.data for s in self._sensors)
        )
        ffs = (ctypes.c_void_p * nr)(*(ctypes.addressof(f.args) for f in self._ff))
        before = getattr(self, "_tick_args", None)  # bound again (a test): carry on from it
        self._close_semaphore_addresses()
        self._feed_addresses = [rt.semaphore_address(sem) for sem in self.feeds]
        self._done_address = rt.semaphore_address(self.done_sem)
        feeds = (ctypes.c_void_p * max(1, len(self.feeds)))(*self._feed_addresses)
        gang = np.array(self._gang.members(), dtype=np.int64).reshape(-1, 3)
        gang_sv, gang_slot, gang_lag = (np.ascontiguousarray(gang[:, c]) for c in range(3))
        (fn_read, a_read), (fn_dac, a_dac), (fn_ctl, a_ctl) = (
            k.address for k in (read, dac, control)
        )
        keep: tuple[object, ...] = (read, dac, control, sensors, guard_state, guard_n, ffs, feeds)
        keep += (gang_sv, gang_slot, gang_lag, self._sensors, self._ff, self._velocity)
        keep += (self._robots, self._check, self._feed, self._torques, self._current)
        keep += (self._publish, self.flight)
        self._tick_kernel = Kernel(
            "kali_sio_tick",
            keep,
            n=n,
            n_robots=nr,
            read_fn=fn_read,
            dac_fn=fn_dac,
            control_fn=fn_ctl,
            read_args=a_read,
            dac_args=a_dac,
            control_args=a_ctl,
            capture=self._capture.ctypes.data,
            velocity=ctypes.addressof(self._velocity.args),
            sensors=ctypes.addressof(sensors),
            guard_state=ctypes.addressof(guard_state),
            guard_n=ctypes.addressof(guard_n),
            n_sensors=len(self._sensors),
            guard_armed=GuardState.ARMED,
            robots=ctypes.addressof(self._robots.args),
            checks=ctypes.addressof(self._check.args),
            ff=ctypes.addressof(ffs),
            feed=ctypes.addressof(self._feed.args),
            torques=ctypes.addressof(self._torques.args),
            current=ctypes.addressof(self._current.args),
            publish=ctypes.addressof(self._publish.args),
            flight=ctypes.addressof(self.flight.kernel_args),
            fault_active=self._fault_active.ctypes.data,
            fault_count=self._fault_count.ctypes.data,
            arm_algo=self._arm_algo,
            arm_op=self._arm_op,
            shadows=self._shadows,
            bounds=np.array([*lv.map.base, n], dtype=np.int64),
            whole=self._whole.ctypes.data,
            mark=self.mark,
            ff_out=self.ff,
            arm_none=layout.ARM_NONE,
            arm_free=layout.ARM_FREE,
            arm_held=layout.ARM_HELD,
            feeds=ctypes.addressof(feeds),
            n_feeds=len(self.feeds),
            done_sem=self._done_address,
            ctrl_done=self._ctrl_done.ctypes.data,
            slice_ns=self.slice_ns,
            ctrl_tick=self._ctrl_tick.ctypes.data,
            fed_ns=ctrl["fed_ns"].ctypes.data,
            served_max=ctrl["sv_served_max_ns"].ctypes.data,
            robots_tick=self._robots_tick,
            robots_faults=self._robots_faults,
            sv_fed_tick=ctrl["sv_fed_tick"].ctypes.data,
            signal_tick=procs["signal_tick"],
            ack_tick=procs["ack_tick"],
            vouched_tick=procs["vouched_tick"],
            gang_sv=gang_sv.ctypes.data,
            gang_slot=gang_slot.ctypes.data,
            gang_lag=gang_lag.ctypes.data,
            n_gang=len(gang),
            clock_tick=self._clock["tick"].ctypes.data,
            lat_last=self._lat_last.ctypes.data,
            lat_max=self._lat_max.ctypes.data,
            hist=self._hist.ctypes.data,
            linear_us=layout.HIST_LINEAR_US,
            log_bins=layout.HIST_LOG_BINS,
            stage=ST_READ,
            faults_seen=int(self._fault_count) if before is None else before.faults_seen,
            retrigger_tick=-1 if before is None else before.retrigger_tick,
        )
        self._tick_args = self._tick_kernel.args
        self._step = self._tick_kernel

    @property
    def retrigger_tick(self) -> int:
        """The clock's tick at SIO's last retrigger (falling edge, C.4), -1 before the first:
        the clock's, not the signalled one, since a late cycle writes the boards ticks after
        its signal."""
        return int(self._tick_args.retrigger_tick)

    def activate(self, ack_early: np.ndarray | None) -> None:
        """The compiled tick acknowledges early where ``acknowledge`` does (real time: the
        process's acknowledgement word, ``Daemon._ack_early``; None in lockstep)."""
        self._tick_args.ack_early = ack_early.ctypes.data if ack_early is not None else None

    def close(self) -> None:
        """Outside the cycle: release what the constructor took."""
        self._close_semaphore_addresses()
        self.hw.close()

    def _close_semaphore_addresses(self) -> None:
        """Give back the compiled tick's opens of the feed and done semaphores."""
        for address in (*getattr(self, "_feed_addresses", ()), getattr(self, "_done_address", 0)):
            rt.close_semaphore_address(address)
        self._feed_addresses, self._done_address = [], 0

    # ------------------------------------------------------------------ the tick

    def cycle(self, tick: int) -> None:
        """Inside the cycle: (a) sensors, (b) checks and feed, (c) torques out, as one compiled
        call (``kali_sio_tick``: the front pass up to the feeds posted, the sleep until the
        servos are done, the back pass; ``_tick_reference`` is what it does).  What it hands
        back, SIO does here in Python (``_event``) and the call goes on."""
        a = self._tick_args
        a.tick = tick
        a.stage = ST_READ  # whatever a tick that raised out of its Python left
        a.post = self.serve is None
        while (event := self._step()) != SIO_DONE:
            if event == SIO_FED:  # not posted: the lockstep executive runs the SVs here
                self.serve(tick)  # type: ignore[misc]
            elif event == SIO_WAIT:  # not done within a period: wait on in slices, judge
                a.ok = ok = self._wait_done(tick, a.fed, timed_out=True)
                if not ok:
                    self.fed_mask[:] = False
                a.stage = ST_BACK
            else:
                self._event(event, tick)

    def _event(self, event: int, tick: int) -> None:
        """What the common tick does not do, handed back by a compiled pass (outside the
        common path): an index pulse to catch while calibrating, a sensor's halt or reached
        guard, a robot ``kali_sio_robots`` left, a
        joint beyond its range or runaway, a current beyond its limit."""
        a = self._tick_args
        if event == SIO_CAPTURE:
            self._catch_index()
        elif event == SIO_SENSOR:
            a.faulted = self._sensor_event(self._sensors[a.at - 1], a.result, tick, bool(a.faulted))
        elif event == SIO_ROBOTS:
            for k in range(self.level.n_robots):
                if a.result >> k & 1:
                    self._robot(k, tick, bool(a.faulted))
        elif event == SIO_CHECK:
            self._check_fault(tick, a.result)
            a.faulted = True
            self.fed_mask[:] = False
        elif event == SIO_CURRENT:
            self._current_fault(tick, a.result)
        else:
            raise DaemonError(f"{self.name}: the compiled tick returned event {event}")

    def _catch_index(self) -> None:
        """Calibrating: a counter reset by its index pulse, caught right after the read."""
        for calib in self._calib:
            if calib.capture:
                calib.catch_index()

    def _sensor_event(self, sensor: ArmSensor, found: int, tick: int, faulted: bool) -> bool:
        """A wrist sensor's result this tick (``kali_wrench_tick``'s): a halt beyond its
        limits, else its guard reached; whether the tick is faulted now."""
        if found != WRENCH_OK and not faulted:
            return self._halt(FaultCode.FORCE, tick, sensor.message(found))
        if sensor.guard_reached():  # a guarded move touched: its arms hold from now
            self._trip_guards(sensor, tick)
        return faulted

    def _tick_reference(self, tick: int) -> None:
        """SIO's tick in Python, step for step what ``kali_sio_tick`` does: its test's
        reference."""
        lv = self.level
        a = self._tick_args
        t_read = rt.monotonic_ns()
        c_read = rt.thread_time_ns()
        faulted = bool(self._fault_active)
        count = int(self._fault_count)
        if count != a.faults_seen:  # a halt since the last tick, maybe already cleared:
            a.faults_seen = count  # power stays off until the operator enables it
            faulted = True
        # (a) encoders → radians, velocity by backward difference
        self.hw.read(self.q)
        if self._capture.any():
            self._catch_index()
        self._velocity()  # qd = (a·rate·(q - q_prev) + qd_prev) / (1 + a); q_prev = q
        for sensor in self._sensors:  # gauge codes → Newtons (3.3.3); FORCE limits
            found = sensor.tick(tick)
            if found != WRENCH_OK or sensor.guard_reached():
                faulted = self._sensor_event(sensor, found, tick, faulted)
        # (b) per robot: power switch, demand, pots (the fed mask cleared first; a robot where
        # nothing but its motion happens is compiled, any other is _robot's); then the checks
        self._robots_args.faulted = faulted
        others = self._robots()
        if others:
            for k in range(lv.n_robots):
                if others >> k & 1:
                    self._robot(k, tick, faulted)
        if not faulted and self._checks(tick):
            faulted = True
            self.fed_mask[:] = False
        # this tick's feed-forward and the demand's velocity and acceleration (thesis 3.3.6),
        # then feed the slots that servo this tick: demand, position, velocity, the count
        # fed and done = 0, then busy cleared where fed (the SVs may claim now)
        for k, ff in enumerate(self._ff):
            ff.arm = self._arm_robot(k)
            ff.step(tick)
        fed = self._feed()
        t_fed = rt.monotonic_ns()
        lv.ctrl["fed_ns"] = t_fed  # when: the polling SVs learn from it (servo/sv/daemon.py)
        self._ctrl_tick[...] = tick  # last: an SV seeing this tick sees its slots published
        if self.serve is None:
            for sem in self.feeds:
                sem.release()
        else:  # the lockstep executive: the SVs run here, in this process (one call)
            self.serve(tick)
        # (c) wait for the servos at once (the SV on this CPU takes its feed now, not after
        # SIO's next work: see gang.py), then feed-forward and torques out
        if fed and not self._wait_done(tick, fed):
            self.fed_mask[:] = False
        else:  # every servo done: the SVs' acknowledgements before SIO's output (gang.py)
            self._gang.acknowledge(tick)
        t_done = rt.monotonic_ns()
        served = lv.ctrl["sv_served_max_ns"][: len(self.feeds)]  # each SV takes its own
        np.maximum(served, t_done - t_fed, out=served)
        for k in range(lv.n_robots):  # a robot-level servo's torque is the whole torque
            if int(self._arm_algo[k]) != layout.ARM_NONE:
                self.ff[self._spans[k]] = 0.0
        self._torques()  # servo and feed-forward torques of the fed joints, and their sum
        self.hw.write(self.torque, self.current, self.clamped)
        i = self._current()  # a current beyond its limit too long halts; unfed torques 0
        if i >= 0:
            self._current_fault(tick, i)
        t_out = rt.monotonic_ns()
        c_out = rt.thread_time_ns()
        halted = bool(self._fault_active)
        for k in range(lv.n_robots):
            r = self._r[k]
            self.hw.control(k, int(r.power), int(r.enable_ticks), self._calib[k].capture, halted)
        if self.hw.end_tick():
            a.retrigger_tick = int(self._clock["tick"])
        self.acknowledge(tick)  # the tick's I/O is done: what follows is bookkeeping
        self._publish()  # SIO's arrays and the driver's state into the joint records
        self._robots_tick[...] = tick
        self._robots_faults[...] = a.faults_seen & 0xFFFFFFFF
        late = t_out - t_read
        self._lat_last[...] = late
        if late > self._lat_max:
            self._lat_max[...] = late
        self._hist[layout.lateness_bin(late)] += 1
        self.flight.record(tick, t_read, late, t_done - t_fed, c_out - c_read)  # DESIGN 7

    def _trip_guards(self, sensor: ArmSensor, tick: int) -> None:
        """``sensor``'s guard is reached: trip it, and every other guard of the same request
        (a motion system's arms hold together, so none drags the object on).  Outside the
        common path: once per guarded move."""
        seq = int(sensor.state["guard_seq"])
        sensor.trip(tick)
        for other in self._sensors:
            if other is not sensor and int(other.state["guard_seq"]) == seq:
                other.trip(tick)

    def _arm_robot(self, k: int) -> bool:
        """Whether robot ``k`` is fed whole this tick (a robot-level servo runs it, a
        robot-level mailbox operation waits, or a shadow trial runs: ``kali_daemons.servo.shadow``),
        its slots' marks set to match; True if it runs a robot-level servo."""
        arm = int(self._arm_algo[k]) != layout.ARM_NONE
        whole = arm or int(self._arm_op[k]) != 0 or int(self._shadows[k]) != 0
        if whole != self._whole[k]:
            self._whole[k] = whole
            span = self._spans[k]
            self.mark[span] = layout.ARM_HELD if whole else 0
            if whole:
                self.mark[span.start] = layout.ARM_FREE
        return arm

    def _robot(self, k: int, tick: int, faulted: bool) -> None:
        """Power switch, pots and this tick's demand of robot ``k``: every case of it, the
        reference of ``kali_sio_robots``, which does its last branch (the pop) for a robot in
        the common case and leaves every other robot to this."""
        r = self._r[k]
        q, demand = r.q, r.demand
        if not int(r.pots_read):
            self._read_pots(k)
            np.copyto(demand, q)
            return
        state = int(r.power)
        cmd = int(r.power_cmd)
        word = int(r.calib_cmd)
        # a command stamped before the latest halt, or written during one, is void: a halt
        # forgets every pending command (LinuxCNC), so nothing powers on by itself at reset
        void = bool(self._fault_active) or int(r.cmd_faults) != int(self._fault_count) & STAMP
        if cmd:
            r.power_cmd[...] = PowerCmd.NONE
            if cmd not in (PowerCmd.ENABLE, PowerCmd.DISABLE):  # a client's garbage (DESIGN 7)
                r.message[...] = f"power command word {cmd} ignored (1 on, 2 off)".encode()
                cmd = PowerCmd.NONE
            elif void:
                r.message[...] = b"power command dropped: a halt came after it (enable again)"
                cmd = PowerCmd.NONE
        calib = self._calib[k]
        if word:
            r.calib_cmd[...] = 0
            if word != 1:
                r.message[...] = f"calibration word {word} ignored (1 = calibrate)".encode()
            elif void:
                r.message[...] = b"calibration command dropped: a halt came after it"
            elif state == PowerState.ON and not faulted and int(r.calib_state) not in ACTIVE:
                calib.begin()
            elif int(r.calib_state) not in ACTIVE:
                calib.fail("the robot is not powered (kalictl enable first)")
        if (faulted or cmd == PowerCmd.DISABLE) and state != PowerState.OFF:
            r.power[...] = state = PowerState.OFF
            r.message[...] = b"power off" + (b" (halted)" if faulted else b"")
        if cmd == PowerCmd.ENABLE and state == PowerState.OFF and not int(self._fault_active):
            r.power[...] = state = PowerState.ENABLING
            r.enable_ticks[...] = 0
            r.message[...] = b"enabling"
            self.fifos[k].reset(q)
            r.slot_reset[:] = SlotReset.REST  # every servo takes over at rest at its first run
        hw = self.hw
        if state == PowerState.ENABLING:
            n = int(r.enable_ticks) + 1
            r.enable_ticks[...] = n
            if hw.powered(k):
                r.power[...] = state = PowerState.ON
                r.message[...] = b"on"
            elif n > self.power_timeout_ticks:
                r.power[...] = state = PowerState.OFF
                r.message[...] = (
                    f"power did not come on within {POWER_ON_TIMEOUT_MS:g} ms ({hw.power_text(k)})"
                ).encode()
        elif state == PowerState.ON and not hw.amps_on(k):
            r.power[...] = PowerState.OFF
            self.inst.raise_fault(
                FaultCode.POWER,
                self.name,
                f"robot '{self.level.names[k]}': amplifiers went off while servoing "
                f"({hw.power_text(k)}); {self._since()}",
            )
            return
        if state == PowerState.OFF:
            if int(r.calib_state) in ACTIVE:
                calib.fail("power went off")
            self.fifos[k].reset(q)  # hold where the arm is: no jump when power comes on
            np.copyto(demand, q)
            return
        if state == PowerState.ON and int(r.calib_state) in ACTIVE:
            calib.step()  # calibration drives the demand; motion requests wait
            self.fifos[k].reset(demand)
        elif int(self._guard_state[k]) == GuardState.TRIPPED:
            hold = self._guard_q[k]  # where the arm was when it touched, until the TG ends
            self.fifos[k].reset(hold)  # the motion: set-points it pushed meanwhile dropped
            np.copyto(demand, hold)
        elif int(r.guided):  # guided by hand: the demand follows the arm (admittance.py),
            self.fifos[k].reset(q)  # so another servo selected next holds it where it is
            np.copyto(demand, q)
        else:
            self._pops[k]()  # this tick's demand (channels.InterpolatingFifo.pop_into)
        if hw.amps_on(k):
            r.fed[:] = True

    def _read_pots(self, k: int) -> None:
        """One step of reading robot ``k``'s absolute joint sensors at start (its pots, or
        absolute encoders: ``Hardware.absolute_angles``); then the angles from them."""
        said = self.hw.absolute_angles(k)
        if said is None:
            return
        r = self._r[k]
        self.driver.angles(self.q)
        self.q_prev[self.level.map.span(k)] = r.q
        self.fifos[k].reset(r.q)
        r.pots_read[...] = 1
        if self.inst.config.robots[k].type.absolute_encoders:
            r.calibrated[...] = 1  # exact from power-up
        r.message[...] = said.encode()

    def _checks(self, tick: int) -> bool:
        """Joint range and runaway on powered joints; True when it halted.

        Every joint at once, in one kernel (``kali_checks``, docs/internals/kernels.md);
        only a fault builds a message, in ``_check_fault``.  The client-written limits count
        only in (0, π] (NaN fails both): a garbage one leaves the last valid limit in force
        (DESIGN 7)."""
        found = self._check()
        if found == NO_FAULT:
            return False
        return self._check_fault(tick, found)

    def _check_fault(self, tick: int, found: int) -> bool:
        """Halt for the first robot at fault, its range before its runaway: ``found`` is
        ``kali_checks``'s joint i (range) or n + i (runaway) (outside the common path: the
        tick halts)."""
        lv = self.level
        q = self.q
        i = found % lv.n
        if found < lv.n:
            above = q[i] > self._q_max[i]
            limit = self._q_max[i] if above else self._q_min[i]
            return self._halt(
                FaultCode.RANGE,
                tick,
                f"{lv.map.label(i)} at {math.degrees(q[i]):.2f}° "
                f"is beyond its limit {math.degrees(limit):.2f}°",
            )
        return self._halt(
            FaultCode.RUNAWAY,
            tick,
            f"{lv.map.label(i)}: tracking error "
            f"{float(self.demand[i] - q[i]):+.4f} rad beyond safe "
            f"{float(self._safe_ok[i]):.4f} rad (runaway)",
        )

    def _current_fault(self, tick: int, i: int) -> None:
        """Joint ``i``'s demand was beyond its motor's current limit for ``current_fault_ms``
        (``kali_current_check``, which zeroes the torque sent where not fed): halt."""
        lv = self.level
        demand = float(self.servo_torque[i] + self.ff[i]) / float(self.driver.gkt[i])
        what, unit = self.driver.current_unit
        self._halt(
            FaultCode.CURRENT,
            tick,
            f"{lv.map.label(i)}: {what} demand {demand:+.2f} {unit} beyond its limit "
            f"{float(self.driver.current_limit[i]):.2f} {unit} "
            f"for {int(self.over[i]) * lv.cfg.clock.servo_period_ms:g} ms",
        )
        self.over[:] = 0

    def _halt(self, code: FaultCode, tick: int, message: str) -> bool:
        """Raise a fault (power off through the boards, clock stops); DAC to zero."""
        self.inst.raise_fault(code, self.name, message, tick=tick)
        self.driver.zero()
        return True

    def _wait_done(self, tick: int, fed: int, timed_out: bool = False) -> bool:
        """Sleep until every fed slot ran; False after halting, naming the culprit.

        The common path is one semaphore wait.  Past a servo period the wait goes on in
        slices, and after each an SV that died holding a slot halts the system at once
        (PROCESS_DIED); past ``wait_s`` a servo still unfinished halts it (DEADLINE), naming
        the SV that holds it and the algorithm, or the joints no SV claimed.  ``timed_out``:
        the compiled tick's wait of one period has just timed out (its first slice).
        """
        done = self._ctrl_done
        deadline = 0

        def sliced() -> bool:  # a slice timed out: whether to stop waiting
            nonlocal deadline
            now = rt.monotonic_ns()
            if not deadline:  # measured from the wait's start: slices overrun a little
                deadline = now - self.slice_ns + self.wait_ns
            return self._dead_servo(tick) or now >= deadline

        stop = timed_out and sliced()
        while not stop and int(done) < fed:
            try:
                self.done_sem.acquire(self.slice_s)
            except posix_ipc.BusyError:
                stop = sliced()
        # drain a post that raced with the last check (looked at first: a failed acquire
        # raises, which costs more than the post; only SIO takes from this semaphore)
        while self.done_sem.value:
            try:
                self.done_sem.acquire(0)
            except posix_ipc.BusyError:
                break
        if int(done) >= fed:
            return True
        if self.inst.fault["active"]:
            return False  # _dead_servo halted
        lv = self.level
        late, holders = [], []
        for i in range(lv.n):
            if not self.fed_mask[i] or int(lv.slots["ran_tick"][i]) == tick:
                continue
            holder = int(self._slot_busy[i])
            joint = f"{lv.names[lv.map.robot_of[i]]} joint {lv.map.joint_of[i] + 1}"
            if holder == 0:
                late.append(f"{joint} (unclaimed)")
                continue
            algo = lv.name_of(int(lv.slot_structs[i].algo))
            late.append(f"{joint} (servo '{algo}', claimed by sv.{holder - 1})")
            holders.append(f"sv.{holder - 1}")
        self.inst.raise_fault(
            FaultCode.DEADLINE,
            holders[0] if holders else self.name,  # the culprit, if one SV holds it
            f"servos not done {self.wait_s * 1000:g} ms after tick {tick} "
            f"(sio waited): {', '.join(late)}",
            tick=tick,
        )
        self.driver.zero()
        return False

    def _dead_servo(self, tick: int) -> bool:
        """Halt with PROCESS_DIED if an SV holding an unfinished slot died; True if so.
        Only after a servo period without the done post: never on the common path."""
        lv = self.level
        for i in range(lv.n):
            holder = int(self._slot_busy[i])
            if not self.fed_mask[i] or int(lv.slots["ran_tick"][i]) == tick:
                continue
            if not 0 < holder <= len(self.sv_slots):
                continue  # unclaimed (or a busy word no SV wrote): the deadline names it
            slot = self.sv_slots[holder - 1]
            pid = int(self.inst.procs[slot]["pid"])
            if not pid_alive(pid):
                name = f"sv.{holder - 1}"
                self.inst.raise_fault(
                    FaultCode.PROCESS_DIED,
                    name,
                    f"process '{name}' (pid {pid}) died holding {lv.map.label(i)} "
                    f"at tick {tick} (sio noticed)",
                    tick=tick,
                )
                self.driver.zero()
                return True
        return False

    def _since(self) -> str:
        """How long ago, by the clock, SIO last retriggered the watchdog: a gap beyond
        ``watchdog_ms`` says the watchdog cut the amplifiers because SIO did not run (the
        board clears its trip bit at the next retrigger, so the register may no longer
        show it).  In the clock's ticks: wall time in real time, the plant's in lockstep;
        not SIO's signalled tick, which after a stall is the one it was signalled long ago."""
        if self.retrigger_tick < 0:
            return "SIO has not retriggered the watchdog yet"
        now = int(self._clock["tick"])
        gap_ms = (now - self.retrigger_tick) * self.base_ms
        return (
            f"SIO last retriggered the watchdog {gap_ms:g} ms ago (at clock tick "
            f"{self.retrigger_tick}, now {now}; watchdog {self.watchdog_ms:g} ms)"
        )


class _RobotViews:
    """Robot ``k``'s fields, viewed once at configure: indexing a record by field name builds
    a new view every time, which has no place in the cycle."""

    __slots__ = (
        "calib_cmd",
        "calib_found",
        "calib_shift",
        "calib_state",
        "calibrated",
        "cmd_faults",
        "demand",
        "enable_ticks",
        "fed",
        "guided",
        "message",
        "pots_read",
        "power",
        "power_cmd",
        "q",
        "slot_reset",
    )
    # robot k's fields of ``layout.ROBOT_STATE``, each a 0-d view, made in ``__init__``
    power: np.ndarray
    power_cmd: np.ndarray
    pots_read: np.ndarray
    enable_ticks: np.ndarray
    message: np.ndarray
    calib_cmd: np.ndarray
    calib_state: np.ndarray
    calib_found: np.ndarray
    calibrated: np.ndarray
    guided: np.ndarray
    cmd_faults: np.ndarray

    def __init__(self, sio: SioCycle, k: int) -> None:
        robots = sio.level.robots

        def one(records: np.ndarray, field: str) -> np.ndarray:
            return records[k : k + 1][field].reshape(())

        for field in (
            "power",
            "power_cmd",
            "pots_read",
            "enable_ticks",
            "message",
            "calib_cmd",
            "calib_state",
            "calib_found",
            "calibrated",
            "guided",
            "cmd_faults",
        ):
            setattr(self, field, one(robots, field))
        span = sio.level.map.span(k)
        self.calib_shift = sio.level.joints["calib_shift"][span]
        self.q, self.demand = sio.q[span], sio.demand[span]
        self.fed = sio.fed_mask[span]
        self.slot_reset = sio.level.slots["reset"][span]
