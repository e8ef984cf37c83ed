"""Tests for kali_daemons.runtime.config: the default file, every rejection path, and immutability.

Malformed configs are small edits of config/default.yaml, so each case shows exactly which
change is wrong and which message (field path, value, what is allowed) it must produce.
"""

from __future__ import annotations

import dataclasses
import os
from pathlib import Path

import pytest

from kali_daemons.core.errors import ConfigError
from kali_daemons.hardware.registry import hardware_kind
from kali_daemons.runtime import config as config_mod
from kali_daemons.runtime.config import (
    CONFIG_VERSION,
    PROCESS_NAMES,
    ClockConfig,
    KaliConfig,
    PlantConfig,
    ProcessConfig,
    RobotConfig,
    load_config,
    parse_config,
    with_overrides,
)

from .conftest import make_config

DEFAULT_PATH = Path(__file__).resolve().parents[1] / "config" / "default.yaml"
DEFAULT_TEXT = DEFAULT_PATH.read_text(encoding="utf-8")
SOURCE = "config/default.yaml"
FAKE_CPUS = 4


@pytest.fixture(autouse=True)
def _fixed_cpu_count(monkeypatch: pytest.MonkeyPatch) -> None:
    """Pretend every machine has FAKE_CPUS CPUs so messages and defaults are deterministic."""
    monkeypatch.setattr(config_mod, "_cpu_count", lambda: FAKE_CPUS)


def edit(*pairs: tuple[str, str]) -> str:
    """The default text with each ``(old, new)`` applied; ``old`` must occur exactly once."""
    text = DEFAULT_TEXT
    for old, new in pairs:
        assert text.count(old) == 1, f"edit target {old!r} must occur exactly once"
        text = text.replace(old, new)
    return text


def error_of(text: str) -> str:
    """The ConfigError message parse_config gives for ``text``."""
    with pytest.raises(ConfigError) as info:
        parse_config(text, SOURCE)
    return str(info.value)


def line_of(fragment: str) -> int:
    """1-based line number of ``fragment`` in the default text."""
    for number, line in enumerate(DEFAULT_TEXT.splitlines(), 1):
        if fragment in line:
            return number
    raise AssertionError(fragment)


EXPECTED_PROCESSES = (
    ProcessConfig("wallclock", "wallclock", 0, 90, 1, False, 0),
    ProcessConfig("plant", "plant", 1, 83, 1, True, 0),
    ProcessConfig("tg", "tg", 1, 80, 10, True, 1),
    ProcessConfig("sio", "sio", 0, 85, 1, True, 2),
    ProcessConfig("sv.0", "sv", 0, 84, 1, True, 2, 200, 4),
    ProcessConfig("sv.1", "sv", 1, 84, 1, True, 2, 200, 4),
    ProcessConfig("dynamics", "dynamics", 1, 40, 10, False, 3),
    ProcessConfig("viewer", "viewer", 1, 0, 40, False, 4),
)
EXPECTED_ROBOTS = (
    RobotConfig("left", "puma560", (-0.6, 0.0, 0.0), 0.0, ff="full"),
    RobotConfig("right", "puma560", (0.6, 0.0, 0.0), 180.0, ff="full"),
)


# --------------------------------------------------------------------------------------------
# The default file


def test_default_file_loads_to_expected_objects() -> None:
    cfg = load_config(DEFAULT_PATH)
    assert cfg == KaliConfig(
        version=CONFIG_VERSION,
        instance="default",
        arena_kib=6144,
        startup_timeout_s=60.0,
        clock=ClockConfig(1, 1, 10, 20, 5.0, 0),
        processes=EXPECTED_PROCESSES,
        robots=EXPECTED_ROBOTS,
        source=str(DEFAULT_PATH),
        text=DEFAULT_TEXT,
        plugins=("kali_daemons.examples.servo_plugin_example",),
        tg_functions=("kali_daemons.examples.tg_function_example",),
        plant=PlantConfig(conveyor_m_s=(0.0, 0.02)),
        base_dir=str(DEFAULT_PATH.parent),
    )
    assert isinstance(cfg.startup_timeout_s, float)  # the YAML says 60: int accepted as float
    assert isinstance(cfg.robots[0].base_yaw_deg, float)


def test_default_file_round_trips_through_its_text() -> None:
    cfg = load_config(DEFAULT_PATH)
    assert parse_config(cfg.text, cfg.source, cfg.base_dir) == cfg


@pytest.mark.parametrize("name", ["default.yaml", "mixed.yaml", "force.yaml", "bridge.yaml"])
def test_the_shipped_cells_start_every_arm_with_full_feed_forward(name: str) -> None:
    """Issue 52 item 5: the simulator's dynamics model is exact (the plant and the dynamics
    process build each arm from the same URDF and drive facts), so the configs a researcher
    starts from start every arm with the full feed-forward (tests/test_mixed_cell.py: the
    Panda's tool lags 1.3 mm on a 5 cm/s circle without it); a config leaving out its robots
    gets default.yaml's, and an arm written without ``ff`` starts without."""
    path = DEFAULT_PATH.parent / name
    cfg = load_config(path)
    assert [r.ff for r in cfg.robots] == ["full"] * len(cfg.robots)
    bare = parse_config("version: 1\ninstance: x\nrobots:\n  - {name: a, model: puma560}\n")
    assert bare.robots[0].ff == "off"


