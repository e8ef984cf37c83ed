"""``kalictl``: start, stop and inspect a Kali instance (DESIGN section 8).

    kalictl start [-c FILE] [--lockstep]     kalictl status [--json]   kalictl mem
    kalictl top [--once]                     kalictl flight [FILE]
    kalictl clock start|stop|set MS|step N   kalictl rate PROCESS MS
    kalictl reset                            kalictl stop

``-i NAME`` picks the instance (default: ``$KALI_INSTANCE``, else the config's, else
``default``), so two instances run side by side.

Long on purpose: kalictl's whole command tree in one click group; each command is a thin call
into the module that does the work.
"""

from __future__ import annotations

import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from functools import wraps
from pathlib import Path
from typing import Any

import click
import numpy as np

from ..client import remote
from ..client.common import INSTANCE_ENV
from ..client.motion import Kali
from ..client.remote import REMOTE_ENV, SESSION_ENV
from ..core import layout
from ..core.errors import InstanceError, KaliError, MotionError
from ..core.layout import (
    CalibState,
    PowerState,
    ProcState,
    RunMode,
    ShadowState,
)
from ..robots import known_types, robot_type
from ..runtime import config as config_mod
from ..runtime import flightrec
from ..runtime.config import DEFAULT_FILE, KaliConfig, cell_of, load_config
from ..runtime.instance import (
    LOCK_STUCK_S,
    Instance,
    check_instance_name,
    decode,
    estop_pressed,
    time_ms,
)
from ..servo import registry_for, schedule, shadow
from ..servo.client import ServoClient, ServoError
from ..wallclock import (
    set_control_rate,
    set_kali_clock,
    start_kali_clock,
    step_kali_clock,
    stop_kali_clock,
)
from . import introspect, launcher

DEFAULT_CONFIG = DEFAULT_FILE  # the shipped cell
# what the system runs without when a non-serious process dies (DESIGN 7: degrade)
TOP_INTERVAL_S = (0.05, 60.0)  # kalictl top's refresh interval
MOVE_TIMEOUT_S = 3600.0  # kalictl move's longest wait
MAX_PUSH_N = 5000.0  # kalictl push: the largest force per axis
MAX_PUSH_S = 600.0  # and the longest push
STALL_S = 2.0  # a non-serious process this long without a heartbeat is reported stalled
STOP_CONFIRM_S = 5.0  # kalictl run's Ctrl-C: longest it waits to see the program's arms stop
DEGRADED = {
    "dynamics": "feed-forward (SIO drops it as stale)",
    "viewer": "dashboard",
    "bridge": "remote access (Zenoh bridge)",
}


def _us(value: float) -> str:
    """A lateness percentile for the status table, 9 wide: '-' when nothing was measured
    (``launcher.percentile`` of an empty histogram is NaN)."""
    return f"{'-':>9}" if math.isnan(value) else f"{value:>7.0f}us"


def _errors(fn: Callable) -> Callable:
    """Turn a KaliError into one line on stderr and exit status 1."""

    @wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except KaliError as exc:
            click.echo(f"kalictl: {exc}", err=True)
            sys.exit(1)

    return wrapper


def _number(
    command: str,
    option: str,
    text: str,
    lo: float,
    hi: float,
    unit: str,
    error: type[KaliError] = KaliError,
    lo_open: bool = False,
) -> float:
    """``text`` as a finite number in [lo, hi] ((lo, hi] with ``lo_open``); a one-line
    ``error`` naming the command, option and value if not (click's FloatRange lets NaN
    through: every comparison with it is false)."""
    try:
        value = float(text)
    except (TypeError, ValueError):
        value = math.nan
    above = lo < value if lo_open else lo <= value
    if not (above and value <= hi):  # NaN fails both
        span = f"{'(' if lo_open else '['}{lo:g}, {hi:g}]"
        raise error(f"{command}: {option} {text}: must be a number of {unit} in {span}")
    return value


def _instance_name(ctx: click.Context) -> str:
    """The instance named by -i or $KALI_INSTANCE, else 'default'; an empty name is refused
    (it is a mistake, not a wish for the default)."""
    name = ctx.obj["instance"]
    return "default" if name is None else check_instance_name(name)


def _given_instance(ctx: click.Context) -> str | None:
    """The instance named by -i or $KALI_INSTANCE, checked, or None (the config's then)."""
    name = ctx.obj["instance"]
    return None if name is None else check_instance_name(name)


def _attach(ctx: click.Context) -> Instance:
    return Instance.attach(_instance_name(ctx))


@click.group()
@click.option(
    "-i",
    "--instance",
    default=lambda: os.environ.get("KALI_INSTANCE"),
    help="Instance name (default: $KALI_INSTANCE, else the config's, else 'default').",
)
@click.pass_context
def main(ctx: click.Context, instance: str | None) -> None:
    """Control a Kali multi-arm robot controller instance."""
    ctx.ensure_object(dict)
    ctx.obj["instance"] = instance


@main.command()
@click.option(
    "-c",
    "--config",
    "config_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help=f"Config file (default {DEFAULT_CONFIG}).",
)
@click.option("--lockstep", is_flag=True, help="Deterministic mode: the clock never sleeps.")
@click.option(
    "--separate-processes",
    "separate",
    is_flag=True,
    help="With --lockstep: a process per daemon as in real time (to kill one), not the "
    "lockstep executive's one process.",
)
@click.option(
    "--record",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help="Also record the dashboard to this .rrd file (replay: rerun FILE).",
)
@click.pass_context
@_errors
def start(
    ctx: click.Context,
    config_path: Path | None,
    lockstep: bool,
    separate: bool,
    record: Path | None,
) -> None:
    """Start every Kali process; return when all are ready."""
    if separate and not lockstep:
        raise click.UsageError("--separate-processes goes with --lockstep (real time always is)")
    cfg = load_config(config_path or DEFAULT_CONFIG, instance=_given_instance(ctx))
    name = cfg.instance
    report = launcher.start(cfg, lockstep=lockstep, instance=name, record=record, separate=separate)
    if report.stale_cleaned:
        click.echo(
            f"cleaned a stale instance '{name}' left by a crash: " + ", ".join(report.stale_cleaned)
        )
    mode = "real time (clock running)"
    if lockstep:
        how = "a process per daemon" if separate else "one process"
        mode = f"lockstep, {how} (clock stopped at tick 0)"
    click.echo(
        f"instance '{name}' started in {report.seconds:.1f} s, {mode}: "
        + ", ".join(f"{n}[{p}]" for n, p in report.pids.items())
    )
    click.echo(f"logs in {report.log_dir}")
    with Instance.attach(name) as inst:
        _echo_dashboard(launcher.dashboard(inst))
    hint = feedforward_hint(cfg, name)
    if hint:
        click.echo(hint)


def feedforward_hint(cfg: KaliConfig, instance: str) -> str | None:
    """The line ``kalictl start`` prints when arms start without the dynamics feed-forward
    (``ff: off``, or the dynamics process left out): which, and how to turn it on; None when
    every arm starts with it (gravity counts: it was chosen)."""
    names = [r.name for r in cfg.robots]
    if not any(p.kind == "dynamics" for p in cfg.processes):
        off, how = names, "processes.dynamics.enabled: true in the config"
        why = "the dynamics process is left out: "
    else:
        off = [r.name for r in cfg.robots if r.ff == "off"]
        if not off:
            return None
        robot = f" {off[0]}" if len(off) == 1 else "" if off == names else " ROBOT"  # "": all
        flag = "" if instance == "default" else f" -i {instance}"
        how = f"ff: full in the config or kalictl{flag} ff on{robot}"
        why = ""
    whose = "its servos alone follow its motions"
    if len(off) > 1:
        whose = "their servos alone follow their motions"
    return f"feed-forward off: {', '.join(off)} ({why}{whose}, and lag); turn it on with {how}"


