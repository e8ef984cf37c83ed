"""``kalictl top``: a live table of an instance, redrawn about twice a second (DESIGN 8).

Each refresh takes one ``introspect`` snapshot and the lateness histograms; figures "over
the interval" are differences from the previous refresh (acknowledgements per second,
wake-up lateness percentiles from the difference of the histograms), the others are since
start.  In lockstep mode nothing happens between steps, so rates are per second of Kali's
clock (ticks × base tick) and the clock line says how fast the clock runs against real time.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from rich import box
from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.table import Table
from rich.text import Text

from ..core import layout
from ..runtime.instance import Instance
from . import launcher
from .introspect import Introspector


@dataclass
class Sample:
    """One refresh: the snapshot and the histograms it is compared with next time."""

    snap: dict[str, Any]
    hists: np.ndarray  # (MAX_PROCESSES, HIST_BINS) wake-up lateness
    latency: np.ndarray | None  # SIO sensor-to-DAC histogram
    mono_ns: int


def take(spy: Introspector) -> Sample:
    """A sample of the instance now."""
    hists, latency = spy.histograms()
    snap = spy.snapshot()
    return Sample(snap, hists, latency, int(snap["monotonic_ns"]))


def _us(v: float | None) -> str:
    """µs for a table cell: whole µs, ms above 10 ms, '-' for no value."""
    if v is None or (isinstance(v, float) and math.isnan(v)):
        return "-"
    if v >= 10_000:
        return f"{v / 1000:.0f}ms"
    return f"{v:.0f}"


def _hist_max_us(h: np.ndarray) -> float | None:
    """Upper edge of the highest non-empty bin, µs (None for an empty histogram)."""
    nz = np.flatnonzero(h)
    return layout.bin_upper_us(int(nz[-1])) if nz.size else None


def _interval(prev: Sample | None, cur: Sample) -> tuple[float, str]:
    """Seconds the rates are over, and what kind of seconds."""
    if prev is None:
        return 0.0, ""
    if cur.snap["mode"] == "lockstep":
        dt = (cur.snap["clock"]["tick"] - prev.snap["clock"]["tick"]) * cur.snap["clock"][
            "base_tick_ms"
        ]
        return dt / 1000.0, "Kali"
    return (cur.mono_ns - prev.mono_ns) / 1e9, "wall"


WIDE = 132  # columns from which every column is shown


def _table(title: str) -> Table:
    t = Table(
        box=box.SIMPLE_HEAD,
        padding=(0, 1),
        pad_edge=False,
        collapse_padding=True,
        show_edge=False,
        title_justify="left",
        title_style="bold",
    )
    t.title = title
    return t


def header(prev: Sample | None, cur: Sample) -> Text:
    """The instance, its clock and the arena, on two lines."""
    s, c = cur.snap, cur.snap["clock"]
    t = Text()
    t.append(f"Kali '{s['instance']}'", style="bold")
    t.append(f"  {s['mode']}  clock ")
    t.append(c["mode"], style="green" if c["mode"] != "stopped" else "yellow")
    t.append(f"  tick {c['tick']}  {c['time_ms'] / 1000:.3f} s  base tick {c['base_tick_ms']:g} ms")
    t.append("\n")
    if prev is not None:
        wall = (cur.mono_ns - prev.mono_ns) / 1e9
        dticks = c["tick"] - prev.snap["clock"]["tick"]
        if wall > 0:
            speed = dticks * c["base_tick_ms"] / 1000 / wall
            t.append(f"{dticks / wall:.0f} ticks/s ({speed:.2f}× real time)  ")
    t.append(f"overruns {c['overruns']} (skipped {c['skipped_ticks']} ticks)")
    a = s["arena"]
    t.append(f"  arena {a['used_bytes'] / 2**20:.1f}/{a['bytes'] / 2**20:.1f} MiB")
    return t


def fault_line(cur: Sample) -> Text:
    """The fault in red, or 'no fault'."""
    f = cur.snap["fault"]
    if f["active"]:
        return Text(f"HALTED: {f['text']}  (kalictl reset)", style="bold white on red")
    if f["count"]:
        return Text(f"no active fault; last: {f['text']}", style="dim")
    return Text("no fault", style="green")


PROCESS_COLUMNS = (  # header, justification, shown in narrow terminals
    ("process", "left", True),
    ("pid", "right", False),
    ("state", "left", True),
    ("cpu", "right", False),
    ("prio", "right", False),
    ("period", "right", True),
    ("Hz", "right", True),
    ("exec\nlast", "right", True),
    ("exec\nmax", "right", True),
    ("late\np50", "right", True),
    ("late\np99", "right", True),
    ("late\np99.9", "right", True),
    ("late\nmax", "right", True),
    ("all\np99.9", "right", False),
    ("all\nmax", "right", False),
    ("miss", "right", True),
)


def processes(prev: Sample | None, cur: Sample, wide: bool) -> Table:
    """Per process: identity, rate, execution time, wake-up lateness, misses."""
    dt, kind = _interval(prev, cur)
    if prev is None:
        span = "waiting for a second sample"
    elif dt > 0:
        span = f"Hz and lateness over the last {dt:.2f} {kind} s"
    else:
        span = "the clock did not move (Hz shows +acks)"
    t = _table(f"processes: times in µs; {span}")
    for name, just, narrow in PROCESS_COLUMNS:
        if wide or narrow:
            t.add_column(name, justify=just, no_wrap=True)  # type: ignore[arg-type]
    before = {r["slot"]: r for r in prev.snap["processes"]} if prev is not None else {}
    base_ms = cur.snap["clock"]["base_tick_ms"]
    for r in cur.snap["processes"]:
        slot = r["slot"]
        old = before.get(slot)
        same = old is not None and old["pid"] == r["pid"]
        period = f"{r['period_ms']:g}ms" if r["periodic"] else "own"
        if r["name"] == "wallclock":
            period = f"{base_ms:g}ms"
        rate = "-"
        p50 = p99 = p999 = mx = "-"
        misses = Text(str(r["misses"]))
        if same and prev is not None and old is not None:
            d_acks = r["acks"] - old["acks"]
            rate = f"{d_acks / dt:.0f}" if dt > 0 else f"+{d_acks}"
            h = cur.hists[slot] - prev.hists[slot]
            if h.sum() > 0:
                # bins have upper edges up to 1/8 octave wide: never show more than the max
                cap = r["late_max_us"]
                a, b, c = (min(launcher.percentile(h, q), cap) for q in (0.5, 0.99, 0.999))
                top = _hist_max_us(h)
                p50, p99, p999, mx = _us(a), _us(b), _us(c), _us(min(top or 0.0, cap))
            if r["misses"] > old["misses"]:
                misses = Text(f"{r['misses']} +{r['misses'] - old['misses']}", style="yellow")
        state = Text(r["state"] if r["alive"] else "DEAD")
        if not r["alive"] or r["state"] == "ERROR":
            state.stylize("bold red")
        cells = [
            r["name"],
            str(r["pid"]),
            state,
            str(r["cpu"]),
            str(r["priority"]),
            period,
            rate,
            _us(r["exec_last_us"]),
            _us(r["exec_max_us"]),
            p50,
            p99,
            p999,
            mx,
            _us(r["late_p999_us"]),
            _us(r["late_max_us"]),
            misses,
        ]
        t.add_row(*(c for c, col in zip(cells, PROCESS_COLUMNS, strict=True) if wide or col[2]))
    return t


def robots(cur: Sample, wide: bool) -> Table | Text:
    """Per robot: power, calibration, worst tracking error, worst current, feed-forward, TG."""
    rs = cur.snap["robots"]
    if rs is None:
        return Text("robots: SIO has not laid out its records yet", style="yellow")
    tg = cur.snap["tg"]
    busy = {e["robot"]: e for e in tg["robots"]} if tg is not None else {}
    queued = f"; {tg['queued']} requests queued for the TG" if tg and tg["queued"] else ""
    t = _table(f"robots: worst joints (error in encoder counts){queued}")
    columns = [
        ("robot", "left"),
        ("power", "left"),
        ("calib", "left"),
        ("|err|", "right"),
        ("|current|", "right"),
        ("limit", "right"),
        ("ff", "left"),
        ("servo", "left"),
        ("TG", "left"),
    ]
    if wide:
        columns[4:4] = [("°", "right")]
        columns.append(("message", "left"))
    for name, just in columns:
        t.add_column(name, justify=just, no_wrap=name != "message")  # type: ignore[arg-type]
    for r in rs:
        err = np.abs(np.array(r["error_counts"], dtype=float))
        j = int(np.argmax(err))
        cur_a = np.abs(np.array(r["current_a"], dtype=float))
        lim = np.array(r["current_limit_a"], dtype=float)
        jc = int(np.argmax(cur_a / lim))
        frac = cur_a[jc] / lim[jc]
        on = r["power"] == "ON"
        power = Text(r["power"].lower(), style="green" if on else "yellow")
        calib = "yes" if r["calibrated"] else r["calibration"].lower().replace("idle", "no")
        err_cell = Text(f"{err[j]:.1f} j{j + 1}" if on else "-")
        if on and abs(r["error_rad"][j]) > 0.5 * r["safe_rad"][j]:
            err_cell.stylize("bold yellow")
        ff = r["feedforward"]
        ff_cell = "-" if ff is None else f"{ff['mode'] or '?'}/{ff['state'] or '?'}".lower()
        b = busy.get(r["name"])
        req = "guided" if r.get("guided") else "idle"  # by hand: the TG will not move it
        if b is not None and b["busy_seq"]:
            req = f"#{b['busy_seq']}"
            if "state" in b:
                req += f" {b['state'].lower()} {100 * b['progress']:.0f}%"
        cells = [
            r["name"],
            power,
            calib,
            err_cell,
            f"{cur_a[jc]:.2f} A j{jc + 1}",
            Text(f"{frac:.0%}", style="bold red" if frac >= 1 else ""),
            ff_cell,
            servo_cell(r.get("servo")),
            req,
        ]
        if wide:
            cells[4:4] = [f"{math.degrees(abs(r['error_rad'][j])):.4f}" if on else "-"]
        if wide:
            cells.append(r["message"])
        t.add_row(*cells)
    return t


def servo_cell(servo: dict[str, Any] | None) -> str:
    """What a robot runs: its robot-level servo or its joint servos' names, and the servos
    in shadow trial beside them (``kalictl servo compare`` has their figures)."""
    if servo is None:
        return "-"
    cell = servo["robot"] or "/".join(dict.fromkeys(servo["joints"]))
    running = [t["shadow"] for t in servo["trials"] if t["state"] == "RUNNING"]
    if running:
        cell += f" (shadow {'/'.join(dict.fromkeys(running))})"
    return cell


def servo_lines(prev: Sample | None, cur: Sample) -> Text:
    """SIO's sensor-to-DAC latency and each SV's execution time."""
    sv = cur.snap["servo"]
    if sv is None:
        return Text("servo level: not laid out yet", style="yellow")
    lat = sv["latency_us"]
    t = Text()
    t.append("SIO sensor→DAC µs", style="bold")
    t.append(f"  last {_us(lat['last'])}")
    if prev is not None and prev.latency is not None and cur.latency is not None:
        h = cur.latency - prev.latency
        if h.sum():
            a, b, c = (launcher.percentile(h, q) for q in (0.5, 0.99, 0.999))
            t.append(f"  p50/p99/p99.9 {_us(a)}/{_us(b)}/{_us(c)}")
    t.append(f"  all: p99 {_us(lat['p99'])} max {_us(lat['max'])}\n")
    t.append("SV exec µs (last/max)", style="bold")
    for w in sv["sv"]:
        t.append(f"  {w['name']} {_us(w['exec_last_us'])}/{_us(w['exec_max_us'])}")
    return t


def footer(cur: Sample) -> Group:
    """Recent misses and the flight recorder."""
    lines: list[Text] = []
    m = cur.snap["misses"]
    if m["total"]:
        last = m["recent"][-1]
        lines.append(
            Text(
                f"missed deadlines: {m['total']}; last at tick {last['tick']}: {last['process']} "
                f"({last['consecutive']} in a row)",
                style="yellow",
            )
        )
    fl = cur.snap["flight"]
    if fl is not None:
        text = f"flight recorder: {fl['seconds']:g} s ({fl['rows']} servo ticks)"
        if fl["pending"]:
            text += "; dumping…"
        elif fl["last_dump"]:
            text += f"; last dump {fl['last_dump']}"
        lines.append(Text(text))
    return Group(*lines)


def frame(
    prev: Sample | None,
    cur: Sample,
    interval: float,
    width: int = WIDE,
    height: int | None = None,
) -> Group:
    """One whole screen for a terminal ``width`` columns wide; with a ``height`` (a live
    screen) the parts are spaced out and the refresh shown only if it all still fits."""
    wide = width >= WIDE
    parts: list[RenderableType] = [
        header(prev, cur),
        fault_line(cur),
        processes(prev, cur, wide),
        robots(cur, wide),
        servo_lines(prev, cur),
        footer(cur),
    ]
    if height is None:
        return Group(*parts[:2], Text(""), parts[2], Text(""), parts[3], Text(""), *parts[4:])
    compact = Group(*parts)
    console = Console(width=width, color_system=None)
    used = len(console.render_lines(compact, console.options, pad=False))
    if used + 4 > height:
        return compact
    hint = Text(f"refresh every {interval:g} s; Ctrl-C quits", style="dim")
    return Group(*parts[:2], Text(""), parts[2], Text(""), parts[3], Text(""), *parts[4:], hint)


def run(inst: Instance, interval: float, once: bool, console: Console | None = None) -> None:
    """Draw the instance until Ctrl-C (or one frame after ``interval`` with ``once``)."""
    console = console or Console()
    spy = Introspector(inst)
    try:
        prev = take(spy)
        if once:
            time.sleep(interval)
            console.print(frame(prev, take(spy), interval, console.width))
            return
        with Live(
            frame(None, prev, interval, console.width, console.height),
            console=console,
            auto_refresh=False,
        ) as live:
            try:
                while not inst.shutting_down:
                    time.sleep(interval)
                    cur = take(spy)
                    live.update(
                        frame(prev, cur, interval, console.width, console.height), refresh=True
                    )
                    prev = cur
            except KeyboardInterrupt:
                pass
        if inst.shutting_down:
            console.print(f"instance '{inst.name}' was stopped")
    finally:
        spy.close()
