"""Benchmark: how fast lockstep runs, in simulated seconds per wall second, by cell and options.

Each scenario is a row: a cell (``config/default.yaml``'s two PUMAs; ``config/mixed.yaml``'s
PUMA and Panda, its robots on default.yaml, which writes out the defaults mixed.yaml takes;
bench_servo's ``four`` cell of two PUMAs, a UR5 and a Panda; ``config/fr3.yaml``'s FR3, its
link taking turns with franky-sim over libfranka's protocol), options as config overrides
(feed-forward off / full on every arm; the viewer left out, or recording the dashboard to an
.rrd in the run's temporary directory with no web viewer and no live connection) and the
keyword arguments ``launcher.start`` gets besides the config
(``lockstep=True``: the lockstep executive, every daemon in one process; ``separate=True``
too: a process per daemon, the row that says what the executive saves).  Per scenario: start
the instance in lockstep mode, step 30 ticks, power every arm, step ``SETTLE_TICKS`` so they
settle, queue the program (``move``: each arm swings every joint ±``SWING_RAD`` from where it
holds and back, ``MOVES`` requests queued at ``SPEED``, enough to keep it moving through
the window; ``hold``: nothing), then the window: ``kalictl clock step --ticks`` as one
request (``step_kali_clock``), timed with the wall clock.  Simulated seconds are ticks x base
tick; the speed is simulated / wall seconds (1.0 = real time).  Also the CPU every Kali
process took in the window (scheduler run time, all processes summed), per simulated second.

The floor: the plant alone (``bench_plant.in_process``, ``PlantSim.cycle`` of the two PUMAs
in this process, best of five) simulates the default cell at ``floor`` x real time: lockstep
cannot beat the physics, and the ratio says how much of the executive's time is the plant's.

Goals (issue 26): >= 10x real time for the default cell with feed-forward on, >= 5x with the
viewer recording.  Exit status 0 whatever the verdicts, 1 on errors.

    .venv/bin/python scripts/bench_lockstep.py                    # every scenario, 5000 ticks
    .venv/bin/python scripts/bench_lockstep.py --ticks 2000 --scenarios default-ff,default-ff-rec
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from bench_plant import in_process
from benchlib import BenchError, machine_facts, machine_line, to_json, unwind_on_sigterm
from harness import (
    CELLS,
    DEFAULT_CONFIG,
    REPO,
    Goal,
    KaliRun,
    Verdict,
    Window,
    cell_config,
    file_cell,
    kept_logs,
    pick,
    table,
)

from kali_daemons.client import Kali
from kali_daemons.core.errors import KaliError
from kali_daemons.core.layout import PowerState
from kali_daemons.wallclock import step_kali_clock

MIXED_CONFIG = REPO / "config" / "mixed.yaml"
FR3_CONFIG = REPO / "config" / "fr3.yaml"
# an FR3 cell's franky-sim binds its robot's address: this run's own, beside any other
FR3_OWN = {"robots.*.hardware.address": f"127.{os.getpid() % 250 + 1}.54.1"}
SETTLE_TICKS = 1500  # after power-on (tests/test_tg.py's ``powered``)
SWING_RAD = 0.3
SPEED = 0.5  # of the joint speed and acceleration limits
MOVES = 4  # requests queued per arm, out and back twice (~2 s each; a client's share of the
# TG's request queue is 16: four arms x 4)
PLANT_CYCLES = 2000  # the floor's in-process plant cycles
FF_FULL = {"robots.*.ff": "full"}  # as config/default.yaml starts them
FF_OFF = {"robots.*.ff": "off"}
SEPARATE = {"lockstep": True, "separate": True}  # a process per daemon, not the executive
VIEWER_OFF = {"processes.viewer.enabled": False}


def viewer_recording(path: Path) -> dict[str, object]:
    """The viewer on, recording the dashboard to ``path``, serving and connecting nowhere."""
    return {
        "processes.viewer.enabled": True,
        "dashboard.record": str(path),
        "dashboard.web": "off",
        "dashboard.connect": None,
    }


@dataclass(frozen=True)
class Scenario:
    """One row: a cell (a config file and overrides), the viewer recording or not, the
    program, and the keyword arguments of ``launcher.start`` besides the config."""

    name: str
    base: Path
    overrides: dict[str, object] = field(default_factory=dict)
    record: bool = False  # the viewer records to an .rrd (else it is left out)
    program: str = "move"  # "move" or "hold"
    start: dict[str, object] = field(default_factory=lambda: {"lockstep": True})


SCENARIOS = {
    s.name: s
    for s in (
        Scenario("default-hold", DEFAULT_CONFIG, FF_OFF, program="hold"),
        Scenario("default", DEFAULT_CONFIG, FF_OFF),
        Scenario("default-ff", DEFAULT_CONFIG, FF_FULL),
        Scenario("ff-separate", DEFAULT_CONFIG, FF_FULL, start=SEPARATE),
        Scenario("default-ff-rec", DEFAULT_CONFIG, FF_FULL, record=True),
        Scenario("mixed-ff", DEFAULT_CONFIG, {**file_cell(MIXED_CONFIG), **FF_FULL}),
        Scenario("four-ff", DEFAULT_CONFIG, {**CELLS["four"], **FF_FULL}),
        Scenario("fr3-ff", FR3_CONFIG, FR3_OWN),  # over libfranka's protocol, franky-sim
    )
}

GOALS = {
    "default-ff": Goal(
        "lockstep default cell, feed-forward on", "speed", ">=", 10.0, "x real time",
        source="issue 26", floor="the plant alone",
    ),
    "default-ff-rec": Goal(
        "lockstep default cell, feed-forward on, viewer recording", "speed", ">=", 5.0,
        "x real time", source="issue 26", floor="the plant alone",
    ),
}  # fmt: skip


@dataclass
class Result:
    """One scenario's figures, also written by ``--json``."""

    scenario: str
    arms: str = ""
    options: str = ""
    start: dict[str, object] = field(default_factory=dict)
    ticks: int = 0
    sim_s: float = math.nan
    wall_s: float = math.nan
    speed: float = math.nan  # simulated seconds per wall second
    cpu_s_per_sim_s: float = math.nan  # every Kali process's CPU per simulated second
    moves_done: int = 0
    fault: str | None = None
    notes: list[str] = field(default_factory=list)
    error: str | None = None


