"""Robot driver (thesis 3.5): the table of functions between board registers and the units
servos work in, for arms of any robot type on McGill I/O and DAC boards.

Servos only ever see joint radians and joint N·m (3.3.4); this module owns every conversion
between those and the hardware, vectorised over all arms (flat joints, arm ``k``'s joint ``j``
at ``JointMap.base[k] + j``; on the arm's board, channel ``j``), each arm's drive from its
robot type: 12-bit encoder readings accumulated into 32-bit counts (so each counter must be
read before it moves 2048 counts), counts to angles through the signed gear ratio and the
calibration offset (3.5.1), and joint torque to a clamped motor current and a DAC code.  The
formulas: docs/internals/robots-hardware-plant.md.

Inside the cycle: preallocated arrays only, and each conversion one compiled kernel
(``kali_daemons.core.kernels``: ``kali_read``, ``kali_dac``, with their numpy references).
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ...core.joints import ArmCopy, JointMap
from ...core.kernels import COUNTER_BITS, COUNTER_HALF, COUNTER_MODULO, Kernel, channel_offsets
from ...robots import RobotType
from . import registers

__all__ = ["COUNTER_BITS", "COUNTER_HALF", "COUNTER_MODULO", "DAC_MAX", "JointDriver"]
DAC_MAX = (1 << registers.DAC_BITS) - 1


class JointDriver:
    """Conversions for the arms of ``types`` (one robot type per arm, in robot order), on the
    boards whose encoder and DAC registers are ``encoders`` and ``codes`` (``(n_arms, 8)``
    uint16 views, joint ``j`` on channel ``j``).

    Its state, ``acc`` (int32 accumulated counts), ``prev`` (last raw readings) and ``offset``
    (rad), is flat and private; ``load``/``store`` move it from/to the arena's per-joint
    records so a restarted SIO resumes with the same counts and calibration.
    """

    current_unit = ("motor current", "A")  # SIO's "current": the amplifier's demand

    def __init__(
        self,
        types: list[RobotType],
        encoders: np.ndarray,
        codes: np.ndarray,
        current_limit: np.ndarray | None = None,
        index_phase: np.ndarray | None = None,
    ) -> None:
        """``index_phase``: each joint's index-pulse motor angle (rad, flat), the arms'
        calibration sheets (``RobotConfig.index_phases``); needed only to calibrate."""
        self.n_arms = len(types)
        self.map = JointMap(
            tuple(f"arm {k}" for k in range(len(types))), tuple(t.n_joints for t in types)
        )
        n = self.n = self.map.total

        def tile(values: Callable[[RobotType], object]) -> np.ndarray:
            return np.concatenate([np.asarray(values(t), dtype=np.float64) for t in types])

        self.types = types
        self.acc = np.zeros(n, dtype=np.int32)
        self.prev = np.zeros(n, dtype=np.int32)
        self.offset = np.zeros(n)
        self.gear = tile(lambda t: t.drive.gear)  # signed: motor angle = G · joint angle
        # counts per joint radian, signed: counts grow with the motor angle G·q
        self.counts_per_rad = tile(lambda t: t.drive.counts_per_rev) * self.gear / (2.0 * math.pi)
        self.rad_per_count = 1.0 / self.counts_per_rad
        self.q_min = tile(lambda t: t.q_min)
        self.q_max = tile(lambda t: t.q_max)
        self.gkt = self.gear * tile(lambda t: t.drive.kt)  # joint N·m per motor A
        limit = tile(lambda t: t.drive.max_current) if current_limit is None else current_limit
        self.current_limit = np.broadcast_to(np.asarray(limit, dtype=np.float64), (n,)).copy()
        self.torque_limit = self.current_limit * np.abs(self.gkt)  # N·m at the joint
        self.index_spacing = 2.0 * math.pi / np.abs(self.gear)  # rad between index pulses
        # DAC codes per motor ampere: codes per volt over the amplifier's amperes per volt
        self.codes_per_amp = tile(
            lambda t: (
                [registers.DAC_ZERO / t.drive.dac_volts / t.drive.amp_gain_a_per_v] * t.n_joints
            )
        )
        self.index_phase = (
            np.zeros(n) if index_phase is None else np.asarray(index_phase, dtype=np.float64)
        ).reshape(n)
        self._raw = np.zeros(n, dtype=np.int32)
        self._f = np.zeros(n)
        self._encoders = ArmCopy(self.map, self._raw, encoders)  # counters → _raw
        self._codes = ArmCopy(self.map, self._f, codes)  # _f → DAC codes
        m = self.map  # where each joint's counter and DAC code sit in the registers
        self._encoder_regs = encoders
        self._enc_off = channel_offsets(encoders, m.robot_of, m.joint_of)
        self._dac_regs = codes
        self._dac_off = channel_offsets(codes, m.robot_of, m.joint_of)
        self._read: Kernel | None = None  # bound to the caller's arrays by ``bind``
        self._dac: Kernel | None = None
        self._read_q: np.ndarray | None = None
        self._dac_arrays: tuple[np.ndarray, ...] = ()

    # ------------------------------------------------------------------ state

    def load(self, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray) -> None:
        """Take the state from flat per-joint views (outside the cycle)."""
        np.copyto(self.acc, acc)
        np.copyto(self.prev, prev)
        np.copyto(self.offset, offset)

    def store(self, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray) -> None:
        """Publish the state into flat per-joint views; safe inside the cycle."""
        np.copyto(acc, self.acc)
        np.copyto(prev, self.prev)
        np.copyto(offset, self.offset)

    # ------------------------------------------------------------------ encoders → radians

    def start(self) -> None:
        """Take the counters' readings as the reference: no motion yet."""
        self._encoders.to_flat()
        np.copyto(self.prev, self._raw)

    def bind(
        self, q: np.ndarray, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray
    ) -> None:
        """Bind ``read`` to ``q`` and ``output`` to its three arrays, outside the cycle (a
        call with other arrays binds those first: fine outside any cycle, in tests and
        tools)."""
        self._bind_read(q)
        self._bind_dac(torque, current, clamped)

    def _bind_read(self, q: np.ndarray) -> None:
        self._read = Kernel(
            "kali_read",
            (self._encoder_regs,),
            n=self.n,
            encoders=self._encoder_regs.ctypes.data,
            enc_off=self._enc_off,
            acc=self.acc,
            prev=self.prev,
            offset=self.offset,
            rad_per_count=self.rad_per_count,
            q=q,
            modulo=COUNTER_MODULO,
            half=COUNTER_HALF,
        )
        self._read_q = q

    def _bind_dac(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        assert clamped.dtype == np.bool_, f"clamped is bool, not {clamped.dtype}"
        self._dac = Kernel(
            "kali_dac",
            (self._dac_regs,),
            n=self.n,
            torque=torque,
            gkt=self.gkt,
            current_limit=self.current_limit,
            codes_per_amp=self.codes_per_amp,
            current=current,
            clamped=clamped,
            dacs=self._dac_regs.ctypes.data,
            dac_off=self._dac_off,
            zero=float(registers.DAC_ZERO),
            top=float(DAC_MAX),
        )
        self._dac_arrays = (torque, current, clamped)

    def kernels(self) -> tuple[Kernel, Kernel]:
        """The read and DAC kernels ``bind`` bound (``read`` and ``output`` on those arrays),
        for a kernel that calls them (SIO's compiled tick)."""
        assert self._dac_arrays, "driver: bind before asking for its kernels"
        return self._read, self._dac  # type: ignore[return-value]

    def read(self, q: np.ndarray) -> None:
        """Accumulate the counter readings (low 12 bits, the difference wrapped into
        -2048 .. 2047, figure C.3) and write joint angles (rad) into ``q`` (``(n,)``
        float64): ``kernels.read_reference``."""
        if q is not self._read_q:
            self._bind_read(q)
        self._read()  # type: ignore[misc]

    def angles(self, q: np.ndarray) -> None:
        """Joint angles (rad) of the accumulated counts, with the calibration offsets."""
        np.multiply(self.acc, self.rad_per_count, out=q)
        np.add(q, self.offset, out=q)

    def counts_of(self, i: int, angle: float) -> int:
        """Accumulated count that reads as ``angle`` (rad) on joint ``i`` (outside the cycle)."""
        return round((angle - float(self.offset[i])) * float(self.counts_per_rad[i]))

    def set_angle(self, i: int, angle: float) -> None:
        """Make joint ``i`` read ``angle`` now by moving its offset (calibration)."""
        self.offset[i] = angle - float(self.acc[i]) * float(self.rad_per_count[i])

    # ------------------------------------------------------------------ index pulses (3.5.1)

    def at_index(self, i: int, raw: int, index_angle: float) -> None:
        """Joint ``i``'s counter was reset to 0 by its index pulse since the last reading
        (capture on, C.3): count from the pulse from now on, and let the pulse read as
        ``index_angle``.  ``raw`` is this tick's counter reading, i.e. the counts travelled
        past the pulse (signed, it may have gone back through 0)."""
        r = int(raw) & (COUNTER_MODULO - 1)
        self.acc[i] = r - COUNTER_MODULO if r >= COUNTER_HALF else r
        self.prev[i] = r
        self.offset[i] = index_angle

    def nearest_index(self, i: int, angle: float) -> float:
        """The joint angle (rad) of joint ``i``'s index pulse nearest ``angle``: pulses sit at
        motor angles ``phase + 2π m``, i.e. joint angles ``(phase + 2π m) / G``."""
        g, phase = float(self.gear[i]), float(self.index_phase[i])
        m = round((g * angle - phase) / (2.0 * math.pi))
        return (phase + 2.0 * math.pi * m) / g

    # ------------------------------------------------------------------ torque → DAC

    def output(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        """Joint torques (N·m) → motor currents (A, clamped at the limit) → DAC codes
        (``kernels.dac_reference``).

        ``clamped`` (bool ``(n,)``) is set where the demand exceeded the current limit.
        """
        a = self._dac_arrays
        if not a or a[0] is not torque or a[1] is not current or a[2] is not clamped:
            self._bind_dac(torque, current, clamped)
        self._dac()  # type: ignore[misc]

    def zero(self) -> None:
        """Every joint's DAC channel to 0 V."""
        self._codes.fill_arms(registers.DAC_ZERO)

    # ------------------------------------------------------------------ potentiometers

    def pot_table(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """The linear interpolation table of joint ``i``'s potentiometer (3.5.1): ADC codes
        and the joint angles they read.  Two points, at the joint limits (0.25 V and 4.75 V)."""
        codes = np.array([0.25, 4.75]) / 5.0 * 255.0
        angles = np.array([self.q_min[i], self.q_max[i]])
        return codes, angles

    def pot_angle(self, i: int, code: int) -> float:
        """Joint ``i``'s angle (rad) as its 8-bit pot reading ``code`` tells it (coarse)."""
        codes, angles = self.pot_table(i)
        return float(np.interp(code, codes, angles, left=angles[0], right=angles[1]))
