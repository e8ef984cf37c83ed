"""Wrist force/torque sensors (issue 27 items 1, 2, 5), end to end in lockstep: the plant's
sensor behind the board's gauge ADC bank, SIO's conversion to Newtons (tare, gravity, frames,
the FORCE halts), ``Robot.read_wrench``/``tare`` and ``kalictl push``."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.errors import ServoError
from kali_daemons.core.kernels import (
    WRENCH_CONTACT,
    WRENCH_OK,
    WRENCH_RATED,
    WRENCH_SATURATED,
    WRENCH_SILENT,
)
from kali_daemons.core.layout import FaultCode
from kali_daemons.hardware.ftsensor import FT_RAIL, FT_REQUEST, FT_SEQ_MASK, MINI45
from kali_daemons.hardware.mcgill import registers
from kali_daemons.plant.board import FtBank
from kali_daemons.runtime.config import parse_config
from kali_daemons.sio.wrench import ArmSensor, convert_reference
from kali_daemons.wallclock import step_kali_clock
from tests.test_launcher import kalictl

PUSH_S = 0.4  # each static load is held this long (simulated)


def sim_ns(k: Kali) -> int:
    """The plant's simulated time."""
    return int(k.inst.arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH)["sim_time_ns"])


def five_sigma(k: Kali, tared_ns: int) -> np.ndarray:
    """Five times the sheet's error per axis of a sample taken now, after a tare at
    ``tared_ns``, with a margin for the arithmetic."""
    return 5 * MINI45.error_sd((sim_ns(k) - tared_ns) * 1e-9) + 1e-3


def truth(k: Kali) -> np.ndarray:
    """The plant's truth records (never read by the controller)."""
    return k.inst.arena.existing(layout.KEY_TRUTHS, layout.ARM_TRUTH, len(k.names))


def test_the_sensor_reads_the_plant_s_wrench_after_a_tare_and_each_static_load(
    kali: Callable[..., str],
) -> None:
    """Before a tare the reading is off by the sensor's own offsets; a tare removes them, and
    then at 20 random static loads (pushes on the braked arm's tool) SIO's reading equals the
    wrench the plant's sensor carries within 5 σ of the sheet's error since the tare (noise,
    the offsets' drift, the ADC's quantum: 5 σ of the noise alone, 0.30 N on Fy, was 0.31 N
    off after 10 s in one run of the suite), and the contact force
    in the world equals the push.  The left arm's tool weighs 0.5 kg, its centre of mass off
    the axis: SIO removes its weight at the arm's pose."""
    tool = "ft: {tool_mass_kg: 0.5, tool_com_m: [0.01, -0.02, 0.03]}"
    name = kali(lockstep=True, edits={r"^(  - \{name: left.*)\}$": rf"\1, {tool}}}"})
    rng = np.random.default_rng(27)
    with Kali(name) as k:
        left = k.robot("left")
        step_kali_clock(k.inst, 200)
        ft = k.ft[0]
        assert int(ft["present"]) == 1 and int(ft["samples"]) > 150
        sensor, true = left.read_wrench("sensor"), truth(k)["ft_wrench"][0].copy()
        offset = sensor - true
        assert np.abs(offset[:3]).max() > 0.5, "an untared sensor reads its offsets"
        left.tare()
        tared_ns = sim_ns(k)
        # at once: no contact, the weight removed, and no filter lag of the old offsets
        assert np.abs(left.read_wrench("world")[:3]).max() < 0.2
        step_kali_clock(k.inst, 50)
        assert int(ft["tare_count"]) == 1
        error = left.read_wrench("sensor") - truth(k)["ft_wrench"][0]
        assert np.all(np.abs(error) < five_sigma(k, tared_ns)), error
        for _ in range(20):
            force = rng.uniform(-40.0, 40.0, 3)
            k.inst.push(0, force, PUSH_S)
            step_kali_clock(k.inst, 300)
            reading = left.read_wrench("sensor")
            true = truth(k)["ft_wrench"][0]
            assert np.all(np.abs(reading - true) < five_sigma(k, tared_ns)), (reading, true)
            # the arm is not calibrated: its angles, from the pots, are right to a degree or
            # so, and so is the sensor frame SIO turns the reading into the world with
            world = left.read_wrench("world")
            assert np.linalg.norm(world[:3] - force) < 0.05 * np.linalg.norm(force) + 0.3
            step_kali_clock(k.inst, 200)  # the push ends; the arm rests again
        assert not int(k.inst.fault["active"])