def program(kali: Kali, name: str) -> list:
    """Queue the scenario's program (not waiting): the handles of its requests."""
    if name == "hold":
        return []
    handles = []
    level = kali.servo.level
    for k, robot in enumerate(kali.names):
        centre = level.arm("demand", k).copy()
        signs = np.where(np.arange(len(centre)) % 2 == 0, 1.0, -1.0)
        if k % 2:  # facing the arm before it: its first joint the other way, wrists apart
            signs[0] = -signs[0]
        arm = kali.robot(robot)
        for m in range(MOVES):
            target = centre + (SWING_RAD * signs if m % 2 == 0 else 0.0)
            handles.append(arm.move_joints(target, speed=SPEED, wait=False))
    return handles


def measure(s: Scenario, ticks: int, tmp: Path) -> Result:
    """Start ``s`` in lockstep, power, settle, queue its program, time ``ticks`` ticks."""
    res = Result(s.name, start=dict(s.start), ticks=ticks)
    instance = f"bls{os.getpid()}-{s.name}"
    rec = viewer_recording(tmp / f"{instance}.rrd") if s.record else VIEWER_OFF
    try:
        cfg = cell_config({**s.overrides, **rec}, instance, s.base, s.name)
        res.arms = f"{'+'.join(r.model for r in cfg.robots)} ({cfg.joints.total} joints)"
        ff = sorted({r.ff for r in cfg.robots})
        res.options = f"ff {'/'.join(ff)}, viewer {'recording' if s.record else 'off'}, {s.program}"
        run = KaliRun(cfg, log_dir=tmp, **s.start)  # type: ignore[arg-type]
        with run, Kali(instance) as kali:
            step_kali_clock(kali.inst, 30)
            for robot in kali.names:
                kali.servo.power(robot, True)
            step_kali_clock(kali.inst, SETTLE_TICKS)
            states = [kali.servo.power_state(r) for r in kali.names]
            if states != [PowerState.ON] * len(states) or kali.inst.fault_text():
                why = kali.inst.fault_text() or ", ".join(s.name for s in states)
                raise BenchError(f"the arms did not power on: {why}")
            handles = program(kali, s.program)
            window = Window(kali.inst, [], pids=run.pids)
            window.open()
            t0 = time.perf_counter()
            step_kali_clock(kali.inst, ticks, timeout=3600.0)
            res.wall_s = time.perf_counter() - t0
            window.close()
            res.fault = kali.inst.fault_text()
            res.moves_done = sum(h.done for h in handles)
            base_s = cfg.clock.base_tick_ms / 1000.0
            res.sim_s = ticks * base_s
            res.speed = res.sim_s / res.wall_s
            # one name per process: the executive's daemons share its pid
            each = {pid: n for n, pid in run.pids.items()}.values()
            cpu_s = sum(window.cpu_pct(n) for n in each) / 100.0 * window.wall_ns / 1e9
            res.cpu_s_per_sim_s = cpu_s / res.sim_s
            if s.program == "move" and res.moves_done < len(handles):
                res.notes.append(
                    f"{res.moves_done} of {len(handles)} moves done: the arms moved throughout"
                )
        res.notes += run.notes()
    except (KaliError, BenchError, OSError) as exc:
        res.error = f"{type(exc).__name__}: {exc}"
    return res


