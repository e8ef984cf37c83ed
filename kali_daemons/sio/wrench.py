"""SIO's wrist force/torque sensors: gauge codes → Newtons (thesis 3.3.3; issue 27).

3.3.3 gives SIO the sensors: it "gathers sensor information, such as joint position from
encoders or force readings from force sensors, converts them to standard angles and forces
(ie., Newtons)".  Once per servo tick, for every arm with a sensor (``config.FtConfig``):

1. **The bank's handshake** (``ftsensor``): when the board answers the sequence number SIO
   asked for, its six codes are this tick's sample and SIO asks for the next at once; a
   sensor silent for ``stale_ms`` halts (FORCE).
2. **Counts → wrench**: volts, then the data sheet's calibration matrix, less the tare's bias:
   the wrench the tool exerts on the sensor, sensor frame (``FT_STATE.sensor``).  A gauge at
   its ADC rail, or an axis beyond the sheet's rated range, halts (FORCE).
3. **Gravity**: the sensor frame in the world is the arm's base pose times its flange pose
   at the measured joints (``chain.py``, this tick's angles); the tool's weight there,
   ``[m g; c × m g]``, is subtracted: the contact wrench, what the environment applies to the
   tool.  A contact force beyond the robot's limit halts (FORCE).
4. **Filter and frames**: a first-order low-pass at ``cutoff_hz``, then moved to the tool
   point (``tool_tip_m`` along z) in tool axes (``FT_STATE.tool``) and world axes (``world``).

A tare (``FT_STATE.tare_cmd``) averages the next ``TARE_MS`` of samples of the reading less
the tool's gravity: that mean is the sensor's offset, the new bias.  The arm should be still
and touch nothing; the bias stays in the arena, so a restarted SIO keeps it.

Inside the cycle: preallocated arrays, no allocation beyond numpy views; only a halt builds a
message.
"""

from __future__ import annotations

import math

import numpy as np

from .. import ftsensor, layout
from ..chain import Chain, chain_of
from ..config import KaliConfig, ms_to_ns
from ..ftsensor import AXES, AXIS_UNITS, FT_PRESENT, FT_READY, FT_REQUEST, FT_SEQ_MASK
from ..kernels import chain_pose
from ..layout import TareState

TARE_MS = 100.0  # a tare averages this long of samples


