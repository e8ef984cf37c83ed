"""Issue 24, items 3 and 8: the e-stop and reset keep LinuxCNC's promise (a halt voids every
pending power and calibration command; ``reset`` with a button still pressed is refused), and
the config and command-line inputs that used to start, hang or trace back are refused with one
line naming the value and the limit.

Functional tests start a real instance in lockstep and drive it as a user would, through
``kalictl`` where the user would.
"""

from __future__ import annotations

import os
import re
import signal
import threading
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.core.errors import ConfigError
from kali_daemons.core.layout import PowerCmd, PowerState
from kali_daemons.runtime.config import arena_need, load_config, parse_config
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo import MAX_DATA_BYTES
from kali_daemons.servo.client import ServoClient
from kali_daemons.tools import launcher
from kali_daemons.wallclock import step_kali_clock

from ..conftest import leftovers, make_config, unique_name, wait_for
from ..test_config import DEFAULT_TEXT
from ..test_launcher import kalictl

POTS_TICKS = 30  # SIO reads the potentiometers first
POWER_TICKS = 200  # enable bit, relay, brakes: well within this


def _ok(*args: str) -> str:
    r = kalictl(*args)
    assert r.returncode == 0, (args, r.stdout, r.stderr)
    return r.stdout


def _powers(client: ServoClient) -> list[PowerState]:
    return [client.power_state(r) for r in client.names]


# ------------------------------------------------------------------ item 3: e-stop and reset


def test_an_enable_pending_at_an_estop_is_void_after_reset(kali: Callable[..., str]) -> None:
    """enable, estop, estop --release, reset: the arms stay off (they powered on by
    themselves, in lockstep, because SIO took the enable written before the halt)."""
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            step_kali_clock(inst, POTS_TICKS)
            _ok("-i", name, "enable")
            _ok("-i", name, "estop")
            _ok("-i", name, "estop", "--release")
            _ok("-i", name, "reset")
            step_kali_clock(inst, POWER_TICKS)
            assert inst.fault_text() is None
            assert _powers(client) == [PowerState.OFF] * 2
            # an enable after the reset is taken as usual
            _ok("-i", name, "enable")
            step_kali_clock(inst, POWER_TICKS)
            assert _powers(client) == [PowerState.ON] * 2, inst.fault_text()
        finally:
            client.close()


def test_a_power_command_written_during_a_halt_is_never_taken(kali: Callable[..., str]) -> None:
    """A command word written straight into the arena while a fault is active (past the
    client's own refusal) is void: neither taken when the fault is cleared nor later."""
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            step_kali_clock(inst, POTS_TICKS)
            _ok("-i", name, "estop")
            _ok("-i", name, "estop", "--release")
            robots = client.level.robots
            robots["power_cmd"][:] = PowerCmd.ENABLE
            robots["calib_cmd"][:] = 1
            _ok("-i", name, "reset")
            step_kali_clock(inst, POWER_TICKS)
            assert _powers(client) == [PowerState.OFF] * 2
            assert [int(v) for v in robots["power_cmd"]] == [0, 0]
            assert [int(v) for v in robots["calib_cmd"]] == [0, 0]
        finally:
            client.close()