def test_default_file_loads_on_this_machine(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.undo()  # the real CPU count
    if (os.cpu_count() or 1) < 2:
        pytest.skip("config/default.yaml binds CPU 1; this machine has one CPU")
    assert load_config(DEFAULT_PATH).processes == EXPECTED_PROCESSES


def test_optional_sections_default_to_the_default_file() -> None:
    minimal = parse_config("version: 1\ninstance: default\n")
    full = parse_config(DEFAULT_TEXT)
    # the default file names the example plugins and gives the stand a belt; without the
    # sections there are none
    assert full.plugins == ("kali_daemons.examples.servo_plugin_example",)
    assert minimal.plugins == ()
    assert full.tg_functions == ("kali_daemons.examples.tg_function_example",)
    assert minimal.tg_functions == () and minimal.plant.conveyor_m_s == (0.0, 0.0)
    bare = dataclasses.replace(full, text="", plugins=(), tg_functions=(), plant=PlantConfig())
    assert dataclasses.replace(minimal, text="") == bare


def test_process_entries_default_per_kind() -> None:
    text = "version: 1\ninstance: x\n"
    text += "clock: {base_tick_ms: 3, servo_period_ms: 6, tg_period_ms: 15}\n"
    text += "processes: {" + ", ".join(f"{k}: {{}}" for k in PROCESS_NAMES) + "}\n"
    cfg = parse_config(text)
    periods = {p.name: p.period_ms for p in cfg.processes}
    # servo/TG ratio 2.5 is allowed; the viewer's 40 ms is rounded up to whole ticks.
    assert periods == {
        "wallclock": 3,
        "plant": 3,
        "tg": 15,
        "sio": 6,
        "sv.0": 6,
        "sv.1": 6,
        "dynamics": 15,
        "viewer": 42,
    }
    assert {p.name: p.stage for p in cfg.processes} == {
        "wallclock": 0,
        "plant": 0,
        "tg": 1,
        "sio": 2,
        "sv.0": 2,
        "sv.1": 2,
        "dynamics": 3,
        "viewer": 4,
    }
    assert all(p.cpu is None and p.priority == 0 for p in cfg.processes)
    # left out, ``serious`` is as in the default config: a servo process never loses its halt
    serious = {"plant", "tg", "sio", "sv.0", "sv.1"}
    assert {p.name for p in cfg.processes if p.serious} == serious


def test_sv_count_expands_workers_in_order() -> None:
    cfg = parse_config(edit(("{count: 2, cpus: [0, 1],", "{count: 3, cpus: [null, 3, 2],")), SOURCE)
    names = [p.name for p in cfg.processes]
    workers = ["sv.0", "sv.1", "sv.2"]
    assert names == ["wallclock", "plant", "tg", "sio", *workers, "dynamics", "viewer"]
    assert [cfg.process(f"sv.{i}").cpu for i in range(3)] == [None, 3, 2]


def test_process_lookup_and_periodic() -> None:
    cfg = parse_config(DEFAULT_TEXT, SOURCE)
    assert cfg.process("sv.1") == EXPECTED_PROCESSES[5]
    assert cfg.periodic() == EXPECTED_PROCESSES[1:]
    with pytest.raises(ConfigError, match=r"no process 'sv'; known processes: wallclock, plant"):
        cfg.process("sv")


# --------------------------------------------------------------------------------------------
# Malformed configs: each a small edit of the default text and a substring its error must hold

CPU_MSG = f"must be null or a CPU index 0..{FAKE_CPUS - 1} (this machine has {FAKE_CPUS} CPUs)"

BAD_CONFIGS: list[tuple[str, list[tuple[str, str]], str]] = [
    (
        "plant-substep-not-dividing-the-plant-period",
        [("substep_ms: 0.5 ", "substep_ms: 0.3 ")],
        "plant.substep_ms = 0.3: must divide processes.plant.period_ms = 1 (the plant advances "
        "one period per cycle, in whole substeps)",
    ),
    (
        "plant-substep-longer-than-the-plant-period",
        [
            ("base_tick_ms: 1 ", "base_tick_ms: 0.5 "),
            ("period_ms: 1, serious: true, stage: 0", "period_ms: 0.5, serious: true, stage: 0"),
            ("substep_ms: 0.5 ", "substep_ms: 1 "),
        ],
        "plant.substep_ms = 1.0: must divide processes.plant.period_ms = 0.5",
    ),
    (
        "plant-unknown-key",
        [("  brake_delay_ms: 50 ", "  brake_delay: 50 ")],
        "plant.brake_delay: unknown key (did you mean 'brake_delay_ms'?); allowed keys: ",
    ),
    (
        "plant-negative-watchdog",
        [("watchdog_ms: 20 ", "watchdog_ms: -5 ")],
        "plant.watchdog_ms = -5",
    ),
    (
        "plant-watchdog-not-longer-than-the-retrigger-cycle",
        [("watchdog_ms: 20 ", "watchdog_ms: 4 ")],
        "plant.watchdog_ms = 4.0: must be > 4: SIO retriggers the board every 4 ms (each level "
        "held for the whole 1 ms servo periods that last two plant periods, 1 ms, so that the "
        "board reads it)",
    ),
    (
        "plant-watchdog-not-longer-than-the-retrigger-cycle-of-a-slow-plant",
        [
            ("period_ms: 1, serious: true, stage: 0", "period_ms: 10, serious: true, stage: 0"),
            ("watchdog_ms: 20 ", "watchdog_ms: 40 "),
        ],
        "plant.watchdog_ms = 40.0: must be > 40: SIO retriggers the board every 40 ms",
    ),
    # (id, edits, expected substring of the message)
    (
        "tick-negative",
        [("base_tick_ms: 1 ", "base_tick_ms: -1 ")],
        "config: config/default.yaml: clock.base_tick_ms = -1: must be a number >= 0.1 and "
        "<= 100 that is a whole number of microseconds (e.g. 0.5 or 0.25)",
    ),
    (
        "tick-too-big",
        [("base_tick_ms: 1 ", "base_tick_ms: 101 ")],
        "clock.base_tick_ms = 101: must be a number >= 0.1 and <= 100 that is a whole number",
    ),
    (
        "tick-not-whole-microseconds",
        [("base_tick_ms: 1 ", "base_tick_ms: 0.1234 ")],
        "clock.base_tick_ms = 0.1234: must be a number >= 0.1 and <= 100 that is a whole number "
        "of microseconds (e.g. 0.5 or 0.25)",
    ),
    (
        "tick-below-a-tenth-of-a-ms",
        [("base_tick_ms: 1 ", "base_tick_ms: 0.0005 ")],
        "clock.base_tick_ms = 0.0005: must be a number >= 0.1 and <= 100 that is a whole number "
        "of microseconds",
    ),
    (
        "tick-string",
        [("base_tick_ms: 1 ", "base_tick_ms: '1' ")],
        "clock.base_tick_ms = '1': must be a number >= 0.1 and <= 100 that is a whole number of "
        "microseconds (e.g. 0.5 or 0.25), not a string",
    ),
    (
        "tick-bool",
        [("base_tick_ms: 1 ", "base_tick_ms: true ")],
        "clock.base_tick_ms = true: must be a number >= 0.1",
    ),
    (
        "servo-not-multiple-of-tick",
        [("base_tick_ms: 1 ", "base_tick_ms: 2 "), ("servo_period_ms: 1 ", "servo_period_ms: 3 ")],
        "clock.servo_period_ms = 3: must be a multiple of clock.base_tick_ms (2)",
    ),
    (
        "servo-not-multiple-of-fractional-tick",
        [
            ("base_tick_ms: 1 ", "base_tick_ms: 0.2 "),
            ("servo_period_ms: 1 ", "servo_period_ms: 0.3 "),
        ],
        "clock.servo_period_ms = 0.3: must be a multiple of clock.base_tick_ms (0.2)",
    ),
    (
        "servo-shorter-than-fractional-tick",
        [
            ("base_tick_ms: 1 ", "base_tick_ms: 0.5 "),
            ("servo_period_ms: 1 ", "servo_period_ms: 0.25 "),
        ],
        "clock.servo_period_ms = 0.25: must be a multiple of clock.base_tick_ms (0.5)",
    ),
    (
        "servo-default-not-multiple-of-tick",
        [("base_tick_ms: 1 ", "base_tick_ms: 3 "), ("  servo_period_ms: 1 ", "  # (deleted) ")],
        "clock.servo_period_ms = 1: must be a multiple of clock.base_tick_ms (3) (the default; "
        "set clock.servo_period_ms explicitly)",
    ),
    (
        "servo-zero",
        [("servo_period_ms: 1 ", "servo_period_ms: 0 ")],
        "clock.servo_period_ms = 0: must be a number > 0 and <= 60000",
    ),
    (
        "tg-faster-than-servo",
        [("servo_period_ms: 1 ", "servo_period_ms: 20 ")],
        "clock.tg_period_ms = 10: must be >= clock.servo_period_ms (20)",
    ),
    (
        "miss-tolerance-too-big",
        [("serious_miss_tolerance_ms: 20", "serious_miss_tolerance_ms: 1001")],
        "clock.serious_miss_tolerance_ms = 1001: must be an integer >= 0 and <= 1000",
    ),
    (
        "ack-timeout-zero",
        [("lockstep_ack_timeout_s: 5.0", "lockstep_ack_timeout_s: 0")],
        "clock.lockstep_ack_timeout_s = 0: must be a number > 0 and <= 600",
    ),
    (
        "ack-timeout-nan",
        [("lockstep_ack_timeout_s: 5.0", "lockstep_ack_timeout_s: .nan")],
        "clock.lockstep_ack_timeout_s = nan: must be a number > 0 and <= 600",
    ),
    (
        "busy-wait-too-long",
        [("busy_wait_us: 0 ", "busy_wait_us: 501 ")],
        "clock.busy_wait_us = 501: must be an integer >= 0 and <= 500",
    ),
    (
        "sv-poll-too-long",
        [("poll_us: 200", "poll_us: 501")],
        "processes.sv.poll_us = 501: must be an integer >= 0 and <= 500",
    ),
    (
        "sv-poll-negative",
        [("poll_us: 200", "poll_us: -1")],
        "processes.sv.poll_us = -1: must be an integer >= 0 and <= 500",
    ),
    (
        "sv-rest-not-a-tick-multiple",
        [("poll_us: 200}", "poll_us: 200, rest_ms: 2.5}")],
        "processes.sv.rest_ms = 2.5: must be a multiple of clock.base_tick_ms (1)",
    ),
    (
        "sv-rest-too-long",
        [("poll_us: 200}", "poll_us: 200, rest_ms: 21}")],
        "processes.sv.rest_ms = 21: must be 0 or a whole multiple of clock.servo_period_ms "
        "(1) up to clock.serious_miss_tolerance_ms (20)",
    ),
    (
        "sv-rest-negative",
        [("poll_us: 200}", "poll_us: 200, rest_ms: -4}")],
        "processes.sv.rest_ms = -4: must be a number > 0 and <= 60000",
    ),
    (
        "poll-on-sio",
        [("stage: 2}\n  # sv", "stage: 2, poll_us: 200}\n  # sv")],
        "processes.sio.poll_us: unknown key",
    ),
    (
        "version-2",
        [("version: 1", "version: 2")],
        "version = 2: unsupported; this Kali reads version 1",
    ),
    (
        "version-float",
        [("version: 1", "version: 1.0")],
        "version = 1.0: unsupported; this Kali reads version 1",
    ),
    ("version-missing", [("version: 1\n", "")], "version: missing; required"),
    (
        "instance-upper-case",
        [("instance: default", "instance: Default")],
        "instance = 'Default': must be a string matching [a-z0-9][a-z0-9_-]{0,23}",
    ),
    (
        "instance-dot",
        [("instance: default", "instance: a.b")],
        "instance = 'a.b': must be a string matching",
    ),
    (
        "instance-slash",
        [("instance: default", "instance: a/b")],
        "instance = 'a/b': must be a string matching",
    ),
    (
        "instance-too-long",
        [("instance: default", "instance: " + "a" * 25)],
        "instance = '" + "a" * 25 + "': must be a string matching",
    ),
    (
        "instance-number",
        [("instance: default", "instance: 7")],
        "instance = 7: must be a string matching [a-z0-9][a-z0-9_-]{0,23}, not an integer",
    ),
    ("instance-missing", [("instance: default\n", "")], "instance: missing; required"),
    (
        "arena-too-small",
        [("arena_kib: 6144", "arena_kib: 63")],
        "arena_kib = 63: must be an integer >= 64 and <= 1048576",
    ),
    (
        "miss-tolerance-not-beyond-a-servo-period",
        [("serious_miss_tolerance_ms: 20", "serious_miss_tolerance_ms: 1")],
        "clock.serious_miss_tolerance_ms = 1: must exceed clock.servo_period_ms = 1",
    ),
    (
        "miss-tolerance-zero",
        [("serious_miss_tolerance_ms: 20", "serious_miss_tolerance_ms: 0")],
        "clock.serious_miss_tolerance_ms = 0: must exceed clock.servo_period_ms = 1",
    ),
    (
        "arena-too-small-for-the-cell",
        [("arena_kib: 6144", "arena_kib: 1024")],
        "arena_kib = 1024: the cell needs 29",  # ~2,900 KiB: the flight recorder's 1,875
    ),
    (
        "arena-string",
        [("arena_kib: 6144", "arena_kib: '6144'")],
        "arena_kib = '6144': must be an integer >= 64 and <= 1048576, not a string",
    ),
    (
        "startup-timeout-too-long",
        [("startup_timeout_s: 60", "startup_timeout_s: 601")],
        "startup_timeout_s = 601: must be a number > 0 and <= 600",
    ),
    (
        "unknown-top-key",
        [("arena_kib: 6144", "arena_kb: 6144")],
        "arena_kb: unknown key (did you mean 'arena_kib'?); allowed keys: version, instance, "
        "arena_kib, startup_timeout_s, clock, processes, robots",
    ),
    (
        "unknown-clock-key",
        [("busy_wait_us: 0 ", "busy_wait: 0 ")],
        "clock.busy_wait: unknown key (did you mean 'busy_wait_us'?); allowed keys: "
        "base_tick_ms, servo_period_ms, tg_period_ms",
    ),
    (
        "process-missing",
        [("  viewer:    {cpu: 1, priority: 0, period_ms: 40, serious: false, stage: 4}\n", "")],
        "processes.viewer: missing; every one of wallclock, plant, tg, sio, sv, dynamics, "
        "viewer must be configured",
    ),
    (
        "process-unknown",
        [("  viewer:  ", "  vewer:  ")],
        "processes.vewer: unknown key (did you mean 'viewer'?); allowed keys: wallclock, plant",
    ),
    (
        "process-not-mapping",
        [("  sio:       {cpu: 0, priority: 85, serious: true, stage: 2}", "  sio: 3")],
        "processes.sio = 3: must be a mapping with keys from: cpu, priority, serious, stage",
    ),
    (
        "cpu-too-big",
        [("sio:       {cpu: 0,", f"sio:       {{cpu: {FAKE_CPUS},")],
        f"processes.sio.cpu = {FAKE_CPUS}: {CPU_MSG}",
    ),
    (
        "cpu-negative",
        [("plant:     {cpu: 1,", "plant:     {cpu: -1,")],
        f"processes.plant.cpu = -1: {CPU_MSG}",
    ),
    (
        "sv-cpus-entry",
        [("cpus: [0, 1]", "cpus: [0, -1]")],
        f"processes.sv.cpus[1] = -1: {CPU_MSG}",
    ),
    (
        "sv-cpus-wrong-length",
        [("cpus: [0, 1]", "cpus: [0, null, 1]")],
        "processes.sv.cpus = [0, null, 1]: must be a list of 2 entries (one per worker, "
        "sv.count = 2), each a CPU index or null; got 3 entries",
    ),
    (
        "sv-count-too-big",
        [("{count: 2, cpus: [0, 1],", "{count: 9,")],
        "processes.sv.count = 9: must be an integer >= 1 and <= 8",
    ),
    (
        "sv-count-zero",
        [("{count: 2, cpus: [0, 1],", "{count: 0,")],
        "processes.sv.count = 0: must be an integer >= 1 and <= 8",
    ),
    (
        "sv-cpu-key",
        [("cpus: [0, 1]", "cpu: 0")],
        "processes.sv.cpu = 0: not allowed: sv has one worker per entry of cpus",
    ),
    (
        "tg-period",
        [("tg:        {cpu: 1,", "tg:        {period_ms: 5, cpu: 1,")],
        "processes.tg.period_ms = 5: not allowed: the tg period comes from clock.tg_period_ms",
    ),
    (
        "sio-period",
        [("sio:       {cpu: 0,", "sio:       {period_ms: 1, cpu: 0,")],
        "processes.sio.period_ms = 1: not allowed: the sio period comes from clock.servo_period_ms",
    ),
    (
        "sv-period",
        [("{count: 2,", "{period_ms: 1, count: 2,")],
        "processes.sv.period_ms = 1: not allowed: the sv period comes from clock.servo_period_ms",
    ),
    (
        "wallclock-stage",
        [("{cpu: 0, priority: 90}", "{cpu: 0, priority: 90, stage: 0}")],
        "processes.wallclock.stage: unknown key; allowed keys: cpu, priority",
    ),
    (
        "priority-too-big",
        [("priority: 80,", "priority: 100,")],
        "processes.tg.priority = 100: must be an integer >= 0 and <= 99",
    ),
    (
        "nice-at-fifo",
        [("priority: 40, period_ms: 10", "priority: 40, nice: -5, period_ms: 10")],
        "processes.dynamics.nice = -5: applies to normal scheduling (priority 0); at SCHED_FIFO "
        "priority 40 the process outranks every normal one already",
    ),
    (
        "nice-too-low",
        [("priority: 0, period_ms: 40", "priority: 0, nice: -21, period_ms: 40")],
        "processes.viewer.nice = -21: must be an integer >= -20 and <= 19",
    ),
    (
        "stage-too-big",
        [("stage: 4}", "stage: 16}")],
        "processes.viewer.stage = 16: must be an integer >= 0 and <= 15",
    ),
    (
        "sv-stage-after-sio",
        [("stage: 2, poll_us: 200}", "stage: 3, poll_us: 200}")],
        "processes.sv.stage = 3: must equal processes.sio.stage (2): SIO waits within its "
        "tick for the SVs' servos, so in lockstep they run in one stage",
    ),
    (
        "sio-stage-before-sv",
        [("serious: true, stage: 2}\n  # sv", "serious: true, stage: 3}\n  # sv")],
        "processes.sv.stage = 2: must equal processes.sio.stage (3)",
    ),
    (
        "serious-int",
        [("priority: 80, serious: true", "priority: 80, serious: 1")],
        "processes.tg.serious = 1: must be true or false, not an integer",
    ),
    (
        "period-not-multiple-of-tick",
        [
            ("base_tick_ms: 1 ", "base_tick_ms: 2 "),
            ("servo_period_ms: 1 ", "servo_period_ms: 2 "),
            ("period_ms: 1, serious: true, stage: 0", "period_ms: 2, serious: true, stage: 0"),
            ("period_ms: 40,", "period_ms: 45,"),
        ],
        "processes.viewer.period_ms = 45: must be a multiple of clock.base_tick_ms (2)",
    ),
    (
        "period-not-multiple-of-fractional-tick",
        [("base_tick_ms: 1 ", "base_tick_ms: 0.5 "), ("period_ms: 40,", "period_ms: 40.25,")],
        "processes.viewer.period_ms = 40.25: must be a multiple of clock.base_tick_ms (0.5)",
    ),
    (
        "period-bool",
        [("period_ms: 40,", "period_ms: true,")],
        "processes.viewer.period_ms = true: must be a number > 0 and <= 60000, not a bool",
    ),
    (
        "period-zero",
        [("period_ms: 10, serious: false", "period_ms: 0, serious: false")],
        "processes.dynamics.period_ms = 0: must be a number > 0 and <= 60000",
    ),
    (
        "robots-too-many",
        [("ff: full}\n\n", "ff: full}\n  - {name: a}\n  - {name: b}\n  - {name: c}")],
        "robots = [{'name': 'left', 'model': 'puma560', 'base_xyz': [-0.6, ...: must be a list "
        "of 1..4 entries, not 5",
    ),
    (
        "robot-name-duplicate",
        [("{name: right,", "{name: left,")],
        "robots[1].name = 'left': duplicate; robot names must be unique (also robots[0])",
    ),
    (
        "robot-name-pattern",
        [("{name: left,", "{name: Left,")],
        "robots[0].name = 'Left': must be a string matching [a-z][a-z0-9_]{0,15}",
    ),
    (
        "robot-name-missing",
        [("{name: left,  model", "{model")],
        "robots[0].name: missing; required",
    ),
    (
        "robot-model",
        [("{name: left,  model: puma560", "{name: left,  model: kuka_kr6")],
        "robots[0].model = 'kuka_kr6': must be one of: ",
    ),
    (
        "robot-index-phases-length",
        [("base_yaw_deg: 0,", "base_yaw_deg: 0, index_phases_deg: [1, 2, 3],")],
        "robots[0].index_phases_deg = [1, 2, 3]: must be a list of 6 numbers (one per joint), "
        "not 3",
    ),
    (
        "robot-index-phases-range",
        [("base_yaw_deg: 0,", "base_yaw_deg: 0, index_phases_deg: [1, 2, 3, 4, 5, 360],")],
        "robots[0].index_phases_deg[5] = 360.0: must be >= 0 and < 360",
    ),
    (
        "robot-grasp-yaw-range",
        [("base_yaw_deg: 180,", "base_yaw_deg: 180, grasp_yaw_deg: 270,")],
        "robots[1].grasp_yaw_deg = 270: must be a number > -180 and <= 180",
    ),
    (
        "robot-grasp-yaw-string",
        [("base_yaw_deg: 180,", "base_yaw_deg: 180, grasp_yaw_deg: half,")],
        "robots[1].grasp_yaw_deg = 'half': must be a number > -180 and <= 180, not a string",
    ),
    (
        "robot-xyz-length",
        [("[-0.6, 0.0, 0.0]", "[-0.6, 0.0]")],
        "robots[0].base_xyz = [-0.6, 0.0]: must be a list of 3 numbers [x, y, z] in metres",
    ),
    (
        "robot-xyz-inf",
        [("[0.6, 0.0, 0.0]", "[0.6, .inf, 0.0]")],
        "robots[1].base_xyz[1] = inf: must be a finite number",
    ),
    (
        "robot-yaw-string",
        [("base_yaw_deg: 180", "base_yaw_deg: east")],
        "robots[1].base_yaw_deg = 'east': must be a finite number, not a string",
    ),
    (
        "robot-unknown-key",
        [("base_yaw_deg: 180", "base_yaw: 180")],
        "robots[1].base_yaw: unknown key (did you mean 'base_yaw_deg'?); allowed keys: name, "
        "model, base_xyz, base_yaw_deg",
    ),
    (
        "robot-hardware-unknown-kind",
        [("base_yaw_deg: 180", "base_yaw_deg: 180, hardware: {kind: mcgil}")],
        "robots[1].hardware.kind = 'mcgil': no hardware kind 'mcgil' (did you mean 'mcgill'?); "
        "the kinds are: franka, mcgill",
    ),
    (
        "robot-hardware-bad-name",
        [("base_yaw_deg: 180", "base_yaw_deg: 180, hardware: {kind: McGill}")],
        "robots[1].hardware.kind = 'McGill': must be a string matching",
    ),
    (
        "robot-hardware-unknown-key",
        [("base_yaw_deg: 180", "base_yaw_deg: 180, hardware: {kind: mcgill, adress: x}")],
        "robots[1].hardware.adress: unknown key",
    ),
    (
        "robot-hardware-mcgill-address",
        [("base_yaw_deg: 180", "base_yaw_deg: 180, hardware: {kind: mcgill, address: 10.0.0.2}")],
        "robots[1].hardware.address = '10.0.0.2': only for a networked robot (a mcgill arm is "
        "reached through its boards)",
    ),
    (
        "robot-hardware-franka-puma",
        [
            (
                "base_yaw_deg: 180",
                "base_yaw_deg: 180, ft: {sensor: none}, hardware: {kind: franka, address: x}",
            )
        ],
        "robots[1].hardware.kind = 'franka': cannot drive a puma560: libfranka drives 7-joint "
        "Franka arms with absolute encoders (model: fr3)",
    ),
    (
        "robot-hardware-mcgill-fr3",
        [("model: puma560, base_xyz: [0.6", "model: fr3, base_xyz: [0.6")],
        "robots[1].hardware.kind = 'mcgill': cannot drive a fr3: its joint 5 moves 112361 encoder "
        "counts in a servo period at 2.63 rad/s; the board's counters must be read within 2048",
    ),
]


def test_a_robot_names_its_hardware_kind_and_the_default_is_the_mcgill_board() -> None:
    cfg = parse_config(
        edit(("base_yaw_deg: 180", "base_yaw_deg: 180, hardware: {kind: mcgill}")), SOURCE
    )
    assert [r.hardware.kind for r in cfg.robots] == ["mcgill", "mcgill"]
    assert hardware_kind("mcgill").channels >= max(r.n_joints for r in cfg.robots)


@pytest.mark.parametrize(
    ("edits", "expected"),
    [pytest.param(edits, expected, id=case_id) for case_id, edits, expected in BAD_CONFIGS],
)
def test_malformed_config_is_rejected(edits: list[tuple[str, str]], expected: str) -> None:
    message = error_of(edit(*edits))
    assert message.startswith(f"config: {SOURCE}: ")
    assert expected in message


def replace_section(name: str, replacement: str) -> str:
    """The default text with the top-level section ``name:`` (up to the next one) replaced."""
    start = DEFAULT_TEXT.index(f"\n{name}:") + 1
    end = len(DEFAULT_TEXT)
    for later in ("\n# ", "\nprocesses:", "\nrobots:"):
        found = DEFAULT_TEXT.find(later, start)
        if found != -1:
            end = min(end, found + 1)
    return DEFAULT_TEXT[:start] + replacement + DEFAULT_TEXT[end:]


@pytest.mark.parametrize(
    ("section", "replacement", "expected"),
    [
        ("clock", "clock: 5\n", "clock = 5: must be a mapping with keys from: base_tick_ms"),
        ("processes", "processes: [tg]\n", "processes = ['tg']: must be a mapping with keys"),
        ("robots", "robots: []\n", "robots = []: must be a list of 1..4 entries, not 0"),
        ("robots", "robots: left\n", "robots = 'left': must be a list of 1..4 entries, not a"),
        ("robots", "robots:\n  - left\n", "robots[0] = 'left': must be a mapping with keys"),
    ],
)
def test_section_of_wrong_type(section: str, replacement: str, expected: str) -> None:
    text = replace_section(section, replacement)
    assert text.count(f"\n{section}:") == 1
    assert expected in error_of(text)


def test_cpu_beyond_real_machine_names_cpu_count(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.undo()
    ncpu = os.cpu_count() or 1
    text = "version: 1\ninstance: x\n"
    text += "processes: {" + ", ".join(f"{k}: {{}}" for k in PROCESS_NAMES if k != "sio")
    text += f", sio: {{cpu: {ncpu}}}}}\n"
    message = error_of(text)
    assert f"processes.sio.cpu = {ncpu}:" in message
    assert f"(this machine has {ncpu} CPUs)" in message


def test_sv_poll_applies_to_every_worker_and_defaults_to_the_default_files() -> None:
    """``processes.sv.poll_us`` is the SVs' alone; left out, it is the default file's."""

    def polls(text: str) -> dict[str, int]:
        return {p.name: p.poll_us for p in parse_config(text, SOURCE).processes if p.poll_us}

    assert polls(DEFAULT_TEXT) == {"sv.0": 200, "sv.1": 200}
    assert polls(edit((", poll_us: 200", ""))) == {"sv.0": 200, "sv.1": 200}
    assert polls(edit(("poll_us: 200", "poll_us: 0"))) == {}
    three = edit(("count: 2, cpus: [0, 1]", "count: 3, cpus: [0, 1, 1]"), ("_us: 200", "_us: 7"))
    assert polls(three) == {"sv.0": 7, "sv.1": 7, "sv.2": 7}


def test_sv_rest_is_a_whole_number_of_servo_periods_and_defaults_to_the_default_files() -> None:
    """``processes.sv.rest_ms``: 0 (never rest), or servo periods up to the serious tolerance;
    left out, 4 ms rounded up to whole servo periods, or never where that is beyond it."""

    def rests(text: str) -> dict[str, float]:
        return {p.name: p.rest_ms for p in parse_config(text, SOURCE).processes if p.kind == "sv"}

    def rest(value: str) -> tuple[str, str]:
        return ("poll_us: 200}", f"poll_us: 200, rest_ms: {value}}}")

    def servo(period_ms: str) -> tuple[str, str]:
        return ("servo_period_ms: 1 ", f"servo_period_ms: {period_ms} ")

    assert rests(DEFAULT_TEXT) == {"sv.0": 4, "sv.1": 4}
    assert rests(edit(rest("0"))) == {"sv.0": 0, "sv.1": 0}
    assert rests(edit(rest("20"))) == {"sv.0": 20, "sv.1": 20}
    assert rests(edit(servo("3"))) == {"sv.0": 6, "sv.1": 6}  # left out: rounded up
    tolerance = ("serious_miss_tolerance_ms: 20 ", "serious_miss_tolerance_ms: 3 ")
    assert rests(edit(tolerance)) == {"sv.0": 0, "sv.1": 0}  # beyond the tolerance: never
    message = error_of(edit(servo("2"), rest("3")))
    assert "processes.sv.rest_ms = 3: must be 0 or a whole multiple" in message


# --------------------------------------------------------------------------------------------
# YAML-level errors and types


def test_yaml_syntax_error_names_the_line() -> None:
    line = line_of("tg:        {cpu: 1,")
    message = error_of(edit(("tg:        {cpu: 1,", "tg:        {cpu: 1,,")))
    assert f"config: {SOURCE}: line {line}, column " in message
    assert "YAML does not parse" in message


def test_duplicate_key_is_an_error_with_its_line() -> None:
    text = edit(("arena_kib: 6144\n", "arena_kib: 6144\narena_kib: 8192\n"))
    assert f"line {line_of('arena_kib: 6144') + 1}, column 1" in error_of(text)
    assert "duplicate key 'arena_kib'" in error_of(text)


def test_control_character_names_the_line() -> None:
    message = error_of(edit(("instance: default", "instance: de\x07fault")))
    assert f"line {line_of('instance: default')}: YAML does not parse: character U+0007" in message


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("", "the top level = null: must be a mapping (the file is empty), not null"),
        ("- version: 1\n", "the top level = [{'version': 1}]: must be a mapping, not a list"),
        ("just a string\n", "the top level = 'just a string': must be a mapping, not a string"),
    ],
)
def test_top_level_must_be_a_mapping(text: str, expected: str) -> None:
    assert expected in error_of(text)


