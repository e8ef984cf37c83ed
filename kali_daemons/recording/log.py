"""Reading a recording back (``kali_daemons.recording.log.read``): each arm's servo ticks as numpy
arrays aligned on ticks, from the MCAP file ``kali.record`` wrote (``recording``).

    from kali_daemons import log
    run = log.read("run.mcap")
    left = run.arms["left"]            # ArmLog: tick, time_s, q, qd, q_d, ..., wrench
    error = left.q_d[:, 1] - left.q[:, 1]
    run.frame("left")                   # a pandas DataFrame, where pandas is installed

Any MCAP reader opens the file; this one knows Kali's topics.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from ..core.errors import KaliError

# the quantities of a recorded servo tick (kali_msgs/msg/ServoTick, one value per joint)
SERVO_FIELDS = (
    "q", "qd", "q_d", "qd_d", "servo_torque", "ff_torque", "torque", "current", "shadow_torque",
)  # fmt: skip


@dataclass
class ArmLog:
    """One arm's recorded servo ticks: ``tick`` (N,), ``time_s`` (N,) and each servo
    quantity (N, joints): ``q``, ``qd``, ``q_d``, ``qd_d``, ``servo_torque``, ``ff_torque``,
    ``torque``, ``current``, ``shadow_torque``; ``wrench`` (N, 6: force, torque, tool axes)
    where the arm has a wrist sensor, else None."""

    name: str
    tick: np.ndarray
    time_s: np.ndarray
    series: dict[str, np.ndarray]
    wrench: np.ndarray | None

    def __getattr__(self, name: str) -> np.ndarray:
        series: dict[str, np.ndarray] = self.__dict__.get("series", {})
        if name in series:
            return series[name]
        raise AttributeError(name)


@dataclass(frozen=True)
class ServoChange:
    """A change of an arm's servos at ``tick``: ``joint`` (1.., 0 the robot-level servo),
    ``kind`` (select, params, enable, disable, shadow, shadow_stopped, ...), ``servo`` and its
    ``params`` as they then were."""

    tick: int
    joint: int
    kind: str
    servo: str
    params: dict[str, float]


@dataclass
class TruthLog:
    """The simulator's truth of one arm, one row a recorder period: ``tick`` (the clock's),
    ``sim_time_s``, per joint ``q``, ``qd``, ``current``, ``torque`` (N, joints) and
    ``contact_wrench``, ``grasp_wrench`` (N, 6)."""

    tick: np.ndarray
    sim_time_s: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    current: np.ndarray
    torque: np.ndarray
    contact_wrench: np.ndarray
    grasp_wrench: np.ndarray


@dataclass
class Log:
    """A recording: each arm's ``ArmLog`` by name, and the ticks it lost (``gaps``: (first
    tick, ticks) pairs; empty when every tick is there); each arm's ``servo_changes`` and,
    from a simulated cell, its ``truth`` (``TruthLog``)."""

    path: Path
    arms: dict[str, ArmLog]
    gaps: list[tuple[int, int]] = field(default_factory=list)
    servo_changes: dict[str, list[ServoChange]] = field(default_factory=dict)
    truth: dict[str, TruthLog] = field(default_factory=dict)

    def frame(self, arm: str) -> Any:
        """Arm ``arm``'s ticks as a pandas DataFrame indexed by tick, a column per quantity
        and joint (``q_1`` .. ``q_6``); ImportError if pandas is not installed."""
        import pandas as pd  # here: pandas is optional, and only this needs it

        a = self.arms[arm]
        columns: dict[str, np.ndarray] = {"time_s": a.time_s}
        for name, values in a.series.items():
            for j in range(values.shape[1]):
                columns[f"{name}_{j + 1}"] = values[:, j]
        if a.wrench is not None:
            for j, axis in enumerate(("fx", "fy", "fz", "tx", "ty", "tz")):
                columns[axis] = a.wrench[:, j]
        return pd.DataFrame(columns, index=pd.Index(a.tick, name="tick"))


def read(path: str | Path) -> Log:
    """The recording at ``path``; KaliError if it cannot be read or is not Kali's."""
    path = Path(path)
    ticks: dict[str, list[int]] = {}
    stamps: dict[str, list[int]] = {}
    series: dict[str, dict[str, list[Any]]] = {}
    wrenches: dict[str, dict[int, list[float]]] = {}
    gaps: list[tuple[int, int]] = []
    changes: dict[str, list[ServoChange]] = {}
    truths: dict[str, list[Any]] = {}
    try:
        with open(path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _schema, channel, message, msg in reader.iter_decoded_messages():
                parts = channel.topic.split("/")
                if channel.topic == "/kali/gaps":
                    gaps.append((int(msg.first_tick), int(msg.ticks)))
                elif len(parts) == 4 and parts[1] == "kali" and parts[3] == "servo":
                    arm = parts[2]
                    ticks.setdefault(arm, []).append(int(msg.tick))
                    stamps.setdefault(arm, []).append(int(message.log_time))
                    s = series.setdefault(arm, {name: [] for name in SERVO_FIELDS})
                    for name in SERVO_FIELDS:
                        s[name].append(getattr(msg, name))
                elif len(parts) == 4 and parts[1] == "kali" and parts[3] == "servo_changes":
                    params = dict(zip(msg.names, map(float, msg.values), strict=True))
                    change = ServoChange(int(msg.tick), int(msg.joint), msg.kind, msg.servo, params)
                    changes.setdefault(parts[2], []).append(change)
                elif len(parts) == 5 and parts[1:3] == ["kali", "sim"] and parts[4] == "truth":
                    truths.setdefault(parts[3], []).append(msg)
                elif len(parts) == 4 and parts[1] == "kali" and parts[3] == "wrench":
                    w = msg.wrench
                    wrenches.setdefault(parts[2], {})[int(message.log_time)] = [
                        w.force.x,
                        w.force.y,
                        w.force.z,
                        w.torque.x,
                        w.torque.y,
                        w.torque.z,
                    ]
    except FileNotFoundError:
        raise KaliError(f"log: {path}: no such file") from None
    except (McapError, ValueError, EOFError, OSError) as exc:
        raise KaliError(f"log: {path} is not a readable MCAP recording ({exc})") from None
    if not ticks:
        raise KaliError(f"log: {path} holds no Kali servo ticks (/kali/<arm>/servo)")
    arms = {}
    for arm, t in ticks.items():
        w = wrenches.get(arm)
        arms[arm] = ArmLog(
            name=arm,
            tick=np.array(t, dtype=np.int64),
            time_s=np.array(stamps[arm]) / 1e9,
            series={f: np.array(v, dtype=np.float64) for f, v in series[arm].items()},
            wrench=None if w is None else np.array([w[ns] for ns in stamps[arm]]),
        )
    truth = {
        arm: TruthLog(
            tick=np.array([m.tick for m in ms], dtype=np.int64),
            sim_time_s=np.array([m.sim_time_s for m in ms]),
            q=np.array([m.q for m in ms]),
            qd=np.array([m.qd for m in ms]),
            current=np.array([m.current for m in ms]),
            torque=np.array([m.torque for m in ms]),
            contact_wrench=np.array([m.contact_wrench for m in ms]),
            grasp_wrench=np.array([m.grasp_wrench for m in ms]),
        )
        for arm, ms in truths.items()
    }
    return Log(path=path, arms=arms, gaps=gaps, servo_changes=changes, truth=truth)
