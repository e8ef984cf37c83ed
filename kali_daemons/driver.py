"""Robot driver (thesis 3.5): the table of functions between board registers and the units
servos work in, for PUMA 560 arms on McGill I/O and DAC boards.

Servos only ever see joint radians and joint N·m (3.3.4); this module owns every conversion
between those and the hardware, vectorised over all arms (joint ``6 k + j`` is joint ``j``
of arm ``k``):

- **Encoders** (figure C.3): each 12-bit HCTL-2000 reading is compared with the previous one
  and the difference, wrapped at half range (±2048), is added to a 32-bit accumulated count.
  The counters must therefore be read before 2048 counts pass (at 1 kHz that is over 100
  motor revolutions per second, far above the motors' top speed).
- **Angles**: ``q = counts / (counts per motor rev · G / 2π) + offset``; the signed gear
  ratio G gives the direction, the offset comes from calibration (3.5.1).
- **Torque out**: joint torque τ → motor current ``i = τ / (G · Kt)``, clamped at the
  current limit → amplifier input ``V = i / 2.5 A/V`` → 12-bit offset-binary DAC code over
  ±10 V.  Returns whether each joint's demand had to be clamped, for SIO's current check.

Inside the cycle: preallocated arrays only.
"""

from __future__ import annotations

import math

import numpy as np

from . import layout, puma560

COUNTER_BITS = 12
COUNTER_MODULO = 1 << COUNTER_BITS
COUNTER_HALF = COUNTER_MODULO // 2  # wrap threshold of figure C.3
DAC_MAX = (1 << layout.DAC_BITS) - 1
CODES_PER_VOLT = layout.DAC_ZERO / puma560.DAC_VOLTS  # 204.8


