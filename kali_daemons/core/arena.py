"""The shared-memory arena: one POSIX segment per instance (thesis 3.6.1, DESIGN section 2).

Layout: a versioned header, a directory of block descriptors kept as a doubly linked list in
address order (the thesis's "master list"), then the heap.  ``shmalloc(key, size)`` returns
the existing block when the key exists, else allocates first-fit and splits;
``shfree(key)`` returns the block and coalesces it with free neighbours.  Changes to the
directory are serialised by a test-and-set spinlock in the header; reading it takes no lock,
so a process stopped (or dead) while holding that lock can keep nobody from attaching,
looking a block up, halting or stopping the instance: ``lookup`` scans the descriptors (a
block in use never moves), and ``blocks``/``stats`` copy the directory between two equal
even values of the header's ``dir_gen`` sequence count.  Only offsets are stored;
``address`` is the one place an offset becomes an address.

``kalictl start`` creates and ``kalictl stop`` unlinks the segment; everyone else attaches
and closes.  The segment is opened through ``posix_ipc`` and mapped with ``mmap``, so no
resource tracker ever unlinks it behind the owner's back (Python 3.11's
``multiprocessing.shared_memory`` would, when a non-owner exits).
"""

from __future__ import annotations

import glob
import mmap
import os
import pwd
import stat
import time
from dataclasses import dataclass

import numpy as np
import posix_ipc

from . import atomic, layout
from .errors import ArenaError, ArenaFullError
from .spinlock import SpinLock, holder_text

SEGMENT_PREFIX = "/kali."
DIR_READ_WAIT_S = 0.5  # longest a reader waits for a directory change to finish
SEM_BYTES = 32  # sizeof(sem_t) on Linux: the size of a real POSIX semaphore's file


def instances_present() -> list[str]:
    """The names of the instances whose segments are in /dev/shm (anyone's), sorted: what a
    refusal to attach can offer instead."""
    prefix = "/dev/shm" + SEGMENT_PREFIX
    return sorted(path.removeprefix(prefix) for path in glob.glob(glob.escape(prefix) + "*"))


def segment_name(instance: str) -> str:
    """POSIX name of an instance's segment (``/dev/shm/kali.<instance>``)."""
    return f"{SEGMENT_PREFIX}{instance}"


@dataclass(frozen=True)
class Block:
    """One directory entry as ``kalictl mem`` shows it."""

    key: str
    offset: int
    size: int
    requested: int
    used: bool


@dataclass(frozen=True)
class ArenaStats:
    """Heap occupancy and external fragmentation (thesis 3.6.1, [Randell69])."""

    heap_bytes: int
    used_bytes: int
    used_blocks: int
    free_bytes: int
    free_fragments: int
    largest_free: int

    @property
    def fragmentation(self) -> float:
        """1 - largest free fragment / free bytes: 0 when all free memory is one block."""
        return 0.0 if self.free_bytes == 0 else 1.0 - self.largest_free / self.free_bytes