@pytest.mark.parametrize(
    ("edits", "expected"),
    [
        (("arena_kib: 6144", "arena_kib: true"), "arena_kib = true: must be an integer >= 64"),
        (("priority: 80,", "priority: yes,"), "processes.tg.priority = true: must be an integer"),
        (("cpus: [0, 1]", "cpus: [0, false]"), "processes.sv.cpus[1] = false: must be null or"),
        (("startup_timeout_s: 60", "startup_timeout_s: true"), "startup_timeout_s = true: must"),
        (("version: 1", "version: true"), "version = true: unsupported"),
    ],
)
def test_bool_is_not_an_int(edits: tuple[str, str], expected: str) -> None:
    message = error_of(edit(edits))
    assert expected in message
    if "version" not in expected:
        assert message.endswith("not a bool")


def test_unknown_key_lists_allowed_keys() -> None:
    message = error_of(edit(("stage: 3}", "stage: 3, colour: red}")))
    assert message == (
        f"config: {SOURCE}: processes.dynamics.colour: unknown key; allowed keys: "
        "enabled, cpu, priority, nice, period_ms, serious, stage"
    )


def test_int_accepted_where_float_expected() -> None:
    cfg = parse_config(edit(("lockstep_ack_timeout_s: 5.0", "lockstep_ack_timeout_s: 2")))
    assert cfg.clock.lockstep_ack_timeout_s == 2.0
    assert isinstance(cfg.clock.lockstep_ack_timeout_s, float)