class Puma560Driver:
    """Conversions for ``n_arms`` PUMA 560s.

    Its state, ``acc`` (int32 accumulated counts), ``prev`` (last raw readings) and ``offset``
    (rad), is flat and private; ``load``/``store`` move it from/to the arena's per-robot
    records so a restarted SIO resumes with the same counts and calibration.
    """

    def __init__(
        self,
        n_arms: int,
        current_limit: np.ndarray | None = None,
        index_phase: np.ndarray | None = None,
    ) -> None:
        """``index_phase``: each joint's index-pulse motor angle (rad, flat ``(6 n_arms,)``),
        the arms' calibration sheets (``puma560.index_phases``); needed only to calibrate."""
        self.n_arms = n_arms
        n = self.n = 6 * n_arms

        def tile(values: np.ndarray) -> np.ndarray:
            return np.tile(np.asarray(values, dtype=np.float64), n_arms)

        self.acc = np.zeros(n, dtype=np.int32)
        self.prev = np.zeros(n, dtype=np.int32)
        self.offset = np.zeros(n)
        # counts per joint radian, signed: counts grow with the motor angle G·q
        self.counts_per_rad = tile(puma560.COUNTS_PER_MOTOR_REV * puma560.G / (2.0 * math.pi))
        self.rad_per_count = 1.0 / self.counts_per_rad
        self.q_min = tile(puma560.Q_MIN)
        self.q_max = tile(puma560.Q_MAX)
        self.gkt = tile(puma560.G * puma560.KT)  # joint N·m per motor A
        limit = tile(puma560.MAX_CURRENT) if current_limit is None else current_limit
        self.current_limit = np.broadcast_to(np.asarray(limit, dtype=np.float64), (n,)).copy()
        self.torque_limit = self.current_limit * np.abs(self.gkt)  # N·m at the joint
        self.gear = tile(puma560.G)  # signed: motor angle = G · joint angle
        self.index_spacing = tile(2.0 * math.pi / np.abs(puma560.G))  # rad between index pulses
        self.index_phase = (
            np.zeros(n) if index_phase is None else np.asarray(index_phase, dtype=np.float64)
        ).reshape(n)
        self._raw = np.zeros(n, dtype=np.int32)
        self._delta = np.zeros(n, dtype=np.int32)
        self._f = np.zeros(n)

    # ------------------------------------------------------------------ state

    def load(self, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray) -> None:
        """Take the state from ``(n_arms, 6)`` views (outside the cycle)."""
        np.copyto(self.acc.reshape(self.n_arms, 6), acc)
        np.copyto(self.prev.reshape(self.n_arms, 6), prev)
        np.copyto(self.offset.reshape(self.n_arms, 6), offset)

    def store(self, acc: np.ndarray, prev: np.ndarray, offset: np.ndarray) -> None:
        """Publish the state into ``(n_arms, 6)`` views; safe inside the cycle."""
        np.copyto(acc, self.acc.reshape(self.n_arms, 6))
        np.copyto(prev, self.prev.reshape(self.n_arms, 6))
        np.copyto(offset, self.offset.reshape(self.n_arms, 6))

    # ------------------------------------------------------------------ encoders → radians

    def start(self, raw: np.ndarray) -> None:
        """Take ``raw`` (``(n_arms, ≥6)`` counter readings) as the reference: no motion yet."""
        np.copyto(self.prev.reshape(self.n_arms, 6), raw[:, :6], casting="unsafe")

    def read(self, raw: np.ndarray, q: np.ndarray) -> None:
        """Accumulate the counter readings ``raw`` (``(n_arms, ≥6)`` uint16 view, low 12 bits)
        and write joint angles (rad) into ``q`` (``(n,)`` float64)."""
        r, d = self._raw, self._delta
        np.copyto(r.reshape(self.n_arms, 6), raw[:, :6], casting="unsafe")
        np.bitwise_and(r, COUNTER_MODULO - 1, out=r)
        np.subtract(r, self.prev, out=d)
        np.add(d, COUNTER_HALF, out=d)  # wrap the difference into -2048 .. 2047
        np.bitwise_and(d, COUNTER_MODULO - 1, out=d)
        np.subtract(d, COUNTER_HALF, out=d)
        np.add(self.acc, d, out=self.acc)
        np.copyto(self.prev, r)
        self.angles(q)

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

    def output(
        self, torque: np.ndarray, current: np.ndarray, codes: np.ndarray, clamped: np.ndarray
    ) -> None:
        """Joint torques (N·m) → motor currents (A, clamped at the limit) → DAC codes.

        ``codes`` is the ``(n_arms, ≥6)`` uint16 DAC register view; ``clamped`` (bool ``(n,)``)
        is set where the demand exceeded the current limit.
        """
        np.divide(torque, self.gkt, out=current)
        np.greater(np.abs(current, out=self._f), self.current_limit, out=clamped)
        np.minimum(current, self.current_limit, out=current)
        np.negative(self.current_limit, out=self._f)
        np.maximum(current, self._f, out=current)
        self.codes_of(current, self._f)
        np.copyto(codes[:, :6], self._f.reshape(self.n_arms, 6), casting="unsafe")

    def codes_of(self, current: np.ndarray, out: np.ndarray) -> None:
        """Motor currents (A) → DAC codes as float64 (rounded, 0 .. 4095)."""
        np.multiply(current, CODES_PER_VOLT / puma560.AMP_GAIN_A_PER_V, out=out)
        np.add(out, layout.DAC_ZERO, out=out)
        np.rint(out, out=out)
        np.maximum(out, 0, out=out)
        np.minimum(out, DAC_MAX, out=out)

    def zero(self, codes: np.ndarray) -> None:
        """Every DAC channel to 0 V (codes view ``(n_arms, ≥6)``)."""
        codes[:, :6] = layout.DAC_ZERO

    # ------------------------------------------------------------------ potentiometers

    @staticmethod
    def pot_table(joint: int) -> tuple[np.ndarray, np.ndarray]:
        """The linear interpolation table of one joint's potentiometer (3.5.1): ADC codes and
        the joint angles they read.  Two points, at the joint limits (0.25 V and 4.75 V)."""
        codes = np.array([0.25, 4.75]) / 5.0 * 255.0
        angles = np.array([puma560.Q_MIN[joint], puma560.Q_MAX[joint]])
        return codes, angles

    def pot_angle(self, i: int, code: int) -> float:
        """Joint ``i``'s angle (rad) as its 8-bit pot reading ``code`` tells it (coarse)."""
        codes, angles = self.pot_table(i % 6)
        return float(np.interp(code, codes, angles, left=angles[0], right=angles[1]))