def _echo_dashboard(d: launcher.Dashboard | None) -> None:
    """Where the live dashboard is, a line per sink."""
    if d is None or not d.ready:
        click.echo("dashboard: the viewer is not up")
        return
    if d.web_url:
        click.echo(f"dashboard: {d.web_url}")
    if d.live_url:
        click.echo(f"dashboard: streaming to the rerun viewer at {d.live_url}")
    if d.record:
        click.echo(f"dashboard: recording to {d.record} (replay: rerun {d.record})")
    if d.message:
        click.echo(f"dashboard: {d.message}")


@main.command()
@click.option("--url", "url_only", is_flag=True, help="Print only the web viewer's URL.")
@click.pass_context
@_errors
def view(ctx: click.Context, url_only: bool) -> None:
    """Where the live dashboard is: open the URL in a browser (thesis 3.3.7's viewer)."""
    with _attach(ctx) as inst:
        d = launcher.dashboard(inst)
        if url_only:
            if d is None or not d.web_url:
                click.echo(f"kalictl: instance '{inst.name}': no web viewer served", err=True)
                sys.exit(1)
            click.echo(d.web_url)
            return
        _echo_dashboard(d)


@main.command()
@click.pass_context
@_errors
def stop(ctx: click.Context) -> None:
    """Stop everything; leave no process, shared memory or semaphore.

    Works whatever state the instance is in, also after a kill -9 of any of its processes.
    """
    name = _instance_name(ctx)
    r = launcher.stop(name)
    for what in r.left:
        click.echo(f"kalictl: stop: left {what}", err=True)
    if not (r.stopped or r.killed or r.removed):
        click.echo(f"instance '{name}': nothing to stop")
        sys.exit(1 if r.left else 0)
    n = len(r.stopped)
    msg = f"instance '{name}' stopped: {n} process{'es' if n != 1 else ''} left on request"
    if r.killed:
        msg += f", {len(r.killed)} killed ({', '.join(map(str, r.killed))})"
    click.echo(msg + f", {len(r.removed)} /dev/shm objects removed")
    if r.left:
        sys.exit(1)


@main.command()
@click.option("--json", "as_json", is_flag=True, help="Everything, as one JSON document.")
@click.option(
    "--memory", is_flag=True, help="Also each process's memory: PSS and RSS, and their sum."
)
@click.pass_context
@_errors
def status(ctx: click.Context, as_json: bool, memory: bool) -> None:
    """Clock, fault and per-process timing statistics (--json: also robots, servo level, TG,
    flight recorder, for scripts; --memory: each process's PSS and RSS)."""
    with _attach(ctx) as inst:
        if as_json:
            click.echo(json.dumps(introspect.snapshot(inst), indent=2, allow_nan=False))
            return
        c = inst.clock
        mode = introspect.clock_mode(inst)
        click.echo(
            f"instance '{inst.name}'  {'lockstep' if c['lockstep'] else 'real time'}  "
            f"clock {mode}  tick {int(c['tick'])}  time {time_ms(c):.0f} ms  "
            f"base tick {int(c['base_tick_ns']) / 1e6:g} ms  overruns {int(c['overruns'])} "
            f"(skipped {int(c['skipped_ticks'])} ticks)"
        )
        fault = inst.fault_text()
        click.echo(f"fault: {fault}" if fault else "fault: none")
        for lock in inst.held_locks():
            click.echo(
                f"lock: '{lock.name}' held by {lock.holder} for over {LOCK_STUCK_S:g} s "
                f"(nothing on the safety path waits for it)"
            )
        rows = launcher.describe(inst)
        clock_pid = next((r["pid"] for r in rows if r["name"] == "wallclock"), 0)
        for r in rows:
            lost = DEGRADED.get(str(r["name"]))
            if r["state"] == ProcState.DIED.name:
                click.echo(
                    f"degraded: {r['name']} (pid {r['pid']}) died; not serious, so the rest "
                    f"runs on without it" + (f": no {lost}" if lost else "")
                )
            elif _stalled(r, clock_pid):
                click.echo(
                    f"degraded: {r['name']} (pid {r['pid']}) stalled: no heartbeat for "
                    f"{r['heartbeat_age_ms'] / 1000:.1f} s; not serious, so the rest runs on"
                    + (f": {lost} stalled" if lost else "")
                )
        dump = introspect.Introspector(inst).flight()
        if dump is not None and dump["last_dump"]:
            click.echo(
                f"flight recorder: last dump {dump['last_dump']} (fault at tick "
                f"{dump['last_dump_tick']}; kalictl flight)"
            )
        head = (
            f"{'process':<10} {'pid':>7} {'state':<9} {'cpu':>3} {'prio':>4} {'period':>7} "
            f"{'ser':>3} {'signals':>9} {'acks':>9} {'miss':>6} {'exec':>8} {'exec max':>9} "
            f"{'late p50':>9} {'late p99':>9} {'late max':>9} {'hb age':>7}"
        )
        click.echo(head)
        for r in rows:
            period = f"{r['period_ms']:g}ms" if r["periodic"] else "own"
            if r["name"] == "wallclock":
                period = f"{int(c['base_tick_ns']) / 1e6:g}ms"
            state = r["state"] if r["alive"] else "DEAD"
            click.echo(
                f"{r['name']:<10} {r['pid']:>7} {state:<9} {r['cpu']:>3} {r['priority']:>4} "
                f"{period:>7} {'yes' if r['serious'] else 'no':>3} {r['signals']:>9} "
                f"{r['acks']:>9} {r['misses']:>6} {r['exec_last_us']:>6.0f}us "
                f"{r['exec_max_us']:>7.0f}us {_us(r['late_p50_us'])} "
                f"{_us(r['late_p99_us'])} {r['late_max_us']:>7.0f}us "
                f"{r['heartbeat_age_ms']:>5.0f}ms"
            )
        for r in rows:  # a networked robot's link: what it has counted
            if str(r["name"]).startswith("link."):
                k = inst.robot_index(str(r["name"]).partition(".")[2])
                click.echo(f"{r['name']}: {inst.hardware(k).link_status(k)}")
        servo_ms = next((r["period_ms"] for r in rows if r["name"] == "sio"), None)
        for r in rows:  # a polling SV with nothing to share (servo/sv/daemon.py)
            if r["name"].startswith("sv.") and servo_ms and r["period_ms"] > servo_ms:
                click.echo(
                    f"{r['name']} rests: signalled every {r['period_ms']:g} ms while the SV on "
                    f"SIO's CPU runs every servo alone (processes.sv.rest_ms)"
                )
        spy = introspect.Introspector(inst)
        t = spy.tg_longest()
        for line in _request_lines(spy.requests(), int(inst.clock["tick"])):
            click.echo(line)
        spy.close()
        if t is not None:
            click.echo(
                f"tg longest tick {t['tick']}: {t['wall_us']:.0f} us ({t['cpu_us']:.0f} us CPU): "
                f"{t['requests']} requests taken in {t['requests_us']:.0f} us, starting waiting "
                f"ones {t['starting_us']:.0f} us, {t['motions']} motions {t['motions_us']:.0f} us"
            )
        if memory:
            _memory_table(rows)
        misses = launcher.recent_misses(inst, 5)
        if misses:
            total = int(inst.misses["count"])
            click.echo(f"last {len(misses)} of {total} missed deadlines:")
            for m in misses:
                click.echo(
                    f"  tick {m['tick']:>9}  {m['process']:<10} signal of tick due "
                    f"{(m['due_ns'] - m['signal_ns']) / 1e6:.0f} ms earlier still "
                    f"unacknowledged ({m['consecutive']} in a row)"
                )


