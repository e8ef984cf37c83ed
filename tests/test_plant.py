"""The plant behind its registers: power switch, watchdog, e-stop, brakes, motors, encoders."""

from __future__ import annotations

import itertools
import math
import time
from collections.abc import Callable, Iterator

import mujoco
import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.hardware.mcgill import PotReader, registers
from kali_daemons.hardware.mcgill.boards import retrigger_bit, retrigger_hold_ticks
from kali_daemons.hardware.mcgill.registers import (
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
from kali_daemons.plant.board import (
    BOARD_STATE,
    EncoderBank,
    IoBoardSim,
    adc_code,
    boards_kernel,
    pot_volts,
)
from kali_daemons.plant.motor import Drive, MotorBank, drive_reference
from kali_daemons.plant.sim import PlantSim
from kali_daemons.robots import puma560
from kali_daemons.robots.model import build_world
from kali_daemons.runtime.instance import Instance
from kali_daemons.wallclock import step_kali_clock, stop_kali_clock

from .conftest import boards_of, make_config
from .test_launcher import kalictl

CFG = make_config("plant")
MS = 1_000_000
N = puma560.ROBOT.n_joints  # the PUMA's joints: channels 0..N-1 of its boards
LEFT = CFG.joints.span(0)  # the left arm's joints in the plant's flat arrays


@pytest.fixture
def plant(arena: Arena) -> Iterator[PlantSim]:
    """A two-arm plant on a fresh arena, stepped in-process (1 ms per cycle)."""
    yield PlantSim(CFG, arena)


def run_ms(sim: PlantSim, ms: int, each: Callable[[int], None] | None = None) -> None:
    for t in range(ms):
        if each is not None:
            each(t)
        sim.cycle()


def enable(sim: PlantSim, k: int = 0, csr_extra: int = 0) -> None:
    """The thesis's enable sequence: disable bit high, enable bit high 15 ms, then low."""
    regs = sim.boards[k].regs
    regs["csr"] = CSR_NO_DISABLE | CSR_ENABLE | csr_extra
    run_ms(sim, 16)
    regs["csr"] = CSR_NO_DISABLE | csr_extra


def power(sim: PlantSim, k: int = 0) -> int:
    return int(sim.boards[k].regs["power"])


# ---------------------------------------------------------------------- power switch


def test_power_on_needs_the_enable_bit_held_15_ms(plant: PlantSim) -> None:
    regs = plant.boards[0].regs
    assert power(plant) & POWER_AMPS_ON == 0
    regs["csr"] = CSR_ENABLE  # disable bit low: enables are overridden
    run_ms(plant, 30)
    assert power(plant) & POWER_AMPS_ON == 0
    regs["csr"] = CSR_NO_DISABLE | CSR_ENABLE
    run_ms(plant, 10)
    regs["csr"] = CSR_NO_DISABLE  # released after 10 ms: the relay did not switch
    run_ms(plant, 5)
    assert power(plant) & POWER_AMPS_ON == 0
    enable(plant)
    assert power(plant) & POWER_AMPS_ON
    assert power(plant) & POWER_BRAKES_RELEASED == 0  # brakes still hold for ~50 ms
    run_ms(plant, 50)
    assert power(plant) & POWER_BRAKES_RELEASED
    assert power(plant, 1) & POWER_AMPS_ON == 0  # the other arm's board is independent
    regs["csr"] = 0  # disable bit low: off at once
    run_ms(plant, 1)
    assert power(plant) & POWER_AMPS_ON == 0


def test_watchdog_trips_after_20_ms_then_brakes(plant: PlantSim) -> None:
    regs = plant.boards[0].regs
    on = CSR_TIMEOUT_ON

    def retrigger(t: int) -> None:
        regs["csr"] = CSR_NO_DISABLE | on | (CSR_RETRIGGER if t % 2 == 0 else 0)

    enable(plant, csr_extra=on)
    run_ms(plant, 200, retrigger)  # retriggered every 2 ms: stays on
    assert power(plant) & POWER_AMPS_ON and power(plant) & POWER_BRAKES_RELEASED
    regs["csr"] = CSR_NO_DISABLE | on  # the controller dies: no more retriggers
    t_off = None
    for t in range(120):
        plant.cycle()
        if t_off is None and not power(plant) & POWER_AMPS_ON:
            t_off = t
            assert power(plant) & POWER_WATCHDOG_TRIPPED
            assert power(plant) & POWER_BRAKES_RELEASED  # brakes still open: ~50 ms solenoid
            assert np.all(plant.current[LEFT] == 0.0)
        if t_off is not None and not power(plant) & POWER_BRAKES_RELEASED:
            assert 48 <= t - t_off <= 52
            break
    else:
        pytest.fail("brakes never engaged")
    assert 19 <= t_off <= 22
    regs["csr"] = CSR_NO_DISABLE | on | CSR_ENABLE  # enabling again is refused while tripped
    run_ms(plant, 20)
    assert power(plant) & POWER_AMPS_ON == 0
    run_ms(plant, 2, retrigger)  # a retrigger clears the trip; then enable works
    enable(plant, csr_extra=on)
    assert power(plant) & POWER_AMPS_ON


@pytest.mark.parametrize("hold", [None, 1])
def test_sios_retrigger_reaches_a_board_that_reads_as_sio_writes(
    plant: PlantSim, hold: int | None
) -> None:
    """The plant reads a board once a period and SIO writes it once a servo tick: when the
    plant reads as SIO writes, each read finds this tick's CSR or the last tick's.  The worst
    order (this tick's, then the last's, in turn) hides every falling edge of a bit toggled
    each tick (``hold`` 1, as SIO did): the watchdog trips with SIO on time, as in a soak.
    SIO's levels (``retrigger_hold_ticks``) last two reads: the board sees every one."""
    ticks = hold or retrigger_hold_ticks(CFG.clock.servo_period_ms, CFG.process("plant").period_ms)
    regs = plant.boards[0].regs
    on = CSR_NO_DISABLE | CSR_TIMEOUT_ON
    enable(plant, csr_extra=CSR_TIMEOUT_ON)
    run_ms(plant, 4, lambda t: regs.__setitem__("csr", on | retrigger_bit(t, 1)))
    assert power(plant) & POWER_AMPS_ON
    for t in range(1000):  # read t sees SIO's tick t, or t - 1
        regs["csr"] = on | retrigger_bit(t - t % 2, ticks)
        plant.cycle()
    tripped = power(plant) & POWER_WATCHDOG_TRIPPED
    assert bool(tripped) == (hold == 1), f"power 0x{power(plant):02x}"


def test_estop_cuts_power_and_blocks_enables(plant: PlantSim) -> None:
    regs = plant.boards[1].regs
    enable(plant, 1)
    run_ms(plant, 60)
    regs["estop"] = 1
    plant.cycle()
    assert power(plant, 1) & POWER_ESTOP and not power(plant, 1) & POWER_AMPS_ON
    run_ms(plant, 51)
    assert not power(plant, 1) & POWER_BRAKES_RELEASED
    enable(plant, 1)
    assert not power(plant, 1) & POWER_AMPS_ON
    regs["estop"] = 0
    enable(plant, 1)
    assert power(plant, 1) & POWER_AMPS_ON


# ---------------------------------------------------------------------- the arm itself


def test_zero_dac_brakes_released_the_arm_falls_brakes_hold(plant: PlantSim) -> None:
    q0 = plant.q[LEFT].copy()
    run_ms(plant, 1000)  # power off: brakes hold
    assert np.max(np.abs(plant.q[LEFT] - q0)) < 2e-3
    enable(plant)
    run_ms(plant, 49)  # brakes still engaged after the enable
    assert np.max(np.abs(plant.q[LEFT] - q0)) < 2e-3
    run_ms(plant, 400)  # zero current, brakes released: gravity wins over friction
    assert abs(plant.q[1] - q0[1]) > 0.1
    plant.boards[0].regs["csr"] = 0  # power off: the brakes catch it ~50 ms later
    run_ms(plant, 40)
    assert np.any(np.abs(plant.qd[LEFT]) > 0.05)  # still falling while the solenoids move
    run_ms(plant, 200)
    assert np.all(np.abs(plant.qd[LEFT]) < 1e-3)  # stopped by the brakes
    q1 = plant.q[LEFT].copy()
    run_ms(plant, 1000)
    assert np.max(np.abs(plant.q[LEFT] - q1)) < 2e-3


def test_dac_drives_the_joint_with_the_right_sign(plant: PlantSim) -> None:
    enable(plant)
    run_ms(plant, 60)
    j = 0  # waist: no gravity, so the sign of the motion is the sign of the torque
    q0 = plant.q[j]
    plant.dac[0]["code"][j] = registers.DAC_ZERO + 400  # +1.95 V → +4.9 A
    run_ms(plant, 100)
    expected = math.copysign(1.0, puma560.G[j])  # joint torque = G·Kt·i
    assert (plant.q[j] - q0) * expected > 0.01
    assert plant.current[j] == pytest.approx(2.5 * 400 * 10 / 2048, rel=0.02)


def test_dac_codes_beyond_12_bits_are_clamped_and_counted(plant: PlantSim) -> None:
    plant.dac[0]["code"][3] = 5000
    plant.cycle()
    assert int(plant.dac[0]["clamped"]) == 1
    assert plant.volts[3] == pytest.approx(4095 / 2048 * 10 - 10)


def test_current_loop_is_first_order_at_500_hz(plant: PlantSim) -> None:
    enable(plant)  # brakes still hold for ~50 ms: the joints stay put while we watch
    plant.dac[0]["code"][:N] = registers.DAC_ZERO + 82  # 0.4 V → 1 A, below every limit
    plant.cycle()
    tau = 1.0 / (2 * math.pi * 500)
    expected = 2.5 * 82 * 10 / 2048 * (1.0 - math.exp(-0.001 / tau))  # one 1 ms cycle
    assert plant.current[LEFT] == pytest.approx(np.full(N, expected), rel=1e-6)
    assert plant.torque[LEFT] == pytest.approx(
        np.asarray(puma560.G) * np.asarray(puma560.KT) * plant.current[LEFT]
    )


def test_current_saturates_at_the_motor_peak(plant: PlantSim) -> None:
    enable(plant)
    plant.dac[0]["code"][:N] = 4095  # +10 V: 25 A asked for
    run_ms(plant, 10)  # the brakes still hold: no speed, no back-EMF
    assert np.allclose(plant.current[LEFT], puma560.MAX_CURRENT)
    plant.boards[0].regs["csr"] = 0  # power off
    plant.cycle()
    assert np.all(plant.current[LEFT] == 0.0)  # a disabled amplifier cuts its current at once


def test_back_emf_limits_the_current_at_speed() -> None:
    bank = MotorBank([puma560.ROBOT])
    bank.enabled[:] = 1.0
    omega_m = np.array([140.0, 140.0, 140.0, 400.0, 400.0, 400.0])  # motor speeds, rad/s
    qd = omega_m / np.asarray(puma560.G)
    bank.cycle(np.full(N, 10.0), qd)
    kt, r = np.asarray(puma560.KT), np.asarray(puma560.R_ARMATURE)
    limit = (puma560.BUS_VOLTAGE - kt * omega_m) / r
    assert np.all(limit < np.asarray(puma560.MAX_CURRENT))  # the voltage, not the peak, binds
    assert bank.range[:, 1] == pytest.approx(limit)
    assert bank.ctrl == pytest.approx(limit)
    bank.cycle(np.full(N, -10.0), qd)  # braking against the motion gets the full peak
    assert bank.ctrl == pytest.approx(-np.asarray(puma560.MAX_CURRENT))
    bank.enabled[:] = 0.0
    bank.cycle(np.full(N, 10.0), qd)
    assert np.all(bank.range == 0.0) and np.all(bank.ctrl == 0.0)


def test_back_emf_limits_the_current_in_the_plant(plant: PlantSim) -> None:
    enable(plant)
    run_ms(plant, 60)  # brakes released
    j, omega_m = 0, 140.0
    plant.data.qvel[plant.world.dof_adr[0][j]] = omega_m / puma560.G[j]  # spinning fast
    plant._read_joints()
    plant.dac[0]["code"][j] = 4095
    run_ms(plant, 2)
    w = puma560.G[j] * plant.qd[j]
    limit = (puma560.BUS_VOLTAGE - puma560.KT[j] * w) / puma560.R_ARMATURE[j]
    assert limit < puma560.MAX_CURRENT[j]
    assert plant.current[j] == pytest.approx(limit, rel=0.05)


# ---------------------------------------------------------------------- encoders and pots


def _board(arena: Arena, phase: float = 0.3) -> tuple[IoBoardSim, EncoderBank, np.ndarray]:
    rack = arena.record(registers.KEY_BOARDS, registers.IO_BOARD, 1)
    regs = rack[0:1].reshape(())
    board = IoBoardSim(regs, CFG.plant, puma560.ROBOT)
    return board, EncoderBank(rack, [puma560.ROBOT], np.full(N, phase), np.zeros(N)), regs


def test_encoder_counts_follow_motor_angle_wrap_and_index_reset(arena: Arena) -> None:
    board, encoders, regs = _board(arena)
    cpr = np.asarray(puma560.COUNTS_PER_MOTOR_REV, dtype=float)
    regs["csr"] = CSR_INDEX_OFF  # capture off: a free-running 12-bit counter
    angles = np.linspace(0, 12 * math.pi, 3000)  # six motor revolutions, forward
    for a in angles:
        encoders.sample(np.full(N, a))
        expected = np.floor(a / (2 * math.pi) * cpr).astype(int) % 4096
        assert list(regs["encoder"][:N]) == list(expected)
    assert int(regs["index"]) == 0
    for a in angles[::-1]:  # and back: counts go down, wrapping below 0 to 4095
        encoders.sample(np.full(N, a - 12 * math.pi))
    assert list(regs["encoder"][:N]) == list(np.floor(-12 * math.pi / (2 * math.pi) * cpr) % 4096)
    # capture on: passing the index pulse (motor angle 0.3 rad + 2πk) resets the counter
    encoders.sample(np.full(N, 0.0))
    regs["csr"] = 0
    encoders.sample(np.full(N, 0.29))
    assert int(regs["index"]) == 0
    encoders.sample(np.full(N, 0.31))
    assert int(regs["index"]) == (1 << N) - 1
    at_index = np.floor(0.3 / (2 * math.pi) * cpr)
    expected = (np.floor(0.31 / (2 * math.pi) * cpr) - at_index) % 4096
    assert list(regs["encoder"][:N]) == list(expected.astype(int))
    regs["csr"] = CSR_INDEX_OFF  # disabling capture clears the register
    board.update(0)
    assert int(regs["index"]) == 0


def _convert(board: IoBoardSim, regs: np.ndarray, q: np.ndarray, ch: int) -> int:
    regs["adc_control"] = ADC_START | ch
    board.convert(q)
    value = int(regs["adc_analog"])
    assert value & ADC_DONE
    regs["adc_control"] = 0
    board.convert(q)
    assert not int(regs["adc_analog"]) & ADC_DONE
    return value & 0xFF


def test_sio_reads_every_pot_right_when_the_board_falls_behind(arena: Arena) -> None:
    """SIO's pot reader (thesis C.5) against the board: in real time the plant keeps its own
    time, so between two of SIO's ticks it may run once, twice or not at all.  Whatever the
    interleaving, each channel's code is that pot's, never the previous channel's."""
    board, _, regs = _board(arena)
    q = np.radians([-120.0, 200.0, -200.0, 150.0, -80.0, 250.0])  # six distinct pot codes
    want = [adc_code(pot_volts(float(q[j]), puma560.Q_MIN[j], puma560.Q_MAX[j])) for j in range(N)]
    assert len(set(want)) == N
    rng = np.random.default_rng(3)
    for _ in range(50):
        reader = PotReader(regs["adc_control"], regs["adc_analog"], N)  # 0-d views, as SIO's
        reader.restart()
        for _tick in range(200):
            if reader.poll():
                break
            for _ in range(int(rng.choice([0, 0, 1, 1, 2]))):  # board cycles this tick
                board.convert(q)
        assert reader.poll(), "every channel was read"
        assert reader.codes == want


def test_potentiometers_are_monotonic_8_bit_and_tell_index_pulses_apart(arena: Arena) -> None:
    board, _, regs = _board(arena)
    lo, hi = puma560.Q_MIN, puma560.Q_MAX
    for j in range(N):
        qs = np.linspace(lo[j], hi[j], 400)
        codes = []
        for qj in qs:
            q = np.zeros(N)
            q[j] = qj
            codes.append(_convert(board, regs, q, j))
        assert all(b >= a for a, b in itertools.pairwise(codes))
        assert min(codes) >= 0 and max(codes) <= 255 and max(codes) - min(codes) > 200
        spacing = 2 * math.pi / abs(puma560.G[j])  # joint angle between index pulses
        span = (hi[j] - lo[j]) / spacing
        assert (max(codes) - min(codes)) / span >= 2.0, f"joint {j + 1}: pot too coarse"
    assert _convert(board, regs, np.zeros(N), 10) == adc_code(2.5)  # self-test reference
    regs["adc_control"] = ADC_START | 15  # beyond the 11 inputs: clamped and counted
    board.convert(np.zeros(N))
    assert int(regs["clamped"]) == 1
    assert pot_volts(lo[0], lo[0], hi[0]) == pytest.approx(0.25)


# ---------------------------------------------------------------------- a mixed cell

MIXED = make_config("plant-mixed", {r"^(  - \{name: right, +)model: puma560": r"\1model: panda"})


def _counts(motor_angle: np.ndarray, at_zero: np.ndarray, cpr: np.ndarray) -> np.ndarray:
    """What a free-running HCTL-2000 reads: counts since ``at_zero``, modulo 4096."""
    per_rad = cpr / (2 * math.pi)
    return (np.floor(motor_angle * per_rad) - np.floor(at_zero * per_rad)) % 4096


def test_a_puma_and_a_panda_keep_their_joints_on_their_own_channels(arena: Arena) -> None:
    """A PUMA 560 (6 joints) and a Panda (7) in one plant: 13 joints flat in the plant and in
    JOINT_TRUTH, each arm's joint j on channel j of its own boards, channels past an arm's
    joint count untouched.  Amplifiers off, brakes on; the arms are moved by hand."""
    joints = MIXED.joints
    assert joints.counts == (6, 7) and joints.total == 13
    sim = PlantSim(MIXED, arena)
    types = [r.type for r in MIXED.robots]
    truth = arena.existing(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, joints.total)
    np.testing.assert_array_equal(truth["q"], np.concatenate([t.q_home for t in types]))
    at_zero = truth["motor_angle"].copy()  # where each counter was powered on
    # every DAC channel of both boards gets a code; only the arms' joints' channels are read
    codes = registers.DAC_ZERO + 100 * np.arange(1, registers.DAC_CHANNELS + 1)
    for k, count in enumerate(joints.counts):
        sim.dac[k]["code"] = codes
        sim.dac[k]["code"][count:] = 5000  # beyond 12 bits, but on no joint: never clamped
        sim.boards[k].regs["csr"] = CSR_INDEX_OFF  # amplifiers off; counters free-running
    # by hand, every joint a little off its home angle, each by its own amount
    for k, t in enumerate(types):
        moved = t.q_home + 0.01 * np.arange(1, t.n_joints + 1) * (1 if k == 0 else -1)
        sim.data.qpos[sim.world.qpos_adr[k]] = moved
    run_ms(sim, 50)
    assert len(truth) == joints.total
    for k, (robot, t) in enumerate(zip(MIXED.robots, types, strict=True)):
        n, span, board = t.n_joints, joints.span(k), sim.boards[k].regs
        q = truth["q"][span]
        np.testing.assert_array_equal(q, sim.data.qpos[sim.world.qpos_adr[k]])
        moved = t.q_home + 0.01 * np.arange(1, n + 1) * (1 if k == 0 else -1)
        assert np.abs(q - moved).max() < 1e-4, f"{robot.name}: the brakes hold"
        np.testing.assert_array_equal(truth["motor_angle"][span], t.drive.gear * q)
        assert not truth["current"][span].any() and not truth["torque"][span].any()
        arm = sim.truth[k]
        assert int(arm["brakes_engaged"]) == 1 and int(arm["amps_on"]) == 0
        assert int(board["power"]) & (POWER_AMPS_ON | POWER_BRAKES_RELEASED) == 0
        cpr = np.asarray(t.drive.counts_per_rev, dtype=float)
        want = _counts(truth["motor_angle"][span], at_zero[span], cpr)
        assert want.min() > 0, "every joint moved by counts"
        assert list(board["encoder"][:n]) == list(want.astype(int)), robot.name
        assert not board["encoder"][n:].any(), f"{robot.name}: channels {n}.. stay 0"
        assert int(board["index"]) == 0
        np.testing.assert_allclose(sim.volts[span], (codes[:n] - registers.DAC_ZERO) * 10 / 2048)
        assert int(sim.dac[k]["clamped"]) == 0
        # the pots: channel j is joint j of this arm; past the arm's joints, unconnected
        for ch in range(registers.BOARD_CHANNELS):
            got = _convert(sim.boards[k], board, q, ch)
            pot = adc_code(pot_volts(float(q[ch]), t.q_min[ch], t.q_max[ch])) if ch < n else 0
            assert got == pot, f"{robot.name} channel {ch}"
        assert int(board["adc_digital"]) >> n == 0
    # an index pulse on the Panda's joint 7 is captured on channel 6 of the right board only
    right, j = 1, 6
    i = joints.index(right, j)
    gear = float(types[right].drive.gear[j])
    phase = float(MIXED.robots[right].index_phases[j])
    board = sim.boards[right].regs
    for regs in (sim.boards[0].regs, board):
        regs["csr"] = 0  # capture on (still disabled: no amplifiers)
    run_ms(sim, 1)
    around = 2 * math.pi * math.floor(sim.motor_angle[i] / (2 * math.pi)) + phase
    for motor in (around - 0.02, around + 0.02):
        sim.data.qpos[sim.world.qpos_adr[right][j]] = motor / gear
        run_ms(sim, 1)
    assert int(board["index"]) == 1 << j
    assert int(sim.boards[0].regs["index"]) == 0
    cpr = float(types[right].drive.counts_per_rev[j])
    after = math.floor((around + 0.02) * cpr / (2 * math.pi)) - math.floor(
        around * cpr / (2 * math.pi)
    )
    assert int(board["encoder"][j]) == after % 4096
    assert not board["encoder"][7:].any()


# ---------------------------------------------------------------------- as a process


def test_plant_steps_with_the_clock_in_lockstep(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        truth = inst.arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
        t0 = int(truth["sim_time_ns"])
        step_kali_clock(inst, 100)
        assert int(truth["sim_time_ns"]) - t0 == 100 * MS


@pytest.mark.serial
def test_plant_keeps_running_when_kali_halts(kali: Callable[..., str]) -> None:
    name = kali(lockstep=False)
    with Instance.attach(name) as inst:
        stop_kali_clock(inst)
        truth = inst.arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)
        t0 = int(truth["ticks"])
        time.sleep(0.3)
        assert int(truth["ticks"]) > t0 + 200  # its own clock, about 1 kHz


def test_kalictl_estop_presses_the_button_and_halts(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    r = kalictl("-i", name, "estop", "left")
    assert r.returncode == 0 and "e-stop pressed: left" in r.stdout
    with Instance.attach(name) as inst:
        board = boards_of(inst)[inst.robot_index("left")]
        assert int(board["estop"]) == 1
        assert "ESTOP in kalictl" in inst.fault_text()
        inst.clear_fault()
        step_kali_clock(inst, 2)
        assert int(board["power"]) & POWER_ESTOP
    r = kalictl("-i", name, "estop", "--release")
    assert r.returncode == 0 and "released: left, right" in r.stdout
    r = kalictl("-i", name, "estop", "nosuch")
    assert r.returncode == 1 and "no robot 'nosuch'" in r.stderr


# ---------------------------------------------------------------------- cooperative grasp

# Joint angles (each arm in its own base frame) that put the flange on its grasp site of the
# bar, found by the model tests (tests/test_model.py).
GRASP_Q = np.radians([19.939, 58.398, -210.022, 0.0, -28.376, 19.939])


def weld_rows(plant: PlantSim, k: int) -> np.ndarray:
    """Arm ``k``'s weld force and torque found the long way: its rows searched by type and
    equality id among all of MuJoCo's constraint rows (empty when it does not hold)."""
    d = plant.data
    rows = np.flatnonzero(
        (d.efc_type[: d.nefc] == mujoco.mjtConstraint.mjCNSTR_EQUALITY)
        & np.isin(d.efc_id[: d.nefc], plant.world.weld[k])
    )
    return d.efc_force[rows]


def test_two_arms_grasp_the_bar_and_carry_real_internal_forces(plant: PlantSim) -> None:
    """The welds carry the bar, and the truth's grasp wrenches are each weld's own rows."""
    for k in range(2):
        plant.place_arm(k, GRASP_Q)
        assert plant.nearest_grasp(k)[1] < 0.005
    bar = plant.object_truth["pose"][0]
    z0 = float(bar[2])
    plant.boards[0].regs["gripper"] = 1
    plant.boards[1].regs["gripper"] = 1
    run_ms(plant, 5)
    assert all(int(t["grasped"]) for t in plant.truth)
    assert [int(t["held"]) for t in plant.truth] == [0, 0]  # the scene's first free object
    # the left arm's amplifiers come on and its brakes open: the arm now hangs on the bar,
    # which the braked right arm holds; its joint-2 motor pushes one way, then the other
    enable(plant, 0)
    run_ms(plant, 60)
    pushes = {}
    for sign in (+1, -1):
        plant.dac[0]["code"][1] = registers.DAC_ZERO + sign * 300
        run_ms(plant, 100)
        pushes[sign] = float(plant.world_truth["internal_force"])
        for k, t in enumerate(plant.truth):
            assert np.linalg.norm(t["grasp_wrench"][:3]) > 1.0  # both welds carry load
            np.testing.assert_array_equal(t["grasp_wrench"], weld_rows(plant, k))
    assert abs(pushes[+1] - pushes[-1]) > 10.0, pushes  # the squeeze follows the motor
    assert abs(float(bar[2]) - z0) < 0.02  # the bar is held
    plant.boards[0].regs["gripper"] = 0  # letting go releases the weld
    run_ms(plant, 2)
    assert not int(plant.truth[0]["grasped"]) and int(plant.truth[1]["grasped"])
    assert weld_rows(plant, 0).size == 0 and not plant.truth[0]["grasp_wrench"].any()
    np.testing.assert_array_equal(plant.truth[1]["grasp_wrench"], weld_rows(plant, 1))
    assert float(plant.world_truth["internal_force"]) == 0.0  # one grasp: no squeeze


def test_internal_force_is_positive_for_a_squeeze(plant: PlantSim) -> None:
    """WORLD_TRUTH.internal_force's sign: the left arm hanging on the bar (amplifiers on at
    zero, brakes open) that the braked right arm holds, a push on the left tool towards the
    right arm (+x) squeezes the bar, one away from it stretches it."""
    for k in range(2):
        plant.place_arm(k, GRASP_Q)
    for board in plant.boards:
        board.regs["gripper"] = 1
    run_ms(plant, 5)
    enable(plant, 0)
    run_ms(plant, 60)
    rest = float(plant.world_truth["internal_force"])
    seen = {}
    for sign in (+1, -1):
        plant.pushes["force"][0] = [sign * 80.0, 0.0, 0.0]
        plant.pushes["duration_ns"][0] = 200_000_000
        plant.pushes["seq"][0] += 1
        run_ms(plant, 100)
        seen[sign] = float(plant.world_truth["internal_force"]) - rest
    assert seen[+1] > 5.0 and seen[-1] < -5.0, seen


def test_the_conveyor_carries_the_bar_at_its_speed_while_its_motor_runs(arena: Arena) -> None:
    """The stand's top as a belt (``plant.conveyor_m_s``, issue 28): the first board's
    conveyor line runs it; the bar's x, y then go at exactly the belt's velocity (its z and
    attitude as physics has them), and stay when the line drops."""
    cfg = make_config("belt", {r"^  conveyor_m_s: .*$": "  conveyor_m_s: [0.0, 0.02]"})
    assert cfg.plant.conveyor_m_s == (0.0, 0.02)
    sim = PlantSim(cfg, arena)
    bar = sim.object_truth["pose"][0]
    run_ms(sim, 50)  # settled on the stand
    start = bar[:3].copy()
    run_ms(sim, 200)  # the motor is off: nothing moves (it settles a few µm)
    assert np.allclose(bar[:3], start, atol=5e-5)
    start = bar[:3].copy()
    sim.regs["conveyor"][0] = 1
    run_ms(sim, 1000)
    moved = bar[:3] - start
    assert moved[1] == pytest.approx(0.02, abs=2e-5)  # 1 s at 2 cm/s
    assert abs(moved[0]) < 1e-5 and abs(moved[2]) < 1e-4
    sim.regs["conveyor"][0] = 0
    run_ms(sim, 300)
    assert float(bar[1] - start[1]) == pytest.approx(0.02, abs=5e-4)  # it stops (friction)


@pytest.mark.parametrize("cell", ["default", "mixed"])
def test_the_compiled_drive_equals_the_reference(cell: str) -> None:
    """``kali_motors`` (``MotorBank.compiled``) gives what ``drive_reference`` gives, to
    1e-15 (libm's tanh against numpy's): the bank's control, range and friction and MuJoCo's
    actuator ranges, controls, activations and applied forces, in the plant's own index maps,
    over random DAC volts (beyond the amplifier's reach too), speeds, currents and amplifiers
    on and off; what the maps do not name is left alone."""
    cfg = CFG if cell == "default" else MIXED
    world = build_world(cfg.robots)
    m = world.model
    n_arms = len(cfg.robots)
    index = [
        np.concatenate([getattr(world, f)[k] for k in range(n_arms)])
        for f in ("motor", "motor_act_adr", "dof_adr")
    ]
    rng = np.random.default_rng(27)
    banks = [MotorBank([r.type for r in cfg.robots]) for _ in range(2)]
    n = banks[0].n
    outs = [
        Drive(
            *index,
            rng.normal(size=(m.nu, 2)),
            rng.normal(size=m.nu),
            rng.normal(size=m.na),
            rng.normal(size=m.nv),
        )
        for _ in range(2)
    ]
    outs[1] = outs[1]._replace(**{f: getattr(outs[0], f).copy() for f in Drive._fields[3:]})
    volts, qd, current = np.zeros(n), np.zeros(n), np.zeros(n)
    kernel = banks[1].compiled(volts, qd, current, outs[1])
    for _ in range(200):
        volts[:] = rng.uniform(-12.0, 12.0, n)
        qd[:] = rng.normal(0.0, 2.0, n) * rng.choice([0.0, 0.01, 1.0, 5.0], n)
        current[:] = rng.normal(0.0, 3.0, n)
        for bank in banks:
            bank.enabled[:] = rng.integers(0, 2, n) if bank is banks[0] else banks[0].enabled
        drive_reference(banks[0], volts, qd, current, outs[0])
        kernel()
        for f in ("ctrl", "range", "friction"):
            np.testing.assert_allclose(
                getattr(banks[1], f), getattr(banks[0], f), rtol=1e-15, atol=1e-15
            )
        for f in Drive._fields[3:]:
            np.testing.assert_allclose(
                getattr(outs[1], f), getattr(outs[0], f), rtol=1e-15, atol=1e-15
            )


@pytest.mark.parametrize("cell", ["default", "mixed"])
def test_the_compiled_encoders_equal_the_reference(cell: str) -> None:
    """``kali_encoders`` (``EncoderBank.compiled``) counts what ``EncoderBank.sample`` counts,
    bit for bit: every counter register, index register and the counts' references, while the
    motors turn both ways through many index pulses and each board's index capture is
    switched on and off (CSR_INDEX_OFF); the kernel returns the indexes it captured."""
    cfg = CFG if cell == "default" else MIXED
    joints, types = cfg.joints, [r.type for r in cfg.robots]
    n = joints.total
    rng = np.random.default_rng(26)
    phases = rng.uniform(0.0, 2 * math.pi, n)
    start = rng.uniform(-20.0, 20.0, n)
    regs = [np.zeros(joints.n_robots, dtype=registers.IO_BOARD) for _ in range(2)]
    angles = [start.copy(), start.copy()]
    banks = [EncoderBank(r, types, phases, a, joints) for r, a in zip(regs, angles, strict=True)]
    kernel = banks[1].compiled(angles[1])
    speed = rng.normal(0.0, 3.0, n)  # rad per step: a revolution every few steps
    total = 0
    for step in range(400):
        if step % 50 == 0:
            csr = rng.integers(0, 2, joints.n_robots) * CSR_INDEX_OFF
            for r in regs:
                r["csr"] = csr
                r["index"] = 0
        angles[0] += speed * rng.uniform(0.0, 1.0, n)
        angles[1][:] = angles[0]
        before = regs[1]["index"].copy()
        banks[0].sample(angles[0])
        captured = kernel()
        assert regs[1].tobytes() == regs[0].tobytes()
        for f in ("_ref", "_rev", "_count"):
            same = getattr(banks[1], f).tobytes() == getattr(banks[0], f).tobytes()
            assert same, (f, step)
        assert captured >= int(np.count_nonzero(regs[1]["index"] != before))
        total += captured
    assert total > 0  # indexes were captured along the way


@pytest.mark.parametrize("cell", ["default", "mixed"])
def test_the_compiled_boards_equal_the_reference(cell: str) -> None:
    """``kali_boards_update`` and ``kali_boards_convert`` (``boards_kernel``) do what each
    board's ``IoBoardSim.update`` and ``.convert`` do, bit for bit: registers, the boards'
    state, the motors' enable and the brakes per joint, and the truth's flags, while random
    command/status words (enable, no-disable, timeout mode, retrigger, index-off), e-stops,
    ADC starts on every channel (past the last too) and index registers come and go over
    plant time that runs past the enable hold, the watchdog and the brake delay."""
    cfg = CFG if cell == "default" else MIXED
    joints, types = cfg.joints, [r.type for r in cfg.robots]
    n, arms = joints.total, joints.n_robots
    rng = np.random.default_rng(27)
    regs = [np.zeros(arms, dtype=registers.IO_BOARD) for _ in range(2)]
    truth = [np.zeros(arms, dtype=layout.ARM_TRUTH) for _ in range(2)]
    states = [np.zeros((arms, BOARD_STATE), np.int64) for _ in range(2)]
    boards = [
        [IoBoardSim(r[k : k + 1].reshape(()), cfg.plant, types[k], s[k]) for k in range(arms)]
        for r, s in zip(regs, states, strict=True)
    ]
    q = np.zeros(n)
    enabled, braked = np.zeros(n), np.ones(n, dtype=bool)
    kernel = boards_kernel(boards[1], regs[1], truth[1], joints, q, enabled, braked)
    convert = kernel.sibling("kali_boards_convert")
    board_truth = kernel.sibling("kali_boards_truth")
    lo = np.concatenate([t.q_min for t in types])
    hi = np.concatenate([t.q_max for t in types])
    csr_bits = [CSR_ENABLE, CSR_NO_DISABLE, CSR_TIMEOUT_ON, CSR_RETRIGGER, CSR_INDEX_OFF]
    now, changes, seen = 0, 0, set()
    for step in range(3000):
        now += int(rng.integers(0, 3)) * 1_000_000  # 0-2 ms: holds and delays pass
        if rng.random() < 0.3:  # the watchdog's pulse, now and then
            for r in regs:
                r["csr"] ^= CSR_RETRIGGER
        if rng.random() < 0.02:
            csr = np.zeros(arms, np.uint8)
            for bit in csr_bits:
                csr |= (rng.random(arms) < 0.6).astype(np.uint8) * np.uint8(bit)
            estop = (rng.random(arms) < 0.1).astype(np.uint8)
            adc = rng.integers(0, 16, arms) | (rng.random(arms) < 0.5) * ADC_START
            index = rng.integers(0, 64, arms)
            for r in regs:
                r["csr"], r["estop"], r["adc_control"], r["index"] = csr, estop, adc, index
        q[:] = rng.uniform(lo - 0.2, hi + 0.2)  # past the pots' ends too
        ref_enabled, ref_braked = np.zeros(n), np.zeros(n, dtype=bool)
        ref_changed = False
        for k, b in enumerate(boards[0]):
            b.update(now)
            span = joints.span(k)
            ref_enabled[span] = 1.0 if b.amps_on else 0.0
            ref_braked[span] = not b.brakes_released
            ref_changed |= bool(braked[span.start] != (not b.brakes_released))
        kernel.args.now_ns = now
        changed = kernel()
        assert changed == ref_changed, step
        changes += changed
        for k, b in enumerate(boards[0]):
            b.convert(q[joints.span(k)])
        convert()
        board_truth()
        assert regs[1].tobytes() == regs[0].tobytes(), step
        assert states[1].tobytes() == states[0].tobytes(), step
        assert enabled.tobytes() == ref_enabled.tobytes() and (braked == ref_braked).all()
        for k, b in enumerate(boards[0]):
            t = truth[1][k]
            flags = (t["amps_on"], t["brakes_engaged"], t["watchdog_tripped"], t["estop"])
            assert flags == (b.amps_on, not b.brakes_released, b.tripped, regs[0][k]["estop"])
        seen.update(int(p) for p in regs[0]["power"])
    assert changes > 10  # brakes came and went
    assert {POWER_AMPS_ON, POWER_WATCHDOG_TRIPPED | POWER_BUZZER} <= {
        p & bit for p in seen for bit in (POWER_AMPS_ON, POWER_WATCHDOG_TRIPPED | POWER_BUZZER)
    }


@pytest.mark.parametrize("cell", ["default", "mixed"])
def test_the_compiled_joint_and_dac_reads_equal_the_reference(cell: str, arena: Arena) -> None:
    """``kali_plant_joints`` and ``kali_plant_dac`` (bound by ``PlantSim``) do what its
    ``_read_joints`` and ``_read_dac`` do, bit for bit: angles, velocities, currents, motor
    angles and torques gathered from random MuJoCo states, and volts from random DAC codes,
    codes past 12 bits clamped and counted on their arm's board alike."""
    sim = PlantSim(CFG if cell == "default" else MIXED, arena)
    rng = np.random.default_rng(28)
    d, dac = sim.data, sim.dac
    outs = (sim.q, sim.qd, sim.current, sim.motor_angle, sim.torque, sim.volts)
    clamps = 0
    for step in range(200):
        d.qpos[:] = rng.uniform(-4.0, 4.0, len(d.qpos))
        d.qvel[:] = rng.normal(0.0, 3.0, len(d.qvel))
        d.act[:] = rng.normal(0.0, 5.0, len(d.act))
        top = 65535 if step % 4 == 0 else 4095  # a quarter of the ticks with bad codes
        dac["code"] = rng.integers(0, top + 1, dac["code"].shape)
        before = dac["clamped"].copy()
        sim._read_joints()
        sim._read_dac()
        want = [a.copy() for a in outs]
        counted = dac["clamped"].copy()
        for a in outs:
            a[:] = np.nan
        sim._joints_in()
        sim._dac_in()
        for a, b in zip(outs, want, strict=True):
            assert a.tobytes() == b.tobytes(), step
        assert (dac["clamped"] - counted == counted - before).all(), step
        clamps += int((counted - before).sum())
    assert clamps > 0


@pytest.mark.parametrize("cell", ["default", "mixed"])
def test_the_compiled_truth_equals_the_reference(cell: str, arena: Arena) -> None:
    """``kali_plant_truth`` (with the joints' copies and the boards' flags: ``_write_truth``)
    writes what ``_write_truth_reference`` writes, bit for bit: grasps held and let go in
    every combination (their weld rows from MuJoCo's constraint forces), the grasp sites
    apart and on one point (no squeeze line), random sensor wrenches, pushes, times and
    poses."""
    sim = PlantSim(CFG if cell == "default" else MIXED, arena)
    rng = np.random.default_rng(1128)
    m, d = sim.model, sim.data
    records = (sim.truth, sim.world_truth, sim.joint_truth, sim.object_truth)
    n = len(sim.truth)
    sim._grasp_site[:] = sim.world.grasp_site[:n]  # where each arm took hold: a site each
    held_seen, squeezes = set(), 0
    for step in range(300):
        d.qpos[:] += rng.normal(0.0, 0.05, len(d.qpos))
        d.eq_active[:] = rng.random(m.neq) < 0.5
        mujoco.mj_forward(m, d)  # the constraint rows of the welds now active, positions
        if step % 10 == 0 and m.neq > 1:  # both grasp sites on one point: no line
            g = sim.world.grasp_site
            d.site_xpos[g[1]] = d.site_xpos[g[0]]
        d.xfrc_applied[:] = rng.normal(0.0, 20.0, d.xfrc_applied.shape)
        sim._ft_true[:] = rng.normal(0.0, 30.0, sim._ft_true.shape)
        sim.sim_ns, sim.ticks = int(rng.integers(0, 2**62)), int(rng.integers(0, 2**62))
        sim._write_truth_reference()
        want = [r.tobytes() for r in records]
        for r in records:  # garbage in every field, so the kernels must write each one
            for f in r.dtype.names:
                if not f.startswith("_"):
                    r[f] = np.nan if r[f].dtype.kind == "f" else 0x25
        sim._held[:] = ~sim._held
        sim._held_object[:] = 7
        sim._weld[:] = np.nan  # read afresh from MuJoCo by the kernel's path too
        sim._write_truth()
        for r, w in zip(records, want, strict=True):
            assert r.tobytes() == w, step
        held_seen.add(tuple(bool(h) for h in sim._held))
        squeezes += float(sim.world_truth["internal_force"]) != 0.0
    assert len(held_seen) == 2 ** len(sim._held)  # every combination of grasps
    assert squeezes > 20
