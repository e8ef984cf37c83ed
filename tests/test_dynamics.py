"""Feed-forward dynamics (issue 6, thesis 3.3.6 and 2.2.3): the torques against
robotics-toolbox-python, tracking of the standard jtraj move with feed-forward off and on,
and SIO dropping stale feed-forward.
"""

from __future__ import annotations

import os
import signal
import time
from collections.abc import Callable

import numpy as np
import pytest
import roboticstoolbox as rtb

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.core.layout import FfMode, FfState, PowerState
from kali_daemons.dynamics.daemon import Dynamics
from kali_daemons.robots import puma560
from kali_daemons.robots.inverse import InverseDynamics, central_differences
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo.client import ServoClient
from kali_daemons.wallclock import step_kali_clock

from .conftest import make_config
from .test_launcher import kalictl
from .test_tg import MIXED

# The move is jtraj qz → qn in 1.5 s.  That needs 3.93 rad/s on joint 3, and the
# PUMA 560's joint-3 motor reaches 2.85 rad/s on the 40 V bus (puma560.MAX_JOINT_SPEED): the
# amplifier saturates and SIO halts on CURRENT, feed-forward on or off.  2.5 s (peak
# 2.36 rad/s) is the same standard move at a speed this arm has.
MOVE_S = 2.5
SAMPLE_TICKS = 5  # tracking error sampled every 5 servo ticks
LEFT = slice(0, puma560.ROBOT.n_joints)  # the default cell's left PUMA: the first flat joints


def ff_records(inst: Instance) -> np.ndarray:
    return inst.arena.existing(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, 2)


def test_full_torques_match_the_toolbox_rne() -> None:
    """M q̈ + C q̇ + g + rotor inertia + motor friction, against rtb's rne with its friction."""
    puma = rtb.models.DH.Puma560()
    inverse = InverseDynamics(puma560.ROBOT)
    rng = np.random.default_rng(6)
    for _ in range(20):
        q = rng.uniform(puma560.Q_MIN, puma560.Q_MAX)
        qd = rng.uniform(0.5, 2.0, 6) * rng.choice([-1.0, 1.0], 6)  # tanh(|G| q̇ / ω₀) ≈ 1
        qdd = rng.uniform(-5.0, 5.0, 6)
        ours = inverse.torque(FfMode.FULL, q, qd, qdd, np.zeros(6)).copy()
        np.testing.assert_allclose(ours, puma.rne(q, qd, qdd), atol=0.05, rtol=1e-3)
        gravity = inverse.torque(FfMode.GRAVITY, q, qd, qdd, np.zeros(6))
        np.testing.assert_allclose(gravity, puma.gravload(q), atol=1e-6)
    kv = np.array([250.0, 330.0, 75.0, 16.0, 14.0, 16.0])
    with_kv = inverse.torque(FfMode.FULL, q, qd, qdd, kv).copy()
    np.testing.assert_allclose(with_kv - ours, kv * qd, atol=1e-9)


def test_central_differences_are_exact_for_a_parabola_over_unequal_segments() -> None:
    a, b, c = np.arange(6.0), np.linspace(-1, 1, 6), np.full(6, 0.7)

    def q(t: float) -> np.ndarray:
        return a + b * t + 0.5 * c * t * t

    qd, qdd, scratch = np.zeros(6), np.zeros(6), np.zeros(6)
    central_differences(q(0.3), q(0.32), q(0.345), 0.02, 0.025, qd, qdd, scratch)
    np.testing.assert_allclose(qd, b + c * 0.32, atol=1e-9)
    np.testing.assert_allclose(qdd, c, atol=1e-7)


def test_a_mixed_cell_gets_rows_as_wide_as_each_arm(arena: Arena) -> None:
    """A PUMA 560 (6 joints) and a Panda (7): each arm's FIFO, scratch and feed-forward
    columns are its joint count wide (the record's other columns stay 0), its torques are its
    own type's, and its servos' k_v are read from its own slots (flat base[k] + j)."""
    cfg = make_config("mixed", MIXED)
    arena.record(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, 2)  # as SIO lays it out
    arena.record(layout.KEY_LOADS, layout.LOAD, 2)  # as kalictl start does
    dyn = Dynamics(cfg.instance, "dynamics")
    dyn.load(cfg)
    dyn.attach(cfg, arena)
    assert [f.width for f in dyn.fifos] == [6, 7] and [a.n for a in dyn.arms] == [6, 7]
    dyn._algo = np.zeros(13, dtype=np.uint32)
    dyn._enabled = np.ones(13, dtype=np.uint8)
    dyn._kv_views = [[np.array([float(i)])] for i in range(13)]  # slot i's only algorithm: i
    dyn._servo_gains(1)
    np.testing.assert_array_equal(dyn.arms[1].kv, np.arange(6.0, 13.0))
    ff = dyn.ff
    for k, r in enumerate(cfg.robots):
        rtype = r.type
        points = [rtype.q_home + 0.01 * i for i in range(3)]
        for q in points:
            dyn.fifos[k].push(q)
        dyn._robot(k, FfMode.GRAVITY)
        own = InverseDynamics(rtype, (r.ft.tool_mass_kg, r.ft.tool_com_m))  # its tool's too
        for i, q in enumerate(points):
            row = (i + 1) % layout.FF_ROWS
            assert int(ff["key"][k, row]) == i + 1
            np.testing.assert_array_equal(ff["q"][k, row, : rtype.n_joints], q)
            zero = np.zeros(rtype.n_joints)
            gravity = own.torque(FfMode.GRAVITY, q, zero, zero, zero)
            np.testing.assert_allclose(ff["tau"][k, row, : rtype.n_joints], gravity, atol=1e-12)
            assert not ff["q"][k, row, rtype.n_joints :].any()
            assert not ff["tau"][k, row, rtype.n_joints :].any()
    del ff