def _request_lines(req: dict[str, Any] | None, tick: int) -> list[str]:
    """``kalictl status``'s lines on the TG's requests, only when something holds them up:
    a request waiting for a status record (and who holds the records), the queue at least
    half full (and whose entries), a program at its share of unread outcomes."""
    if req is None:
        return []
    programs: list[dict] = req["programs"]
    queue: dict = req["queue"]
    lines = []
    if req["blocked_seq"]:
        who = ", ".join(
            f"{p['program']} {p['live']} queued or running" for p in programs if p["live"]
        )
        lines.append(
            f"requests: blocked for {tick - int(req['blocked_tick']):d} ticks: request "
            f"{req['blocked_seq']} waits for a status record, every one holds a request "
            f"queued or running ({who or 'none'}); stops still go first"
        )
    if queue["entries"] * 2 >= queue["capacity"]:
        who = ", ".join(f"{p['program']} {p['in_queue']}" for p in programs if p["in_queue"])
        lines.append(
            f"requests: queue holds {queue['entries']} of {queue['capacity']} entries "
            f"({who}; {queue['share']} each at most)"
        )
    for p in programs:
        if p["unread"] >= layout.STATUS_SHARE:
            lines.append(
                f"requests: {p['program']} keeps {p['unread']} outcomes unread: its oldest "
                f"give way to its new requests (their handles read LOST)"
            )
    return lines


def _stalled(row: dict[str, object], clock_pid: object) -> bool:
    """A non-serious process alive but silent for over STALL_S (stopped, or hung): its
    heartbeat is refreshed every cycle and every idle wait.  A daemon the lockstep executive
    hosts (the wall clock's pid) has no heartbeat of its own."""
    return (
        not row["serious"]
        and bool(row["alive"])
        and row["state"] == ProcState.ACTIVE.name
        and row["pid"] != clock_pid
        and float(row["heartbeat_age_ms"]) > STALL_S * 1000  # type: ignore[arg-type]
    )


def _memory_table(rows: list[dict[str, object]]) -> None:
    """Each live process's PSS and RSS (``introspect.pss_kib``) and the set's sums.  PSS
    shares a page among the processes mapping it, so its sum is what the set takes."""
    click.echo(f"{'memory':<10} {'pid':>7} {'PSS':>9} {'RSS':>9}")
    pss_sum = rss_sum = 0
    for r in rows:
        pid = int(r["pid"])  # type: ignore[call-overload]
        try:
            pss, rss = introspect.pss_kib(pid) if r["alive"] else (-1, -1)
        except OSError:  # gone since, or not ours to read
            pss = rss = -1
        if pss < 0:
            click.echo(f"{r['name']:<10} {r['pid']:>7} {'-':>9} {'-':>9}")
            continue
        pss_sum += pss
        rss_sum += rss
        click.echo(f"{r['name']:<10} {r['pid']:>7} {pss / 1024:>6.1f} MB {rss / 1024:>6.1f} MB")
    click.echo(f"{'total':<10} {'':>7} {pss_sum / 1024:>6.1f} MB {rss_sum / 1024:>6.1f} MB")


@main.command()
@click.option(
    "--fields",
    "pattern",
    default=None,
    is_flag=False,
    flag_value="*",
    metavar="[KEYS]",
    help="Each record's fields and values (KEYS: a glob of block keys, e.g. 'robots*').",
)
@click.pass_context
@_errors
def mem(ctx: click.Context, pattern: str | None) -> None:
    """Show the arena: blocks, free list, fragmentation; with --fields, every record of the
    layout with its writer, readers, fields and values.

    Like LinuxCNC's ``halcmd show``: every block in shared memory by name.
    """
    with _attach(ctx) as inst:
        if pattern is not None:
            registry = registry_for(inst.config.plugins, inst.config.base_dir, inst.config.files)
            cell = cell_of(inst.config, *registry.dtypes())
            lines = introspect.record_lines(inst, cell, pattern)
            if not lines:
                raise InstanceError(f"mem --fields {pattern!r}: no block of the layout matches")
            click.echo("\n".join(lines))
            return
        a = inst.arena
        h = a.header
        click.echo(
            f"arena {a.name}  layout v{int(h['layout_version'])}  {a.size} B  "
            f"header+directory {int(h['header_bytes'])} B  owner pid {int(h['owner_pid'])}"
        )
        click.echo(f"{'offset':>10} {'size':>10} {'requested':>10}  key")
        blocks = a.blocks()
        for b in blocks:
            if b.used:
                click.echo(f"{b.offset:#10x} {b.size:>10} {b.requested:>10}  {b.key}")
        click.echo("free list:")
        for b in blocks:
            if not b.used:
                click.echo(f"{b.offset:#10x} {b.size:>10}")
        s = a.stats()
        click.echo(
            f"used {s.used_bytes} B in {s.used_blocks} blocks, free {s.free_bytes} B in "
            f"{s.free_fragments} fragments (largest {s.largest_free} B), "
            f"fragmentation {100 * s.fragmentation:.1f} %"
        )


@main.command()
@click.option("--once", is_flag=True, help="Print one frame (after one interval) and exit.")
@click.option(
    "--interval",
    default=0.5,
    show_default=True,
    type=str,
    help=f"Seconds between refreshes, {TOP_INTERVAL_S[0]:g} to {TOP_INTERVAL_S[1]:g}.",
)
@click.pass_context
@_errors
def top(ctx: click.Context, once: bool, interval: str) -> None:
    """A live table: processes, robots, servo latency, clock and fault; Ctrl-C quits.

    Rates and lateness percentiles are over the last interval (in lockstep mode per second
    of Kali's clock); the "all" columns are since start.
    """
    from . import top as top_view  # rich is loaded for this command only

    lo, hi = TOP_INTERVAL_S
    seconds = _number("top", "--interval", interval, lo, hi, "seconds")
    with _attach(ctx) as inst:
        top_view.run(inst, seconds, once)


@main.command()
@click.argument(
    "file", required=False, type=click.Path(exists=True, dir_okay=False, path_type=Path)
)
@click.option(
    "--ticks",
    default=10,
    show_default=True,
    type=click.IntRange(1, 10_000),
    help="Ticks before the fault shown one by one.",
)
@click.option("--now", is_flag=True, help="Dump the ring as it stands, without a halt, first.")
@click.pass_context
@_errors
def flight(ctx: click.Context, file: Path | None, ticks: int, now: bool) -> None:
    """What led to a halt: the flight recorder's dump FILE (default: the instance's latest).

    The fault, the ticks covered, each robot's worst tracking error, torque and current over
    them, and tick by tick before the halt.  With --now: the last 2 s as they stand, written
    to a ring-*.npz file of their own.
    """
    if now:
        with _attach(ctx) as inst:
            file = flightrec.dump_now(inst)
    path = file or flightrec.find_latest(_instance_name(ctx))
    click.echo(f"flight recorder dump {path}")
    for line in flightrec.summary(flightrec.load(path), ticks):
        click.echo(line)


@main.group()
def record() -> None:
    """Record every servo tick of every arm to an MCAP file (start, stop, status)."""