@pytest.mark.parametrize(
    ("force", "says"),
    [
        ((1000.0, 0.0, 0.0), "saturated"),  # along the sensor's z at home: past its rail
        ((0.0, 200.0, 0.0), "beyond its limit 150 N"),  # in the sensor's range, past the limit
    ],
)
def test_a_load_past_the_sensor_or_the_contact_limit_halts(
    kali: Callable[..., str], force: tuple[float, float, float], says: str
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        step_kali_clock(k.inst, 100)
        k.robot("left").tare()
        k.inst.push(0, np.asarray(force), 0.2)
        step_kali_clock(k.inst, 100)
        info = k.inst.read_fault()
        assert FaultCode[info.code] == FaultCode.FORCE
        text = k.inst.fault_text() or ""
        assert "robot 'left'" in text and says in text, text


def test_read_wrench_and_tare_refuse_an_arm_without_a_sensor_and_a_bad_frame(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True, edits={r"^(  - \{name: right.*)\}$": r"\1, ft: {sensor: none}}"})
    with Kali(name) as k:
        with pytest.raises(ServoError, match="robot 'right' has no wrist force/torque sensor"):
            k.robot("right").read_wrench()
        with pytest.raises(ServoError, match="frame 'flange'"):
            k.robot("left").read_wrench("flange")


def test_kalictl_push_checks_its_numbers(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    bad = kalictl("-i", name, "push", "left", "nan", "0", "0")
    assert bad.returncode != 0 and "FX nan" in bad.stderr
    ok = kalictl("-i", name, "push", "left", "0", "0", "5", "--for", "0.1")
    assert ok.returncode == 0, ok.stderr
    assert "left: pushed with (0, 0, 5) N for 0.1 s" in ok.stdout


def test_the_ft_section_is_checked() -> None:
    base = "version: 1\ninstance: x\nrobots:\n  - name: a\n    ft: {}\n"
    with pytest.raises(Exception, match=r"robots\[0\]\.ft\.sensor"):
        parse_config(base.replace("{}", "{sensor: jr3}"))
    with pytest.raises(Exception, match=r"robots\[0\]\.ft\.tool_mass_kg"):
        parse_config(base.replace("{}", "{tool_mass_kg: -1}"))
    cfg = parse_config(base.replace("{}", "{sensor: none}"))
    assert cfg.robots[0].ft.sheet is None
    # a sensor its hardware cannot read: a McGill board has no joint torques, an FR3 no gauges
    with pytest.raises(Exception, match=r"ft\.sensor = 'joint-torques': mcgill hardware takes a "
                       r"wrist wrench from mini45; or none"):  # fmt: skip
        parse_config(base.replace("{}", "{sensor: joint-torques}"))
    fr3 = "    model: fr3\n    hardware: {kind: franka, address: 127.0.0.1}\n"
    with pytest.raises(Exception, match=r"ft\.sensor = 'mini45': franka hardware takes a wrist "
                       r"wrench from joint-torques, robot; or none"):  # fmt: skip
        parse_config(base.replace("{}", "{sensor: mini45}") + fr3)


def convert_both(kernel: ArmSensor, ref: ArmSensor, i: int) -> int:
    """``kali_wrench_convert`` on ``kernel``, ``convert_reference`` on its twin ``ref``: the
    same result, and every output within 1e-12; the result."""
    result = (kernel.convert(), convert_reference(ref))
    assert result[0] == result[1], (i, result)
    for f in ("sensor", "tool", "world", "bias", "rotation"):
        np.testing.assert_allclose(kernel.state[f], ref.state[f], rtol=0, atol=1e-12)
    for a, b in ((kernel.filt, ref.filt), (kernel.raw, ref.raw), (kernel.grav, ref.grav)):
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-12)
    assert kernel.args.tare_left == ref.args.tare_left
    assert kernel.args.force == pytest.approx(ref.args.force, abs=1e-12)
    return result[0]


def test_the_compiled_conversion_equals_its_numpy_reference() -> None:
    """``kali_wrench`` against ``convert_reference`` on twin sensors fed the same random
    samples, poses, biases, limits and tares, including saturated codes, loads beyond the
    range and past the contact limit: the same result and every output within 1e-12."""
    cfg = parse_config(
        "version: 1\ninstance: x\nrobots:\n  - name: a\n"
        "    ft: {tool_mass_kg: 0.7, tool_com_m: [0.01, -0.02, 0.04], contact_limit_n: 120}\n"
    )
    rng = np.random.default_rng(7)
    twins = []
    for _ in range(2):
        regs = np.zeros((), registers.IO_BOARD)
        state = np.zeros((), layout.FT_STATE)
        q = np.zeros(cfg.robots[0].n_joints)
        twins.append((ArmSensor(cfg, 0, regs, state, q, 0.001), regs, state, q))
    (kernel, *_), (ref, *_) = twins
    rtype = cfg.robots[0].type
    found = set()
    for i in range(400):
        codes = rng.integers(-4000, 4000, 6)
        if i % 7 == 0:
            codes[rng.integers(6)] = rng.choice([FT_RAIL, -FT_RAIL - 1])
        if i % 11 == 0:
            codes[2] = 30_000  # Fz far past its range, below the rail
        q = rng.uniform(rtype.q_min, rtype.q_max)
        bias = rng.normal(0.0, 3.0, 6)
        limit = rng.choice([0.0, 50.0, 500.0, np.nan])
        tare = int(rng.integers(0, 3)) if i % 5 == 0 else 0
        for arm, regs, state, q_arm in twins:
            regs["ft_gauge"] = codes
            q_arm[:] = q
            if i == 0 or i % 13 == 0:
                state["bias"] = bias
            state["contact_limit"] = limit
            if tare:
                arm.args.tare_left = tare
        found.add(convert_both(kernel, ref, i))
    assert found == {WRENCH_OK, WRENCH_SATURATED, WRENCH_RATED, WRENCH_CONTACT}


def test_a_wrench_the_hardware_gives_goes_through_the_same_conversion() -> None:
    """An arm with no gauges (``ft.sensor: joint-torques``: its hardware gives the wrench at
    the flange): ``kali_wrench_convert`` equals ``convert_reference`` on random wrenches,
    poses, biases, limits and tares; and the tick takes a wrench only when the hardware's
    count has moved, silent past ``stale_limit`` ticks without one."""
    cfg = parse_config(
        "version: 1\ninstance: x\nrobots:\n  - name: a\n    model: fr3\n"
        "    ft: {sensor: joint-torques, tool_mass_kg: 0.73, tool_com_m: [-0.01, 0, 0.03],"
        " tool_tip_m: 0.1034, contact_limit_n: 120}\n"
        "    hardware: {kind: franka, address: 127.0.0.1}\n"
    )
    rng = np.random.default_rng(11)
    twins = []
    for _ in range(2):
        given, count = np.zeros(6), np.zeros((), np.uint64)
        state = np.zeros((), layout.FT_STATE)
        q = np.zeros(cfg.robots[0].n_joints)
        sensor = ArmSensor(cfg, 0, None, state, q, 0.001, (given, count))
        twins.append((sensor, given, count, state, q))
    (kernel, *_), (ref, *_) = twins
    rtype = cfg.robots[0].type
    found = set()
    for i in range(300):
        wrench = rng.normal(0.0, 40.0, 6)
        q = rng.uniform(rtype.q_min, rtype.q_max)
        limit = rng.choice([0.0, 50.0, 500.0, np.nan])
        tare = int(rng.integers(0, 3)) if i % 5 == 0 else 0
        for arm, given, _, state, q_arm in twins:
            given[:] = wrench
            q_arm[:] = q
            state["contact_limit"] = limit
            if tare:
                arm.args.tare_left = tare
        found.add(convert_both(kernel, ref, i))
        np.testing.assert_array_equal(kernel.raw, wrench)
    assert found == {WRENCH_OK, WRENCH_CONTACT}  # no gauges: nothing saturates, no range
    arm, given, count, state, _ = twins[0]
    state["contact_limit"] = 0.0
    given[:] = 0.0
    samples = int(state["samples"])
    assert arm.tick(1) == WRENCH_OK and int(state["samples"]) == samples  # the count stood
    count[...] = count + 1
    assert arm.tick(2) == WRENCH_OK and int(state["samples"]) == samples + 1
    for tick in range(3, 3 + arm.stale_limit):
        assert arm.tick(tick) == WRENCH_OK
    assert arm.tick(3 + arm.stale_limit) == WRENCH_SILENT
    assert "no new wrench from its hardware" in arm.message(WRENCH_SILENT)


def test_a_board_that_did_not_scan_is_no_silence_of_its_sensor() -> None:
    """A simulated board's sensor (``cycles``: its board's ``scans``): a tick with no new
    sample is one more silent tick only if the board scanned since the tick before; while
    it stands (the plant stopped, or its CPU taken by the machine: the clock's to judge)
    the count stands; past ``stale_limit`` of its scans the sensor is silent."""
    cfg = parse_config(
        "version: 1\ninstance: x\nrobots:\n  - name: a\n    ft: {tool_mass_kg: 0.7}\n"
    )
    regs = np.zeros((), registers.IO_BOARD)
    state = np.zeros((), layout.FT_STATE)
    q = np.zeros(cfg.robots[0].n_joints)
    scans = regs["scans"]
    arm = ArmSensor(cfg, 0, regs, state, q, 0.001, cycles=scans)
    arm.start()
    for tick in range(1, 3 * arm.stale_limit):  # the board stands: no silence counted
        assert arm.tick(tick) == WRENCH_OK
    assert int(state["stale"]) == 0
    for tick in range(3 * arm.stale_limit, 4 * arm.stale_limit):  # it scans: silent ones
        scans[...] = scans + 1
        assert arm.tick(tick) == WRENCH_OK
    assert int(state["stale"]) == arm.stale_limit
    assert arm.tick(4 * arm.stale_limit) == WRENCH_OK  # no scan since: not one more
    scans[...] = scans + 1
    assert arm.tick(4 * arm.stale_limit + 1) == WRENCH_SILENT
    assert "no sensor on its board" in arm.message(WRENCH_SILENT)


def test_the_sheet_s_error_grows_as_the_plant_s_offsets_drift() -> None:
    """``FtSheet.error_sd``'s drift term against the plant's gauge bank: 300 sensors walk for
    a simulated second at 1 kHz; the spread of their offsets' change, through the calibration,
    is the sheet's drift per axis within 15 % (300 samples)."""
    dt, cycles, n = 0.001, 1000, 300
    change = np.empty((n, layout.WRENCH))
    for i in range(n):
        bank = FtBank(np.zeros((), registers.IO_BOARD), MINI45, seed=i, dt_s=dt)
        start = bank.offset.copy()
        for _ in range(cycles):
            bank.cycle(np.zeros(layout.WRENCH))
        change[i] = MINI45.calibration @ (bank.offset - start)
    seconds = dt * cycles
    drift = np.sqrt(MINI45.error_sd(seconds) ** 2 - MINI45.error_sd(0.0) ** 2)
    ratio = change.std(axis=0) / drift
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio


def test_the_compiled_gauge_bank_equals_the_reference() -> None:
    """``kali_ft_bank`` (``FtBank.compiled``) does what ``FtBank.cycle`` does, bit for bit,
    drawing the same normals from the same generator: the offsets' walk every cycle, and on
    each new request (a sequence number not served yet, sometimes repeated, sometimes with the
    request bit low) the codes, clipped at the rails for wrenches past the range, and the
    status; over enough cycles that the kernel's block of draws is refilled many times, with
    six draws left over and with none."""
    regs = [np.zeros((), registers.IO_BOARD) for _ in range(2)]
    banks = [FtBank(r, MINI45, seed=24, dt_s=0.001) for r in regs]
    wrench = [np.zeros(layout.WRENCH) for _ in range(2)]
    step = banks[1].compiled(wrench[1])
    rng = np.random.default_rng(26)
    rated = np.asarray(MINI45.rated)
    seq, requests, saturated = 0, 0, 0
    for cycle in range(5000):
        if rng.random() < 0.5:
            if rng.random() < 0.8:
                seq = (seq + 1) & FT_SEQ_MASK  # else the same one again: not served twice
            request = FT_REQUEST if rng.random() < 0.9 else 0
            for r in regs:
                r["ft_control"] = request | seq
        w = rng.normal(0.0, 0.5, layout.WRENCH) * rated * (3.0 if rng.random() < 0.1 else 1.0)
        wrench[0][:], wrench[1][:] = w, w
        before = int(regs[0]["ft_status"])
        banks[0].cycle(wrench[0])
        step()
        requests += int(regs[0]["ft_status"]) != before
        saturated += bool(np.isin(regs[0]["ft_gauge"], (FT_RAIL, -FT_RAIL - 1)).any())
        assert regs[1].tobytes() == regs[0].tobytes(), cycle
        assert banks[1].offset.tobytes() == banks[0].offset.tobytes(), cycle
    assert requests > 1000 and saturated > 10