def test_a_motions_last_set_point_gets_its_resting_row_as_soon_as_it_is_pushed(
    arena: Arena,
) -> None:
    """Issue 24: a set-point's full row needs its successor (central differences), and a
    motion's last one got its row only once SIO had drained the FIFO and this process ran
    again: until then SIO held the arm on the row before, a moving one (Coulomb friction,
    deceleration), 53 ms in a soak, an arm sagging 4 mrad as the grippers closed.  The TG now
    marks the last set-point (``push(q, rest=True)``): its row, the arm at rest there, is
    written with the others; an unmarked newest set-point still waits for its successor."""
    cfg = make_config("rests", None)
    arena.record(layout.KEY_FEEDFORWARD, layout.FEEDFORWARD, 2)  # as SIO lays it out
    arena.record(layout.KEY_LOADS, layout.LOAD, 2)  # as kalictl start does
    dyn = Dynamics(cfg.instance, "dynamics")
    dyn.load(cfg)
    dyn.attach(cfg, arena)
    joints = cfg.joints.total
    dyn._algo = np.zeros(joints, dtype=np.uint32)
    dyn._enabled = np.ones(joints, dtype=np.uint8)
    dyn._kv_views = [[np.array([2.0])] for _ in range(joints)]
    ff = dyn.ff
    rtype = cfg.robots[0].type
    points = [rtype.q_home + 0.01 * i for i in range(3)]
    for k in (0, 1):
        for i, q in enumerate(points):
            dyn.fifos[k].push(q, rest=k == 0 and i == 2)
        dyn._servo_gains(k)
        dyn._robot(k, FfMode.FULL)
    assert [bool(dyn.fifos[0].rests_at(i)) for i in range(3)] == [False, False, True]
    assert [int(ff["key"][0, i + 1]) for i in range(3)] == [1, 2, 3]
    assert [int(ff["key"][1, i + 1]) for i in range(2)] == [1, 2]
    assert int(ff["key"][1, 3]) != 3, "unmarked: its row waits for its successor"
    n = rtype.n_joints
    np.testing.assert_array_equal(ff["qd"][0, 3, :n], 0.0)
    np.testing.assert_array_equal(ff["qdd"][0, 3, :n], 0.0)
    assert np.abs(ff["qd"][0, 2, :n]).min() > 0.5  # the row before moves (1 rad/s here)
    r = cfg.robots[0]
    own = InverseDynamics(rtype, (r.ft.tool_mass_kg, r.ft.tool_com_m))
    zero = np.zeros(n)
    rest = own.torque(FfMode.FULL, points[2], zero, zero, np.full(n, 2.0))
    np.testing.assert_allclose(ff["tau"][0, 3, :n], rest, atol=1e-12)
    del ff


