"""Joint-space motion profiles sampled at the TG period (thesis 2.2.1).

``joint_move`` is the simple joint move ``kalictl move`` pushes through the TG → SIO FIFO:
every joint follows the same quintic (minimum-jerk) time law from rest to rest, so all joints
start and arrive together with continuous position, velocity and acceleration, and the
slowest joint sets the duration at its speed limit.
"""

from __future__ import annotations

import math

import numpy as np

from ..errors import KaliError

PEAK_SPEED_FACTOR = 15.0 / 8.0  # peak of the quintic's velocity, in units of distance/time
MIN_DURATION_S = 0.1


class MotionError(KaliError):
    """A motion request that cannot be carried out (bad target, speed or limits)."""


def quintic(s: np.ndarray) -> np.ndarray:
    """The minimum-jerk time law 10 s³ − 15 s⁴ + 6 s⁵ on normalised time ``s`` in [0, 1]."""
    return s * s * s * (10.0 + s * (-15.0 + 6.0 * s))


def move_duration(start: np.ndarray, target: np.ndarray, max_speed: np.ndarray) -> float:
    """Seconds for the quintic move so no joint's peak speed exceeds ``max_speed`` (rad/s)."""
    distance = np.abs(np.asarray(target, dtype=np.float64) - np.asarray(start, dtype=np.float64))
    return max(MIN_DURATION_S, float(np.max(PEAK_SPEED_FACTOR * distance / max_speed)))


def joint_move(
    start: np.ndarray,
    target: np.ndarray,
    period_s: float,
    max_speed: np.ndarray | float,
    q_min: np.ndarray,
    q_max: np.ndarray,
    robot: str = "robot",
) -> np.ndarray:
    """Set-points ``(n, 6)`` at ``period_s`` from ``start`` (exclusive) to ``target``
    (inclusive, the last row exactly), or MotionError naming the joint, value and limit."""
    start = np.asarray(start, dtype=np.float64)
    target = np.asarray(target, dtype=np.float64)
    if target.shape != start.shape:
        raise MotionError(
            f"move: robot '{robot}': {target.size} joint values, expected {start.size}"
        )
    speed = np.broadcast_to(np.asarray(max_speed, dtype=np.float64), start.shape)
    for j in range(start.size):
        if not math.isfinite(float(target[j])):
            raise MotionError(f"move: robot '{robot}' joint {j + 1}: target {target[j]} rad")
        if not q_min[j] <= target[j] <= q_max[j]:
            raise MotionError(
                f"move: robot '{robot}' joint {j + 1}: target {math.degrees(target[j]):.2f}° "
                f"is outside its range {math.degrees(q_min[j]):.1f}° .. "
                f"{math.degrees(q_max[j]):.1f}°; nothing moved"
            )
        if not (math.isfinite(float(speed[j])) and speed[j] > 0.0):
            raise MotionError(
                f"move: robot '{robot}' joint {j + 1}: speed {speed[j]} rad/s, must be > 0"
            )
    duration = move_duration(start, target, speed)
    n = max(1, math.ceil(duration / period_s))
    s = np.arange(1, n + 1, dtype=np.float64) / n
    points = start + np.outer(quintic(s), target - start)
    points[-1] = target
    return points
