"""The hardware boundary (docs/decisions/0015): kinds found by name, their records laid out
with the cell's, their out-of-cycle operations from the arena alone."""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.core.errors import ArenaError, ConfigError, InstanceError
from kali_daemons.hardware import HardwareKind, hardware_kind, known_kinds
from kali_daemons.hardware.mcgill import KIND, McGillOps, registers
from kali_daemons.runtime.config import cell_of
from kali_daemons.runtime.instance import Instance
from kali_daemons.tools import launcher

from .conftest import leftovers, make_config, unique_name

MCGILL = hardware_kind("mcgill")


def test_the_mcgill_board_is_a_kind_found_by_name() -> None:
    assert known_kinds() == ["franka", "mcgill"]
    assert MCGILL is KIND and MCGILL.channels == registers.BOARD_CHANNELS == 8
    assert {r.key for r in MCGILL.records} == {"hw.mcgill.boards", "hw.mcgill.dacs"}


@pytest.mark.parametrize(
    ("name", "expected"),
    [
        (
            "mcgil",
            "no hardware kind 'mcgil' (did you mean 'mcgill'?); the kinds are: franka, mcgill",
        ),
        ("kuka", "no hardware kind 'kuka'; the kinds are: franka, mcgill"),
        ("../mcgill", "no hardware kind '../mcgill'"),
    ],
)
def test_an_unknown_kind_is_refused_naming_the_kinds(name: str, expected: str) -> None:
    with pytest.raises(ConfigError, match=re.escape(expected)):
        hardware_kind(name)


def test_a_kind_declares_what_fits_kalis_records() -> None:
    """A kind carrying more joints than an arm's records hold, or keying a record outside its
    own ``hw.<kind>.`` namespace, is refused where it is declared."""
    with pytest.raises(ConfigError, match="carries 9 joints per arm; Kali's per-arm records hold"):
        dataclasses.replace(MCGILL, channels=layout.MAX_JOINTS + 1)
    stray = dataclasses.replace(MCGILL.records[0], key="boards")
    with pytest.raises(ConfigError, match=re.escape("every record's key starts hw.mcgill.")):
        HardwareKind("mcgill", "x", 6, operations=McGillOps, drive=MCGILL.drive, records=(stray,))


def test_a_kinds_version_is_a_digest_of_its_records() -> None:
    """Stored in the cell record at start: a field added to a board's record changes it."""
    grown = np.dtype([*registers.IO_BOARD.descr, ("extra", "u1")])
    record = dataclasses.replace(MCGILL.records[0], dtype=grown)
    assert dataclasses.replace(MCGILL, records=(record, *MCGILL.records[1:])).version != (
        MCGILL.version
    )
    assert dataclasses.replace(MCGILL).version == MCGILL.version


def test_the_layout_holds_no_board_and_lays_out_the_cells_kinds() -> None:
    """Kali's layout has no board of its own: the McGill registers are its kind's records,
    laid out with the cell's (and sealed like them once the arena is)."""
    assert not any(name.startswith(("CSR_", "POWER_", "ADC_", "DAC_")) for name in vars(layout))
    cfg = make_config("hw")
    assert cfg.hardware_kinds == ("mcgill",)
    cell = cell_of(cfg, ())
    blocks = {b.key: b for b in layout.blocks(cell)}
    assert blocks["hw.mcgill.boards"].dtype == registers.IO_BOARD
    assert blocks["hw.mcgill.boards"].count == len(cfg.robots)
    assert blocks["hw.mcgill.dacs"].dtype == registers.DAC_BOARD
    assert layout.is_layout_key("hw.mcgill.boards") and layout.is_layout_key("hw.other.x")
    assert not layout.is_layout_key("program.mine")


def test_the_boards_operations_work_on_the_arena_alone(arena: Arena) -> None:
    """Outside any cycle and without a lock: nothing to do before the boards are laid out;
    then the e-stop, the cut, the gripper and the conveyor are the board's lines."""
    ops = McGillOps(arena, 2)
    ops.cut()  # not laid out: nothing is powered, nothing to cut
    assert ops.amplifiers_cut() == [False, False] and ops.estops_pressed() == [False, False]
    with pytest.raises(ArenaError, match=re.escape("no block 'hw.mcgill.boards'")):
        ops.grip(0, True)
    boards = arena.record(registers.KEY_BOARDS, registers.IO_BOARD, 2)
    boards["csr"] = registers.CSR_NO_DISABLE
    boards["power"] = registers.POWER_AMPS_ON
    assert ops.amplifiers_cut() == [False, False]
    ops.press_estop(1, True)
    assert ops.estops_pressed() == [False, True] and ops.amplifiers_cut() == [False, True]
    ops.cut()
    assert not (boards["csr"] & registers.CSR_NO_DISABLE).any()
    assert ops.amplifiers_cut() == [True, True]
    ops.grip(1, True)
    ops.run_conveyor(True)
    assert boards["gripper"].tolist() == [0, 1] and boards["conveyor"].tolist() == [1, 0]
    del boards
    assert np.all(ops.estops_pressed() == [False, True])


def test_a_process_of_another_kali_refuses_a_cells_other_hardware_records() -> None:
    """``kalictl start`` stores each robot's hardware kind and its records' version in the
    cell record; a process whose kind's records differ refuses the cell (it must not misread,
    or write, a register) and names both versions."""
    name = unique_name("hw")
    launcher._create(make_config(name), name, lockstep=True).close()
    try:
        with Instance.attach(name) as inst:
            assert inst.cell.hardware == ("mcgill", "mcgill")
            assert inst.hardware_kind("mcgill") is MCGILL
            assert inst.hardware(1).amplifiers_cut() == [True, True]  # at rest: disabled
            rec = inst.arena.existing(layout.KEY_CELL, layout.CELL)
            rec["robots"]["hardware_version"][1] = MCGILL.version ^ 1
            del rec
        with Instance.attach(name) as other:
            expected = (
                f"instance '{name}': its mcgill hardware records are version "
                f"{MCGILL.version ^ 1}, this Kali's {MCGILL.version}"
            )
            with pytest.raises(InstanceError, match=re.escape(expected)):
                other.cell  # noqa: B018 - reading it is the check
    finally:
        launcher.stop(name)
    assert leftovers(name) == ([], [])
