"""What a recording carries besides the servo ticks (``recording``): the servo level's changes
and, in simulation only, the plant's truth.

Both are seen at the recorder's period (every TG period), not in SIO's cycle:

- ``/kali/<arm>/servo_changes`` (``kali_msgs/msg/ServoChange``): a joint's servo selected,
  its parameters changed, its servo disabled or enabled, a shadow trial begun or ended (and
  how), a robot-level servo selected (joint 0; servo '' when the arm goes back to its joint
  servos) or its parameters changed; each with the servo's parameters as they then were.
  The servo level has no log of its mailbox, so the recorder compares what it sees with what
  it saw: a change undone within one recorder period is not seen.
- ``/kali/sim/<arm>/truth`` (``kali_msgs/msg/SimTruth``): the simulator's truth of the arm
  (true joints, velocities, currents, motor torques, the contact and grasp wrenches), one
  message a recorder period, stamped with the clock's tick and the plant's own time.  It is
  what the controller never measures, so it is under ``/kali/sim`` and only where the cell
  has a simulated plant.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ..core import layout
from ..core.layout import ShadowState
from ..runtime.instance import Instance
from ..servo import loading
from ..servo.algorithms.algorithm import struct_view
from ..servo.level import ServoLevel

TRUTH_FIELDS = ("q", "qd", "current", "torque")  # per joint (JOINT_TRUTH)
# what ``ServoWatch`` compares: each slot's and each robot's fields
JOINT_KEYS = ("algo", "enabled", "shadow", "shadow_state", "ops")
ARM_KEYS = ("arm_algo", "arm_shadow", "arm_shadow_state", "arm_ops")
# the fields behind them: a slot's, a robot's record
SLOT_FIELDS = ("algo", "enabled", "shadow", "shadow_state", "ops_done")
ROBOT_FIELDS = ("arm_algo", "arm_shadow", "arm_shadow_state", "arm_ops_done")

# a change: (arm index, joint (1.., 0 the robot-level servo), kind, servo, its parameters)
Change = tuple[int, int, str, str, dict[str, float]]


class ServoWatch:
    """The servo level's changes since the last look (``changes``), from the slots' and the
    robots' records: the active algorithm, enabled, the shadow trial and its state, and the
    mailbox operations done (a parameter change shows only there)."""

    def __init__(self, inst: Instance) -> None:
        self.level = level = ServoLevel(inst)
        self.map = level.map
        self.registry = level.registry
        s, r = level.slots, level.robots  # the fields compared, viewed once
        self._columns = ([s[f] for f in SLOT_FIELDS], [r[f] for f in ROBOT_FIELDS])
        # the same fields' bytes, gathered at once: most looks find them as they were
        self._bytes = [
            (records.reshape(-1).view(np.uint8), byte_offsets(records, keys))
            for records, keys in ((s, SLOT_FIELDS), (r, ROBOT_FIELDS))
        ]
        self._said_bytes = self._glance()
        self._said = self._look()
        n, nr = level.n, level.n_robots
        self._params: list[dict[str, float]] = [self._joint_params(i) for i in range(n)]
        self._arm_params: list[dict[str, float]] = [self._robot_params(k) for k in range(nr)]

    def _look(self) -> tuple[np.ndarray, np.ndarray]:
        """The joints' fields ``JOINT_KEYS`` and the robots' ``ARM_KEYS`` as they stand,
        one new array each (a row a field): compared whole, most looks find nothing."""
        joints = np.empty((len(JOINT_KEYS), self.level.n), np.int64)
        arms = np.empty((len(ARM_KEYS), self.level.n_robots), np.int64)
        for row, column in zip(joints, self._columns[0], strict=True):
            row[:] = column
        for row, column in zip(arms, self._columns[1], strict=True):
            row[:] = column
        return joints, arms

    def _glance(self) -> np.ndarray:
        """The compared fields' bytes as they stand, one array."""
        return np.concatenate([raw[at] for raw, at in self._bytes])

    def _name(self, a: int) -> str:
        return self.registry[a].name if 0 <= a < len(self.registry) else ""

    def _arm_name(self, a: int) -> str:
        arms = self.registry.arms
        return arms[a].name if 0 <= a < len(arms) else ""

    def _joint_params(self, i: int, a: int | None = None) -> dict[str, float]:
        """Joint ``i``'s parameters of algorithm ``a`` (default: its active one)."""
        a = int(self.level.slots["algo"][i]) if a is None else a
        if not 0 <= a < len(self.registry):
            return {}
        rec = self.level.data[i][a].copy()
        return self.registry[a].get_params(struct_view(rec))

    def _robot_params(self, k: int, a: int | None = None) -> dict[str, float]:
        """Robot ``k``'s parameters of robot-level servo ``a`` (default: its active one)."""
        a = int(self.level.robots["arm_algo"][k]) if a is None else a
        arms = self.registry.arms
        if not 0 <= a < len(arms):
            return {}
        return arms[a].get_params(self.level.arm_data[k][a].copy())

    def changes(self) -> list[Change]:
        """What changed since the last call, in joint order, robot-level last."""
        if int(self.level.loads["generation"]) != self.level.taken:
            loading.take(self.level)  # servo plugins loaded while running: their names
        glance = self._glance()
        if np.array_equal(glance, self._said_bytes):
            return []
        self._said_bytes = glance
        look = self._look()
        said, self._said = self._said, look
        now = dict(zip(JOINT_KEYS + ARM_KEYS, (*look[0], *look[1]), strict=True))
        was = dict(zip(JOINT_KEYS + ARM_KEYS, (*said[0], *said[1]), strict=True))
        out: list[Change] = []
        moved = np.zeros(self.level.n, dtype=bool)
        for key in ("algo", "enabled", "shadow", "shadow_state", "ops"):
            moved |= now[key] != was[key]
        for i in (int(x) for x in np.flatnonzero(moved)):
            k, j = int(self.map.robot_of[i]), int(self.map.joint_of[i]) + 1
            a = int(now["algo"][i])
            if a != was["algo"][i]:
                self._params[i] = self._joint_params(i, a)
                out.append((k, j, "select", self._name(a), self._params[i]))
            elif now["ops"][i] != was["ops"][i]:
                params = self._joint_params(i, a)
                if not same(params, self._params[i]):
                    self._params[i] = params
                    out.append((k, j, "params", self._name(a), params))
            if now["enabled"][i] != was["enabled"][i]:
                kind = "enable" if now["enabled"][i] else "disable"
                out.append((k, j, kind, self._name(a), self._params[i]))
            trial = self._trial(now["shadow"][i], now["shadow_state"][i], self._name)
            if trial is not None and (
                now["shadow"][i] != was["shadow"][i]
                or now["shadow_state"][i] != was["shadow_state"][i]
            ):
                kind, servo = trial
                s = int(now["shadow"][i])
                out.append((k, j, kind, servo, self._joint_params(i, s)))
        for k in range(self.level.n_robots):
            a = int(now["arm_algo"][k])
            if a != was["arm_algo"][k]:
                self._arm_params[k] = self._robot_params(k, a)
                out.append((k, 0, "select", self._arm_name(a), self._arm_params[k]))
            elif now["arm_ops"][k] != was["arm_ops"][k]:
                params = self._robot_params(k, a)
                if not same(params, self._arm_params[k]):
                    self._arm_params[k] = params
                    out.append((k, 0, "params", self._arm_name(a), params))
            if (now["arm_shadow"][k], now["arm_shadow_state"][k]) != (
                was["arm_shadow"][k],
                was["arm_shadow_state"][k],
            ):
                state = now["arm_shadow_state"][k]
                trial = self._trial(now["arm_shadow"][k], state, self._arm_name)
                if trial is not None:
                    s = int(now["arm_shadow"][k])
                    out.append((k, 0, trial[0], trial[1], self._robot_params(k, s)))
        out.sort(key=lambda c: (c[0], c[1] == 0))
        return out

    @staticmethod
    def _trial(algo: Any, state: Any, name: Callable[[int], str]) -> tuple[str, str] | None:
        """A trial's kind ('shadow' while it runs, 'shadow_stopped' and so on once it ended)
        and servo; None before any trial."""
        s = ShadowState(int(state)) if int(state) in ShadowState._value2member_map_ else None
        if s is None or s == ShadowState.NONE or int(algo) == layout.NO_SHADOW:
            return None
        kind = "shadow" if s == ShadowState.RUNNING else f"shadow_{s.name.lower()}"
        return kind, name(int(algo))


def byte_offsets(records: np.ndarray, keys: tuple[str, ...]) -> np.ndarray:
    """Where fields ``keys`` of every record of ``records`` lie in its bytes."""
    fields = records.dtype.fields
    assert fields is not None
    one = np.concatenate([fields[k][1] + np.arange(fields[k][0].itemsize) for k in keys])
    at: np.ndarray = np.arange(len(records))[:, None] * records.strides[0] + one
    return at.ravel()


def same(a: dict[str, float], b: dict[str, float]) -> bool:
    """Parameter sets equal, NaN equal to NaN."""
    if a.keys() != b.keys():
        return False
    return all(x == b[n] or (math.isnan(x) and math.isnan(b[n])) for n, x in a.items())


class TruthRecords:
    """The plant's truth records: every arm's, every joint's and the world's."""

    def __init__(self, inst: Instance) -> None:
        cfg = inst.config
        arena, n = inst.arena, len(cfg.robots)
        self.arms = arena.existing(layout.KEY_TRUTHS, layout.ARM_TRUTH, n)
        self.joints = arena.existing(layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, cfg.joints.total)
        self.world = arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH, 1)