def test_reset_with_an_estop_button_still_pressed_is_refused(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        _ok("-i", name, "estop", "right")
        r = kalictl("-i", name, "reset")
        assert r.returncode == 1, r.stdout
        assert "robot 'right'" in r.stderr and "e-stop" in r.stderr, r.stderr
        assert "kalictl estop --release right" in r.stderr, r.stderr
        assert inst.fault["active"]  # nothing cleared
        _ok("-i", name, "estop", "--release", "right")
        assert "cleared" in _ok("-i", name, "reset")
        assert inst.fault_text() is None


# ------------------------------------------------------------------ item 8: config inputs

FAST_S = 3.0  # "refused fast": well under this, on a loaded two-core machine


def _laughs(levels: int = 9) -> str:
    """A flow list of ``levels`` anchors, each ten aliases of the one before: 10**levels
    leaves once expanded ("billion laughs")."""
    items = ["&x0 [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]"]
    items += [f"&x{i} [" + ", ".join([f"*x{i - 1}"] * 10) + "]" for i in range(1, levels)]
    return "[" + ", ".join(items) + "]"


def _refused_fast(call: Callable[[], object], expected: str) -> str:
    """``call`` raises a one-line ConfigError containing ``expected`` within FAST_S; the test
    thread never waits on it longer than that (a hang fails, it does not hang the suite)."""
    box: dict[str, BaseException | None] = {}

    def run() -> None:
        try:
            call()
            box["exc"] = None
        except BaseException as exc:  # handed to the test thread
            box["exc"] = exc

    t0 = time.monotonic()
    worker = threading.Thread(target=run, daemon=True)
    worker.start()
    worker.join(FAST_S)
    assert "exc" in box, f"not refused within {FAST_S} s (still running)"
    exc = box["exc"]
    assert isinstance(exc, ConfigError), repr(exc)
    text = str(exc)
    assert "\n" not in text and expected in text, text
    assert time.monotonic() - t0 < FAST_S
    return text


@pytest.mark.parametrize(
    ("case", "key", "expected"),
    [
        ("laughs-as-instance", "instance: default", "aliases expand to more than"),
        ("laughs-as-arena", "arena_kib: 6144", "aliases expand to more than"),
    ],
)
def test_an_alias_bomb_is_refused_fast(case: str, key: str, expected: str) -> None:
    text = DEFAULT_TEXT.replace(key, key.split(":")[0] + ": " + _laughs(), 1)
    _refused_fast(lambda: parse_config(text, case), expected)


@pytest.mark.parametrize("opening", ["[", "{a: "])
def test_deep_nesting_is_refused_fast(opening: str) -> None:
    closing = "]" if opening == "[" else "}"
    text = "version: 1\ninstance: x\nrobots: " + opening * 50_000 + "1" + closing * 50_000
    _refused_fast(lambda: parse_config(text, "deep"), "nested deeper than")


def test_a_config_that_is_dev_zero_is_refused_fast() -> None:
    _refused_fast(lambda: load_config("/dev/zero"), "not a regular file (a character device)")


def test_a_config_that_is_a_fifo_is_refused_fast(tmp_path: Path) -> None:
    fifo = tmp_path / "cfg.fifo"
    os.mkfifo(fifo)  # nobody writes: opening it for reading would wait for a writer forever
    _refused_fast(lambda: load_config(fifo), "not a regular file (a FIFO)")


def test_a_config_file_larger_than_the_limit_is_refused(tmp_path: Path) -> None:
    big = tmp_path / "big.yaml"
    big.write_text(DEFAULT_TEXT + "#" * (2 << 20))
    _refused_fast(lambda: load_config(big), "larger than")


def test_kalictl_start_with_dev_zero_is_one_line() -> None:
    r = kalictl("start", "-c", "/dev/zero")
    assert r.returncode != 0 and "not a regular file" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_the_arena_needed_is_what_an_instance_uses(kali: Callable[..., str]) -> None:
    """The size computed at parse time is at least what a started instance lays out (header
    and directory plus every block), and more only by the plugins' largest allowance (their
    dtypes are not known before they are imported)."""
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        step_kali_clock(inst, POTS_TICKS)  # every daemon has laid out its records
        cfg = inst.config
        stats = inst.arena.stats()
        used = layout.header_bytes() + stats.used_bytes
        need, blocks, _ = arena_need(cfg)
        # a plugin's joint servo for every joint and robot-level servo for every robot
        allowance = (6 + 1) * len(cfg.robots) * MAX_DATA_BYTES * len(cfg.plugins)
        assert used <= need <= used + allowance, (need, used, allowance)
        # each plugin counted as possibly registering a robot-level servo's block too
        assert blocks == stats.used_blocks + stats.free_fragments + len(cfg.plugins)


@pytest.mark.parametrize("kib", [256, 1024, 1800])
def test_an_arena_too_small_is_refused_at_parse_time(kib: int) -> None:
    """256-1024 KiB used to start and then fail 6 s later in whichever daemon came last."""
    text = DEFAULT_TEXT.replace("arena_kib: 6144", f"arena_kib: {kib}")
    with pytest.raises(ConfigError) as info:
        parse_config(text, "small.yaml")
    need_kib = -(-arena_need(parse_config(DEFAULT_TEXT, "x"))[0] // 1024)
    assert f"arena_kib = {kib}: the cell needs {need_kib} KiB" in str(info.value)
    assert f"set arena_kib to at least {need_kib}" in str(info.value)


# ------------------------------------------------------------------ item 8: command line


def _one_line_error(r: object, *expected: str) -> str:
    """A refused kalictl command: exit 1, one line on stderr containing every ``expected``."""
    err = r.stderr.strip()
    assert r.returncode == 1, (r.returncode, r.stdout, err)
    assert "Traceback" not in err and len(err.splitlines()) == 1, err
    for e in expected:
        assert e in err, err
    return err


def test_top_interval_must_be_a_finite_number_in_range(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    for value in ("nan", "inf", "0", "-1", "61"):
        r = kalictl("-i", name, "top", "--once", "--interval", value)
        _one_line_error(r, f"--interval {value}", "0.05", "60")


def _dump_of_an_estop(name: str) -> Path:
    """Press the e-stop and let the wall clock write the flight dump; its path."""
    _ok("-i", name, "estop")
    out = _ok("-i", name, "flight")
    path = Path(re.search(r"flight recorder dump (\S+)", out).group(1))
    assert "fault: ESTOP" in out, out
    return path


def test_corrupt_flight_dumps_give_one_line(kali: Callable[..., str], tmp_path: Path) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        step_kali_clock(inst, POTS_TICKS)
    good = _dump_of_an_estop(name)
    data = good.read_bytes()
    cases = {
        "half": data[: len(data) // 2],  # a copy cut short
        "head": data[:100],
        "tail": data[len(data) // 2 :],
        "garbage": bytes(range(256)) * 64,
        "empty": b"",
    }
    for label, blob in cases.items():
        bad = tmp_path / f"{label}.npz"
        bad.write_bytes(blob)
        _one_line_error(kalictl("-i", name, "flight", str(bad)), str(bad))
    # a zip of the right names whose arrays have the wrong shapes
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files}
    arrays["q"] = np.zeros(3)
    arrays["tick"] = np.array([[1, 2], [3, 4]])
    shapes = tmp_path / "shapes.npz"
    np.savez(shapes, **arrays)
    _one_line_error(kalictl("-i", name, "flight", str(shapes)), str(shapes))


def _powered(name: str) -> tuple[Instance, ServoClient]:
    inst = Instance.attach(name)
    client = ServoClient(inst)
    step_kali_clock(inst, POTS_TICKS)
    for robot in client.names:
        client.power(robot, True)
    step_kali_clock(inst, POWER_TICKS)
    assert _powers(client) == [PowerState.ON] * 2
    return inst, client


def test_move_validates_every_argument_before_anything_moves(kali: Callable[..., str]) -> None:
    """Each refused: one line naming the argument; then, clock stepped, nothing moved."""
    name = kali(lockstep=True)
    inst, client = _powered(name)
    try:
        demand = np.array(client.level.joints["demand"].reshape(2, 6))
        go = ["-i", name, "move", "left", "--joints", "10,0,0,0,0,0"]
        cases = [
            (["-i", name, "move", "lfet", "--joints", "0,0,0,0,0,0"], "'lfet'"),
            (["-i", name, "move", "left", "--joints", "0,0,0,0,0"], "5 values, expected 6"),
            (["-i", name, "move", "left", "--joints", "0,0,0,0,0,nan"], "nan"),
            (["-i", name, "move", "left", "--joints", "0,0,0,inf,0,0"], "inf"),
            (["-i", name, "move", "left", "--joints", "0,0,0,0,0,1e400"], "1e400"),
            ([*go, "--speed", "nan"], "--speed nan"),
            ([*go, "--speed", "0"], "--speed 0"),
            ([*go, "--timeout", "nan"], "--timeout nan"),
            ([*go, "--timeout", "-1"], "--timeout -1"),
            ([*go, "--timeout", "inf"], "--timeout inf"),
            ([*go, "--timeout", "0"], "--timeout 0"),
        ]
        for args, expected in cases:
            _one_line_error(kalictl(*args), "move", expected)
        step_kali_clock(inst, 300)
        assert np.abs(client.level.joints["demand"].reshape(2, 6) - demand).max() < 1e-6
    finally:
        client.close()
        inst.close()


@pytest.mark.serial
def test_move_timeout_is_a_clear_error(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Real time: a move not there within --timeout is one line naming the robot, the request
    and the timeout (it was a TimeoutError traceback)."""
    name = unique_name()
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path / "logs"))
    launcher.start(make_config(name), lockstep=False)
    try:
        _ok("-i", name, "enable")
        r = kalictl("-i", name, "move", "left", "--joints", "60,60,-60,0,0,0", "--timeout", "0.05")
        _one_line_error(r, "robot 'left'", "request", "not there within 0.05 s")
    finally:
        launcher.stop(name)
        assert leftovers(name) == ([], [])


# ------------------------------------------------------------------ item 8: flight dumps


@pytest.mark.serial
def test_the_wall_clocks_death_leaves_a_flight_dump(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True, separate=True)  # the wall clock alone is killed
    with Instance.attach(name) as inst:
        step_kali_clock(inst, POTS_TICKS)
        os.kill(int(inst.clock["pid"]), signal.SIGKILL)
        wait_for(lambda: bool(inst.fault["active"]), 10.0, "a halt naming the wall clock")
        assert "wall clock" in inst.fault_text()
    out = _ok("-i", name, "flight")
    assert "fault: PROCESS_DIED in wallclock" in out and "died" in out, out


def test_flight_never_shows_an_earlier_runs_dump_as_this_halt(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Run 1 halts and leaves a dump; run 2 of the same instance has not halted: kalictl
    flight says so and names the earlier dump, it does not present it as this run's."""
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path / "logs"))
    name = unique_name()
    try:
        launcher.start(make_config(name), lockstep=True)
        with Instance.attach(name) as inst:
            step_kali_clock(inst, POTS_TICKS)
        earlier = _dump_of_an_estop(name)
        launcher.stop(name)
        launcher.start(make_config(name), lockstep=True)
        r = kalictl("-i", name, "flight")
        err = _one_line_error(r, f"instance '{name}' has not halted since it started")
        assert str(earlier) in err and "earlier run" in err, err
        # a file named explicitly is shown, whatever run it is from
        assert "fault: ESTOP" in _ok("-i", name, "flight", str(earlier))
    finally:
        launcher.stop(name)
        assert leftovers(name) == ([], [])


def test_flight_never_shows_an_earlier_halts_dump_when_this_ones_failed(
    kali: Callable[..., str],
) -> None:
    """Two halts; the second's dump cannot be written (its directory is gone, a file in its
    place): kalictl flight says there is no dump of this halt and why, not the first's."""
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        step_kali_clock(inst, POTS_TICKS)
    first = _dump_of_an_estop(name)
    _ok("-i", name, "estop", "--release")
    _ok("-i", name, "reset")
    logs = launcher.log_dir(name)
    logs.rename(logs.with_name(f"{name}.moved"))
    logs.write_text("a file where the log directory was\n")
    _ok("-i", name, "estop")
    r = kalictl("-i", name, "flight")
    err = _one_line_error(r, "no dump of this halt (ESTOP in kalictl", "dump to", "failed")
    assert f"{first} is of an earlier halt" in err, err


# ------------------------------------------------------------------ item 8: logs


@pytest.mark.serial
def test_two_instances_never_share_log_files(kali: Callable[..., str], tmp_path: Path) -> None:
    a, b = kali(lockstep=True, separate=True), kali(lockstep=True, separate=True)  # a log each
    da, db = launcher.log_dir(a), launcher.log_dir(b)
    assert da != db and da.parent == db.parent == tmp_path / "logs"
    for d in (da, db):
        assert (d / "sio.log").is_file(), sorted(p.name for p in d.iterdir())
    assert not (tmp_path / "logs" / "sio.log").exists()


# ------------------------------------------------------------------ item 8: servo plugins

BAD_STEP = """
import numpy as np
from kali_daemons.servo import STATUS_OK, ServoAlgorithm

DTYPE = np.dtype([("kp", "<f8")], align=True)


def init(data, init_data, interval):
    data.kp = float(init_data.get("kp", 1.0))


def step(data, demand, position):
    return RESULT


def register(registry):
    registry.register(ServoAlgorithm(
        "badstep", DTYPE, ("kp",), init, step, lambda d, h: None,
        lambda d, v: init(d, v, 0.001), lambda d: {"kp": d.kp},
    ))
"""


@pytest.mark.parametrize(
    ("result", "shown"),
    [
        ("data.kp * (demand - position)", "returned 0.01"),  # a bare torque
        ("[1.0, 0.0, 0]", "returned [1.0, 0.0, 0]"),
        ("(1.0, 0.0)", "returned (1.0, 0.0)"),
        ("('1.0', 0.0, 0)", "returned ('1.0', 0.0, 0)"),
        ("(float('nan'), 0.0, 0)", "returned (nan, 0.0, 0)"),
        ("(1.0, 0.0, 0.5)", "returned (1.0, 0.0, 0.5)"),
    ],
)
def test_a_plugin_step_returning_the_wrong_type_is_refused_at_start(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, result: str, shown: str
) -> None:
    monkeypatch.setenv("KALI_LOG_DIR", str(tmp_path / "logs"))
    plugin = tmp_path / "badstep.py"
    plugin.write_text(BAD_STEP.replace("RESULT", result))
    name = unique_name()
    cfg = make_config(name, {r"(?m)^plugins: .*$": f"plugins: [{plugin}]"})
    try:
        with pytest.raises(ConfigError) as info:
            launcher.start(cfg, lockstep=True)
    finally:
        launcher.stop(name)  # had it started (the old code did), nothing is left behind
    text = str(info.value)
    assert f"plugin '{plugin}'" in text and "'badstep'" in text and shown in text, text
    assert "(torque, error, status)" in text, text
    assert leftovers(name) == ([], [])


def test_servo_gains_beyond_the_declared_bounds_are_refused(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    r = kalictl("-i", name, "servo", "set", "left", "2", "kp=1e9")
    _one_line_error(r, "parameter kp = 1e+09 N·m/rad must be <= 1e+06")
    r = kalictl("-i", name, "servo", "set", "left", "2", "integration_band=4")
    _one_line_error(r, "parameter integration_band = 4 rad must be <= 3.14159")
    assert "kp=13000" in _ok("-i", name, "servo", "get", "left", "2")  # unchanged