def test_non_integer_servo_tg_ratio_is_allowed() -> None:
    cfg = parse_config(edit(("servo_period_ms: 1 ", "servo_period_ms: 3 ")))
    assert (cfg.process("sio").period_ms, cfg.process("tg").period_ms) == (3, 10)


def test_fractional_base_tick_is_accepted() -> None:
    cfg = parse_config(
        edit(
            ("base_tick_ms: 1 ", "base_tick_ms: 0.5 "),
            ("servo_period_ms: 1 ", "servo_period_ms: 0.5 "),
            ("period_ms: 40,", "period_ms: 1.5,"),
        )
    )
    assert cfg.clock == ClockConfig(base_tick_ms=0.5, servo_period_ms=0.5, tg_period_ms=10)
    periods = {p.name: p.period_ms for p in cfg.processes}
    assert periods == {
        "wallclock": 0.5,
        "plant": 1,  # two ticks, each cycle two 0.5 ms substeps
        "tg": 10,
        "sio": 0.5,
        "sv.0": 0.5,
        "sv.1": 0.5,
        "dynamics": 10,
        "viewer": 1.5,
    }
    assert cfg.plant.substep_ms == 0.5
    # a tick of a tenth of a ms: 3 and 7 ticks, stored as the decimals written
    tenth = parse_config(
        edit(
            ("arena_kib: 6144", "arena_kib: 8192"),  # 2 s of flight recorder at 0.3 ms
            ("base_tick_ms: 1 ", "base_tick_ms: 0.1 "),
            ("servo_period_ms: 1 ", "servo_period_ms: 0.3 "),
            ("tg_period_ms: 10 ", "tg_period_ms: 0.7 "),
        )
    )
    assert (tenth.clock.servo_period_ms, tenth.clock.tg_period_ms) == (0.3, 0.7)


