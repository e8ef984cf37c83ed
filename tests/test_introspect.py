"""``kalictl status --json`` and ``kalictl top`` (DESIGN 8), on real instances."""

from __future__ import annotations

import json
import re
from collections.abc import Callable

import pytest
from rich.console import Console

from kali_daemons.core.layout import FaultCode
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo.client import ServoClient
from kali_daemons.tools import top
from kali_daemons.tools.introspect import Introspector, plain
from kali_daemons.wallclock import step_kali_clock

from .test_launcher import PROCESSES, kalictl


def strict_json(text: str) -> dict:
    """Parse JSON that must not contain NaN or Infinity."""

    def refuse(name: str) -> None:
        raise AssertionError(f"{name} in the JSON")

    return json.loads(text, parse_constant=refuse)


def test_plain_turns_numpy_and_nan_into_json_types() -> None:
    import numpy as np

    got = plain({"a": np.float64("nan"), "b": np.arange(2), "c": (np.int32(3), float("inf"))})
    assert got == {"a": None, "b": [0, 1], "c": [3, None]}


def test_status_json_has_everything_as_plain_json(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        client = ServoClient(inst)
        try:
            step_kali_clock(inst, 30)
            for robot in client.names:
                client.power(robot, True)
            step_kali_clock(inst, 300)
        finally:
            client.close()
    r = kalictl("-i", name, "move", "left", "--joints", "5,45,-180,0,45,0", "--speed", "0.2")
    assert r.returncode == 0, r.stderr
    r = kalictl("-i", name, "clock", "step", "50")
    assert r.returncode == 0, r.stderr
    r = kalictl("-i", name, "status", "--json")
    assert r.returncode == 0, r.stderr
    s = strict_json(r.stdout)
    assert s["instance"] == name and s["mode"] == "lockstep"
    assert s["clock"] == {
        "mode": "stopped",
        "tick": 380,
        "time_ms": 380.0,
        "base_tick_ms": 1.0,
        "overruns": 0,
        "skipped_ticks": 0,
    }
    assert s["fault"]["active"] is False and s["fault"]["code"] == "NONE"
    procs = {p["name"]: p for p in s["processes"]}
    assert sorted(procs) == sorted(PROCESSES)
    sio = procs["sio"]
    assert sio["acks"] == 380 and sio["alive"] and sio["state"] == "ACTIVE"
    assert 0 < sio["late_p50_us"] <= sio["late_p999_us"] and sio["misses"] == 0
    left, right = s["robots"]
    assert (left["name"], left["power"], right["power"]) == ("left", "ON", "ON")
    assert len(left["q_rad"]) == 6 and len(left["error_counts"]) == 6
    assert left["current_limit_a"][0] == 8.0 and left["message"] == "on"
    assert left["feedforward"] is None or left["feedforward"]["mode"] in ("OFF", "GRAVITY", "FULL")
    servo = s["servo"]
    assert servo["ready"] and servo["fed"] == 12 and servo["latency_us"]["ticks"] == 380
    assert [w["name"] for w in servo["sv"]] == ["sv.0", "sv.1"]
    assert 0 < servo["latency_us"]["p50"] <= servo["latency_us"]["max"] * 1.2
    tg = {e["robot"]: e for e in s["tg"]["robots"]}
    assert tg["left"]["busy_seq"] > 0 and tg["left"]["state"] == "RUNNING"
    assert tg["right"]["busy_seq"] == 0
    # the TG's longest tick so far, in parts that make up its wall time
    longest = s["tg"]["longest_tick"]
    assert 0 <= longest["tick"] < 380 and longest["requests"] <= 8
    parts = longest["requests_us"] + longest["starting_us"] + longest["motions_us"]
    assert abs(parts - longest["wall_us"]) < 1e-6 and longest["wall_us"] > 0
    assert longest["cpu_us"] > 0
    assert s["tg"]["now"] is None  # the clock stands: the TG is between ticks
    assert s["misses"] == {"total": 0, "recent": []}
    assert s["flight"]["rows"] == 2000 and s["flight"]["recorded"] == 380
    assert s["flight"]["last_dump"] is None and s["flight"]["dumps"] == 0
    assert 0 < s["arena"]["used_bytes"] < s["arena"]["bytes"]
    # a halt shows in the fault record, and the text status still works
    with Instance.attach(name) as inst:
        inst.raise_fault(FaultCode.OPERATOR, "test", "halted for the test")
    s = strict_json(kalictl("-i", name, "status", "--json").stdout)
    assert s["fault"]["active"] and s["fault"]["code"] == "OPERATOR"
    assert s["fault"]["text"] == "OPERATOR in test at tick 380: halted for the test"
    text = kalictl("-i", name, "status").stdout
    assert "fault: OPERATOR in test" in text
    assert re.search(r"tg longest tick \d+: \d+ us \(\d+ us CPU\): \d+ requests taken", text), text


def render(frame: object, width: int) -> str:
    console = Console(record=True, width=width, color_system=None)
    console.print(frame)
    return console.export_text()


def test_top_draws_rates_lateness_robots_and_the_fault(kali: Callable[..., str]) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        spy = Introspector(inst)
        try:
            step_kali_clock(inst, 30)
            before = top.take(spy)
            step_kali_clock(inst, 200)
            after = top.take(spy)
            wide = render(top.frame(before, after, 0.5, 160), 160)
            narrow = render(top.frame(before, after, 0.5, 80), 80)
            # lockstep: rates per second of Kali's clock, 200 ticks = 0.2 s
            assert "Hz and lateness over the last 0.20 Kali s" in wide
            for text, hz in ((wide, 4), (narrow, 2)):  # Hz: after cpu, prio, period / period
                rows = {line.split()[0]: line.split() for line in text.splitlines() if line}
                assert rows["sio"][rows["sio"].index("ACTIVE") + hz] == "1000", text
                assert rows["tg"][rows["tg"].index("ACTIVE") + hz] == "100", text
                assert "no fault" in text and "flight recorder: 2 s" in text
                assert re.search(r"left\s+off\s+no", text), text
            assert max(len(line) for line in narrow.splitlines()) <= 80
            assert str(int(inst.procs[inst.slot_of("sio")]["pid"])) in wide  # pid: wide only
            assert str(int(inst.procs[inst.slot_of("sio")]["pid"])) not in narrow
            inst.raise_fault(FaultCode.OPERATOR, "test", "stop here")
        finally:
            spy.close()
    r = kalictl("-i", name, "top", "--once", "--interval", "0.1")
    assert r.returncode == 0, r.stderr
    assert "HALTED: OPERATOR in test at tick 230: stop here" in r.stdout
    assert "the clock did not move" in r.stdout and "SIO sensor→DAC" in r.stdout


@pytest.mark.serial
def test_top_once_in_real_time(kali: Callable[..., str]) -> None:
    name = kali(lockstep=False)
    r = kalictl("-i", name, "top", "--once", "--interval", "0.3", env={"COLUMNS": "160"})
    assert r.returncode == 0, r.stderr
    assert "real time  clock running" in r.stdout and "wall s" in r.stdout
    rows = {line.split()[0]: line.split() for line in r.stdout.splitlines() if line.strip()}
    for p in PROCESSES:
        assert p in rows, r.stdout
    hz = rows["sio"][rows["sio"].index("ACTIVE") + 4]  # pid state cpu prio period Hz
    assert int(hz) > 0, r.stdout
