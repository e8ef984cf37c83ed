"""SIO's wrist force/torque sensors: gauge codes → Newtons (thesis 3.3.3).

Once per servo tick, for every arm with a sensor (``config.FtConfig``): the board's sample
handshake (``ftsensor``); codes → volts → the data sheet's calibration matrix, less the
tare's bias (``FT_STATE.sensor``); the tool's weight at the measured pose subtracted (the
contact wrench); a first-order low-pass; the result at the tool point in tool and world axes
(``FT_STATE.tool``, ``world``).  A silent sensor, a gauge at its ADC rail, an axis beyond its
rated range or a contact force beyond the limit halts (FORCE).  A tare (``FT_STATE.tare_cmd``)
averages ``TARE_MS`` of samples into the bias, which stays in the arena.

All of it is one compiled kernel a tick (``kali_wrench_tick``, the conversion in it
``kali_wrench_convert``); ``convert_reference`` is the conversion's numpy reference.  Only a
halt builds a message.  The steps in detail: docs/internals/sio-viewer-core.md.
"""

from __future__ import annotations

import math

import numpy as np

from ..core import atomic
from ..core.kernels import WRENCH_CONTACT, WRENCH_OK, WRENCH_RATED, WRENCH_SATURATED, Kernel
from ..core.layout import GuardState, TareState
from ..hardware import ftsensor
from ..hardware.ftsensor import (
    AXES,
    AXIS_UNITS,
    FT_PRESENT,
    FT_READY,
    FT_REQUEST,
    FT_SEQ_MASK,
    gravity_wrench,
)
from ..robots.chain import Chain, base_pose, chain_of, flange_pose
from ..runtime.config import KaliConfig, ms_to_ns

TARE_MS = 100.0  # a tare averages this long of samples


