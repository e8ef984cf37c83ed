"""The flat joint numbering (issue 25 item 3): arms of different joint counts, no gaps, and
copies between flat arrays and per-arm board registers."""

from __future__ import annotations

import numpy as np
import pytest

from kali_daemons.core.errors import ConfigError
from kali_daemons.core.joints import ArmCopy, JointMap
from kali_daemons.hardware.mcgill import registers
from kali_daemons.runtime.config import parse_config

from .conftest import config_text

FOUR_ARMS = JointMap(("a", "b", "ur", "panda"), (6, 6, 6, 7))


def test_four_arms_are_25_joints_numbered_without_gaps() -> None:
    jm = FOUR_ARMS
    assert jm.total == 25 and jm.base == (0, 6, 12, 18) and jm.widest == 7 and jm.uniform == 0
    assert [jm.span(k) for k in range(4)] == [
        slice(0, 6),
        slice(6, 12),
        slice(12, 18),
        slice(18, 25),
    ]
    assert jm.index(3, 6) == 24
    assert list(jm.robot_of[[0, 5, 6, 24]]) == [0, 0, 1, 3]
    assert list(jm.joint_of[[0, 5, 6, 24]]) == [0, 5, 0, 6]
    assert jm.label(24) == "robot 'panda' joint 7"
    assert [v.tolist() for v in jm.split(np.arange(25.0))][3] == list(range(18, 25))


def test_a_uniform_cell_copies_in_one_piece() -> None:
    jm = JointMap(("left", "right"), (6, 6))
    assert jm.uniform == 6 and jm.total == 12
    regs = np.zeros(2, dtype=registers.IO_BOARD)
    flat = np.zeros(12, dtype=np.int32)
    regs["encoder"] = np.arange(16).reshape(2, 8)
    copy = ArmCopy(jm, flat, regs["encoder"])
    copy.to_flat()
    assert flat.tolist() == [0, 1, 2, 3, 4, 5, 8, 9, 10, 11, 12, 13]


@pytest.mark.parametrize("counts", [(6, 7), (7, 6), (3, 8, 6, 1)])
def test_mixed_arms_copy_channel_j_to_joint_j(counts: tuple[int, ...]) -> None:
    """Each arm's joint j is its board's channel j; the channels past its joints stay put."""
    jm = JointMap(tuple(f"r{k}" for k in range(len(counts))), counts)
    dacs = np.zeros(len(counts), dtype=registers.DAC_BOARD)
    codes = dacs["code"]
    codes[...] = 7  # unused channels keep this
    flat = np.arange(1.0, jm.total + 1.0)
    copy = ArmCopy(jm, flat, codes)
    copy.to_arms()
    for k, n in enumerate(counts):
        assert codes[k, :n].tolist() == flat[jm.span(k)].tolist()
        assert (codes[k, n:] == 7).all()
    copy.fill_arms(registers.DAC_ZERO)
    for k, n in enumerate(counts):
        assert (codes[k, :n] == registers.DAC_ZERO).all() and (codes[k, n:] == 7).all()
    back = np.zeros(jm.total)
    codes[...] = np.arange(8)
    ArmCopy(jm, back, codes).to_flat()
    assert back.tolist() == [float(j) for n in counts for j in range(n)]


RIGHT = r"^  - \{name: right, +model: puma560,"


def test_the_config_numbers_a_mixed_cells_joints() -> None:
    cfg = parse_config(config_text("mixjoints", {RIGHT: "  - {name: right, model: panda,"}))
    assert [r.model for r in cfg.robots] == ["puma560", "panda"]
    assert cfg.joints.counts == (6, 7) and cfg.joints.total == 13
    assert len(cfg.robots[1].safe_rad) == 7 and len(cfg.robots[1].index_phases) == 7


def test_a_per_joint_list_of_the_wrong_length_names_the_arms_joint_count() -> None:
    six = "safe_rad: [0.1, 0.1, 0.1, 0.1, 0.1, 0.1],"
    text = config_text("mixjoints", {RIGHT: f"  - {{name: right, model: panda, {six}"})
    with pytest.raises(
        ConfigError, match=r"safe_rad.*7 numbers \(one per joint of a panda\), not 6"
    ):
        parse_config(text)