@record.command("start")
@click.argument("path", type=click.Path(dir_okay=False, path_type=Path))
@click.pass_context
@_errors
def record_start(ctx: click.Context, path: Path) -> None:
    """Start recording to PATH (a new .mcap file) until kalictl record stop."""
    from ..recording import recorder  # here: the recorder's mcap only when recording

    with _attach(ctx) as inst:
        pid = recorder.start(inst, path)
        click.echo(f"recording instance '{inst.name}' to {path.absolute()} (recorder pid {pid})")


@record.command("stop")
@click.pass_context
@_errors
def record_stop(ctx: click.Context) -> None:
    """Stop recording: what is left is drained and the file finished."""
    from ..recording import recorder  # here: the recorder's mcap only when recording

    with _attach(ctx) as inst:
        doc = recorder.stop(inst)
        click.echo(_record_line(doc))
        if doc["error"]:
            raise click.ClickException(doc["error"])


@record.command("status")
@click.pass_context
@_errors
def record_status(ctx: click.Context) -> None:
    """The recording in progress, or the last one."""
    from ..recording import recorder  # here: the recorder's mcap only when recording

    name = _instance_name(ctx)
    doc = recorder.read_status(name)
    click.echo(_record_line(doc) if doc else f"instance '{name}': no recording yet")


def _record_line(doc: dict[str, Any]) -> str:
    gaps = f", {doc['gaps']} ticks LOST" if doc["gaps"] else ", no tick lost"
    error = f"; {doc['error']}" if doc["error"] else ""
    return (
        f"recording {doc['state']}: {doc['path']}: {doc['ticks']} servo ticks "
        f"({doc['first_tick']}..{doc['last_tick']}){gaps}, {int(doc['bytes']) / 1e6:.1f} MB{error}"
    )


@main.group()
def clock() -> None:
    """Run, stop, set or single-step the wall clock."""


@clock.command("start")
@click.pass_context
@_errors
def clock_start(ctx: click.Context) -> None:
    """Run the wall clock (refused while a fault is active)."""
    with _attach(ctx) as inst:
        start_kali_clock(inst)
        click.echo(f"clock running from tick {int(inst.clock['tick'])}")


@clock.command("stop")
@click.pass_context
@_errors
def clock_stop(ctx: click.Context) -> None:
    """Stop the wall clock: no periodic process is signalled."""
    with _attach(ctx) as inst:
        stop_kali_clock(inst)
        click.echo(f"clock stopped at tick {int(inst.clock['tick'])}")


@clock.command("set")
@click.argument("ms", type=float)
@click.pass_context
@_errors
def clock_set(ctx: click.Context, ms: float) -> None:
    """Set the clock's running time to MS milliseconds."""
    with _attach(ctx) as inst:
        set_kali_clock(inst, ms)
        click.echo(f"clock time set to {ms:g} ms at tick {int(inst.clock['tick'])}")


@clock.command("step")
@click.argument("ticks", type=click.IntRange(min=0))
@click.pass_context
@_errors
def clock_step(ctx: click.Context, ticks: int) -> None:
    """Lockstep: run TICKS more ticks, then stop."""
    with _attach(ctx) as inst:
        tick = step_kali_clock(inst, ticks)
        fault = inst.fault_text()
        click.echo(f"clock at tick {tick}" + (f"; halted: {fault}" if fault else ""))
        if fault:
            sys.exit(1)


_WARN = click.option(
    "--warn",
    is_flag=True,
    help="If the schedulability check predicts the servo tick will not fit, warn and go ahead.",
)


@main.command()
@click.option(
    "--margin",
    type=click.FloatRange(0.0, 1.0, max_open=True),
    default=schedule.DEFAULT_MARGIN,
    show_default=True,
    help="Headroom the servo tick must leave in its period.",
)
@click.pass_context
@_errors
def check(ctx: click.Context, margin: float) -> None:
    """Schedulability: does the servo tick fit its period on its CPUs, as measured now?"""
    with _attach(ctx) as inst:
        verdict = schedule.check(inst, margin=margin)
    click.echo(verdict.text())
    if not verdict.fits:
        sys.exit(1)


@main.command()
@click.argument("process")
@click.argument("ms", type=click.FLOAT)
@_WARN
@click.pass_context
@_errors
def rate(ctx: click.Context, process: str, ms: float, warn: bool) -> None:
    """Set PROCESS's period to MS milliseconds, a whole number of base ticks (e.g. 1.5)."""
    with _attach(ctx) as inst:
        change = schedule.Change(f"rate {process} {ms:g} ms", process=process, period_us=ms * 1e3)
        schedule.guard(inst, change, warn, lambda text: click.echo(text, err=True))
        set_control_rate(inst, process, ms)
        click.echo(f"{process}: period {ms:g} ms")


@main.command()
@click.argument("robot", required=False)
@click.option("--release", is_flag=True, help="Release the button; power stays off until enabled.")
@click.pass_context
@_errors
def estop(ctx: click.Context, robot: str | None, release: bool) -> None:
    """Press the emergency-stop button of ROBOT (default: every robot).

    The board cuts the amplifiers at once, the brakes follow, and the system halts.
    """
    with _attach(ctx) as inst:  # the arena alone: no config parsed, no user code run
        if not release:
            click.echo(estop_pressed(inst.press_estop(robot or None, "kalictl")))
            return
        targets = [robot] if robot else list(inst.cell.names)
        for name in targets:
            k = inst.robot_index(name)
            inst.hardware(k).press_estop(k, False)
        click.echo(f"e-stop released: {', '.join(targets)}")


@main.command(context_settings={"ignore_unknown_options": True})
@click.argument("robot")
@click.argument("fx")
@click.argument("fy")
@click.argument("fz")
@click.option("--for", "seconds", default="1", show_default=True, help="seconds (simulated)")
@click.pass_context
@_errors
def push(ctx: click.Context, robot: str, fx: str, fy: str, fz: str, seconds: str) -> None:
    """Push ROBOT's tool with the force FX FY FZ (N, world frame) for --for seconds: the
    plant applies it to the tool, as a hand or a collision would (a simulated cell only)."""
    force = np.array(
        [
            _number("push", axis, v, -MAX_PUSH_N, MAX_PUSH_N, "N")
            for axis, v in zip(("FX", "FY", "FZ"), (fx, fy, fz), strict=True)
        ]
    )
    duration = _number("push", "--for", seconds, 0.0, MAX_PUSH_S, "seconds", lo_open=True)
    with _attach(ctx) as inst:
        k = inst.robot_index(robot)
        inst.push(k, force, duration)
        click.echo(f"{robot}: pushed with ({fx}, {fy}, {fz}) N for {duration:g} s")


@main.command()
@click.argument("robots", nargs=-1, required=True)
@click.pass_context
@_errors
def tare(ctx: click.Context, robots: tuple[str, ...]) -> None:
    """Zero the wrist sensors of ROBOTS: SIO averages the next 0.1 s of each reading less the
    tool's weight and takes that as the sensor's offset.  Keep the arms still, touching
    nothing.  Needed before a servo moved by the sensor (admittance, guiding) is selected."""
    with Kali(_instance_name(ctx)) as kali:
        for name in robots:
            if name not in kali.names:
                raise ServoError(f"tare: no robot {name!r:.40}; robots: {', '.join(kali.names)}")
        for name in robots:
            arm = kali.robot(name)
            arm.tare()
            force = np.linalg.norm(arm.read_wrench("sensor")[:3])
            click.echo(f"{name}: tared; the sensor reads {force:.2f} N (the tool's weight)")


