"""The arena laid out up front (issue 25 item 6): one declarative list, allocated by kalictl
start before any process starts, the arena then sealed; the layout's version a digest of
every dtype; ``kalictl mem --fields`` shows each record's fields and values."""

from __future__ import annotations

import re
from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.core.arena import Arena
from kali_daemons.core.errors import ArenaError
from kali_daemons.runtime.config import arena_need, cell_of, parse_config
from kali_daemons.runtime.instance import Instance
from kali_daemons.servo import registry_for

from .conftest import ROOT, config_text
from .test_launcher import kalictl

MIXED = {r"^  - \{name: right, +model: puma560,": "  - {name: right, model: panda,"}


def test_the_version_is_a_digest_of_every_dtype(monkeypatch: pytest.MonkeyPatch) -> None:
    """A field added, renamed or resized anywhere changes the version; nothing else does."""
    assert layout._digest() == layout.LAYOUT_VERSION
    grown = np.dtype([*layout.JOINT_STATE.descr, ("extra", "<f8")])
    monkeypatch.setattr(layout, "JOINT_STATE", grown)
    assert layout._digest() != layout.LAYOUT_VERSION
    monkeypatch.undo()
    renamed = [("pid_", t) if n == "pid" else (n, t) for n, t in layout.CLOCK.descr]
    monkeypatch.setattr(layout, "CLOCK", np.dtype(renamed, align=True))
    assert layout._digest() != layout.LAYOUT_VERSION
    monkeypatch.undo()
    monkeypatch.setattr(layout, "FLIGHT_SECONDS", 3.0)  # not a dtype: no new version
    assert layout._digest() == layout.LAYOUT_VERSION


def test_a_mixed_cells_blocks_are_sized_by_each_arms_joints() -> None:
    cfg = parse_config(config_text("lay", MIXED), "<mixed>", str(ROOT / "config"))
    registry = registry_for(cfg.plugins, cfg.base_dir)
    cell = cell_of(cfg, *registry.dtypes())
    blocks = {b.key: b for b in layout.blocks(cell)}
    assert cell.joints == (6, 7) and cell.n_joints == 13
    assert blocks["robots.joints"].count == 13 and blocks["servo.slots"].count == 13
    assert blocks["fifo.left.ring"].count == layout.FIFO_CAPACITY * 6
    assert blocks["fifo.right.ring"].count == layout.FIFO_CAPACITY * 7
    assert blocks["flight.ring"].dtype == layout.flight_row(13, 2)
    # each algorithm's private data is one block, a record per joint (the SVs' units)
    # (then the spares of servos loaded while running, each record the mailbox's size)
    servo = [k for k in blocks if re.fullmatch(r"servo\.data\.\d+", k)]
    assert len(servo) == len(registry) + layout.SERVO_LOADABLE
    last = blocks[f"servo.data.{len(registry) - 1}"]
    assert last.dtype == registry[len(registry) - 1].dtype and last.count == 13
    spare = blocks[f"servo.data.{len(registry)}"]
    assert spare.dtype == layout.LOADED_RECORD and spare.count == 13
    # each robot-level servo's private data is one block too, a record per robot
    arms = [k for k in blocks if re.fullmatch(r"servo\.arm\.\d+", k)]
    assert len(arms) == len(registry.arms) + layout.ARM_LOADABLE
    assert len(registry.arms) >= 2
    assert blocks["servo.arm.1"].dtype == registry.arms[1].dtype
    assert blocks["servo.arm.1"].count == 2
    assert blocks[f"servo.arm.{len(registry.arms)}"].dtype == layout.LOADED_RECORD
    # the size kalictl checks the arena against is this layout's (plugins at their largest,
    # each counted as possibly registering a robot-level servo too)
    need, n_blocks, _ = arena_need(cfg)
    assert n_blocks == len(blocks) + 1 + len(cfg.plugins)
    assert need >= layout.header_bytes() + sum(b.nbytes for b in blocks.values())


def test_a_sealed_arena_takes_no_new_layout_record(arena: Arena) -> None:
    """Once kalictl start has laid out the records, none can be added late (a robot's FIFO
    the layout did not give it, say); attaching still works, and a program may still
    shmalloc a block of its own (thesis 3.6.1)."""
    arena.record("clock", layout.CLOCK)
    arena.header["sealed"] = 1
    assert arena.record("clock", layout.CLOCK).shape == ()
    with pytest.raises(ArenaError, match=r"no block 'fifo.third', a record of layout.RECORDS"):
        arena.record("fifo.third", layout.FIFO_HEADER)
    with pytest.raises(ArenaError, match=r"no block 'servo.data.9'"):
        arena.shmalloc("servo.data.9", 64)
    assert arena.record("my.trace", layout.CLOCK).shape == ()
    assert not layout.is_layout_key("my.trace") and layout.is_layout_key("fifo.left.ring")


def test_kalictl_start_lays_out_every_record_and_the_daemons_only_attach(
    kali: Callable[..., str],
) -> None:
    """After start-up, with every process ACTIVE, the directory holds exactly the layout's
    blocks, at the sizes the layout gives them, and the arena is sealed."""
    name = kali(lockstep=True, edits=MIXED)
    with Instance.attach(name) as inst:
        cfg = inst.config
        registry = registry_for(cfg.plugins, cfg.base_dir)
        want = {b.key: b.nbytes for b in layout.blocks(cell_of(cfg, *registry.dtypes()))}
        have = {b.key: b.requested for b in inst.arena.blocks() if b.used}
        assert have == want
        assert int(inst.arena.header["sealed"]) == 1
        assert int(inst.arena.header["layout_version"]) == layout.LAYOUT_VERSION

        r = kalictl("-i", name, "mem", "--fields", "robots*")
        assert r.returncode == 0, r.stderr
        lines = r.stdout.splitlines()
        assert lines[0].startswith("robots  2 records of ") and "writer: SIO" in lines[0]
        assert re.search(r"^    n_joints +\[6 7\]$", r.stdout, re.M), r.stdout
        head = next(i for i, t in enumerate(lines) if t.startswith("robots.joints  13 records"))
        safe = next(t for t in lines[head:] if t.strip().startswith("safe "))
        assert safe.split(None, 1)[1].count("0.15") == 13 or "..." in safe
        r = kalictl("-i", name, "mem", "--fields", "nothing*")
        assert r.returncode == 1 and "no block of the layout matches" in r.stderr
        r = kalictl("-i", name, "mem")
        assert r.returncode == 0 and "servo.slots" in r.stdout and "fragmentation" in r.stdout