def test_a_move_right_after_calibration_gets_the_demands_own_velocity(
    kali: Callable[..., str],
) -> None:
    """A motion's first row takes q_{i-1} from the hold row this process wrote while the FIFO
    was drained.  Calibration re-bases the angles and SIO holds the arm where it now reads,
    at once; a move pushed before this process ran again got a velocity from the old hold
    position: on the first move after ``ready()`` the left arm's demanded q̇ swung to
    -34°/s on joint 1 (the move goes the other way) over 20 ms while the demand stood still,
    and the feed-forward sent 263 N m.  The demand's velocity must agree with its positions
    (it integrates to the demand's displacement) and the feed-forward stay near gravity."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        k.ready(["left"])
        left = k.robot("left")
        start = left.read_joints()
        left.move_joints(start + np.radians([15, -10, 20, 0, 25, 0]), speed=0.5, wait=False)
        states = []
        for _ in range(60):
            step_kali_clock(k.inst, 1)
            states.append(left.read_state())
    q_d = np.array([s.q_d for s in states])
    qd_d = np.array([s.qd_d for s in states])
    ff = np.array([s.ff_torque for s in states])
    travelled = np.degrees(qd_d[1:].sum(axis=0) * 1e-3)  # 1 ms servo ticks
    moved = np.degrees(q_d[-1] - q_d[0])
    np.testing.assert_allclose(travelled, moved, atol=0.02)
    assert np.abs(ff[:, 0]).max() < 20.0, np.round(ff[:, 0], 1)  # no gravity on joint 1


def _run(inst: Instance, client: ServoClient, traj: np.ndarray) -> np.ndarray:
    """Push ``traj`` (TG-rate set-points) into left's FIFO as the commanded path, step the
    clock through it and return the tracking error (demand − q) every SAMPLE_TICKS."""
    r = client.level.joints  # per joint, flat; the left arm's are LEFT
    fifo = client.level.fifo(0)
    ratio = int(fifo.ratio)
    for row in traj[1:]:
        fifo.push(row)
    errors = []
    for k in range(1, (len(traj) - 1) * ratio // SAMPLE_TICKS + 1):
        step_kali_clock(inst, SAMPLE_TICKS)
        errors.append(r["demand"][LEFT] - r["q"][LEFT])
        if k * SAMPLE_TICKS % ratio == 0:  # a set-point instant: the demand is the path's
            np.testing.assert_array_equal(r["demand"][LEFT], traj[k * SAMPLE_TICKS // ratio])
    step_kali_clock(inst, 300)  # the arm comes to rest
    assert inst.fault_text() is None
    return np.array(errors)


def standard_move(
    inst: Instance, client: ServoClient, program: Kali
) -> tuple[np.ndarray, np.ndarray]:
    """Bring the powered left arm to qz, and return the standard move's set-points at the TG
    rate, there (jtraj qz → qn in ``MOVE_S``, offset by qz as this arm measures it) and back."""
    home = program.robot("left").move_joints(np.zeros(6), speed=0.5, wait=False)
    while not home.done:
        step_kali_clock(inst, 50)
    step_kali_clock(inst, 1000)
    puma = rtb.models.DH.Puma560()
    period_s = inst.config.clock.tg_period_ms / 1000.0
    t = np.linspace(0.0, MOVE_S, round(MOVE_S / period_s) + 1)
    q0 = client.level.joints["demand"][LEFT].copy()
    there = rtb.jtraj(puma.qz, puma.qn, t).q + q0
    return there, there[::-1].copy()


def test_full_feedforward_lowers_the_tracking_error_of_the_standard_jtraj_move(
    kali: Callable[..., str], capsys: pytest.CaptureFixture[str]
) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst, Kali(name) as program:
        client = ServoClient(inst)
        step_kali_clock(inst, 30)
        client.power("left", True)
        step_kali_clock(inst, 300)
        assert client.power_state("left") == PowerState.ON
        there, back = standard_move(inst, client, program)
        rms = {}
        for mode in ("off", "on"):
            r = kalictl("-i", name, "ff", mode, "left")
            assert r.returncode == 0, r.stderr
            step_kali_clock(inst, 1000)  # faded in (ramp_ms 200) and settled
            want = FfState.ON if mode == "on" else FfState.OFF
            assert FfState(int(ff_records(inst)["state"][0])) == want
            rms[mode] = np.sqrt((_run(inst, client, there) ** 2).mean(axis=0))
            _run(inst, client, back)
        rows = ff_records(inst)["rows_written"][0]
        client.close()
    off, on = np.degrees(rms["off"]), np.degrees(rms["on"])
    with capsys.disabled():
        print(f"\njtraj qz → qn in {MOVE_S:g} s, RMS tracking error (deg), left arm:")
        print("joint          " + "".join(f"{j:>9}" for j in range(1, 7)))
        print("ff off         " + "".join(f"{v:9.4f}" for v in off))
        print("ff on (full)   " + "".join(f"{v:9.4f}" for v in on))
        print(f"all joints: {np.sqrt((off**2).mean()):.4f}° off, {np.sqrt((on**2).mean()):.4f}° on")
    assert rows > 2 * len(there)
    for j in (1, 2, 4):  # the joints that move
        assert on[j] < 0.2 * off[j], f"joint {j + 1}: {on[j]:.4f}° on against {off[j]:.4f}° off"
    assert np.sqrt((on**2).mean()) < 0.1 * np.sqrt((off**2).mean())


def _wait(what: str, cond: Callable[[], bool], timeout_s: float) -> float:
    """Seconds until ``cond`` holds; fails naming ``what`` after ``timeout_s``."""
    t0 = time.monotonic()
    while not cond():
        assert time.monotonic() - t0 < timeout_s, f"not within {timeout_s} s: {what}"
        time.sleep(0.005)
    return time.monotonic() - t0


@pytest.mark.serial
def test_stale_feedforward_is_dropped_and_comes_back(kali: Callable[..., str]) -> None:
    """Real time: the dynamics process stopped (SIGSTOP) → STALE within feedforward.stale_ms,
    its torque faded out within ramp_ms, no halt; continued (SIGCONT) → ON again."""
    name = kali(lockstep=False, edits={r"^(  - \{name: left.*), ff: full\}$": r"\1, ff: gravity}"})
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        _stop_and_continue_dynamics(inst, client)
        client.close()


def _stop_and_continue_dynamics(inst: Instance, client: ServoClient) -> None:
    ffc = inst.config.feedforward
    rec = ff_records(inst)
    r = client.level.joints
    client.power("left", True)
    _wait("left powered", lambda: client.power_state("left") == PowerState.ON, 5.0)
    _wait("feed-forward on", lambda: float(rec["weight"][0]) == 1.0, 5.0)
    assert FfMode(int(rec["mode"][0])) == FfMode.GRAVITY
    assert FfState(int(rec["state"][0])) == FfState.ON
    gravity = r["ff_torque"][LEFT].copy()
    assert abs(gravity[1]) > 5.0, f"joint 2 gravity feed-forward {gravity[1]:.2f} N·m"
    pid = int(inst.procs[inst.find_slot("dynamics")]["pid"])
    os.kill(pid, signal.SIGSTOP)
    try:
        went = _wait(
            "STALE", lambda: int(rec["state"][0]) == FfState.STALE, 2.0 + ffc.stale_ms / 1e3
        )
        _wait("faded out", lambda: not r["ff_torque"][LEFT].any(), 2.0 + ffc.ramp_ms / 1e3)
        assert int(rec["stale_events"][0]) == 1
        assert client.power_state("left") == PowerState.ON
        assert inst.fault_text() is None
    finally:
        os.kill(pid, signal.SIGCONT)
    _wait("back on", lambda: int(rec["state"][0]) == FfState.ON, 2.0)
    _wait("faded in", lambda: float(rec["weight"][0]) == 1.0, 2.0 + ffc.ramp_ms / 1e3)
    np.testing.assert_allclose(r["ff_torque"][LEFT], gravity, atol=0.5)
    assert int(rec["stale_events"][0]) == 1
    assert inst.fault_text() is None
    assert went < 1.0 + ffc.stale_ms / 1e3


def test_kalictl_ff_names_the_modes_and_robots(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    r = kalictl("-i", name, "ff", "gravity", "right")
    assert r.returncode == 0 and "feed-forward gravity: right" in r.stdout, r.stderr
    r = kalictl("-i", name, "ff", "on")
    assert r.returncode == 0 and "feed-forward full: left, right" in r.stdout, r.stderr
    r = kalictl("-i", name, "ff", "loud", "left")
    assert r.returncode != 0 and "loud" in r.stderr
    r = kalictl("-i", name, "ff", "off", "middle")
    assert r.returncode != 0 and "middle" in r.stderr and "left, right" in r.stderr
    with Instance.attach(name) as inst:
        assert list(ff_records(inst)["mode"]) == [FfMode.FULL, FfMode.FULL]


def test_the_start_hint_names_the_arms_without_feed_forward_and_how_to_turn_it_on() -> None:
    """Issue 52 item 5: ``kalictl start``'s line (cli.feedforward_hint) for arms starting
    without the dynamics feed-forward: none where every arm has it (the shipped configs), the
    arm to name where one is off, every arm where all are (or the dynamics process is left
    out), the instance where it is not the default one."""
    from kali_daemons.tools.cli import feedforward_hint

    assert feedforward_hint(make_config("default"), "default") is None
    gravity = {r"^(  - \{name: left,.*), ff: full\}$": r"\1, ff: gravity}"}
    assert feedforward_hint(make_config("default", gravity), "default") is None
    right_off = {r"^(  - \{name: right,.*), ff: full\}$": r"\1, ff: off}"}
    assert feedforward_hint(make_config("default", right_off), "default") == (
        "feed-forward off: right (its servos alone follow its motions, and lag); turn it on "
        "with ff: full in the config or kalictl ff on right"
    )
    all_off = {r"^(  - \{name: .*), ff: full\}$": r"\1, ff: off}"}
    assert feedforward_hint(make_config("lab", all_off), "lab") == (
        "feed-forward off: left, right (their servos alone follow their motions, and lag); "
        "turn it on with ff: full in the config or kalictl -i lab ff on"
    )
    no_dynamics = {r"^(  dynamics: +\{)": r"\1enabled: false, "}
    assert feedforward_hint(make_config("default", no_dynamics), "default") == (
        "feed-forward off: left, right (the dynamics process is left out: their servos alone "
        "follow their motions, and lag); turn it on with processes.dynamics.enabled: true "
        "in the config"
    )