@main.command()
@click.pass_context
@_errors
def reset(ctx: click.Context) -> None:
    """Clear the active fault and restart the clock; power stays off until `kalictl enable`.

    Refused while an e-stop button is still pressed (LinuxCNC: the e-stop chain must be
    closed before the machine can be reset)."""
    with _attach(ctx) as inst:
        pressed = [
            name
            for k, name in enumerate(inst.cell.names)
            if inst.hardware(k).estops_pressed()[k]
        ]
        if pressed:
            raise InstanceError(
                f"reset: the e-stop of robot '{pressed[0]}' is still pressed"
                + (f" (also {', '.join(repr(p) for p in pressed[1:])})" if pressed[1:] else "")
                + f"; release it first: kalictl estop --release {pressed[0]}"
            )
        text = inst.fault_text()
        if inst.clear_fault():
            click.echo(f"cleared: {text}")
        else:
            click.echo("no active fault")
        if not inst.lockstep and int(inst.clock["mode"]) == RunMode.STOPPED:
            start_kali_clock(inst)
            click.echo(f"clock running from tick {int(inst.clock['tick'])}")
        click.echo("power stays off until: kalictl enable")


@contextmanager
def _servo_client(ctx: click.Context) -> Iterator[tuple[Instance, ServoClient]]:
    """Attach and open the servo level for one command."""
    with _attach(ctx) as inst:
        client = ServoClient(inst)
        try:
            yield inst, client
        finally:
            client.close()


def _robots(client: ServoClient, robot: str | None) -> list[str]:
    return [client.names[client.robot_index(robot)]] if robot else list(client.names)


def _power(ctx: click.Context, robot: str | None, on: bool, timeout_s: float) -> None:
    """``enable``/``disable``: the arena alone (no config parsed, no user code run)."""
    with _attach(ctx) as inst:
        names = [inst.cell.names[inst.robot_index(robot)]] if robot else list(inst.cell.names)
        for name in names:
            inst.command_power(inst.robot_index(name), on)
        if inst.lockstep:
            click.echo(
                f"{'enable' if on else 'disable'} requested: {', '.join(names)} "
                "(lockstep: step the clock)"
            )
            return
        _wait_power(inst, names, on, timeout_s)


def _wait_power(inst: Instance, names: list[str], on: bool, timeout_s: float) -> None:
    """Wait until SIO reports every robot in ``names`` powered on (off); ServoError if not."""
    want = PowerState.ON if on else PowerState.OFF
    robots = inst.robot_states()
    index = [inst.robot_index(n) for n in names]
    deadline = time.monotonic() + timeout_s
    while any(int(robots["power"][k]) != want for k in index):
        if time.monotonic() > deadline or inst.fault["active"]:
            states = ", ".join(
                f"{n}: {_power_name(int(robots['power'][k]))} ({decode(robots['message'][k])})"
                for n, k in zip(names, index, strict=True)
            )
            why = inst.fault_text() or f"not {want.name} within {timeout_s:g} s"
            raise ServoError(f"power: {why}; {states}")
        time.sleep(0.01)
    click.echo(f"power {want.name.lower()}: {', '.join(names)}")


def _power_name(word: int) -> str:
    """A power word's name (the arena is not trusted: any other value is shown as it is)."""
    try:
        return PowerState(word).name
    except ValueError:
        return f"INVALID({word})"


@main.group("config")
def config_group() -> None:
    """The config file: its schema, and a file read with every default written out."""


@config_group.command("schema")
def config_schema() -> None:
    """Print the config file's JSON Schema: every field with its type, default, bounds, unit
    and description (editors validate a config against it)."""
    click.echo(json.dumps(config_mod.schema(), indent=2))


@config_group.command("show")
@click.option(
    "-c",
    "--config",
    "config_path",
    type=click.Path(dir_okay=False, path_type=Path),
    default=None,
    help=f"Config file (default {DEFAULT_CONFIG}).",
)
@click.pass_context
@_errors
def config_show(ctx: click.Context, config_path: Path | None) -> None:
    """Print the config as kalictl start reads it, every default written out (YAML); checked
    as kalictl start checks it."""
    cfg = load_config(config_path or DEFAULT_CONFIG, instance=_given_instance(ctx))
    click.echo(config_mod.show(cfg), nl=False)


@main.command()
@click.argument("files", nargs=-1)
@_errors
def types(files: tuple[str, ...]) -> None:
    """List the robot types a config's robots[].model may name: those shipped with Kali
    (kali_daemons/robots), then each .py FILE given, loaded and checked as kalictl start
    would (its ROBOT, URDF and kinematics)."""
    for name in known_types():
        t = robot_type(name)
        click.echo(f"{name:<12} {t.n_joints} joints  {t.description}")
    for file in files:
        t = robot_type(str(Path(file).expanduser().resolve()) if file.endswith(".py") else file)
        click.echo(f"{file:<12} {t.n_joints} joints  {t.description} (ROBOT {t.name!r})")
    if not files:
        click.echo(
            "or a .py file defining ROBOT, your own arm (docs/guide/robot-types.md); "
            "kalictl types FILE checks one"
        )


@main.command()
@click.argument("robot", required=False)
@click.pass_context
@_errors
def enable(ctx: click.Context, robot: str | None) -> None:
    """Power ROBOT's amplifiers (default: every robot); the arm holds where it is."""
    _power(ctx, robot, True, 2.0)


@main.command()
@click.argument("robot", required=False)
@click.pass_context
@_errors
def disable(ctx: click.Context, robot: str | None) -> None:
    """Cut ROBOT's amplifiers (default: every robot); the brakes follow."""
    _power(ctx, robot, False, 2.0)


@main.command()
@click.argument("mode", type=click.Choice(["on", "off", "gravity", "full"]))
@click.argument("robot", required=False)
@click.pass_context
@_errors
def ff(ctx: click.Context, mode: str, robot: str | None) -> None:
    """Feed-forward of ROBOT (default: every robot), on line (thesis 3.3.6): on (= full, the
    inverse dynamics of the demanded motion), gravity, or off.  It fades in or out."""
    with _servo_client(ctx) as (_inst, client):
        names = _robots(client, robot)
        for name in names:
            client.feedforward(name, mode)
        shown = "full" if mode == "on" else mode
        click.echo(f"feed-forward {shown}: {', '.join(names)}")


@main.command()
@click.argument("robot", required=False)
@click.option("--timeout", default=30.0, show_default=True, help="seconds to wait")
@click.pass_context
@_errors
def calibrate(ctx: click.Context, robot: str | None, timeout: float) -> None:
    """Calibrate ROBOT (default: every robot) against its encoder index pulses (thesis 3.5.1).

    Powers the robot first if it is off.  Every joint moves by at most about 7° to its
    nearest index pulse and holds there; progress is shown until all are calibrated.  An arm
    with absolute encoders (an FR3) has nothing to calibrate: it is left as it is.
    """
    with _servo_client(ctx) as (inst, client):
        names = []
        for n in _robots(client, robot):
            model = inst.config.robot(n).model
            if inst.config.robot(n).type.absolute_encoders:  # exact from power-up (an FR3)
                click.echo(f"{n} ({model}): nothing to calibrate: its encoders are absolute")
            else:
                names.append(n)
        if not names:
            return
        off = [n for n in names if client.power_state(n) != PowerState.ON]
        if inst.lockstep:
            if off:
                raise ServoError(
                    f"calibrate: {', '.join(off)} not powered; in lockstep mode run "
                    f"kalictl enable and step the clock first"
                )
            for n in names:
                client.calibrate(n)
            click.echo(f"calibrate requested: {', '.join(names)} (lockstep: step the clock)")
            return
        if off:
            for n in off:
                client.power(n, True)
            _wait_power(inst, off, True, 2.0)
        for n in names:
            client.calibrate(n)
        _follow_calibration(inst, client, names, timeout)