def test_integer_periods_stay_integers() -> None:
    cfg = parse_config(DEFAULT_TEXT)
    clock = cfg.clock
    values = [clock.base_tick_ms, clock.servo_period_ms, clock.tg_period_ms]
    values += [p.period_ms for p in cfg.processes]
    assert all(type(v) is int for v in values)
    # a whole number written as a float reads as the same int
    whole = parse_config(edit(("base_tick_ms: 1 ", "base_tick_ms: 1.0 ")))
    assert type(whole.clock.base_tick_ms) is int and whole.clock == clock


def test_viewer_default_rounds_up_to_whole_fractional_ticks() -> None:
    text = "version: 1\ninstance: x\narena_kib: 8192\n"  # 2 s of flight recorder at 0.3 ms
    text += "clock: {base_tick_ms: 0.3, servo_period_ms: 0.3, tg_period_ms: 3}\n"
    text += "processes: {" + ", ".join(f"{k}: {{}}" for k in PROCESS_NAMES) + "}\n"
    text += "plant: {substep_ms: 0.1}\n"
    cfg = parse_config(text)
    assert cfg.process("viewer").period_ms == 40.2  # 134 ticks of 0.3 ms
    assert cfg.process("plant").period_ms == 0.3


@pytest.mark.parametrize(
    ("period_ms", "tick_ms", "ticks"),
    [(1, 1, 1), (10, 1, 10), (0.5, 0.5, 1), (1.5, 0.5, 3), (0.3, 0.1, 3), (40, 0.3, None)],
)
def test_period_ticks_counts_whole_ticks_in_nanoseconds(
    period_ms: float, tick_ms: float, ticks: int | None
) -> None:
    if ticks is None:
        with pytest.raises(ValueError, match=r"period 40 ms is not a whole multiple of the 0\.3"):
            config_mod.period_ticks(period_ms, tick_ms)
        assert config_mod.period_ticks(period_ms, tick_ms, round_up=True) == 134
    else:
        assert config_mod.period_ticks(period_ms, tick_ms) == ticks


