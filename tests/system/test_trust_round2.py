"""Issue 51 ("Trust, round two"), each item as a hostile tester found it on main:

- 13: ``set_tool`` refuses a tool that is not a rigid, finite 4×4 pose.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.errors import MotionError

# ------------------------------------------------------------------ item 13: set_tool


NOT_A_TOOL = [  # (tool, what the message says after "tool")
    (np.diag([2.0, 2.0, 2.0, 1.0]), r" is not a rigid pose: max \|RᵀR − I\| = 3 \(limit 1e-06\)"),
    (np.diag([1.0, 1.0, -1.0, 1.0]), r" is not a rigid pose: .*, det R = -1"),
    (np.full((4, 4), np.nan), r"\[0, 0\] is nan, not a finite number"),
    (np.eye(3), r" has shape \(3, 3\), expected \(4, 4\)"),
    (np.diag([1.0, 1.0, 1.0, 2.0]), r" bottom row is \[0.0, 0.0, 0.0, 2.0\], expected \[0, 0, 0"),
    (np.eye(4) + np.eye(4, k=3) * 20.0, r" is 20 m from its frame's origin along an axis"),
]


def test_set_tool_refuses_a_tool_that_is_not_a_rigid_pose(kali: Callable[..., str]) -> None:
    """A scaled or mirrored tool, NaN, the wrong shape, a wrong bottom row: each refused
    naming the value and the rule, the tool unchanged.  Before: a scaled tool was taken,
    ``read_pose`` gave a scaled pose and the next move was refused with "grasp ... is not a
    rigid pose"."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        left = k.robot("left")
        tip = np.eye(4)
        tip[2, 3] = 0.1
        left.set_tool(tip)
        for tool, expected in NOT_A_TOOL:
            with pytest.raises(MotionError, match=rf"set_tool: robot 'left': tool{expected}"):
                left.set_tool(tool)
            assert np.array_equal(left.tool, tip)  # nothing changed