def _follow_calibration(
    inst: Instance, client: ServoClient, names: list[str], timeout_s: float
) -> None:
    """Print each robot's calibration progress as it changes; ServoError unless all succeed."""
    deadline = time.monotonic() + timeout_s
    shown: dict[str, str] = {}
    robots = client.level.robots
    while True:
        finished = []
        for n in names:
            k = client.robot_index(n)
            state, found, message = client.calibration(n)
            taken = not int(robots["calib_cmd"][k])
            line = f"{n}: {message}"
            if state == CalibState.SEARCH:
                n_joints = inst.config.robots[k].n_joints
                joints = " ".join(str(j + 1) for j in range(n_joints) if found >> j & 1)
                joints = joints or "none"
                line += f" (found: joints {joints})"
            if taken and shown.get(n) != line:
                click.echo(line)
                shown[n] = line
            finished.append(taken and state in (CalibState.DONE, CalibState.FAILED))
        if all(finished):
            break
        if inst.fault["active"]:
            raise ServoError(f"calibrate: halted: {inst.fault_text()}")
        if time.monotonic() > deadline:
            raise ServoError(f"calibrate: not finished within {timeout_s:g} s")
        time.sleep(0.05)
    failed = [n for n in names if client.calibration(n)[0] == CalibState.FAILED]
    for n in names:
        if n not in failed:
            shift = client.level.arm("calib_shift", client.robot_index(n))
            moved = "  ".join(
                f"{j + 1}:{math.degrees(float(v)):+.2f}°" for j, v in enumerate(shift)
            )
            click.echo(f"{n}: calibrated; angles corrected by {moved}")
    if failed:
        raise ServoError(f"calibrate: failed on {', '.join(failed)}")


def _descendants(pid: int) -> list[int]:
    """Every live descendant of ``pid`` (from /proc), children first."""
    found: list[int] = []
    todo = [pid]
    while todo:
        parent = todo.pop()
        for task in Path(f"/proc/{parent}/task").glob("*/children"):
            try:
                kids = [int(c) for c in task.read_text().split()]
            except OSError:
                continue
            found += kids
            todo += kids
    return found


def _kill_tree(proc: subprocess.Popen) -> int:
    """SIGKILL ``proc`` and everything it started, and reap it: nothing is left behind."""
    for pid in [*_descendants(proc.pid), proc.pid]:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    return proc.wait()


@main.command(context_settings={"ignore_unknown_options": True, "allow_interspersed_args": False})
@click.argument("program", type=click.Path(exists=True, dir_okay=False, path_type=Path))
@click.argument("args", nargs=-1, type=click.UNPROCESSED)
@click.option(
    "--remote",
    "endpoint",
    metavar="ENDPOINT",
    help="run here, on an instance of another machine, through its Zenoh bridge "
    "(e.g. tcp/HOST:7447; $KALI_REMOTE_USER/$KALI_REMOTE_PASSWORD if it asks)",
)
@click.pass_context
@_errors
def run(ctx: click.Context, program: Path, args: tuple[str, ...], endpoint: str | None) -> None:
    """Run the robot program PROGRAM (a Python file) attached to this instance; everything
    after PROGRAM (after a ``--``, if one follows it) goes to the program unchanged.

    ``Kali()`` in the program connects to it ($KALI_INSTANCE).  Ctrl-C first stops the arms
    the program owns on their paths, through the TG's queue (taking them over, so the program
    cannot start them again), then sends it SIGINT; a second Ctrl-C kills it and whatever it
    started.  With --remote the bridge stops them, in the session kalictl opened for the
    program (which then takes no more calls), and kalictl says so once they are at rest.  The
    exit status is the program's (128 + N when signal N ended it).  Its numeric libraries
    compute on one thread (OPENBLAS_NUM_THREADS=1 ..., unless it sets them).
    """
    # Ctrl-C is how a user stops the arms: taken even when kalictl was started with SIGINT
    # ignored (a background job, nohup), which Python would otherwise keep ignored
    signal.signal(signal.SIGINT, signal.default_int_handler)
    name = _instance_name(ctx)
    if args[:1] == ("--",):
        args = args[1:]
    if endpoint is not None:
        sys.exit(_run_remote(endpoint, name, program, args))
    os.environ.pop(REMOTE_ENV, None)  # this instance, here: the program's Kali() too
    kali = Kali(name, force=True)  # the instance must be up: say so before the program starts
    # numpy's BLAS on one thread, as the daemons' (a program's own setting stands): a periodic
    # function the program runs in a thread must not wait on a BLAS worker below it
    env = {**launcher.SINGLE_THREADED, **os.environ, INSTANCE_ENV: name}
    try:
        proc = subprocess.Popen([sys.executable, str(program), *args], env=env)
        try:
            status = proc.wait()
        except KeyboardInterrupt:
            status = _interrupted(kali, proc, program)
    finally:
        kali.close()
    sys.exit(status if status >= 0 else 128 - status)  # a signal's death as a shell says it


def _run_remote(endpoint: str, name: str, program: Path, args: tuple[str, ...]) -> int:
    """``kalictl run --remote``: the program runs here, its ``Kali()`` connects to instance
    ``name`` through the bridge at ``endpoint`` ($KALI_REMOTE).  kalictl opens the program's
    session itself and hands it over ($KALI_REMOTE_SESSION: the program's ``Kali()`` adopts
    it), so that on Ctrl-C it can have the bridge stop that session's arms whatever the
    program does (``_interrupted_remote``); it closes the session when the program ends.
    Its exit status, as ``run``'s."""
    conn = remote.reach(endpoint, name)  # it must answer: say so before the program starts
    try:
        conn.open(program.name)
        env = {
            **launcher.SINGLE_THREADED,
            **os.environ,
            INSTANCE_ENV: name,
            REMOTE_ENV: endpoint,
            SESSION_ENV: conn.handover(),
        }
        proc = subprocess.Popen([sys.executable, str(program), *args], env=env)
        try:
            status = proc.wait()
        except KeyboardInterrupt:
            status = _interrupted_remote(conn, proc, program)
    finally:
        conn.close()
    return status if status >= 0 else 128 - status


def _stopped_text(kali: Kali, owned: list[int], seq: int) -> str:
    """Wait until the stop ``seq`` of arms ``owned`` is carried out and they are at rest
    (``Kali.stopped``; in lockstep stepping the clock), STOP_CONFIRM_S at most, and say what
    is true then: stopped, halted, or not confirmed (never "stopped" before they are)."""
    arms = ", ".join(kali.names[k] for k in owned)
    if not owned:
        return "it owned no arm"
    deadline = time.monotonic() + STOP_CONFIRM_S
    while not kali.stopped(owned, seq) and time.monotonic() < deadline:
        kali.pause()
    if kali.inst.fault["active"]:
        return f"arms halted ({kali.inst.fault_text()}): {arms}"
    if kali.stopped(owned, seq):
        return f"arms stopped on their paths: {arms}"
    return (
        f"a stop of {arms} was asked, and not confirmed within {STOP_CONFIRM_S:g} s "
        f"(kalictl status says what the TG is doing); kalictl estop halts them"
    )


