"""The shared-memory arena: one POSIX segment per instance (thesis 3.6.1, DESIGN section 2).

Layout: a versioned header, a directory of block descriptors kept as a doubly linked list in
address order (the thesis's "master list"), then the heap.  ``shmalloc(key, size)`` returns
the existing block when the key exists, else allocates first-fit and splits;
``shfree(key)`` returns the block and coalesces it with free neighbours.  The directory is
guarded by a test-and-set spinlock in the header.  Only offsets are stored; ``address`` is
the one place an offset becomes an address.

``kalictl start`` creates and ``kalictl stop`` unlinks the segment; everyone else attaches
and closes.  The segment is opened through ``posix_ipc`` and mapped with ``mmap``, so no
resource tracker ever unlinks it behind the owner's back (Python 3.11's
``multiprocessing.shared_memory`` would, when a non-owner exits).
"""

from __future__ import annotations

import mmap
import os
import pwd
import stat
import time
from dataclasses import dataclass

import numpy as np
import posix_ipc

from . import layout
from .errors import ArenaError, ArenaFullError
from .spinlock import SpinLock

SEGMENT_PREFIX = "/kali."


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
        try:
            shm = posix_ipc.SharedMemory(name)
        except posix_ipc.ExistentialError as exc:
            raise ArenaError(
                f"no instance '{instance}': {name} does not exist (is it started?)"
            ) from exc
        except posix_ipc.PermissionsError:
            raise ArenaError(
                f"instance '{instance}' is not yours: {name} {owner_text(name)}; "
                f"{user_text()} may not attach (Kali instances are owner-only)"
            ) from None
        try:
            if shm.size < layout.HEADER.itemsize:
                raise ArenaError(f"{name} is {shm.size} B, smaller than a header")
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
        """shmalloc a block for ``count`` records of ``dtype`` (or attach to it) and view it."""
        n = 1 if count is None else count
        return self.view(self.shmalloc(key, n * dtype.itemsize), dtype, count)

    def existing(self, key: str, dtype: np.dtype, count: int | None = None) -> np.ndarray:
        """View an existing block; ArenaError if the key is absent or the block too small."""
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
        d = self.directory
        i = int(self.header["head"])
        while i != layout.NULL_INDEX:
            if d[i]["used"] and d[i]["key"] == raw:
                return i
            i = int(d[i]["next"])
        return layout.NULL_INDEX

    def lookup(self, key: str) -> tuple[int, int] | None:
        """(offset, size) of the block named ``key``, or None."""
        raw = _key_bytes(key)
        with self._dir_lock:
            i = self._find(raw)
            if i == layout.NULL_INDEX:
                return None
            return int(self.directory[i]["offset"]), int(self.directory[i]["size"])

    def shmalloc(self, key: str, size: int) -> int:
        """Offset of block ``key``: the existing one, else a new first-fit block, zeroed."""
        raw = _key_bytes(key)
        if size <= 0:
            raise ArenaError(f"block '{key}': size {size} B, must be > 0")
        need = _round_up(size)
        d = self.directory
        with self._dir_lock:
            i = self._find(raw)
            if i != layout.NULL_INDEX:
                have = int(d[i]["requested"])
                if size > have:
                    raise ArenaError(f"block '{key}' exists with {have} B, {size} B requested")
                return int(d[i]["offset"])
            i = int(self.header["head"])
            while i != layout.NULL_INDEX and (d[i]["used"] or int(d[i]["size"]) < need):
                i = int(d[i]["next"])
            if i == layout.NULL_INDEX:
                s = self._stats_locked()
                raise ArenaFullError(
                    f"block '{key}' needs {need} B, {s.free_bytes} B free in "
                    f"{s.free_fragments} fragments (largest {s.largest_free} B)"
                )
            if int(d[i]["size"]) > need:
                self._split(i, need, key)
            d[i]["used"] = 1
            d[i]["key"] = raw
            d[i]["requested"] = size
            offset = int(d[i]["offset"])
            self._bytes[offset : offset + need] = 0
            return offset

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
            d[i]["used"] = 0
            d[i]["key"] = b""
            d[i]["requested"] = 0
            nxt = int(d[i]["next"])
            if nxt != layout.NULL_INDEX and not d[nxt]["used"]:
                self._absorb_next(i)
            prv = int(d[i]["prev"])
            if prv != layout.NULL_INDEX and not d[prv]["used"]:
                self._absorb_next(prv)

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

    def blocks(self) -> list[Block]:
        """Every block and free fragment in address order."""
        d = self.directory
        out: list[Block] = []
        with self._dir_lock:
            i = int(self.header["head"])
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

    def _stats_locked(self) -> ArenaStats:
        d = self.directory
        used = free = nused = nfree = largest = 0
        i = int(self.header["head"])
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
        heap = self.size - int(self.header["header_bytes"])
        return ArenaStats(heap, used, nused, free, nfree, largest)

    def stats(self) -> ArenaStats:
        """Occupancy and fragmentation of the heap."""
        with self._dir_lock:
            return self._stats_locked()


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
    return f"belongs to {user_text(st.st_uid)}, mode {stat.S_IMODE(st.st_mode):04o}"


def unlink_segment(name: str) -> bool:
    """Unlink a segment by POSIX name; False if it did not exist."""
    try:
        posix_ipc.unlink_shared_memory(name)
    except posix_ipc.ExistentialError:
        return False
    return True