def test_period_ticks_rejects_less_than_one_tick() -> None:
    for period in (0, 0.25, -1):
        with pytest.raises(ValueError, match="not a whole multiple"):
            config_mod.period_ticks(period, 0.5)


# --------------------------------------------------------------------------------------------
# Files, overrides, immutability


def test_missing_file_names_the_path(tmp_path: Path) -> None:
    path = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError) as info:
        load_config(path)
    assert str(info.value) == f"config: {path}: cannot read config file: No such file or directory"


def test_directory_is_unreadable(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="cannot read config file"):
        load_config(tmp_path)


def test_load_error_names_the_file(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(edit(("arena_kib: 6144", "arena_kib: 1")), encoding="utf-8")
    with pytest.raises(ConfigError, match=rf"^config: {path}: arena_kib = 1: must be an integer"):
        load_config(path)


def test_with_overrides_replaces_and_validates() -> None:
    cfg = parse_config(DEFAULT_TEXT, SOURCE)
    other = with_overrides(cfg, instance="test-1", arena_kib=8192)
    assert (other.instance, other.arena_kib) == ("test-1", 8192)
    with pytest.raises(ConfigError, match=r"arena_kib = 128: the cell needs \d+ KiB"):
        with_overrides(cfg, arena_kib=128)
    assert other.processes == cfg.processes and cfg.instance == "default"
    with pytest.raises(ConfigError, match=r"\(override\): instance = 'Bad/Name': must be"):
        with_overrides(cfg, instance="Bad/Name")
    with pytest.raises(ConfigError, match="clock: cannot be overridden; overridable fields"):
        with_overrides(cfg, clock=ClockConfig())


def test_config_is_immutable() -> None:
    cfg = parse_config(DEFAULT_TEXT)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.instance = "other"  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.clock.base_tick_ms = 2  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.processes[0].cpu = 3  # type: ignore[misc]
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.robots[0].name = "x"  # type: ignore[misc]
    assert isinstance(cfg.processes, tuple) and isinstance(cfg.robots, tuple)
    assert isinstance(cfg.robots[0].base_xyz, tuple)
    assert hash(cfg) == hash(parse_config(DEFAULT_TEXT))


def test_dynamics_and_viewer_may_be_left_out() -> None:
    cfg = make_config(
        "opt",
        {r"^(  dynamics: +\{)": r"\1enabled: false, ", r"^(  viewer: +\{)": r"\1enabled: false, "},
    )
    assert [p.name for p in cfg.processes] == ["wallclock", "plant", "tg", "sio", "sv.0", "sv.1"]
    with pytest.raises(ConfigError, match=r"processes\.tg\.enabled: unknown key"):
        make_config("opt", {r"^(  tg: +\{)": r"\1enabled: false, "})


def test_the_conveyor_and_tg_function_plugins_are_checked() -> None:
    assert "plant.conveyor_m_s" in error_of(
        edit(("conveyor_m_s: [0.0, 0.02]", "conveyor_m_s: [0.0, 2.0]"))
    )
    assert "2 numbers [vx, vy]" in error_of(
        edit(("conveyor_m_s: [0.0, 0.02]", "conveyor_m_s: [0.0, 0.02, 0.0]"))
    )
    assert "tg_functions" in error_of(edit(("tg_functions: [", "tg_functions: [[], ")))


# --------------------------------------------------------------------------------------------
# The bridge section (issue 29)


def bridge_text(section: str) -> str:
    return replace_section("bridge", section)


def test_the_bridge_is_off_by_default_and_a_process_of_its_own_when_on() -> None:
    assert "bridge" not in [p.name for p in parse_config(DEFAULT_TEXT).processes]
    cfg = parse_config(bridge_text("bridge: {enabled: true, telemetry_hz: 30}\n"))
    bridge = cfg.process("bridge")
    # 1/30 s rounded up to whole 1 ms ticks; non-serious, SCHED_OTHER, after the viewer
    assert (bridge.kind, bridge.period_ms, bridge.serious, bridge.priority) == (
        "bridge",
        34,
        False,
        0,
    )
    assert bridge.stage > cfg.process("viewer").stage and bridge.cpu == 1
    assert cfg.bridge.listen == ("tcp/127.0.0.1:7447",) and not cfg.bridge.authenticated


@pytest.mark.parametrize(
    ("section", "expected"),
    [
        (
            "bridge: {enabled: true, listen: [tcp/0.0.0.0:7447]}\n",
            "bridge.listen[0] = 'tcp/0.0.0.0:7447': is not loopback: listening beyond this "
            "machine needs authentication",
        ),
        ("bridge: {listen: [http://x]}\n", "must be a Zenoh endpoint like tcp/127.0.0.1:7447"),
        ("bridge: {listen: [tcp/127.0.0.1:99999]}\n", "must be a Zenoh endpoint"),
        ("bridge: {readers: [bob]}\n", "roles need authentication: set bridge.users_file"),
        ("bridge: {users_file: nowhere.txt, operators: [a]}\n", "bridge.users_file = "),
        ("bridge: {telemetry_hz: 0}\n", "bridge.telemetry_hz = 0"),
        ("bridge: {max_sessions: 0}\n", "bridge.max_sessions = 0"),
        ("bridge: {listen: [tls/127.0.0.1:7448]}\n", "a tls/ endpoint needs bridge.tls"),
        ("bridge: {tls: {certificate: a.pem}}\n", "bridge.tls.certificate = 'a.pem': "),
        ("bridge: {port: 7447}\n", "bridge.port: unknown key"),
    ],
)
def test_a_bad_bridge_section_is_refused_naming_the_field(section: str, expected: str) -> None:
    assert expected in error_of(bridge_text(section))


def test_bridge_users_and_roles(tmp_path: Path) -> None:
    users = tmp_path / "users.txt"
    users.write_text("op:x\nviewer:y\n")
    section = f"bridge: {{listen: [tcp/0.0.0.0:7447], users_file: {users}, operators: [op]}}\n"
    cfg = parse_config(bridge_text(section))
    assert cfg.bridge.authenticated and cfg.bridge.operators == ("op",)
    assert cfg.bridge.users_file == str(users)
    both = section.replace("operators: [op]", "operators: [op], readers: [op]")
    assert "is an operator too" in error_of(bridge_text(both))
    nobody = section.replace(", operators: [op]", "")
    assert "name at least one user" in error_of(bridge_text(nobody))
