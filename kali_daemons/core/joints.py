"""The cell's joints, numbered flat in config order (the joint count is data).

Every per-joint array of the controller holds all arms' joints one after another: SIO's working
arrays, the servo slots, the per-joint records (``layout.JOINT_STATE``, ``layout.JOINT_TRUTH``) and
the flight recorder.  Robot ``k``'s joint ``j`` (0-based) is flat index ``base[k] + j``, so a cell
of two PUMAs, a UR5 and a Panda has 6 + 6 + 6 + 7 = 25 joints and no gaps. Joint numbers shown to
people are 1-based (``label``), as the thesis numbers the PUMA's.

The hardware keeps its own shape: per arm, ``layout.MAX_JOINTS`` channels at most (a McGill
board's counters and DACs), joint ``j`` on channel ``j``.  ``ArmCopy`` moves values between a flat
array and such a per-arm view, planned once so the cycle does not allocate.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class JointMap:
    """Where each arm's joints sit in the flat numbering.

    ``names`` are the robots' names and ``counts`` their joint counts, in config order
    (``Config.joints`` builds it from the robots' types)."""

    names: tuple[str, ...]
    counts: tuple[int, ...]
    base: tuple[int, ...] = field(init=False)  # flat index of each arm's first joint
    total: int = field(init=False)  # joints in the cell
    robot_of: np.ndarray = field(init=False, repr=False)  # flat index → arm
    joint_of: np.ndarray = field(init=False, repr=False)  # flat index → joint of its arm

    def __post_init__(self) -> None:
        base = tuple(int(b) for b in np.concatenate([[0], np.cumsum(self.counts)[:-1]]))
        object.__setattr__(self, "base", base if self.counts else ())
        object.__setattr__(self, "total", int(sum(self.counts)))
        robot_of = np.repeat(np.arange(len(self.counts)), self.counts)
        joint_of = np.concatenate([np.arange(n) for n in self.counts] or [np.zeros(0, int)])
        robot_of.setflags(write=False)
        joint_of.setflags(write=False)
        object.__setattr__(self, "robot_of", robot_of)
        object.__setattr__(self, "joint_of", joint_of)

    @property
    def n_robots(self) -> int:
        """Arms in the cell."""
        return len(self.counts)

    @property
    def uniform(self) -> int:
        """The joint count every arm has, or 0 when the arms differ."""
        return self.counts[0] if self.counts and len(set(self.counts)) == 1 else 0

    @property
    def widest(self) -> int:
        """The largest joint count of an arm."""
        return max(self.counts, default=0)

    def span(self, k: int) -> slice:
        """Arm ``k``'s joints in a flat array."""
        return slice(self.base[k], self.base[k] + self.counts[k])

    def index(self, k: int, j: int) -> int:
        """Flat index of arm ``k``'s joint ``j`` (0-based)."""
        return self.base[k] + j

    def split(self, flat: np.ndarray) -> list[np.ndarray]:
        """One view of ``flat`` per arm (outside the cycle)."""
        return [flat[self.span(k)] for k in range(self.n_robots)]

    def label(self, i: int) -> str:
        """Flat joint ``i`` as a message names it: ``robot 'left' joint 3``."""
        return f"robot '{self.names[int(self.robot_of[i])]}' joint {int(self.joint_of[i]) + 1}"


class ArmCopy:
    """Copies between a flat joint array and a per-arm array (``(arms, ≥ widest)``, a board
    register or a per-arm record field), planned at set-up: one copy when every arm has the
    same joint count, one per arm otherwise.  Inside the cycle: no allocation."""

    __slots__ = ("_pairs",)

    def __init__(self, joints: JointMap, flat: np.ndarray, arms: np.ndarray) -> None:
        n = joints.uniform
        if n:
            self._pairs = [(flat.reshape(joints.n_robots, n), arms[:, :n])]
        else:
            self._pairs = [
                (flat[joints.span(k)], arms[k, :count]) for k, count in enumerate(joints.counts)
            ]

    def to_flat(self) -> None:
        """Arm values into the flat array (hardware values cast as numpy's ``unsafe``)."""
        for flat, arms in self._pairs:
            np.copyto(flat, arms, casting="unsafe")

    def to_arms(self) -> None:
        """Flat values into the per-arm array."""
        for flat, arms in self._pairs:
            np.copyto(arms, flat, casting="unsafe")

    def fill_arms(self, value: float) -> None:
        """Every used channel of every arm to ``value``."""
        for _, arms in self._pairs:
            arms[...] = value


def per_joint(values: Sequence[Sequence[float]] | Sequence[np.ndarray]) -> np.ndarray:
    """Per-arm value lists laid out flat (outside the cycle)."""
    parts = [np.asarray(v, dtype=np.float64).reshape(-1) for v in values]
    return np.concatenate(parts) if parts else np.zeros(0)
