"""The arena: header checks, owner-only segments, and the shmalloc/shfree allocator."""

from __future__ import annotations

import itertools
import os
import stat
import subprocess
import sys

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, invariant, precondition, rule

from kali_daemons.core import atomic, layout
from kali_daemons.core.arena import DIR_READ_WAIT_S, Arena, segment_name, unlink_segment
from kali_daemons.core.errors import ArenaError, ArenaFullError

from .conftest import unique_name


def test_header_is_versioned_and_attach_reads_it(arena: Arena) -> None:
    assert int(arena.header["magic"]) == layout.MAGIC
    assert int(arena.header["layout_version"]) == layout.LAYOUT_VERSION
    name = arena.name.removeprefix("/kali.")
    with Arena.attach(name) as other:
        assert other.size == arena.size
        assert not other.owner


def test_attach_refuses_wrong_version_naming_both(arena: Arena) -> None:
    arena.header["layout_version"] = 99
    want = rf"layout version 99, this Kali reads version {layout.LAYOUT_VERSION}"
    with pytest.raises(ArenaError, match=want):
        Arena.attach(arena.name.removeprefix("/kali."))


def test_attach_refuses_wrong_magic(arena: Arena) -> None:
    arena.header["magic"] = 12345
    with pytest.raises(ArenaError, match="bad magic 0x3039, not a Kali arena"):
        Arena.attach(arena.name.removeprefix("/kali."))


def test_attach_to_missing_instance_says_so() -> None:
    with pytest.raises(ArenaError, match=r"no instance 'nosuch[\w-]*'.*is it started"):
        Arena.attach(unique_name("nosuch"))


def test_attach_to_missing_instance_names_those_running(arena: Arena) -> None:
    """A program or ``kalictl`` without ``-i`` after ``kalictl start -c config/force.yaml``
    (instance 'force') looks for 'default': the refusal names the instances there are and
    how to pick one."""
    running = arena.name.removeprefix("/kali.")
    with pytest.raises(ArenaError) as err:
        Arena.attach(unique_name("nosuch"))
    message = str(err.value)
    assert "instances running: " in message and running in message.split("running: ")[1]
    assert "kalictl -i NAME" in message and "KALI_INSTANCE" in message


def test_segment_is_owner_only(arena: Arena) -> None:
    mode = os.stat("/dev/shm" + arena.name).st_mode
    assert stat.S_IMODE(mode) == 0o600


def test_close_twice_is_safe(arena: Arena) -> None:
    other = Arena.attach(arena.name.removeprefix("/kali."))
    other.close()
    other.close()