def _interrupted_remote(conn: remote.Connection, proc: subprocess.Popen, program: Path) -> int:
    """Ctrl-C under ``kalictl run --remote``, as ``_interrupted``: the bridge stops the arms
    of the program's session and answers once they are at rest (the session takes no more
    calls, so the program cannot start them again), then the program is signalled; a second
    Ctrl-C kills it.  What kalictl says is what the bridge answered."""
    try:
        try:
            done = conn.stop()
        except KaliError as exc:
            said = f"its arms were not stopped, they may still move: {exc}"
        else:
            arms = ", ".join(done["robots"])
            if done["halted"]:
                said = f"arms halted ({done['halted']}): {arms or 'none moving'}"
            elif not arms:
                said = "it moved no arm"
            elif done["at_rest"]:
                said = f"arms stopped on their paths: {arms}"
            else:
                said = (
                    f"a stop of {arms} was asked, and not confirmed within "
                    f"{done['waited_s']:g} s; kalictl estop halts them"
                )
        click.echo(f"run: {program} interrupted; {said}", err=True)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        return proc.wait()
    except KeyboardInterrupt:
        status = _kill_tree(proc)
        click.echo(f"run: {program} killed (second Ctrl-C)", err=True)
        return status
    except BaseException:
        _kill_tree(proc)
        raise


def _interrupted(kali: Kali, proc: subprocess.Popen, program: Path) -> int:
    """Ctrl-C under ``kalictl run``: stop the program's arms, then signal it; a second
    Ctrl-C kills it.  The program's exit status (negative: the signal that ended it)."""
    try:
        owned = sorted(
            {k for pid in [proc.pid, *_descendants(proc.pid)] for k in kali.owned_by(pid)}
        )
        seq = kali.stop_robots(owned, force=True)  # before the signal: it may ignore it
        click.echo(f"run: {program} interrupted; {_stopped_text(kali, owned, seq)}", err=True)
        if proc.poll() is None:
            proc.send_signal(signal.SIGINT)
        return proc.wait()
    except KeyboardInterrupt:
        status = _kill_tree(proc)
        click.echo(f"run: {program} killed (second Ctrl-C)", err=True)
        return status
    except BaseException:
        _kill_tree(proc)
        raise


@main.command()
@click.argument("robot")
@click.option(
    "--joints",
    required=True,
    help="the arm's joint angles to go to, one per joint, degrees: 0,45,-180,0,45,0 (a PUMA)",
)
@click.option(
    "--speed",
    default="0.5",
    show_default=True,
    help="fraction of the joint speed and acceleration limits, in (0, 1]",
)
@click.option(
    "--timeout",
    default="60",
    show_default=True,
    help=f"seconds to wait, in (0, {MOVE_TIMEOUT_S:g}]; then the arm is stopped on its path",
)
@click.option("--force", is_flag=True, help="take the arm over from the program that owns it")
@click.pass_context
@_errors
def move(
    ctx: click.Context, robot: str, joints: str, speed: str, timeout: str, force: bool
) -> None:
    """Move ROBOT's joints smoothly to --joints through the trajectory generator, every joint
    arriving together; waits until the arm is there.  Every argument is checked before
    anything is queued.  An arm another program owns is refused, naming it, unless --force
    (which stops that program's motion on it)."""
    target_deg = _joint_degrees(joints)  # its count is checked against the arm's below
    speed_f = _number("move", "--speed", speed, 0.0, 1.0, "(0, 1]", MotionError, lo_open=True)
    timeout_s = _number(
        "move", "--timeout", timeout, 0.0, MOVE_TIMEOUT_S, "seconds", MotionError, lo_open=True
    )
    with Kali(_instance_name(ctx), force=force) as kali:
        if robot not in kali.names:
            raise ServoError(f"move: no robot {robot!r:.40}; robots: {', '.join(kali.names)}")
        arm = kali.robot(robot)
        n = kali.inst.config.robots[arm.index].n_joints
        if len(target_deg) != n:
            model = kali.inst.config.robots[arm.index].type.name  # not a type file's path
            raise MotionError(
                f"move: --joints {joints!r:.80}: {len(target_deg)} values, expected {n} "
                f"(robot '{arm.name}' is a {model})"
            )
        if kali.servo.power_state(arm.name) != PowerState.ON:
            raise ServoError(f"move: robot '{arm.name}' is not powered; kalictl enable {arm.name}")
        owner = kali.owner(arm.index)
        if owner is not None and not force:  # the TG refuses it anyway: say so at once
            raise ServoError(
                f"move: robot '{arm.name}' is owned by pid {owner[0]} ({owner[1]}); "
                f"kalictl move --force takes it over"
            )
        t0 = time.monotonic()
        handle = arm.move_joints(np.radians(target_deg), speed=speed_f, wait=False)
        if kali.inst.lockstep:
            click.echo(
                f"move requested: {arm.name}, request {handle.seq} (lockstep: step the clock)"
            )
            return
        try:
            handle.wait(timeout_s)
        except TimeoutError:
            state = handle.state.name.lower()
            handle.cancel()  # an arm left moving after the command gave up would surprise
            raise MotionError(
                f"move: robot '{arm.name}' not there within {timeout_s:g} s (--timeout; request "
                f"{handle.seq} was {state}): stopped on its path"
            ) from None
        at = ", ".join(f"{math.degrees(float(v)):.2f}" for v in arm.read_joints())
        click.echo(f"{arm.name}: at [{at}]° after {time.monotonic() - t0:.2f} s")


def _joint_degrees(joints: str) -> list[float]:
    """``--joints``: finite numbers in degrees, one per joint; MotionError naming the value
    if not (the count is the arm's, checked once the instance is attached)."""
    example = "one number in degrees per joint, e.g. 0,45,-180,0,45,0"
    values = joints.replace(" ", "").split(",")
    if not 1 <= len(values) <= layout.MAX_JOINTS:
        raise MotionError(
            f"move: --joints {joints!r:.80}: {len(values)} values, an arm has 1 .. "
            f"{layout.MAX_JOINTS} joints"
        )
    out = []
    for j, text in enumerate(values, 1):
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            raise MotionError(f"move: --joints {joints!r:.80}: joint {j} = {text!r:.40}: {example}")
        out.append(v)
    return out


@main.group()
def servo() -> None:
    """Servo algorithms per joint or per robot: list, select, set, get (thesis 3.4, 3.3.4)."""


@servo.command("list")
@click.pass_context
@_errors
def servo_list(ctx: click.Context) -> None:
    """The registered algorithms, joint and robot-level, what every robot runs, and the
    servos in shadow trial beside them."""
    with _servo_client(ctx) as (_inst, client):
        loaded = client.loaded()  # the plugins loaded while running registered first
        registry = client.level.registry
        for alg in registry:
            click.echo(f"{alg.name:<16} joint  {', '.join(alg.params)}")
        for arm in registry.arms:
            click.echo(f"{arm.name:<16} robot  {', '.join(arm.params)}")
        for entry in loaded:
            said = entry.verdict
            state = "being loaded" if said is None else f"FAILED: {said}" if said else "loaded"
            click.echo(f"{entry.file}: {', '.join(entry.servos)} {state}")
        click.echo("")
        for k, name in enumerate(client.names):
            r = client.level.robots[k]
            state = PowerState(int(r["power"])).name.lower()
            active = client.arm_active(name)
            if active is not None:
                click.echo(f"{name:<8} power {state:<9} robot-level: {active}")
            else:
                joints = []
                for j in range(1, client.level.map.counts[k] + 1):
                    s = client.level.slot_structs[client.level.map.index(k, j - 1)]
                    mark = "" if s.enabled else " (off)"
                    joints.append(f"{j}:{client.active(name, j)}{mark}")
                click.echo(f"{name:<8} power {state:<9} " + "  ".join(joints))
            running = [t for t in client.trials(name) if t.state == ShadowState.RUNNING]
            if running and running[0].level == "robot":
                click.echo(f"{'':<8} in shadow: {running[0].shadow} (robot-level)")
            elif running:
                click.echo(
                    f"{'':<8} in shadow: " + "  ".join(f"{t.joint}:{t.shadow}" for t in running)
                )