def verdicts(results: list[Result], floor_x: float) -> list[Verdict]:
    """Each goal judged on its scenario's speed (not measured when it did not run)."""
    by_name = {r.scenario: r for r in results}
    out = []
    for name, goal in GOALS.items():
        r = by_name.get(name)
        if r is None or r.error or r.fault:
            why = "not run" if r is None else r.error or f"halted: {r.fault}"
            out.append(goal.judge(None, why=why))
        else:
            out.append(goal.judge(r.speed, floor_x))
    return out


def report(results: list[Result], floor_x: float, machine: dict[str, object]) -> str:
    """The table, the floor and the goals."""
    cols = [("scenario", "left"), ("cell", "left"), ("options", "left"), "start", "ticks",
            "sim s", "wall s", "sim s / wall s", "CPU s / sim s", ("note", "left")]  # fmt: skip
    rows = []
    for r in results:
        start = ",".join(f"{k}={v}" for k, v in r.start.items())
        if r.error:
            rows.append([r.scenario, r.arms, r.options, start, r.ticks, "", "", "", "", r.error])
            continue
        note = "; ".join(([f"HALTED: {r.fault}"] if r.fault else []) + r.notes)
        rows.append([
            r.scenario, r.arms, r.options, start, r.ticks, f"{r.sim_s:.1f}", f"{r.wall_s:.2f}",
            f"{r.speed:.2f}x", f"{r.cpu_s_per_sim_s:.2f}", note,
        ])  # fmt: skip
    lines = [
        machine_line(machine),
        table(cols, rows, title="lockstep speed"),
        f"floor: the plant alone (PlantSim.cycle, 2 PUMAs, in process) {floor_x:.1f}x real time",
    ]
    lines += [v.line() for v in verdicts(results, floor_x)]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run each scenario, then print the table and the goals."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--ticks", type=int, default=5000, help="ticks stepped in each window")
    ap.add_argument(
        "--scenarios",
        type=pick(SCENARIOS, "scenario"),
        default=list(SCENARIOS.values()),
        help=f"comma-separated subset of {','.join(SCENARIOS)} (default: all)",
    )
    ap.add_argument(
        "--json", type=Path, default=None, metavar="PATH", help="also write the numbers"
    )
    args = ap.parse_args(argv)
    if args.ticks < 1:
        ap.error("--ticks must be >= 1")
    unwind_on_sigterm()
    tmp = Path(tempfile.mkdtemp(prefix="bench_lockstep."))
    results: list[Result] = []
    with kept_logs(tmp, "bench_lockstep", lambda: any(r.fault or r.error for r in results)):
        _, wall_us = in_process(2, PLANT_CYCLES)
        floor_x = 1000.0 / wall_us
        for i, s in enumerate(args.scenarios):
            print(f"bench_lockstep: {i + 1}/{len(args.scenarios)} {s.name}", file=sys.stderr)
            results.append(measure(s, args.ticks, tmp))
        print(report(results, floor_x, machine_facts()), flush=True)
        if args.json is not None:
            doc = {
                "floor_plant_x": floor_x,
                "scenarios": [to_json(r) for r in results],
                "goals": [to_json(v) for v in verdicts(results, floor_x)],
            }
            args.json.write_text(json.dumps(doc, indent=2) + "\n")
    return 1 if any(r.error for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