def test_non_owner_exit_does_not_unlink(arena: Arena) -> None:
    """A process that attaches, writes and exits leaves the segment for the owner."""
    name = arena.name.removeprefix("/kali.")
    arena.record("shared", np.dtype("<i8"), 1)
    code = (
        "import numpy as np\n"
        "from kali_daemons.core.arena import Arena\n"
        f"a = Arena.attach({name!r})\n"
        "v = a.record('shared', np.dtype('<i8'), 1)\n"
        "v[0] = 4242\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)
    assert os.path.exists("/dev/shm" + arena.name)
    assert arena.existing("shared", np.dtype("<i8"), 1)[0] == 4242


def test_same_key_same_block_and_growth_refused(arena: Arena) -> None:
    a = arena.shmalloc("sv.3.cmd", 100)
    assert arena.shmalloc("sv.3.cmd", 100) == a
    assert arena.shmalloc("sv.3.cmd", 10) == a
    with pytest.raises(ArenaError, match=r"block 'sv\.3\.cmd' exists with 100 B, 200 B requested"):
        arena.shmalloc("sv.3.cmd", 200)


def test_exhaustion_is_a_clear_error(arena: Arena) -> None:
    arena.shmalloc("a", 400_000)
    arena.shmalloc("b", 400_000)
    arena.shfree("a")
    with pytest.raises(
        ArenaFullError, match=r"block 'big' needs 500032 B, \d+ B free in 2 fragments"
    ):
        arena.shmalloc("big", 500_000)


def test_bad_keys_and_sizes(arena: Arena) -> None:
    with pytest.raises(ArenaError, match="key '' is not allowed"):
        arena.shmalloc("", 8)
    with pytest.raises(ArenaError, match="is not allowed"):
        arena.shmalloc("x" * 40, 8)
    with pytest.raises(ArenaError, match="size 0 B, must be > 0"):
        arena.shmalloc("zero", 0)
    with pytest.raises(ArenaError, match="shfree of unknown block 'ghost'"):
        arena.shfree("ghost")


def test_reading_the_directory_takes_no_lock(arena: Arena) -> None:
    """Another process holding the directory lock (stopped, hung or dead) keeps nobody from
    looking a block up, attaching to an existing one or listing the arena."""
    off = arena.shmalloc("a", 100)
    arena.shmalloc("b", 200)
    lock_word = arena.address_of_field(0, layout.HEADER, "dir_lock")
    atomic.store32(lock_word, 4_000_000)  # a pid nobody has: as if its holder were stopped
    assert arena.lookup("a") == (off, 128)
    assert arena.shmalloc("a", 100) == off  # an existing block: no lock needed
    assert [b.key for b in arena.blocks() if b.used] == ["a", "b"]
    assert arena.stats().used_blocks == 2
    assert arena.block("b") is not None and arena.block("b").requested == 200
    assert arena.lookup("c") is None


def test_a_directory_left_half_changed_is_named_not_waited_on(arena: Arena) -> None:
    arena.shmalloc("a", 100)
    atomic.store32(arena.address_of_field(0, layout.HEADER, "dir_lock"), os.getpid())
    gen = arena.address_of_field(0, layout.HEADER, "dir_gen")
    atomic.store32(gen, atomic.load32(gen) | 1)  # its writer stopped in the middle of a change
    with pytest.raises(
        ArenaError,
        match=rf"half-changed for more than {DIR_READ_WAIT_S:g} s by "
        rf"pid {os.getpid()} \(python",
    ):
        arena.blocks()
    assert arena.lookup("a") is not None  # a block in use never moves: still found


def test_new_block_is_zeroed_and_freed_memory_reused(arena: Arena) -> None:
    v = arena.record("r", np.dtype("u1"), 256)
    v[:] = 7
    off = arena.lookup("r")[0]
    del v
    arena.shfree("r")
    v2 = arena.record("s", np.dtype("u1"), 256)
    assert arena.lookup("s")[0] == off  # first fit takes the lowest free block
    assert not v2.any()


SMALL = 64 * 1024  # a small heap so random sequences reach exhaustion


class AllocatorMachine(RuleBasedStateMachine):
    """Random shmalloc/shfree sequences against a model of which keys hold which sizes."""

    def __init__(self) -> None:
        super().__init__()
        self.name = unique_name("h")
        self.arena = Arena.create(self.name, layout.header_bytes() + SMALL)
        self.model: dict[str, tuple[int, int]] = {}  # key -> (offset, requested)

    def teardown(self) -> None:
        self.arena.close()
        unlink_segment(segment_name(self.name))

    @rule(k=st.integers(0, 40), size=st.integers(1, 9000))
    def alloc(self, k: int, size: int) -> None:
        key = f"k{k}"
        if key in self.model:
            off, req = self.model[key]
            if size <= req:
                assert self.arena.shmalloc(key, size) == off  # same key -> same block
            else:
                with pytest.raises(ArenaError, match="exists with"):
                    self.arena.shmalloc(key, size)
            return
        stats = self.arena.stats()
        need = -(-size // layout.ALIGN) * layout.ALIGN
        if stats.largest_free < need:
            with pytest.raises(ArenaFullError, match=f"block '{key}' needs {need} B"):
                self.arena.shmalloc(key, size)
            return
        off = self.arena.shmalloc(key, size)
        # first fit: no free block below the chosen one was large enough
        for b in self.arena.blocks():
            if b.offset >= off:
                break
            assert b.used or b.size < need
        self.model[key] = (off, size)

    @precondition(lambda self: self.model)
    @rule(data=st.data())
    def free(self, data: st.DataObject) -> None:
        key = data.draw(st.sampled_from(sorted(self.model)))
        self.arena.shfree(key)
        del self.model[key]

    @invariant()
    def blocks_tile_the_heap_and_coalesce(self) -> None:
        blocks = self.arena.blocks()
        pos = layout.header_bytes()
        for a, b in itertools.pairwise(blocks):
            assert a.used or b.used, "two adjacent free fragments: coalescing incomplete"
        for b in blocks:
            assert b.offset == pos, "blocks overlap or leave a gap"
            assert b.size % layout.ALIGN == 0 and b.size > 0
            pos += b.size
        assert pos == self.arena.size, "blocks leave the arena bounds"
        used = {b.key: (b.offset, b.requested) for b in blocks if b.used}
        assert used == self.model
        for off, req in self.model.values():
            assert off + req <= self.arena.size

    @invariant()
    def everything_free_is_one_block(self) -> None:
        if not self.model:
            s = self.arena.stats()
            assert s.free_fragments == 1 and s.free_bytes == SMALL and s.fragmentation == 0.0


TestAllocator = AllocatorMachine.TestCase
TestAllocator.settings = settings(
    max_examples=60,
    stateful_step_count=60,
    deadline=None,
    suppress_health_check=[HealthCheck.too_slow],
)