@servo.command("load")
@click.argument("file", type=click.Path(dir_okay=False, path_type=Path))
@_WARN
@click.pass_context
@_errors
def servo_load(ctx: click.Context, file: Path, warn: bool) -> None:
    """Load the servo plugin FILE into the running instance, every SV, without a restart:
    checked as a plugin the config names (imported, its steps run once), its step against
    the servo period and the schedulability check; then select or try its servos as any
    other's: ``kalictl servo load my_servo.py``, ``kalictl servo shadow left 2 my_servo``."""
    with _servo_client(ctx) as (inst, client):

        def guard(what: str, step_us: float) -> None:
            change = schedule.Change(what, step_us)
            schedule.guard(inst, change, warn, lambda text: click.echo(text, err=True))

        names = client.load(file, None if inst.lockstep else guard)
        if client.loaded()[-1].verdict is None:  # the clock stands: nobody took it yet
            how = "kalictl clock step 1" if inst.lockstep else "kalictl reset"
            click.echo(
                f"{file}: offered {', '.join(names)}; the SVs take it at their next tick ({how})"
            )
            return
        click.echo(f"{file}: loaded {', '.join(names)} into every SV")


def _joint_arg(text: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ServoError(f"servo: joint {text!r}, expected a number (1..n)") from None


def _servo_target_command(name: str) -> Callable[[Callable], Callable]:
    """A ``servo`` subcommand taking ROBOT TARGET [ALGORITHM] and ``--warn`` (select and
    shadow: TARGET is a joint with ALGORITHM, or a robot-level servo's name without)."""

    def wrap(fn: Callable) -> Callable:
        fn = _errors(fn)
        fn = click.pass_context(fn)
        fn = _WARN(fn)
        fn = click.argument("algorithm", required=False)(fn)
        fn = click.argument("target")(fn)
        fn = click.argument("robot")(fn)
        return servo.command(name)(fn)

    return wrap


@_servo_target_command("select")
def servo_select(
    ctx: click.Context, robot: str, target: str, algorithm: str | None, warn: bool
) -> None:
    """Switch ROBOT's JOINT (1..n) to ALGORITHM, bumplessly, while it moves (after the
    schedulability check: refused if the servo tick would no longer fit):
    ``kalictl servo select left 2 pd``.  Without a joint, switch the whole robot to a
    robot-level servo, or back to its joint servos: ``kalictl servo select left impedance``,
    ``kalictl servo select left joints``."""
    with _servo_client(ctx) as (inst, client):
        if algorithm is None:
            client.select_arm(robot, target, wait=not inst.lockstep)
            click.echo(f"{robot}: {target}")
            return
        joint = _joint_arg(target)
        if not inst.lockstep:
            change = schedule.servo_change(client, robot, joint, algorithm)
            schedule.guard(inst, change, warn, lambda text: click.echo(text, err=True))
        client.select(robot, joint, algorithm, wait=not inst.lockstep)
        click.echo(f"{robot} joint {joint}: {algorithm}")


@_servo_target_command("shadow")
def servo_shadow(
    ctx: click.Context, robot: str, target: str, algorithm: str | None, warn: bool
) -> None:
    """Run ALGORITHM in shadow on ROBOT's JOINT beside its active servo: stepped every tick on
    the same inputs, its torque compared, never applied (``kalictl servo compare``); ``off``
    ends the trial, and selecting it afterwards goes on from its own state:
    ``kalictl servo shadow left 2 pd``, ``kalictl servo shadow left 2 off``.  Without a
    joint, a robot-level servo beside the robot's servos: ``kalictl servo shadow left
    computed_torque``, ``kalictl servo shadow left off``."""
    with _servo_client(ctx) as (inst, client):
        wait = not inst.lockstep
        if algorithm is None:
            client.shadow_arm(robot, None if target == "off" else target, wait=wait)
            click.echo(f"{robot}: shadow {target}")
            return
        joint = _joint_arg(target)
        if algorithm == "off":
            client.shadow(robot, joint, None, wait=wait)
        else:
            if not inst.lockstep:
                change = schedule.shadow_change(client, robot, joint, algorithm)
                schedule.guard(inst, change, warn, lambda text: click.echo(text, err=True))
            client.shadow(robot, joint, algorithm, wait=wait)
        click.echo(f"{robot} joint {joint}: shadow {algorithm}")


@servo.command("compare")
@click.argument("robot", required=False)
@click.pass_context
@_errors
def servo_compare(ctx: click.Context, robot: str | None) -> None:
    """Print every shadow trial's figures: (shadow − active) torque, as the motors would get
    them, RMS and peak over the ticks compared, per joint (of ROBOT, or all)."""
    with _servo_client(ctx) as (_inst, client):
        rows = client.trials(robot)
        if not rows:
            click.echo("no shadow trial has run (kalictl servo shadow ROBOT [JOINT] NAME)")
            return
        click.echo(shadow.HEADER)
        for row in rows:
            click.echo(row.text())


@servo.command("set")
@click.argument("robot")
@click.argument("params", nargs=-1, required=True)
@click.option("--servo", "algorithm", default=None, help="Algorithm (default: the active one).")
@click.pass_context
@_errors
def servo_set(
    ctx: click.Context, robot: str, params: tuple[str, ...], algorithm: str | None
) -> None:
    """Set parameters on line: ``kalictl servo set left 2 kp=9000 ki=20000`` (a joint's),
    ``kalictl servo set left kz=500`` (the robot-level servo's)."""
    joint = None
    if params and "=" not in params[0]:
        joint, params = _joint_arg(params[0]), params[1:]
    values: dict[str, float] = {}
    for item in params:
        key, sep, value = item.partition("=")
        try:
            values[key] = float(value)
        except ValueError:
            sep = ""
        if not sep:
            raise ServoError(f"servo set: {item!r}, expected NAME=NUMBER (e.g. kp=9000)")
    if not values:
        raise ServoError("servo set: no NAME=NUMBER given (e.g. kp=9000)")
    shown = " ".join(f"{k}={v:g}" for k, v in values.items())
    with _servo_client(ctx) as (inst, client):
        if joint is None:
            client.set_arm_params(robot, values, algorithm, wait=not inst.lockstep)
            click.echo(f"{robot} {algorithm or client.arm_active(robot)}: {shown}")
            return
        client.set_params(robot, joint, values, algorithm, wait=not inst.lockstep)
        click.echo(f"{robot} joint {joint} {algorithm or client.active(robot, joint)}: {shown}")


@servo.command("get")
@click.argument("robot")
@click.argument("joint", type=int, required=False)
@click.option("--servo", "algorithm", default=None, help="Algorithm (default: the active one).")
@click.pass_context
@_errors
def servo_get(ctx: click.Context, robot: str, joint: int | None, algorithm: str | None) -> None:
    """Print the parameters of ROBOT's JOINT servo, or without a joint of its robot-level
    servo."""
    with _servo_client(ctx) as (_inst, client):
        if joint is None:
            params = client.get_arm_params(robot, algorithm)
            name = algorithm or client.arm_active(robot)
            shown = " ".join(f"{k}={v:g}" for k, v in params.items())
            click.echo(f"{robot} {name}: {shown}")
            return
        name = algorithm or client.active(robot, joint)
        params = client.get_params(robot, joint, name)
        shown = " ".join(f"{k}={v:g}" for k, v in params.items())
        click.echo(f"{robot} joint {joint} {name}: {shown}")


__all__ = ["main"]
