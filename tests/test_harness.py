"""The benchmark harness (scripts/harness.py): config overrides as dotted paths, an instance
that is always stopped, goals judged with the floor beside them, PSS per process."""

from __future__ import annotations

import math
import os
import subprocess
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "scripts"))

from benchlib import BenchError
from harness import (
    CELLS,
    Goal,
    KaliRun,
    Window,
    cell_config,
    pss_kib,
    set_path,
    table,
)

from kali_daemons.core.errors import ConfigError
from kali_daemons.tools import launcher
from kali_daemons.wallclock import step_kali_clock

from .conftest import unique_name

LEAN = {"processes.dynamics.enabled": False, "processes.viewer.enabled": False}


def test_set_path_walks_mappings_lists_and_every_item() -> None:
    doc = {"clock": {"servo_period_ms": 1}, "robots": [{"name": "a"}, {"name": "b"}]}
    set_path(doc, "clock.servo_period_ms", 0.5)
    set_path(doc, "robots.*.ff", "full")
    set_path(doc, "robots.1.name", "c")
    set_path(doc, "dashboard.record", "x.rrd")  # a section the file leaves out is created
    assert doc == {
        "clock": {"servo_period_ms": 0.5},
        "robots": [{"name": "a", "ff": "full"}, {"name": "c", "ff": "full"}],
        "dashboard": {"record": "x.rrd"},
    }
    with pytest.raises(BenchError, match=r"'robots.2.name': no item '2' in a list of 2"):
        set_path(doc, "robots.2.name", "d")
    with pytest.raises(BenchError, match=r"'clock.servo_period_ms.x': float has no key 'x'"):
        set_path(doc, "clock.servo_period_ms.x", 1)


def test_cell_config_applies_overrides_and_parse_config_refuses_a_wrong_key() -> None:
    cfg = cell_config(
        {"clock.servo_period_ms": 0.5, "clock.base_tick_ms": 0.5, "processes.sv.count": 1,
         "processes.sv.cpus": [0], **CELLS["mixed"], "robots.*.ff": "full"},
        "harness-test",
        label="t",
    )  # fmt: skip
    assert cfg.instance == "harness-test" and cfg.clock.servo_period_ms == 0.5
    assert [p.name for p in cfg.processes if p.kind == "sv"] == ["sv.0"]
    assert [(r.model, r.ff) for r in cfg.robots] == [("puma560", "full"), ("panda", "full")]
    with pytest.raises(ConfigError, match=r"clock.servo_perod_ms: unknown key"):
        cell_config({"clock.servo_perod_ms": 0.5}, "harness-test")


def test_goal_is_met_or_missed_with_the_ratio_to_the_floor() -> None:
    goal = Goal("lockstep", "speed", ">=", 10.0, "x real time", floor="the plant alone")
    met = goal.judge(12.0, 20.0)
    assert met.met is True and met.ratio_to_floor == pytest.approx(0.6)
    assert met.line() == (
        "GOAL lockstep: met (speed 12x real time >= 10x real time; 0.60x the plant alone)"
    )
    missed = goal.judge(1.5)
    assert missed.met is False and missed.word == "MISSED" and math.isnan(missed.ratio_to_floor)
    unmeasured = goal.judge(math.nan, why="it halted")
    assert unmeasured.met is None and unmeasured.line() == "GOAL lockstep: not measured (it halted)"
    with pytest.raises(BenchError, match="comparison '=<'"):
        Goal("bad", "x", "=<", 1.0)


def test_pss_kib_of_a_live_and_of_a_gone_process() -> None:
    child = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        pss, rss = pss_kib(child.pid)
        assert 0 < pss <= rss  # the interpreter shares its pages with this one
    finally:
        child.kill()
        child.wait()
    assert pss_kib(child.pid) == (-1, -1)
    assert pss_kib(os.getpid())[0] > 0


def test_table_renders_every_cell_and_a_rule() -> None:
    text = table([("name", "left"), "p99"], [["kali sio", 145], None, ["cyclictest", 61]])
    lines = text.splitlines()
    assert "kali sio" in text and "cyclictest" in text and "p99" in lines[0]
    assert lines.index(next(x for x in lines if "cyclictest" in x)) > lines.index(
        next(x for x in lines if "kali sio" in x)
    )


def test_kali_run_in_lockstep_measures_a_window_and_leaves_nothing_behind() -> None:
    name = unique_name("hr")
    cfg = cell_config(LEAN, name)
    with KaliRun(cfg, lockstep=True) as run:
        assert run.inst is not None and set(run.pids) >= {"wallclock", "sio", "sv.0", "plant"}
        window = Window(run.inst, ["sio"], pids=run.pids)
        window.open()
        step_kali_clock(run.inst, 200)
        window.close()
        assert window.b is not None and window.a is not None
        assert window.b.kali.tick - window.a.kali.tick == 200
        assert window.b.kali.procs["sio"].acks - window.a.kali.procs["sio"].acks == 200
        assert window.cpu_pct("sio") > 0
    assert run.left_behind == []
    assert launcher.shm_objects(name) == [] and launcher.instance_pids(name) == []


def test_kali_run_stops_the_instance_when_the_body_fails() -> None:
    name = unique_name("hr")
    run = KaliRun(cell_config(LEAN, name), lockstep=True)
    with pytest.raises(RuntimeError, match="the benchmark broke"), run:
        assert launcher.instance_pids(name)
        raise RuntimeError("the benchmark broke")
    assert run.left_behind == []
    assert launcher.shm_objects(name) == [] and launcher.instance_pids(name) == []