def _round_up(n: int) -> int:
    return -(-n // layout.ALIGN) * layout.ALIGN


def _key_bytes(key: str) -> bytes:
    raw = key.encode("ascii", "replace") if isinstance(key, str) else b""
    if not raw or len(raw) >= layout.KEY_BYTES or b"\0" in raw or b"?" in raw:
        raise ArenaError(f"key {key!r} is not allowed: 1..{layout.KEY_BYTES - 1} ASCII characters")
    return raw


class Arena:
    """An attached (or owned) arena; views records in place."""

    def __init__(self, name: str, mm: mmap.mmap, owner: bool) -> None:
        self.name = name
        self.owner = owner
        self._mm: mmap.mmap | None = mm
        self._bytes = np.frombuffer(mm, dtype=np.uint8)  # the one buffer export
        self.base_address = int(self._bytes.ctypes.data)
        self.size = len(mm)
        self.header = self._bytes[: layout.HEADER.itemsize].view(layout.HEADER).reshape(())
        d0 = layout.HEADER.itemsize
        d1 = d0 + layout.MAX_BLOCKS * layout.DESCRIPTOR.itemsize
        self.directory = self._bytes[d0:d1].view(layout.DESCRIPTOR)
        self._dir_lock = SpinLock(self.address_of_field(0, layout.HEADER, "dir_lock"), "arena")
        self._dir_gen = self.address_of_field(0, layout.HEADER, "dir_gen")

    # ---------------------------------------------------------------- lifecycle

    @classmethod
    def create(cls, instance: str, size_bytes: int) -> Arena:
        """Create an instance's segment, owner-only (0600); fails if it already exists."""
        name = segment_name(instance)
        size = _round_up(size_bytes)
        if size < layout.header_bytes() + layout.ALIGN:
            raise ArenaError(
                f"{name}: size {size_bytes} B is too small, at least "
                f"{layout.header_bytes() + layout.ALIGN} B needed"
            )
        try:
            shm = posix_ipc.SharedMemory(name, posix_ipc.O_CREX, mode=0o600, size=size)
        except posix_ipc.ExistentialError as exc:
            raise ArenaError(f"{name} already exists ({exc})") from exc
        try:
            mm = mmap.mmap(shm.fd, size)
        finally:
            shm.close_fd()
        arena = cls(name, mm, owner=True)
        arena._format(instance)
        return arena

    @classmethod
    def attach(cls, instance: str) -> Arena:
        """Attach to a running instance's segment; refuse a wrong magic or layout version."""
        name = segment_name(instance)
        squat = foreign_object(shm_path(name), any_owner=True)
        if squat is not None:
            raise ArenaError(
                f"instance '{instance}': {squat}; not Kali's arena, never mapped "
                f"(kalictl -i {instance} stop removes it if it is yours)"
            )
        try:
            shm = posix_ipc.SharedMemory(name)
        except posix_ipc.ExistentialError as exc:
            others = instances_present()
            running = (
                f"; instances running: {', '.join(others)} (kalictl -i NAME, or KALI_INSTANCE=NAME)"
                if others
                else ""
            )
            raise ArenaError(
                f"no instance '{instance}': {name} does not exist (is it started?){running}"
            ) from exc
        except posix_ipc.PermissionsError:
            raise ArenaError(
                f"instance '{instance}' is not yours: {name} {owner_text(name)}; "
                f"{user_text()} may not attach (Kali instances are owner-only)"
            ) from None
        except OSError as exc:  # swapped for something else between the look and the open
            raise ArenaError(
                f"instance '{instance}': {shm_path(name)}: cannot open: {exc.strerror}"
            ) from None
        try:
            if shm.size < layout.header_bytes():
                raise ArenaError(
                    f"instance '{instance}': {shm_path(name)} {owner_text(name)}, {shm.size} B:"
                    f" smaller than an arena header ({layout.header_bytes()} B), not a Kali "
                    f"arena (squatted, or left by a failed start)"
                )
            mm = mmap.mmap(shm.fd, shm.size)
        finally:
            shm.close_fd()
        arena = cls(name, mm, owner=False)
        arena._check_header()
        return arena

    def _format(self, instance: str) -> None:
        h = self.header
        self._bytes[: layout.header_bytes()] = 0
        h["magic"] = layout.MAGIC
        h["layout_version"] = layout.LAYOUT_VERSION
        h["header_bytes"] = layout.header_bytes()
        h["arena_bytes"] = self.size
        h["instance"] = instance.encode()
        h["owner_pid"] = os.getpid()
        h["created_ns"] = time.time_ns()
        d = self.directory
        d[0]["offset"] = layout.header_bytes()
        d[0]["size"] = self.size - layout.header_bytes()
        d[0]["live"] = 1
        d[0]["prev"] = layout.NULL_INDEX
        d[0]["next"] = layout.NULL_INDEX
        h["head"] = 0

    def _check_header(self) -> None:
        h = self.header
        if int(h["magic"]) != layout.MAGIC:
            raise ArenaError(f"{self.name}: bad magic {int(h['magic']):#x}, not a Kali arena")
        version = int(h["layout_version"])
        if version != layout.LAYOUT_VERSION:
            raise ArenaError(
                f"{self.name}: layout version {version}, this Kali reads version "
                f"{layout.LAYOUT_VERSION}; stop the instance with the Kali that started it"
            )
        if int(h["arena_bytes"]) != self.size:
            raise ArenaError(
                f"{self.name}: header says {int(h['arena_bytes'])} B, segment is {self.size} B"
            )

    def close(self) -> None:
        """Unmap this process's view; safe to call twice.

        If record views handed out are still referenced, the mapping stays until they go.
        """
        if self._mm is None:
            return
        mm, self._mm = self._mm, None
        self.header = self.directory = self._bytes = None  # type: ignore[assignment]
        try:
            mm.close()
        except BufferError:
            pass  # views still alive elsewhere keep the mapping; it goes with them

    def unlink(self) -> None:
        """Remove the segment name (owner: kalictl stop).  The memory lives until unmapped."""
        unlink_segment(self.name)

    def __enter__(self) -> Arena:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ---------------------------------------------------------------- offsets and views

    def address(self, offset: int) -> int:
        """Absolute address of an arena offset, for atomic operations."""
        if not 0 <= offset < self.size:
            raise ArenaError(f"{self.name}: offset {offset} outside 0..{self.size - 1}")
        return self.base_address + offset

    def address_of_field(self, offset: int, dtype: np.dtype, field: str, index: int = 0) -> int:
        """Address of ``field`` of record ``index`` in an array of ``dtype`` at ``offset``."""
        assert dtype.fields is not None, f"{self.name}: address_of_field: {dtype} has no fields"
        return self.address(offset + index * dtype.itemsize + dtype.fields[field][1])

    def view(self, offset: int, dtype: np.dtype, count: int | None = None) -> np.ndarray:
        """View ``count`` records (or one 0-d record when None) of ``dtype`` at ``offset``."""
        n = 1 if count is None else count
        end = offset + n * dtype.itemsize
        if offset < 0 or end > self.size:
            raise ArenaError(f"{self.name}: view {offset}..{end} outside 0..{self.size}")
        arr = self._bytes[offset:end].view(dtype)
        return arr.reshape(()) if count is None else arr

    def record(self, key: str, dtype: np.dtype, count: int | None = None) -> np.ndarray:
        """shmalloc a block for ``count`` records of ``dtype`` (or attach to it) and view it;
        zero records are no block (``layout.blocks``), an empty array."""
        if count == 0:
            return np.zeros(0, dtype)
        n = 1 if count is None else count
        return self.view(self.shmalloc(key, n * dtype.itemsize), dtype, count)

    def existing(self, key: str, dtype: np.dtype, count: int | None = None) -> np.ndarray:
        """View an existing block; ArenaError if the key is absent or the block too small.
        Zero records are no block: an empty array."""
        if count == 0:
            return np.zeros(0, dtype)
        found = self.lookup(key)
        if found is None:
            raise ArenaError(f"{self.name}: no block '{key}'")
        offset, size = found
        n = 1 if count is None else count
        if n * dtype.itemsize > size:
            raise ArenaError(
                f"{self.name}: block '{key}' is {size} B, {n * dtype.itemsize} B needed"
            )
        return self.view(offset, dtype, count)

    # ---------------------------------------------------------------- allocator

    def _find(self, raw: bytes) -> int:
        """Descriptor of the block named ``raw``, or NULL_INDEX; never locks.

        Scans the descriptors rather than the address-ordered list: a change in progress
        rewires the list, but never touches a descriptor in use, so a block that exists
        throughout is always found, whoever holds the directory lock.
        """
        d = self.directory
        hits = np.flatnonzero((d["used"] == 1) & (d["key"] == raw))
        for i in hits:
            if d[i]["used"] and d[i]["key"] == raw:  # still it, after the vector scan
                return int(i)
        return layout.NULL_INDEX

    def lookup(self, key: str) -> tuple[int, int] | None:
        """(offset, size) of the block named ``key``, or None; takes no lock."""
        b = self.block(key)
        return None if b is None else (b.offset, b.size)

    def block(self, key: str) -> Block | None:
        """The block named ``key`` (with the size it was requested with), or None; takes no
        lock (a block allocated or freed at the same moment may or may not be seen)."""
        raw = _key_bytes(key)
        i = self._find(raw)
        if i == layout.NULL_INDEX:
            return None
        e = self.directory[i]
        return Block(key, int(e["offset"]), int(e["size"]), int(e["requested"]), True)

    def shmalloc(self, key: str, size: int) -> int:
        """Offset of block ``key``: the existing one, else a new first-fit block, zeroed.

        An existing block is found without the directory lock, so attaching to records laid
        out at start never waits on another process.
        """
        raw = _key_bytes(key)
        if size <= 0:
            raise ArenaError(f"block '{key}': size {size} B, must be > 0")
        need = _round_up(size)
        d = self.directory
        i = self._find(raw)
        if i == layout.NULL_INDEX:
            if int(self.header["sealed"]) and layout.is_layout_key(key):
                raise ArenaError(
                    f"{self.name}: no block '{key}', a record of layout.RECORDS, and the arena "
                    f"is sealed: kalictl start lays out every such record before any process "
                    f"starts, a process only attaches (a program's own blocks are its own)"
                )
            with self._dir_lock:
                return self._allocate(raw, key, size, need)
        have = int(d[i]["requested"])
        if size > have:
            raise ArenaError(f"block '{key}' exists with {have} B, {size} B requested")
        return int(d[i]["offset"])

    def _allocate(self, raw: bytes, key: str, size: int, need: int) -> int:
        """shmalloc's writer side, with the directory lock held."""
        d = self.directory
        i = self._find(raw)
        if i != layout.NULL_INDEX:  # made since the unlocked look
            have = int(d[i]["requested"])
            if size > have:
                raise ArenaError(f"block '{key}' exists with {have} B, {size} B requested")
            return int(d[i]["offset"])
        i = int(self.header["head"])
        while i != layout.NULL_INDEX and (d[i]["used"] or int(d[i]["size"]) < need):
            i = int(d[i]["next"])
        if i == layout.NULL_INDEX:
            s = _stats_of(d, int(self.header["head"]), self._heap_bytes())
            raise ArenaFullError(
                f"block '{key}' needs {need} B, {s.free_bytes} B free in "
                f"{s.free_fragments} fragments (largest {s.largest_free} B)"
            )
        gen = self._begin_change()
        try:
            if int(d[i]["size"]) > need:
                self._split(i, need, key)
            d[i]["requested"] = size
            d[i]["key"] = raw
            d[i]["used"] = 1
        finally:
            self._end_change(gen)
        offset = int(d[i]["offset"])
        self._bytes[offset : offset + need] = 0
        return offset

    def _begin_change(self) -> int:
        """Mark the directory as changing (odd ``dir_gen``); the lock holder only."""
        gen = (atomic.load32(self._dir_gen) | 1) & 0xFFFFFFFF
        atomic.store32(self._dir_gen, gen)
        return gen

    def _end_change(self, gen: int) -> None:
        """Mark the change done (even ``dir_gen``)."""
        atomic.store32(self._dir_gen, (gen + 1) & 0xFFFFFFFF)

    def _split(self, i: int, need: int, key: str) -> None:
        d = self.directory
        spare = np.flatnonzero(d["live"] == 0)
        if spare.size == 0:
            raise ArenaFullError(
                f"block '{key}' needs a directory entry, all {layout.MAX_BLOCKS} are in use"
            )
        j = int(spare[0])
        nxt = int(d[i]["next"])
        d[j] = 0
        d[j]["live"] = 1
        d[j]["offset"] = int(d[i]["offset"]) + need
        d[j]["size"] = int(d[i]["size"]) - need
        d[j]["prev"] = i
        d[j]["next"] = nxt
        if nxt != layout.NULL_INDEX:
            d[nxt]["prev"] = j
        d[i]["next"] = j
        d[i]["size"] = need

    def shfree(self, key: str) -> None:
        """Return block ``key`` to the free list, coalescing with free neighbours.

        The memory is not cleared (thesis 3.6.1); the next shmalloc of it zeroes it.
        """
        raw = _key_bytes(key)
        d = self.directory
        with self._dir_lock:
            i = self._find(raw)
            if i == layout.NULL_INDEX:
                raise ArenaError(f"{self.name}: shfree of unknown block '{key}'")
            gen = self._begin_change()
            try:
                d[i]["used"] = 0
                d[i]["key"] = b""
                d[i]["requested"] = 0
                nxt = int(d[i]["next"])
                if nxt != layout.NULL_INDEX and not d[nxt]["used"]:
                    self._absorb_next(i)
                prv = int(d[i]["prev"])
                if prv != layout.NULL_INDEX and not d[prv]["used"]:
                    self._absorb_next(prv)
            finally:
                self._end_change(gen)

    def _absorb_next(self, i: int) -> None:
        d = self.directory
        j = int(d[i]["next"])
        d[i]["size"] = int(d[i]["size"]) + int(d[j]["size"])
        nxt = int(d[j]["next"])
        d[i]["next"] = nxt
        if nxt != layout.NULL_INDEX:
            d[nxt]["prev"] = i
        d[j] = 0

    # ---------------------------------------------------------------- introspection

    def _snapshot(self) -> tuple[np.ndarray, int]:
        """A consistent copy of the directory and its head, taken without the lock: copied
        between two equal even ``dir_gen`` values.  ArenaError naming the lock's holder if a
        change stays unfinished for DIR_READ_WAIT_S (its writer stopped or died mid-way)."""
        deadline = time.monotonic() + DIR_READ_WAIT_S
        while True:
            gen = atomic.load32(self._dir_gen)
            if not gen & 1:
                d = self.directory.copy()
                head = int(self.header["head"])
                if atomic.load32(self._dir_gen) == gen:
                    return d, head
            if time.monotonic() > deadline:
                raise ArenaError(
                    f"{self.name}: directory left half-changed for more than "
                    f"{DIR_READ_WAIT_S:g} s by {holder_text(self._dir_lock.holder)}"
                )
            time.sleep(0.001)

    def _heap_bytes(self) -> int:
        return self.size - int(self.header["header_bytes"])

    def blocks(self) -> list[Block]:
        """Every block and free fragment in address order (a snapshot; takes no lock)."""
        d, i = self._snapshot()
        out: list[Block] = []
        while i != layout.NULL_INDEX:
            e = d[i]
            out.append(
                Block(
                    key=bytes(e["key"]).decode("ascii", "replace"),
                    offset=int(e["offset"]),
                    size=int(e["size"]),
                    requested=int(e["requested"]),
                    used=bool(e["used"]),
                )
            )
            i = int(e["next"])
        return out

    def stats(self) -> ArenaStats:
        """Occupancy and fragmentation of the heap (a snapshot; takes no lock)."""
        d, head = self._snapshot()
        return _stats_of(d, head, self._heap_bytes())

    @property
    def dir_lock_holder(self) -> int:
        """Pid holding the directory lock, 0 if free (for kalictl status)."""
        return self._dir_lock.holder


def _stats_of(d: np.ndarray, head: int, heap_bytes: int) -> ArenaStats:
    """Occupancy of the address-ordered list starting at ``head`` in directory ``d``."""
    used = free = nused = nfree = largest = 0
    i = head
    while i != layout.NULL_INDEX:
        size = int(d[i]["size"])
        if d[i]["used"]:
            used += size
            nused += 1
        else:
            free += size
            nfree += 1
            largest = max(largest, size)
        i = int(d[i]["next"])
    return ArenaStats(heap_bytes, used, nused, free, nfree, largest)


def shm_path(name: str, semaphore: bool = False) -> str:
    """Where Linux shows the POSIX segment (or semaphore) ``name`` in the file system."""
    return f"/dev/shm/{'sem.' if semaphore else ''}{name.lstrip('/')}"


def user_text(uid: int | None = None) -> str:
    """``uid`` (default: this process's effective one) with its user name, for messages."""
    uid = os.geteuid() if uid is None else uid
    try:
        return f"uid {uid} ({pwd.getpwuid(uid).pw_name})"
    except KeyError:
        return f"uid {uid}"


def owner_text(name: str, semaphore: bool = False) -> str:
    """Who owns the POSIX object ``name`` and its mode, e.g. "belongs to uid 0 (root), mode
    0600", for a refusal's message."""
    try:
        st = os.stat(shm_path(name, semaphore))
    except OSError:
        return "belongs to another user"
    return _owner_of(st)


def foreign_object(path: str, semaphore: bool = False, any_owner: bool = False) -> str | None:
    """Why the ``/dev/shm`` entry ``path`` is not an object this user's Kali made, or None.

    Another user's object (unless ``any_owner``), a non-file, or a file too small to be what
    its name says (a semaphore's file is SEM_BYTES, a segment at least a header): opening
    and mapping such a squatted object would touch memory past its end (SIGBUS) or another
    user's data.
    """
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return None
    what = f"{path} {_owner_of(st)}, {st.st_size} B"
    if not stat.S_ISREG(st.st_mode):
        return f"{what}: {file_kind(st.st_mode)}, not a regular file"
    if st.st_uid != os.geteuid() and not any_owner:
        return f"{what}: not {user_text()}'s"
    least = SEM_BYTES if semaphore else layout.header_bytes()
    if st.st_size < least:
        kind = "semaphore" if semaphore else "arena"
        return f"{what}: smaller than a {kind} ({least} B)"
    return None


_KINDS = {
    stat.S_IFLNK: "a symbolic link",
    stat.S_IFDIR: "a directory",
    stat.S_IFIFO: "a FIFO",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFSOCK: "a socket",
}


def file_kind(mode: int) -> str:
    """What a file of ``mode`` is, for a message: "a directory", "a symbolic link" ..."""
    return _KINDS.get(stat.S_IFMT(mode), "a regular file")


def _owner_of(st: os.stat_result) -> str:
    return f"belongs to {user_text(st.st_uid)}, mode {stat.S_IMODE(st.st_mode):04o}"


def unlink_segment(name: str) -> bool:
    """Unlink a segment by POSIX name; False if it did not exist."""
    try:
        posix_ipc.unlink_shared_memory(name)
    except posix_ipc.ExistentialError:
        return False
    return True