def base_pose(xyz: tuple[float, float, float], yaw_deg: float) -> np.ndarray:
    """A robot's base in the world (4×4): at ``xyz``, turned ``yaw_deg`` about z."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:3, 3] = xyz
    return t


class ArmSensor:
    """One arm's sensor as SIO reads it: its board registers, its FT_STATE record, its
    chain, and the arrays of the conversion, all bound at configure."""

    def __init__(
        self,
        cfg: KaliConfig,
        k: int,
        regs: np.ndarray,
        state: np.ndarray,
        q: np.ndarray,
        servo_period_s: float,
    ) -> None:
        robot = cfg.robots[k]
        ft = robot.ft
        sheet = ft.sheet
        assert sheet is not None, "an ArmSensor needs a sensor"
        self.name = robot.name
        self.sheet = sheet
        self.regs = regs  # IO_BOARD record (0-d)
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
        self.codes = regs["ft_gauge"]
        self._control = regs["ft_control"]
        self._status = regs["ft_status"]
        self.seq = 0
        # scratch and published views
        self._v = np.zeros(ftsensor.GAUGES)
        self._raw = np.zeros(ftsensor.GAUGES)
        self._grav = np.zeros(ftsensor.GAUGES)
        self._contact = np.zeros(ftsensor.GAUGES)
        self._filt = np.zeros(ftsensor.GAUGES)
        self._d = np.zeros(ftsensor.GAUGES)
        self._sum = np.zeros(ftsensor.GAUGES)
        self._tare_left = 0
        self._pose = np.eye(4)
        self._world = np.eye(4)
        self._g = np.zeros(3)
        self._fk = chain_pose(self.chain, q, self._pose)  # this tick's flange pose, compiled
        self._sensor = state["sensor"]
        self._tool = state["tool"]
        self._world_w = state["world"]
        self._bias = state["bias"]
        self._rotation = state["rotation"]
        self._stale = state["stale"]
        self._samples = state["samples"]
        self._sample_tick = state["sample_tick"]
        self._tare_cmd = state["tare_cmd"]
        self._tare_state = state["tare_state"]
        self._tare_count = state["tare_count"]
        self._present = state["present"]
        self._limit = state["contact_limit"]

    def start(self) -> None:
        """Ask for the first sample (at SIO's configure)."""
        self.seq = (int(self._status) + 1) & FT_SEQ_MASK
        self._control[...] = FT_REQUEST | self.seq

    def step(self, tick: int) -> str | None:
        """One servo tick; a halt's message (outside the common path) or None."""
        status = int(self._status)
        if not (status & FT_READY and status & FT_SEQ_MASK == self.seq):
            stale = int(self._stale) + 1
            self._stale[...] = stale
            if stale > self.stale_limit:
                what = "no sensor on its board" if not status & FT_PRESENT else "no new sample"
                return (
                    f"robot '{self.name}': wrist force/torque sensor silent for {stale} ticks "
                    f"({what}); limit {self.stale_limit} ticks"
                )
            return None
        self._stale[...] = 0
        self._present[...] = 1
        # (2) codes → the wrench on the sensor; then ask for the next sample at once
        v, raw = self._v, self._raw
        np.multiply(self.codes, ftsensor.VOLTS_PER_CODE, out=v)
        np.matmul(self.calibration, v, out=raw)
        self.seq = (self.seq + 1) & FT_SEQ_MASK
        self._control[...] = FT_REQUEST | self.seq
        self._samples[...] = int(self._samples) + 1
        self._sample_tick[...] = tick
        # (3) the tool's weight in the sensor frame at this tick's pose; a tare in progress
        self._fk()
        np.matmul(self.base, self._pose, out=self._world)
        rot = self._world[:3, :3]
        np.copyto(self._rotation, rot)
        np.matmul(self.g_world, rot, out=self._g)  # Rᵀ g
        self._gravity()
        self._tare_step()
        np.subtract(raw, self._bias, out=self._sensor)  # with the bias a tare just set
        if int(np.abs(self.codes).max()) >= ftsensor.FT_RAIL:
            return self._saturated()
        if (np.abs(self._sensor) > self.rated).any():
            return self._beyond_rated()
        np.subtract(self._sensor, self._grav, out=self._contact)
        c = self._contact
        force = math.sqrt(float(c[0]) ** 2 + float(c[1]) ** 2 + float(c[2]) ** 2)
        limit = float(self._limit)
        if not 0.0 < limit <= self.limit_config:  # clients may lower it only (DESIGN 7)
            limit = self.limit_config
        if force > limit:
            return (
                f"robot '{self.name}': contact force {force:.1f} N beyond its limit "
                f"{limit:g} N (tool, wrist sensor)"
            )
        # (4) low-pass, then the tool point's wrench in tool and world axes
        f, d = self._filt, self._d
        np.subtract(c, f, out=d)
        d *= self.alpha
        f += d
        tool, tip = self._tool, self.tip
        tool[:3] = f[:3]  # τ at the tool point p = (0, 0, tip): τ − p × F
        tool[3] = float(f[3]) + tip * float(f[1])
        tool[4] = float(f[4]) - tip * float(f[0])
        tool[5] = f[5]
        np.matmul(rot, tool[:3], out=self._world_w[:3])
        np.matmul(rot, tool[3:], out=self._world_w[3:])
        return None

    def _gravity(self) -> None:
        """``[m g; c × m g]`` with g in the sensor frame, into ``_grav``."""
        m, g, c, out = self.mass, self._g, self.com, self._grav
        gx, gy, gz = m * float(g[0]), m * float(g[1]), m * float(g[2])
        cx, cy, cz = float(c[0]), float(c[1]), float(c[2])
        out[0], out[1], out[2] = gx, gy, gz
        out[3], out[4], out[5] = cy * gz - cz * gy, cz * gx - cx * gz, cx * gy - cy * gx

    def _tare_step(self) -> None:
        """Take a tare command; sum samples while averaging; set the bias when done."""
        if int(self._tare_cmd):
            self._tare_cmd[...] = 0
            self._tare_left = self.tare_ticks
            self._sum[:] = 0.0
            self._tare_state[...] = TareState.AVERAGING
        if not self._tare_left:
            return
        # the offset is the calibrated reading less the tool's weight
        self._sum += self._raw
        self._sum -= self._grav
        self._tare_left -= 1
        if not self._tare_left:
            np.divide(self._sum, self.tare_ticks, out=self._bias)
            self._filt[:] = 0.0  # no contact at the tare, by definition: no filter lag after it
            self._tare_count[...] = int(self._tare_count) + 1
            self._tare_state[...] = TareState.DONE

    def _saturated(self) -> str:
        g = int(np.argmax(np.abs(self.codes)))
        return (
            f"robot '{self.name}': wrist force/torque sensor gauge {g + 1} saturated "
            f"(code {int(self.codes[g])}, rail ±{ftsensor.FT_RAIL})"
        )

    def _beyond_rated(self) -> str:
        over = np.abs(self._sensor) / self.rated
        a = int(np.argmax(over))
        return (
            f"robot '{self.name}': wrist force/torque sensor {AXES[a]} = "
            f"{float(self._sensor[a]):+.1f} {AXIS_UNITS[a]} beyond its rated range "
            f"±{self.rated[a]:g} {AXIS_UNITS[a]} ({self.sheet.name})"
        )


def sensors_of(cfg: KaliConfig) -> list[int]:
    """The robots (config order) that have a wrist sensor."""
    return [k for k, r in enumerate(cfg.robots) if r.ft.sheet is not None]


__all__ = ["TARE_MS", "ArmSensor", "base_pose", "layout", "sensors_of"]
