"""Issue 51 ("Trust, round two"), each item as a hostile tester found it on main:

- 13: ``set_tool`` refuses a tool that is not a rigid, finite 4×4 pose;
- 14: a base outside the cell is refused when the config is parsed, and arms whose bodies
  overlap at rest are refused by ``kalictl start`` before any process runs.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons import launcher
from kali_daemons.client import Kali
from kali_daemons.config import parse_config
from kali_daemons.errors import ConfigError, MotionError

from ..conftest import ROOT, config_text, leftovers, make_config, unique_name
from ..test_launcher import kalictl

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


# ------------------------------------------------------------------ item 14: where the arms are


@pytest.mark.parametrize("coordinate", [0, 1, 2])
def test_a_base_outside_the_cell_is_refused_when_the_config_is_parsed(coordinate: int) -> None:
    xyz = ["-0.6", "0.0", "0.0"]
    xyz[coordinate] = "1.0e+9"
    text = config_text("t").replace("[-0.6, 0.0, 0.0]", f"[{', '.join(xyz)}]")
    with pytest.raises(ConfigError) as err:
        parse_config(text, "<test>", str(ROOT / "config"))
    assert f"robots[0].base_xyz[{coordinate}] = 1000000000.0" in str(err.value)
    assert "within ±10 m of the cell's origin" in str(err.value)


def test_arms_overlapping_at_rest_are_refused_by_start_before_anything_runs(
    tmp_path: Path,
) -> None:
    """Two arms at one base: before, both started and the cell halted with FORCE at tick 0."""
    name = unique_name()
    two = {r"\[0\.6, 0\.0, 0\.0\]": "[-0.6, 0.0, 0.0]"}
    try:
        with pytest.raises(ConfigError) as err:
            launcher.start(make_config(name, two), lockstep=True)
        assert leftovers(name) == ([], [])  # nothing laid out, nothing running
        message = str(err.value)
        assert "robots 'left' (puma560) and 'right' (puma560) overlap at rest" in message, message
        assert "link 'base_link' of 'left' and link 'base_link' of 'right'" in message
        assert "-0.199 m" in message
        path = tmp_path / "two.yaml"
        path.write_text(config_text(name, two))
        r = kalictl("start", "-c", str(path), "--lockstep")
        assert r.returncode != 0 and "overlap at rest" in r.stderr, (r.stdout, r.stderr)
        assert leftovers(name) == ([], [])
    finally:
        launcher.stop(name)  # what a start that was not refused left


@pytest.mark.parametrize(
    "config", ["default.yaml", "mixed.yaml", "force.yaml", "bridge.yaml", "bench_wallclock.yaml"]
)
def test_the_shipped_cells_are_clear_at_rest(config: str) -> None:
    from kali_daemons.cell import check_clear_at_rest

    path = ROOT / "config" / config
    check_clear_at_rest(parse_config(path.read_text(), str(path), str(path.parent)))
