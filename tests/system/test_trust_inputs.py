"""Issue 24, items 3 and 8: the e-stop and reset keep LinuxCNC's promise (a halt voids every
pending power and calibration command; ``reset`` with a button still pressed is refused), and
the config and command-line inputs that used to start, hang or trace back are refused with one
line naming the value and the limit.

Functional tests start a real instance in lockstep and drive it as a user would, through
``kalictl`` where the user would.
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from kali_daemons.config import load_config, parse_config
from kali_daemons.errors import ConfigError
from kali_daemons.instance import Instance
from kali_daemons.layout import PowerCmd, PowerState
from kali_daemons.servolevel import ServoClient
from kali_daemons.wallclock import step_kali_clock

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
        ("laughs-as-arena", "arena_kib: 4096", "aliases expand to more than"),
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
