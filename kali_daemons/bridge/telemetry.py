"""What the bridge publishes, read from the arena without locking.

The bridge is a Type 4 reader, like the viewer (thesis 3.3.7): it copies records the servo
level writes and never takes a lock the servo level or the TG may wait for, so a torn read
costs one sample of telemetry, never a command.  ``Telemetry`` builds each robot's state
sample; ``Watch`` finds what changed since the bridge's last cycle — the fault, each robot's
power, calibration and message, each process's state, each request's state — as events, in
the order they are found, numbered so a subscriber can tell that it lost none.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ..client.protocol import finite_or_none
from ..core import layout
from ..core.layout import CalibState, PowerState, ProcState, RequestState
from ..runtime.instance import Instance, decode, time_ms
from ..tools import launcher


def _floats(values: np.ndarray) -> list[float | None]:
    """An array as JSON holds it: NaN and infinities as null (the usual case, all finite,
    is one ``tolist``)."""
    if np.isfinite(values).all():
        return values.tolist()
    return [finite_or_none(float(v)) for v in values]


class Telemetry:
    """Each robot's state sample (``sample(k)``): time, q, q̇, demand, torques, currents,
    the contact wrench if it has a wrist sensor, power and calibration."""

    def __init__(self, inst: Instance) -> None:
        cfg = inst.config
        self.inst = inst
        self.names = [r.name for r in cfg.robots]
        self.spans = [cfg.joints.span(k) for k in range(len(self.names))]
        self.sensed = [r.ft.sheet is not None for r in cfg.robots]
        arena = inst.arena
        n = len(self.names)
        self.robots = arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, n)
        self.joints = arena.existing(layout.KEY_JOINTS, layout.JOINT_STATE, cfg.joints.total)
        self.ft = (
            arena.existing(layout.KEY_FT, layout.FT_STATE, n)
            if any(self.sensed) and arena.lookup(layout.KEY_FT) is not None
            else None
        )

    def sample(self, k: int) -> dict[str, Any]:
        """Robot ``k``'s state now (a snapshot: the fields of one servo tick, or of two
        neighbouring ones when SIO writes meanwhile)."""
        clock = self.inst.clock
        r = self.robots[k]
        j = self.joints[self.spans[k]].copy()
        tick = int(r["tick"])
        out: dict[str, Any] = {
            "robot": self.names[k],
            "tick": tick,  # SIO's last servo tick
            "time_ms": time_ms(clock),
            # when that tick was due (CLOCK_MONOTONIC, ns): a subscriber on this machine
            # tells the sample's age from it
            "due_ns": int(clock["t0_ns"]) + tick * int(clock["base_tick_ns"]),
            "q": _floats(j["q"]),
            "qd": _floats(j["qd"]),
            "demand": _floats(j["demand"]),
            "servo_torque": _floats(j["servo_torque"]),
            "ff_torque": _floats(j["ff_torque"]),
            "torque": _floats(j["torque"]),
            "current": _floats(j["current"]),
            "power": PowerState(int(r["power"])).name,
            "calibrated": bool(r["calibrated"]),
            "calibration": CalibState(int(r["calib_state"])).name,
            "wrench": None,
        }
        if self.ft is not None and self.sensed[k] and self.ft[k]["present"]:
            out["wrench"] = _floats(self.ft[k]["world"])  # contact wrench, world axes
        return out

    def timing(self) -> dict[str, Any]:
        """Per process: state, period, execution and lateness figures, misses."""
        rows = launcher.describe(self.inst)
        keep = (
            "name", "pid", "alive", "state", "period_ms", "serious", "misses", "exec_last_us",
            "exec_max_us", "late_p50_us", "late_p99_us", "late_max_us",
        )  # fmt: skip
        return {
            "tick": int(self.inst.clock["tick"]),
            "time_ms": time_ms(self.inst.clock),
            "processes": [{key: r[key] for key in keep} for r in rows],
        }


class Watch:
    """The changes since the last ``changes()``, as events (mappings with ``kind``)."""

    def __init__(self, inst: Instance) -> None:
        self.inst = inst
        cfg = inst.config
        self.names = [r.name for r in cfg.robots]
        n = len(self.names)
        arena = inst.arena
        self.robots = arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, n)
        self.status = arena.existing(
            layout.KEY_MOTION_STATUS, layout.REQUEST_STATUS, layout.STATUS_RING
        )
        self.fault_count = int(inst.fault["count"])
        self.fault_active = bool(inst.fault["active"])
        self.power = self.robots["power"].copy()
        self.calib = self.robots["calib_state"].copy()
        self.messages = self.robots["message"].copy()
        self.seqs = self.status["seq"].copy()
        self.states = self.status["state"].copy()
        procs = inst.procs
        self.proc_state = procs["state"].copy()
        self.proc_pid = procs["pid"].copy()
        self.proc_name = procs["name"].copy()

    def changes(self) -> list[dict[str, Any]]:
        """Every change since the last call: the fault first, then robots, processes and
        requests (a fault raised and cleared in between is both events)."""
        events: list[dict[str, Any]] = []
        f = self.inst.fault
        count, active = int(f["count"]), bool(f["active"])
        if count != self.fault_count:
            events.append(
                {
                    "kind": "fault",
                    "text": self.inst.fault_text(last=True) or "fault",
                    "faults": count - self.fault_count,
                }
            )
        if (count != self.fault_count or self.fault_active) and not active:
            events.append({"kind": "fault cleared"})
        self.fault_count, self.fault_active = count, active
        robots = self.robots
        for field, last, kind, names in (
            ("power", self.power, "power", PowerState),
            ("calib_state", self.calib, "calibration", CalibState),
        ):
            now = robots[field].copy()
            for k in np.flatnonzero(now != last):
                events.append(
                    {"kind": kind, "robot": self.names[k], "state": names(int(now[k])).name}
                )
            last[:] = now
        messages = robots["message"].copy()
        for k in np.flatnonzero(messages != self.messages):
            events.append({"kind": "message", "robot": self.names[k], "text": decode(messages[k])})
        self.messages[:] = messages
        events.extend(self._processes())
        events.extend(self._motions())
        return events

    def _processes(self) -> list[dict[str, Any]]:
        """Process-table slots whose state, pid or name changed: a process that came, went
        (LEFT) or changed state."""
        p = self.inst.procs
        state, pid, name = p["state"].copy(), p["pid"].copy(), p["name"].copy()
        changed = np.flatnonzero(
            (state != self.proc_state) | (pid != self.proc_pid) | (name != self.proc_name)
        )
        out: list[dict[str, Any]] = []
        for i in changed:
            if self.proc_state[i] != ProcState.FREE and (
                state[i] == ProcState.FREE or name[i] != self.proc_name[i]
            ):
                out.append(
                    {"kind": "process", "process": decode(self.proc_name[i]), "state": "LEFT"}
                )
            if state[i] != ProcState.FREE:
                out.append(
                    {
                        "kind": "process",
                        "process": decode(name[i]),
                        "pid": int(pid[i]),
                        "state": ProcState(int(state[i])).name,
                    }
                )
        self.proc_state, self.proc_pid, self.proc_name = state, pid, name
        return out

    def _motions(self) -> list[dict[str, Any]]:
        """Requests whose state changed: the record's request or its state is new."""
        seqs, states = self.status["seq"].copy(), self.status["state"].copy()
        changed = np.flatnonzero((seqs != self.seqs) | (states != self.states))
        out: list[dict[str, Any]] = []
        for i in changed:
            rec = self.status[i]
            seq, state = int(rec["seq"]), int(rec["state"])
            if seq == 0 or state == RequestState.FREE:
                continue
            out.append(
                {
                    "kind": "motion",
                    "seq": seq,
                    "state": RequestState(state).name,
                    "message": decode(rec["message"]),
                    "client_pid": int(rec["client_pid"]),
                }
            )
        self.seqs[:] = seqs
        self.states[:] = states
        out.sort(key=lambda e: e["seq"])
        return out