class ArmSensor:
    """One arm's sensor as SIO reads it: its board registers (``regs``, a gauge sensor's) or
    the wrench its hardware gives at the flange with that wrench's count (``given``, an arm
    with no gauges: ``ftsensor.JOINT_TORQUES``), its FT_STATE record, its chain, and the arrays
    of the conversion, all bound at configure.  ``cycles`` (0-d uint32), where the hardware
    behind the gauges can stall while SIO runs (a simulated board), counts the cycles it ran:
    a tick it did not run is no silence of the sensor (``Hardware.gauge_cycles``)."""

    def __init__(
        self,
        cfg: KaliConfig,
        k: int,
        regs: np.ndarray | None,
        state: np.ndarray,
        q: np.ndarray,
        servo_period_s: float,
        given: tuple[np.ndarray, np.ndarray] | None = None,
        cycles: np.ndarray | None = None,
    ) -> None:
        robot = cfg.robots[k]
        ft = robot.ft
        sheet = ft.sheet
        assert sheet is not None, "an ArmSensor needs a sensor"
        self.name = robot.name
        self.sheet = sheet
        self.regs = regs  # IO_BOARD record (0-d), or None: no gauges
        self.given = None if given is None else given[0]  # 6 float64: flange, flange axes
        self._given_seq = None if given is None else given[1]  # 0-d uint64: its count
        self.state = state  # FT_STATE record (0-d)
        self.q = q  # SIO's angles of this arm (a view)
        self.chain: Chain = chain_of(robot.type)
        self.base = base_pose(robot.base_xyz, robot.base_yaw_deg)
        self.mass = ft.tool_mass_kg
        self.com = np.asarray(ft.tool_com_m, dtype=np.float64)
        self.tip = ft.tool_tip_m
        self.limit_config = ft.contact_limit_n
        self.g_world = np.array([0.0, 0.0, -robot.type.gravity])
        self.alpha = 1.0 - math.exp(-2.0 * math.pi * ft.cutoff_hz * servo_period_s)
        period_ns = round(servo_period_s * 1e9)
        self.stale_limit = max(1, -(-ms_to_ns(ft.stale_ms) // period_ns))
        self.tare_ticks = max(1, round(TARE_MS / 1000.0 / servo_period_s))
        self.calibration = np.ascontiguousarray(sheet.calibration)
        self.rated = np.asarray(sheet.rated, dtype=np.float64)
        # the gauges' registers; none where the hardware gives the wrench (the kernel then
        # reads neither codes nor status and writes no control)
        self.codes = None if regs is None else regs["ft_gauge"]
        self._control = None if regs is None else regs["ft_control"]
        self._status = None if regs is None else regs["ft_status"]
        self.filt = np.zeros(ftsensor.GAUGES)  # the contact wrench's low-pass state
        self.raw = np.zeros(ftsensor.GAUGES)  # the calibrated sample
        self.grav = np.zeros(ftsensor.GAUGES)  # the tool's weight on the sensor
        self.sum = np.zeros(ftsensor.GAUGES)  # a tare's sum so far
        self.sensor = state["sensor"]
        self.tool = state["tool"]
        self.world = state["world"]
        self.bias = state["bias"]
        self.rotation = state["rotation"]
        self.limit = state["contact_limit"]
        self._stale = state["stale"]
        self._samples = state["samples"]
        self._sample_tick = state["sample_tick"]
        self._tare_cmd = state["tare_cmd"]
        self._tare_state = state["tare_state"]
        self._tare_count = state["tare_count"]
        self._present = state["present"]
        c = self.chain
        assert q.flags.c_contiguous and q.dtype == np.float64 and q.shape == (c.n,), q
        self._tick = Kernel(
            "kali_wrench_tick",
            (c, q, self.calibration, self.base, self.g_world, self.com, self.rated, cycles),
            n=c.n,
            origins=c.origins.ctypes.data,
            axes=c.axes.ctypes.data,
            q=q.ctypes.data,
            codes=_address(self.codes),
            given=0 if self.given is None else self.given.ctypes.data,
            given_seq=0 if self._given_seq is None else self._given_seq.ctypes.data,
            given_seen=0 if self._given_seq is None else int(self._given_seq),
            cycles=_address(cycles),
            cycles_seen=0 if cycles is None else int(cycles),
            cal=self.calibration.ctypes.data,
            base=self.base.ctypes.data,
            g=self.g_world.ctypes.data,
            com=self.com.ctypes.data,
            rated=self.rated.ctypes.data,
            limit=self.limit.ctypes.data,
            mass=self.mass,
            tip=self.tip,
            alpha=self.alpha,
            volts=ftsensor.VOLTS_PER_CODE,
            limit_config=self.limit_config,
            rail=ftsensor.FT_RAIL,
            tare_left=0,
            tare_ticks=self.tare_ticks,
            **{
                f: a.ctypes.data
                for f, a in (
                    ("raw", self.raw),
                    ("grav", self.grav),
                    ("sensor", self.sensor),
                    ("filt", self.filt),
                    ("tool", self.tool),
                    ("world", self.world),
                    ("bias", self.bias),
                    ("sum", self.sum),
                    ("rotation", self.rotation),
                    ("stale", self._stale),
                    ("tare_count", self._tare_count),
                    ("samples", self._samples),
                    ("sample_tick", self._sample_tick),
                    ("present", self._present),
                    ("tare_cmd", self._tare_cmd),
                    ("tare_state", self._tare_state),
                )
            },
            status=_address(self._status),
            control=_address(self._control),
            stale_limit=self.stale_limit,
            ready=FT_READY,
            request=FT_REQUEST,
            seq_mask=FT_SEQ_MASK,
            averaging=TareState.AVERAGING,
            done=TareState.DONE,
        )
        # the kernel's scalars: tick, seq, tare_left, force, limit_used
        self.args = self._tick.args
        self.convert = self._tick.sibling("kali_wrench_convert")  # (2)-(4) alone, for tests
        # a guarded move's watch: the TG arms it, ``trip`` trips it (SIO then holds the arm)
        self._guard_state = state["guard_state"]
        self._guard_n = state["guard_n"]
        self._guard_addr = self._guard_state.ctypes.data
        self._cas = atomic.CompareExchange32()

    def start(self) -> None:
        """Ask for the first sample (at SIO's configure)."""
        if self._status is None or self._control is None:
            return  # the hardware's wrenches come unasked
        self.args.seq = (int(self._status) + 1) & FT_SEQ_MASK
        self._control[...] = FT_REQUEST | self.args.seq

    def tick(self, tick: int) -> int:
        """One servo tick (``kali_wrench_tick``: the handshake, a tare, the conversion):
        ``WRENCH_OK``, or what is wrong (``message`` says it; outside the common path)."""
        self.args.tick = tick
        return self._tick()

    def guard_reached(self) -> bool:
        """In the cycle: this arm's guard is armed and this tick's contact force (the
        sample's, unfiltered: the filter would add its lag to the stop) has reached it."""
        return int(self._guard_state) == GuardState.ARMED and self.args.force >= float(
            self._guard_n
        )

    def trip(self, tick: int) -> bool:
        """Trip this arm's guard if it is armed, noting the tick, the force, the joints and
        the contact wrench first (the TG reads them once it sees TRIPPED), then one
        compare-and-swap (the TG may be disarming it); True if it tripped.  Outside the
        common path: once per guarded move."""
        st = self.state
        st["guard_tick"] = tick
        st["guard_force"] = self.args.force
        st["guard_q"][: self.q.size] = self.q
        st["guard_wrench"] = self.world
        swapped, _ = self._cas(self._guard_addr, GuardState.ARMED, GuardState.TRIPPED)
        return swapped

    def message(self, found: int) -> str:
        """The halt's message for ``kali_wrench_tick``'s result (outside the common path)."""
        if found == WRENCH_SATURATED and self.codes is not None:
            g = int(np.argmax(np.abs(self.codes.astype(np.int64))))
            return (
                f"robot '{self.name}': wrist force/torque sensor gauge {g + 1} saturated "
                f"(code {int(self.codes[g])}, rail ±{ftsensor.FT_RAIL})"
            )
        if found == WRENCH_RATED:
            a = int(np.argmax(np.abs(self.sensor) / self.rated))
            return (
                f"robot '{self.name}': wrist force/torque sensor {AXES[a]} = "
                f"{float(self.sensor[a]):+.1f} {AXIS_UNITS[a]} beyond its rated range "
                f"±{self.rated[a]:g} {AXIS_UNITS[a]} ({self.sheet.name})"
            )
        if found == WRENCH_CONTACT:
            return (
                f"robot '{self.name}': contact force {self.args.force:.1f} N beyond its limit "
                f"{self.args.limit_used:g} N (tool, wrist sensor)"
            )
        if self._status is None:
            what = "no new wrench from its hardware"
        elif not int(self._status) & FT_PRESENT:
            what = "no sensor on its board"
        else:
            what = "no new sample"
        return (
            f"robot '{self.name}': wrist force/torque sensor silent for {int(self._stale)} "
            f"ticks ({what}); limit {self.stale_limit} ticks"
        )


def _address(array: np.ndarray | None) -> int:
    """A kernel's pointer to ``array``'s data; NULL for none."""
    return 0 if array is None else array.ctypes.data


def convert_reference(arm: ArmSensor) -> int:
    """``kali_wrench_convert`` in numpy, on ``arm``'s arrays and kernel scalars (the tests'
    reference: equal to ~1e-12)."""
    a = arm.args
    pose = flange_pose(arm.chain, arm.q)
    rot = (arm.base @ pose)[:3, :3]
    arm.rotation[...] = rot
    if arm.codes is None:
        assert arm.given is not None
        arm.raw[:] = arm.given
    else:
        np.matmul(arm.calibration, arm.codes * ftsensor.VOLTS_PER_CODE, out=arm.raw)
    arm.grav[:] = gravity_wrench(arm.mass, arm.com, rot.T @ arm.g_world)
    if a.tare_left > 0:
        arm.sum += arm.raw - arm.grav
        a.tare_left -= 1
        if a.tare_left == 0:
            arm.bias[:] = arm.sum / arm.tare_ticks
            arm.filt[:] = 0.0
    arm.sensor[:] = arm.raw - arm.bias
    if arm.codes is not None and (np.abs(arm.codes.astype(np.int64)) >= ftsensor.FT_RAIL).any():
        return WRENCH_SATURATED
    if (np.abs(arm.sensor) > arm.rated).any():
        return WRENCH_RATED
    contact = arm.sensor - arm.grav
    a.force = float(np.linalg.norm(contact[:3]))
    limit = float(arm.limit)
    a.limit_used = limit if 0.0 < limit <= arm.limit_config else arm.limit_config
    if a.force > a.limit_used:
        return WRENCH_CONTACT
    arm.filt += arm.alpha * (contact - arm.filt)
    f = arm.filt
    arm.tool[:] = [f[0], f[1], f[2], f[3] + arm.tip * f[1], f[4] - arm.tip * f[0], f[5]]
    arm.world[:3], arm.world[3:] = rot @ arm.tool[:3], rot @ arm.tool[3:]
    return WRENCH_OK


def sensors_of(cfg: KaliConfig) -> list[int]:
    """The robots (config order) that have a wrist sensor."""
    return [k for k, r in enumerate(cfg.robots) if r.ft.sheet is not None]


__all__ = ["TARE_MS", "ArmSensor", "convert_reference", "sensors_of"]
