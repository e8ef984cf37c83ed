"""The McGill robot I/O board of one arm, simulated behind its registers (thesis appendix C).

What Kali sees is only the ``registers.IO_BOARD`` record; this module plays the hardware: the
power switch and brakes, the watchdog, the e-stop, the HCTL-2000 encoder counters with index
capture, the TLC532A pot ADC and the wrist sensor's gauge bank (``FtBank``).  How each behaves
at its registers: docs/internals/robots-hardware-plant.md; the controller's side of the same
bits is ``kali_daemons.hardware.mcgill``.

Unlike the real circuit, the board reads the watchdog's retrigger bit once a plant cycle, so a
level shorter than a cycle can go unseen: SIO holds each level two cycles
(``config.retrigger_hold_ticks``).  All times are the plant's simulated time, so lockstep runs
are deterministic.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..core.joints import ArmCopy, JointMap
from ..core.kernels import Kernel, channel_offsets
from ..hardware import ftsensor
from ..hardware.mcgill import registers
from ..hardware.mcgill.registers import (
    ADC_CHANNEL_MASK,
    ADC_DONE,
    ADC_START,
    CSR_ENABLE,
    CSR_INDEX_OFF,
    CSR_NO_DISABLE,
    CSR_RETRIGGER,
    CSR_TIMEOUT_ON,
    POWER_AMPS_ON,
    POWER_BRAKES_RELEASED,
    POWER_BUZZER,
    POWER_ESTOP,
    POWER_WATCHDOG_TRIPPED,
)
from ..robots import RobotType
from ..runtime.config import PlantConfig

TWO_PI = 2.0 * math.pi
COUNTER_MODULO = 4096
RANDOM_BLOCK = 6 * 512  # a gauge bank's normals drawn ahead for its kernel (FtBank.compiled)
POT_V_MIN, POT_V_MAX = 0.25, 4.75  # pot voltage at the joint limits (0-5 V ADC range)
ADC_CHANNELS = 11  # TLC532A inputs; channel 10 is its self-test reference (V/2)
ADC_SELF_TEST = 10


ADC_VOLTS, ADC_TOP = 5.0, 255  # the TLC532A: 8 bits over 0-5 V

# an I/O board's state, a row of int64 (IoBoardSim.state; csrc/plant.c's B_* in this order)
AMPS, BRAKES, TRIPPED, SWITCH_NS, ENABLE_SINCE, RETRIGGER_NS, PREV_CSR, PREV_ADC = range(8)
BOARD_STATE = 8
NEVER = np.iinfo(np.int64).min  # ENABLE_SINCE while the enable bit is not held


def pot_volts(q: float, lo: float, hi: float) -> float:
    """The potentiometer voltage of a joint at angle ``q`` (linear over the joint range)."""
    v = POT_V_MIN + (POT_V_MAX - POT_V_MIN) * (q - lo) / (hi - lo)
    return min(max(v, 0.0), ADC_VOLTS)


def adc_code(volts: float) -> int:
    """8-bit TLC532A conversion of 0-5 V (±1/2 LSB)."""
    return min(max(round(volts / ADC_VOLTS * ADC_TOP), 0), ADC_TOP)


class IoBoardSim:
    """One arm's I/O board: power, watchdog and pot ADC; ``update`` and ``convert`` once per
    plant cycle.  Joint j's pot is ADC channel j, for the arm's ``n_joints`` joints; the other
    inputs are unconnected.  The encoders of every board are counted together by
    ``EncoderBank``.

    Its state is one int64 row (``state``, fields ``AMPS`` .. ``PREV_ADC``): the plant's
    boards share one array of them, which ``boards_kernel`` steps compiled; ``update`` and
    ``convert`` are that kernel's reference, on the same row.
    """

    def __init__(
        self,
        regs: np.ndarray,
        cfg: PlantConfig,
        robot: RobotType,
        state: np.ndarray | None = None,
    ) -> None:
        self.regs = regs
        self.n_joints = n = robot.n_joints
        self.hold_ns = int(cfg.enable_hold_ms * 1e6)
        self.watchdog_ns = int(cfg.watchdog_ms * 1e6)
        self.brake_ns = int(cfg.brake_delay_ms * 1e6)
        self.lo, self.hi = robot.q_min, robot.q_max  # the pots span the joint range
        self.mid = self.lo + (self.hi - self.lo) * (2.5 - POT_V_MIN) / (POT_V_MAX - POT_V_MIN)
        self._above = np.zeros(n, dtype=bool)
        self._bits = 1 << np.arange(n)
        self.state = np.zeros(BOARD_STATE, np.int64) if state is None else state
        self.state[:] = 0
        self.state[ENABLE_SINCE] = NEVER
        self.state[PREV_CSR] = int(regs["csr"])

    @property
    def amps_on(self) -> bool:
        return bool(self.state[AMPS])

    @property
    def brakes_released(self) -> bool:
        return bool(self.state[BRAKES])

    @property
    def tripped(self) -> bool:
        return bool(self.state[TRIPPED])

    # ------------------------------------------------------------------ power and watchdog

    def update(self, now_ns: int) -> None:
        """Apply the command/status register and e-stop at plant time ``now_ns``."""
        r, s = self.regs, self.state
        r["scans"] += 1
        csr = int(r["csr"])
        prev = int(s[PREV_CSR])
        s[PREV_CSR] = csr
        estop = bool(r["estop"])
        if csr & CSR_TIMEOUT_ON:
            if not prev & CSR_TIMEOUT_ON:
                s[RETRIGGER_NS] = now_ns  # the timer starts when the mode is switched on
            if prev & CSR_RETRIGGER and not csr & CSR_RETRIGGER:
                s[RETRIGGER_NS] = now_ns
                s[TRIPPED] = 0
            elif now_ns - s[RETRIGGER_NS] > self.watchdog_ns:
                s[TRIPPED] = 1
        elif s[TRIPPED] and prev & CSR_RETRIGGER and not csr & CSR_RETRIGGER:
            s[TRIPPED] = 0
        disabled = not csr & CSR_NO_DISABLE or estop or s[TRIPPED]
        if csr & CSR_ENABLE:
            if s[ENABLE_SINCE] == NEVER or not prev & CSR_ENABLE:
                s[ENABLE_SINCE] = now_ns
        else:
            s[ENABLE_SINCE] = NEVER
        if disabled:
            s[ENABLE_SINCE] = NEVER
            self._set_amps(False, now_ns)
        elif s[ENABLE_SINCE] != NEVER and now_ns - s[ENABLE_SINCE] >= self.hold_ns:
            self._set_amps(True, now_ns)
        if s[BRAKES] != s[AMPS] and now_ns - s[SWITCH_NS] >= self.brake_ns:
            s[BRAKES] = s[AMPS]
        if csr & CSR_INDEX_OFF and r["index"]:
            r["index"] = 0  # disabling index capture clears the register
        power = (
            (POWER_AMPS_ON if s[AMPS] else 0)
            | (POWER_BRAKES_RELEASED if s[BRAKES] else 0)
            | (POWER_WATCHDOG_TRIPPED | POWER_BUZZER if s[TRIPPED] else 0)
            | (POWER_ESTOP if estop else 0)
        )
        r["power"] = power

    def _set_amps(self, on: bool, now_ns: int) -> None:
        s = self.state
        if on != bool(s[AMPS]):
            s[AMPS] = on
            s[SWITCH_NS] = now_ns

    # ------------------------------------------------------------------ potentiometers

    def convert(self, q: np.ndarray) -> None:
        """Serve the TLC532A for the arm's joint angles ``q`` (``n_joints``): a rising START
        converts the selected channel.  Inside the cycle."""
        r, s = self.regs, self.state
        ctrl = int(r["adc_control"])
        start = bool(ctrl & ADC_START)
        if start and not s[PREV_ADC]:
            ch = ctrl & ADC_CHANNEL_MASK
            if ch >= ADC_CHANNELS:
                r["clamped"] += 1
                ch = ADC_CHANNELS - 1
            if ch < self.n_joints:
                code = adc_code(pot_volts(float(q[ch]), float(self.lo[ch]), float(self.hi[ch])))
            elif ch == ADC_SELF_TEST:
                code = adc_code(ADC_VOLTS / 2)
            else:
                code = 0  # unconnected inputs
            r["adc_analog"] = ADC_DONE | code
        elif not start and s[PREV_ADC]:
            r["adc_analog"] = int(r["adc_analog"]) & registers.ADC_VALUE_MASK
        s[PREV_ADC] = int(start)
        # digital register: the channels above 2.5 V, i.e. past the middle of their range
        np.greater(q, self.mid, out=self._above)
        r["adc_digital"] = int(self._above @ self._bits)


def boards_kernel(
    boards: list[IoBoardSim],
    regs: np.ndarray,
    truth: np.ndarray,
    joints: JointMap,
    q: np.ndarray,
    enabled: np.ndarray,
    braked: np.ndarray,
) -> Kernel:
    """Every board's ``update`` and ``convert`` compiled (``csrc/plant.c``'s
    ``kali_boards_update``; ``.sibling("kali_boards_convert")`` and
    ``.sibling("kali_boards_truth")`` on the same block).  ``boards``: one per record of
    ``regs`` (IO_BOARD) and ``truth`` (ARM_TRUTH), their ``state`` rows of one C-ordered array;
    ``q``, ``enabled`` (float64: the motors' 1.0 / 0.0) and ``braked`` (bool) flat per joint of
    ``joints``.  Set ``args.now_ns`` before each update; it returns 1 when a brake changed.
    Outside the cycle."""
    state = boards[0].state.base
    assert state is not None and state.shape == (len(boards), BOARD_STATE), "one state array"
    assert all(b.state.base is state for b in boards) and state.flags.c_contiguous
    assert joints.counts == tuple(b.n_joints for b in boards) and len(regs) == len(boards)
    first = boards[0]  # the timings are the plant config's, every board's alike
    assert all(
        (b.hold_ns, b.watchdog_ns, b.brake_ns) == (first.hold_ns, first.watchdog_ns, first.brake_ns)
        for b in boards
    )
    base = np.ascontiguousarray(joints.base, dtype=np.int64)
    count = np.ascontiguousarray(joints.counts, dtype=np.int64)
    lo, hi, mid = (np.concatenate([getattr(b, f) for b in boards]) for f in ("lo", "hi", "mid"))
    arrays = {
        "state": state, "base": base, "count": count, "enabled": enabled, "braked": braked,
        "q": q, "lo": lo, "hi": hi, "mid": mid,
    }  # fmt: skip
    for name, a in arrays.items():
        assert a.flags.c_contiguous and a.dtype in (np.float64, np.int64, np.bool_), name
    return Kernel(
        "kali_boards_update",
        (regs, truth, *arrays.values()),
        n_arms=len(boards),
        **{f: regs[f] for f in ("csr", "estop", "power", "index", "adc_control")},
        **{f: regs[f] for f in ("adc_analog", "adc_digital", "clamped", "scans")},
        **{f: truth[f] for f in ("amps_on", "brakes_engaged", "watchdog_tripped")},
        truth_estop=truth["estop"],
        **{name: a.ctypes.data for name, a in arrays.items()},
        now_ns=0,
        hold_ns=first.hold_ns,
        watchdog_ns=first.watchdog_ns,
        brake_ns=first.brake_ns,
        never=NEVER,
        timeout_on=CSR_TIMEOUT_ON,
        retrigger=CSR_RETRIGGER,
        no_disable=CSR_NO_DISABLE,
        enable=CSR_ENABLE,
        index_off=CSR_INDEX_OFF,
        p_amps=POWER_AMPS_ON,
        p_brakes=POWER_BRAKES_RELEASED,
        p_tripped=POWER_WATCHDOG_TRIPPED | POWER_BUZZER,
        p_estop=POWER_ESTOP,
        adc_start=ADC_START,
        channel_mask=ADC_CHANNEL_MASK,
        adc_done=ADC_DONE,
        value_mask=registers.ADC_VALUE_MASK,
        channels=ADC_CHANNELS,
        self_test=ADC_SELF_TEST,
        pot_v_min=POT_V_MIN,
        pot_v_max=POT_V_MAX,
        adc_volts=ADC_VOLTS,
        adc_top=float(ADC_TOP),
    )


class EncoderBank:
    """The HCTL-2000 counters of every board (C.3), counted in one pass over all the cell's
    joints, numbered flat (``joints.JointMap``): arm ``k``'s joint ``j`` is flat index
    ``base[k] + j`` here and channel ``j`` of the arm's board.

    Each channel counts quadrature counts of its motor angle modulo 4096.  With index capture
    enabled on its board (CSR bit 4 low), passing the index pulse (once per motor revolution,
    at the motor angle ``phase``) resets the counter to 0 and sets the channel's bit in the
    index register.  ``sample`` runs once per plant cycle on preallocated buffers.  Channels
    beyond an arm's joint count are never written (they stay 0).
    """

    def __init__(
        self,
        regs: np.ndarray,
        types: list[RobotType],
        phase: np.ndarray,
        motor_angle: np.ndarray,
        joints: JointMap | None = None,
    ) -> None:
        """``regs``: the IO_BOARD records, one per arm of ``types``; ``phase`` and
        ``motor_angle``: flat per joint.  ``joints`` defaults to the map of ``types``'
        joint counts (the plant passes its config's)."""
        if joints is None:
            joints = JointMap(tuple(t.name for t in types), tuple(t.n_joints for t in types))
        assert joints.counts == tuple(t.n_joints for t in types), "joints disagree with types"
        assert len(regs) == joints.n_robots, "one IO_BOARD record per arm"
        self.joints = joints
        self.regs = regs  # IO_BOARD records, one per arm
        self.n_arms = joints.n_robots
        n = joints.total
        cpr = np.concatenate([np.asarray(t.drive.counts_per_rev, np.float64) for t in types])
        self.phase = np.asarray(phase, dtype=np.float64).reshape(n)  # index motor angle, rad
        self._counts_per_rad = cpr / TWO_PI
        self._index = regs["index"]
        self._csr = regs["csr"]
        self._raw = np.zeros(n, dtype=np.int64)
        self._count = np.zeros(n, dtype=np.int64)
        self._to_boards = ArmCopy(joints, self._count, regs["encoder"])
        self._ref = np.zeros(n, dtype=np.int64)
        self._rev = np.zeros(n)
        self._f = np.zeros(n)
        self._g = np.zeros(n)
        self._crossed = np.zeros(n, dtype=bool)
        for k in range(self.n_arms):
            self.power_on(k, motor_angle[joints.span(k)])

    def power_on(self, k: int, motor_angle: np.ndarray) -> None:
        """Arm ``k``'s counters read 0 at motor angles ``motor_angle`` (its joints; power-on,
        set-up)."""
        sl = self.joints.span(k)
        self._ref[sl] = np.floor(motor_angle * self._counts_per_rad[sl]).astype(np.int64)
        self._rev[sl] = np.floor((motor_angle - self.phase[sl]) / TWO_PI)
        self._count[sl] = 0
        self.regs["encoder"][k] = 0
        self._index[k] = 0

    def compiled(self, motor_angle: np.ndarray) -> Kernel:
        """``sample(motor_angle)`` compiled (``csrc/plant.c``'s ``kali_encoders``): each call of
        the kernel counts the angles now in ``motor_angle`` (flat float64, never moving) and
        returns the indexes captured.  Outside the cycle."""
        j = self.joints
        enc = self.regs["encoder"]
        robot_of = np.ascontiguousarray(j.robot_of, dtype=np.int64)
        joint_of = np.ascontiguousarray(j.joint_of, dtype=np.int64)
        offsets = channel_offsets(enc, robot_of, joint_of)
        arrays = {
            "angle": motor_angle, "cpr": self._counts_per_rad, "phase": self.phase,
            "ref": self._ref, "count": self._count, "rev": self._rev, "robot_of": robot_of,
            "joint_of": joint_of, "enc_off": offsets,
        }  # fmt: skip
        for name, a in arrays.items():
            assert a.shape == (j.total,) and a.flags.c_contiguous, f"encoders: {name} {a.shape}"
            assert a.dtype in (np.float64, np.int64), f"encoders: {name} {a.dtype}"
        return Kernel(
            "kali_encoders",
            (self.regs, *arrays.values()),
            n=j.total,
            encoders=enc.ctypes.data,
            csr=self._csr,
            index=self._index,
            index_off=CSR_INDEX_OFF,
            modulo=COUNTER_MODULO,
            two_pi=TWO_PI,
            **{name: a.ctypes.data for name, a in arrays.items()},
        )

    def sample(self, motor_angle: np.ndarray) -> None:
        """Count the motor angles of every joint (flat) into the counter registers; capture
        indexes (``kali_encoders``' reference: the plant runs ``compiled``).  Inside the
        cycle."""
        f, rev = self._f, self._g
        np.multiply(motor_angle, self._counts_per_rad, out=f)
        np.floor(f, out=f)
        np.copyto(self._raw, f, casting="unsafe")
        np.subtract(motor_angle, self.phase, out=rev)
        np.divide(rev, TWO_PI, out=rev)
        np.floor(rev, out=rev)
        np.not_equal(rev, self._rev, out=self._crossed)
        if self._crossed.any():  # rare: a few times per motor revolution
            robot_of, joint_of = self.joints.robot_of, self.joints.joint_of
            for j in np.flatnonzero(self._crossed):
                k, ch = int(robot_of[j]), int(joint_of[j])
                if int(self._csr[k]) & CSR_INDEX_OFF:
                    continue  # capture disabled: the counter just keeps counting
                passed = max(rev[j], self._rev[j])  # the revolution whose index was passed
                at = (self.phase[j] + TWO_PI * passed) * self._counts_per_rad[j]
                self._ref[j] = math.floor(at)
                self._index[k] |= 1 << ch
        np.copyto(self._rev, rev)
        np.subtract(self._raw, self._ref, out=self._count)
        np.mod(self._count, COUNTER_MODULO, out=self._count)
        self._to_boards.to_arms()


class FtBank:
    """One arm's wrist force/torque sensor and the I/O board's gauge ADC bank behind
    ``ft_gauge``/``ft_control``/``ft_status`` (``kali_daemons.hardware.ftsensor``): the sensor's six
    bridges produce ``v = C⁻¹ (w + noise) + offset`` for the wrench ``w`` the tool exerts on
    it, and a new request (``FT_REQUEST`` with a sequence number not served yet) samples them
    all at once, at the cycle it is seen, into signed 16-bit codes clipped at the rails.

    The offsets are the sensor's own (drawn once per sensor, within the sheet's
    ``offset_v``) and walk with the sheet's thermal drift every cycle; noise and drift come
    from a generator seeded per sensor, so a lockstep run is the same every time.
    """

    def __init__(self, regs: np.ndarray, sheet: ftsensor.FtSheet, seed: int, dt_s: float) -> None:
        self.regs = regs  # this arm's IO_BOARD record (0-d)
        self.sheet = sheet
        self._rng = np.random.Generator(np.random.PCG64(seed))
        self.offset = self._rng.uniform(-sheet.offset_v, sheet.offset_v, ftsensor.GAUGES)
        self._drift = sheet.drift_v_per_sqrt_s * math.sqrt(dt_s)
        self._gauges = np.ascontiguousarray(sheet.gauges)
        self._noise_sd = np.asarray(sheet.noise, dtype=np.float64)
        self._n = np.zeros(ftsensor.GAUGES)
        self._w = np.zeros(ftsensor.GAUGES)
        self._v = np.zeros(ftsensor.GAUGES)
        self._codes = regs["ft_gauge"]
        self._control, self._status = regs["ft_control"], regs["ft_status"]  # viewed once
        self._served = -1  # the last sequence number sampled
        self._status[...] = ftsensor.FT_PRESENT
        self._normals = np.zeros(0)  # drawn ahead for the kernel (compiled)

    def cycle(self, wrench: np.ndarray) -> None:
        """One plant cycle: the offsets drift; a new request samples ``wrench`` (the tool on
        the sensor, sensor frame).  Inside the cycle.  The reference of ``compiled``."""
        assert not len(self._normals), "this bank's generator is drawn ahead for its kernel"
        rng, n = self._rng, self._n
        rng.standard_normal(out=n)
        n *= self._drift
        self.offset += n
        ctrl = int(self._control)
        seq = ctrl & ftsensor.FT_SEQ_MASK
        if not ctrl & ftsensor.FT_REQUEST or seq == self._served:
            return
        self._served = seq
        rng.standard_normal(out=n)
        np.multiply(n, self._noise_sd, out=n)
        np.add(n, wrench, out=self._w)
        np.matmul(self._gauges, self._w, out=self._v)
        np.add(self._v, self.offset, out=self._v)
        np.divide(self._v, ftsensor.VOLTS_PER_CODE, out=self._v)
        np.rint(self._v, out=self._v)
        np.clip(self._v, -ftsensor.FT_RAIL - 1, ftsensor.FT_RAIL, out=self._v)
        np.copyto(self._codes, self._v, casting="unsafe")
        self._status[...] = ftsensor.FT_READY | ftsensor.FT_PRESENT | seq  # last

    def compiled(self, wrench: np.ndarray) -> Callable[[], None]:
        """``cycle(wrench)`` compiled (``csrc/plant.c``'s ``kali_ft_bank``): each call of the
        result is one cycle on the wrench now in ``wrench`` (six float64, contiguous, never
        moving).  The generator's normals are drawn ``RANDOM_BLOCK`` ahead (the same numbers in
        the same order as ``cycle`` draws them) and more are drawn, outside the kernel, when
        it says it is near the end: a few µs once every few hundred cycles.  From here on the
        bank is stepped only this way.  Outside the cycle."""
        assert wrench.shape == (ftsensor.GAUGES,) and wrench.flags.c_contiguous
        assert wrench.dtype == np.float64
        block = self._normals = np.empty(RANDOM_BLOCK)
        self._rng.standard_normal(out=block)
        g = ftsensor.GAUGES
        head, rest, tail = block[:g], block[g:], block[-g:]
        arrays = (block, self.offset, self._gauges, self._noise_sd, wrench)
        kernel = Kernel(
            "kali_ft_bank",
            (self.regs, *arrays),
            normals=block.ctypes.data,
            size=RANDOM_BLOCK,
            at=0,
            offset=self.offset.ctypes.data,
            drift=self._drift,
            gauges=self._gauges.ctypes.data,
            noise_sd=self._noise_sd.ctypes.data,
            wrench=wrench.ctypes.data,
            codes=self._codes.ctypes.data,
            control=self._control.ctypes.data,
            status=self._status.ctypes.data,
            served=self._served,
            seq_mask=ftsensor.FT_SEQ_MASK,
            request=ftsensor.FT_REQUEST,
            ready=ftsensor.FT_READY | ftsensor.FT_PRESENT,
            volts_per_code=ftsensor.VOLTS_PER_CODE,
            rail=float(ftsensor.FT_RAIL),
        )
        args, rng = kernel.args, self._rng

        def step() -> None:
            if kernel():  # near the block's end: the draws left to the front, then more
                if args.at < RANDOM_BLOCK:  # six left (draws are taken six at a time)
                    np.copyto(head, tail)
                    rng.standard_normal(out=rest)
                else:
                    rng.standard_normal(out=block)
                args.at = 0

        return step
