"""The four inter-process channel types of thesis 3.2.1, all living in the arena by key.

1. :class:`RequestQueue` (Type 1): asynchronous producers → one synchronous consumer.
2. :class:`InterpolatingFifo` (Type 2): TG set-points → SIO, interpolated (thesis 2.2.2).
3. :class:`Flag` / :class:`FlagArray` (Type 3): test-and-set flags holding the setter's pid.
4. :class:`Record` (Type 4): a plain record with no synchronisation.

Creator and attacher run the same constructor, ``(arena, key, ...)`` through
``Arena.record``: the creator fixes the geometry, and an attacher asking for another gets a
:class:`ChannelError`.  Consumers never trust what another process wrote (DESIGN 7).  "Safe
in a cycle" below means: no array allocation, no I/O, no logging.  The counters and the
consumers' checks: docs/internals/arena.md, docs/internals/sio-viewer-core.md.

One module on purpose: the four channel types of thesis 3.2.1 side by side, sharing the arena's
creator/attacher handshake.
"""

from __future__ import annotations

import math
import os
import threading
import time
from collections.abc import Mapping
from fractions import Fraction
from typing import TYPE_CHECKING

import numpy as np

from . import atomic, layout
from .arena import Arena
from .errors import ArenaError, ChannelError, QueueFullError
from .kernels import Kernel
from .spinlock import SpinLock

if TYPE_CHECKING:
    from .kernels import Kernel

_INITIALISING = 0xFFFFFFFF  # FIFO capacity word while its creator writes the geometry
_INIT_TIMEOUT_S = 2.0
_U32_MAX = 0xFFFFFFFE


def _block_offset(arena: Arena, key: str) -> int:
    found = arena.lookup(key)
    if found is None:  # pragma: no cover - record() just created it
        raise ArenaError(f"{arena.name}: no block '{key}'")
    return found[0]


def _existing_bytes(arena: Arena, key: str) -> int | None:
    """Bytes the block ``key`` was requested with, or None if it does not exist."""
    for block in arena.blocks():
        if block.used and block.key == key:
            return block.requested
    return None


def _mismatch(kind: str, key: str, field: str, existing: object, requested: object) -> ChannelError:
    return ChannelError(
        f"{kind} '{key}' exists with {field} {existing}, attach asked for {requested}"
    )


def _check_capacity(kind: str, key: str, capacity: int) -> int:
    if isinstance(capacity, bool) or not isinstance(capacity, int | np.integer):
        raise ChannelError(f"{kind} '{key}': capacity {capacity!r} is not an integer")
    if not 1 <= int(capacity) <= _U32_MAX:
        raise ChannelError(f"{kind} '{key}': capacity {capacity}, allowed 1..{_U32_MAX}")
    return int(capacity)


# --------------------------------------------------------------------------------------------
# Type 1


class RequestQueue:
    """Bounded multi-producer, single-consumer queue of ``payload`` records (Type 1).

    Block ``key`` holds a ``layout.QUEUE_HEADER``; block ``key + ".slots"`` holds ``capacity``
    ``layout.queue_entry(payload)`` entries.  Each entry carries a sequence number, starting at
    1 and strictly increasing in the order entries were accepted: its place in the queue + 1
    (the tail it was written at + 1), which is how the consumer knows an entry was written for
    the place it reads.  A full queue refuses the entry (:class:`QueueFullError`) and
    overwrites nothing.  With ``share=(field, n)``, producers are told apart by a payload
    field (the TG's queue: the client's pid) and each may hold at most ``n`` unread entries,
    so one producer flooding it cannot keep the others out.
    """

    def __init__(
        self,
        arena: Arena,
        key: str,
        payload: np.dtype,
        capacity: int,
        share: tuple[str, int] | None = None,
    ) -> None:
        """Create or attach (outside the cycle: takes the directory and producers' locks)."""
        self.key = key
        self.payload = np.dtype(payload)
        if self.payload.fields is None:  # as names: None for an unstructured dtype
            raise ChannelError(f"queue '{key}': payload must be a structured dtype")
        cap = _check_capacity("queue", key, capacity)
        self._h = arena.record(key, layout.QUEUE_HEADER)
        off = _block_offset(arena, key)
        qh = layout.QUEUE_HEADER
        self._lock = SpinLock(arena.address_of_field(off, qh, "lock"), f"queue {key}")
        self._head_addr = arena.address_of_field(off, qh, "head")
        self._tail_addr = arena.address_of_field(off, qh, "tail")
        with self._lock:
            have = int(self._h["capacity"])
            if have == 0:
                self._h["entry_bytes"] = self.payload.itemsize
                self._h["next_seq"] = 1
                self._h["capacity"] = cap
            else:
                if have != cap:
                    raise _mismatch("queue", key, "capacity", have, cap)
                have_bytes = int(self._h["entry_bytes"])
                if have_bytes != self.payload.itemsize:
                    raise _mismatch("queue", key, "entry_bytes", have_bytes, self.payload.itemsize)
        self._capacity = cap
        if share is not None and (share[0] not in self.payload.fields or not 0 < share[1] <= cap):
            raise ChannelError(f"queue '{key}': share {share!r}: a payload field and 1..{cap}")
        self._share = share
        self._slots = arena.record(key + ".slots", layout.queue_entry(self.payload), cap)
        self._seqs = self._slots["seq"]
        payloads = self._slots["payload"]
        self._cells = [payloads[i : i + 1].reshape(()) for i in range(cap)]  # 0-d views
        # a put's validated copy, one per producing thread (a program and its periodic
        # function, Kali.control, may both put through one object)
        self._local = threading.local()
        self._local.staging = np.zeros((), dtype=self.payload)
        # the consumer's own head: the arena's copy is published for producers, never read
        # back, so a write to it from outside cannot make the consumer replay old entries
        self._next = atomic.load64(self._head_addr)
        self._discarded = self._h["discarded"]

    # ---------------------------------------------------------------- producers

    def _staging(self) -> np.ndarray:
        """The calling thread's staging record (made on its first put)."""
        staging = getattr(self._local, "staging", None)
        if staging is None:
            staging = self._local.staging = np.zeros((), dtype=self.payload)
        return staging

    def _stage(self, values: Mapping[str, object] | np.void | np.ndarray) -> np.ndarray:
        """Validate ``values`` into the calling thread's staging record, and return it."""
        staging = self._staging()
        if isinstance(values, np.void | np.ndarray):
            if values.dtype != self.payload or values.size != 1:
                raise ChannelError(
                    f"queue '{self.key}': entry of dtype {values.dtype} shape "
                    f"{np.shape(values)}, expected one record of {self.payload}"
                )
            staging[...] = values.reshape(()) if isinstance(values, np.ndarray) else values
            return staging
        if not isinstance(values, Mapping):
            raise ChannelError(
                f"queue '{self.key}': entry must be a dict or a {self.payload} record, "
                f"not {type(values).__name__}"
            )
        names, fields = self.payload.names, self.payload.fields
        assert names is not None and fields is not None  # a structured payload (__init__)
        for name in values:
            if name not in fields:
                raise ChannelError(
                    f"queue '{self.key}': unknown field {name!r}; fields are {', '.join(names)}"
                )
        for name in names:
            if name not in values:
                raise ChannelError(f"queue '{self.key}': field {name!r} missing")
            value = values[name]
            try:
                staging[name] = value
            except (ValueError, TypeError) as exc:
                ftype = fields[name][0]
                want = ftype.base if ftype.shape else ftype
                raise ChannelError(
                    f"queue '{self.key}': field {name!r} takes {want} of shape {ftype.shape}, "
                    # np.shape takes any object; numpy's stubs only an array-like
                    f"got {type(value).__name__} of shape {np.shape(value)} ({exc})"  # type: ignore[call-overload]
                ) from exc
        return staging

    def put(self, values: Mapping[str, object] | np.void | np.ndarray) -> int:
        """Append one entry and return its sequence number; QueueFullError when full.

        Validates first (unknown or missing fields, wrong shapes → ChannelError, nothing
        written), then writes under the producers' lock.  Allocation-light, meant for
        asynchronous producers; may wait on the lock, so not for the synchronous consumer.
        Threads may share the object: each stages its entry in its own buffer.
        """
        staged = self._stage(values)
        full = None
        with self._lock:
            tail = int(self._h["tail"])  # only lock holders write it
            head = atomic.load64(self._head_addr)
            mine = self._held(head, tail, staged)
            if tail - head >= self._capacity:
                self._h["rejected"] += 1
                full = (tail - head, int(self._seqs[head % self._capacity]))
            elif mine is not None:
                self._h["rejected"] += 1
            else:
                slot = tail % self._capacity
                seq = tail + 1  # from the place, never from next_seq: see the class doc
                np.copyto(self._cells[slot], staged)
                self._seqs[slot] = seq
                self._h["next_seq"] = seq + 1
                atomic.store64(self._tail_addr, tail + 1)  # publish after the slot is written
        if full is not None:
            raise QueueFullError(
                f"queue '{self.key}' full: {full[0]} of {self._capacity} entries unread "
                f"(oldest seq {full[1]}); entry refused, nothing overwritten"
            )
        if mine is not None:
            field, n = self._share  # type: ignore[misc]
            raise QueueFullError(
                f"queue '{self.key}': {field} {mine} already has {n} of its share of {n} "
                f"entries unread; entry refused until the consumer takes one"
            )
        return seq

    def _held(self, head: int, tail: int, staged: np.ndarray) -> object | None:
        """With a share: the ``staged`` entry's producer if it already holds its share of
        the unread entries [head, tail), else None.  Under the producers' lock."""
        if self._share is None or tail <= head:
            return None
        field, n = self._share
        places = np.arange(head, tail) % self._capacity
        who = staged[field]
        if np.count_nonzero(self._slots["payload"][field][places] == who) < n:
            return None
        return who.item()

    # ---------------------------------------------------------------- the consumer

    def get_into(self, out: np.ndarray) -> int | None:
        """Copy the oldest payload into ``out`` (a preallocated one-record array of ``payload``)
        and return its seq, or None when empty.  Single consumer; never locks; safe in a cycle.

        What only a writer outside the protocol can produce is dropped and counted in
        ``discarded``, never returned: an entry whose seq is not its place + 1 (a stale slot
        behind a forged tail, a torn or forged entry), and a tail behind the consumer's head
        or more than ``capacity`` ahead of it (the consumer then skips to the tail).
        """
        if out.dtype != self.payload or out.size != 1:
            raise ChannelError(
                f"queue '{self.key}': get_into needs one preallocated record of "
                f"{self.payload}, got dtype {out.dtype} shape {out.shape}"
            )
        for _ in range(self._capacity + 1):
            head = self._next
            tail = atomic.load64(self._tail_addr)
            if head == tail:
                return None
            if not 0 < tail - head <= self._capacity:  # no producer wrote this tail
                self._discarded[...] = int(self._discarded) + 1
                self._next = tail
                atomic.store64(self._head_addr, tail)
                return None
            slot = head % self._capacity
            np.copyto(out, self._cells[slot])
            seq = int(self._seqs[slot])
            self._next = head + 1
            atomic.store64(self._head_addr, head + 1)  # the slot may be reused from here on
            if seq == head + 1:
                return seq
            self._discarded[...] = int(self._discarded) + 1
        return None

    def next_seq(self) -> int | None:
        """The seq ``get_into`` returns next if the queue is as its producers wrote it, or
        None when empty: lets the consumer take an entry only once it can answer for it.
        Single consumer; never locks; safe in a cycle."""
        return None if self._next == atomic.load64(self._tail_addr) else self._next + 1

    def peek_seq(self) -> int | None:
        """Seq of the oldest unread entry, or None when empty.  Consumer; safe in a cycle."""
        head = atomic.load64(self._head_addr)
        if head == atomic.load64(self._tail_addr):
            return None
        return int(self._seqs[head % self._capacity])

    def put_seq(self) -> int:
        """The seq the next entry accepted will get (every entry put before has a lower
        one).  Any process; never locks."""
        return atomic.load64(self._tail_addr) + 1

    def __len__(self) -> int:
        """Entries unread (a snapshot).  Safe in a cycle."""
        head = atomic.load64(self._head_addr)
        return atomic.load64(self._tail_addr) - head

    @property
    def capacity(self) -> int:
        """Entries the queue holds."""
        return self._capacity

    @property
    def rejected(self) -> int:
        """Puts refused because the queue was full, since creation.  Safe in a cycle."""
        return int(self._h["rejected"])

    @property
    def discarded(self) -> int:
        """Entries the consumer dropped as not written by the protocol (``get_into``)."""
        return int(self._discarded)


# --------------------------------------------------------------------------------------------
# Type 2


def _ratio(key: str, ratio: Fraction | tuple[int, int] | int) -> Fraction:
    try:
        r = Fraction(*ratio) if isinstance(ratio, tuple) else Fraction(ratio)
    except (TypeError, ValueError, ZeroDivisionError) as exc:
        raise ChannelError(f"fifo '{key}': ratio {ratio!r} is not a fraction ({exc})") from exc
    if r < 1:
        raise ChannelError(
            f"fifo '{key}': ratio {r} (servo rate / TG rate) must be >= 1: the servo runs at "
            f"least as fast as the TG"
        )
    if r.numerator > _U32_MAX or r.denominator > _U32_MAX:
        raise ChannelError(f"fifo '{key}': ratio {r} has terms above {_U32_MAX}")
    return r


def _pack(r: Fraction) -> int:
    """``r`` as one u64 ratio word: numerator in the low 32 bits, denominator in the high."""
    return r.numerator | r.denominator << 32


class InterpolatingFifo:
    """Type 2 FIFO: set-points at the TG rate in, one linearly interpolated demand per servo
    tick out (thesis 2.2.2).  One producer (TG), one consumer (SIO).

    With r = servo rate / TG rate = ratio_num / ratio_den (>= 1):

    - The first set-point primes the FIFO: the first pop returns it exactly (A := P0) and the
      segment toward the next set-point starts after it.  ``reset(position)`` instead sets
      A = B = position with an empty ring; SIO calls it at start.
    - Segment j runs from A to B (B = the next set-point, taken when the previous segment
      ended) for n_j servo ticks, from an exact integer accumulator:
      ``acc += ratio_num; n_j = acc // ratio_den; acc %= ratio_den``.  For r = 5/2 segments
      last 2, 3, 2, 3, ... ticks (j segments take floor(j r) ticks); for integer r, r ticks.
    - Tick k = 1 .. n_j - 1 outputs A + k (B - A) / r, i.e. the thesis's increment (B - A)/r
      per tick, computed as A + ((B - A) * (k * ratio_den)) / ratio_num without drift.  Tick
      k = n_j outputs exactly B: the "remaining tail-end amount" of thesis 2.2.2.
    - If the ring is empty when a segment must start, the output holds at B (A := B) and
      ``underruns`` counts the tick; the next segment starts from B when a set-point arrives,
      with no catch-up jump.

    The ratio changes on line (``set_ratio``, when the TG's period changes).  Rule: every
    set-point is stamped, when pushed, with the ratio in force, and the segment ending at it
    lasts that ratio's ticks.  So a change applies exactly from the next set-point pushed and
    never to those already in the ring; two changes between the same two pushes replace each
    other (the last counts); changes with pushes between them each keep their own set-points.
    When the consumer takes a set-point stamped with another ratio it switches (its cache and
    the header's ``ratio_num``/``ratio_den``) and restarts the accumulator at 0: the change
    drops the fraction of a servo tick (< 1) a fractional ratio had accumulated.

    Blocks: ``key`` (``layout.FIFO_HEADER``), ``key + ".ring"`` (float64 ``(capacity, width)``),
    ``key + ".ratios"`` (u64 ``capacity``: each set-point's ratio word, see ``_pack``),
    ``key + ".rests"`` (u8 ``capacity``: 1 where a motion stops, its last set-point) and
    ``key + ".state"`` (float64 ``(3, width)``: current output, segment start A, target B)
    and ``key + ".hold"`` (float64 ``width``: the position of the latest ``reset``).
    All interpolation state is in the arena, so a restarted consumer resumes where it was.
    """

    def __init__(
        self,
        arena: Arena,
        key: str,
        width: int,
        capacity: int,
        ratio: Fraction | tuple[int, int],
        bound: float | None = None,
    ) -> None:
        """Create or attach (outside the cycle).

        The creator fixes ``ratio``; an attacher (a restarted SIO or TG, a user program)
        checks capacity and width but adopts the FIFO's ratios, which may have changed on
        line since: ``ratio`` need only be valid.  ``bound`` is this consumer's sanity limit:
        a set-point with a value not strictly within ±``bound`` (and any non-finite one,
        bound or not) is refused when taken (see ``pop_into``).
        """
        self.key = key
        cap = _check_capacity("fifo", key, capacity)
        if isinstance(width, bool) or not isinstance(width, int | np.integer) or width < 1:
            raise ChannelError(f"fifo '{key}': width {width!r}, must be an integer >= 1")
        width = int(width)
        r = _ratio(key, ratio)
        self._h = arena.record(key, layout.FIFO_HEADER)
        off = _block_offset(arena, key)
        fh = layout.FIFO_HEADER
        self._head_addr = arena.address_of_field(off, fh, "head")
        self._tail_addr = arena.address_of_field(off, fh, "tail")
        self._push_addr = arena.address_of_field(off, fh, "push_ratio")
        self._init_geometry(arena.address_of_field(off, fh, "capacity"), cap, width, r)
        self._capacity = cap
        self.width = width
        # The consumer's ratio, of the segment in progress: the header's, however it came.
        num, den = int(self._h["ratio_num"]), int(self._h["ratio_den"])
        self._num, self._den, self._num_f, self._stamp = num, den, float(num), num | den << 32
        ring = arena.record(key + ".ring", np.dtype("<f8"), cap * width).reshape(cap, width)
        self._rows = [ring[i] for i in range(cap)]
        self._stamps = arena.record(key + ".ratios", np.dtype("<u8"), cap)
        self._rests = arena.record(key + ".rests", np.dtype("u1"), cap)
        state = arena.record(key + ".state", np.dtype("<f8"), 3 * width).reshape(3, width)
        self._cur, self._start, self._target = state[0], state[1], state[2]
        self._hold = arena.record(key + ".hold", np.dtype("<f8"), width)
        self._resets_addr = arena.address_of_field(off, fh, "resets")
        self._hold_index = self._h["hold_index"]
        # Consumer-only header fields as 0-d views, and private scratch (never shared).
        h = self._h
        self._acc = h["phase_acc"]
        self._seg_ticks = h["seg_ticks"]
        self._seg_done = h["seg_done"]
        self._primed = h["primed"]
        self._underruns = h["underruns"]
        self._overflows = h["overflows"]
        self._scratch = np.empty(width)
        self._finite = np.empty(width, dtype=bool)
        if bound is not None and not (isinstance(bound, int | float) and bound > 0):
            raise ChannelError(f"fifo '{key}': bound {bound!r}, must be a number > 0 or None")
        self._bound = math.inf if bound is None else float(bound)
        self._rejected = h["rejected"]
        self._compiled = False  # popped by kali_fifo_pop (compiled_pop), not pop_into

    def _init_geometry(self, cap_addr: int, cap: int, width: int, r: Fraction) -> None:
        ok, seen = atomic.CompareExchange32()(cap_addr, 0, _INITIALISING)
        h = self._h
        if ok:  # this process creates: write the geometry, publish the capacity last
            h["width"] = width
            h["ratio_num"] = r.numerator
            h["ratio_den"] = r.denominator
            atomic.store64(self._push_addr, _pack(r))
            atomic.store32(cap_addr, cap)
            return
        deadline = time.monotonic() + _INIT_TIMEOUT_S
        while seen == _INITIALISING:
            if time.monotonic() > deadline:
                raise ChannelError(
                    f"fifo '{self.key}': creator did not finish writing the geometry "
                    f"within {_INIT_TIMEOUT_S:g} s"
                )
            time.sleep(1e-4)
            seen = atomic.load32(cap_addr)
        if seen != cap:
            raise _mismatch("fifo", self.key, "capacity", seen, cap)
        if int(h["width"]) != width:
            raise _mismatch("fifo", self.key, "width", int(h["width"]), width)

    def _check_vector(self, what: str, values: np.ndarray) -> np.ndarray:
        x = values if isinstance(values, np.ndarray) else np.asarray(values, dtype=np.float64)
        if x.shape != (self.width,):
            raise ChannelError(
                f"fifo '{self.key}': {what} of shape {x.shape}, expected ({self.width},)"
            )
        try:
            np.isfinite(x, out=self._finite)
        except TypeError as exc:
            raise ChannelError(f"fifo '{self.key}': {what} of dtype {x.dtype} ({exc})") from exc
        if not self._finite.all():
            bad = int(np.flatnonzero(~self._finite)[0])
            raise ChannelError(
                f"fifo '{self.key}': {what} component {bad} is {x[bad]}, must be finite; "
                f"nothing written"
            )
        return x

    # ---------------------------------------------------------------- the producer (TG)

    def push(self, setpoint: np.ndarray, rest: bool = False) -> None:
        """Append one set-point of ``width`` values, stamped with the ratio in force and
        ``rest`` (its motion stops there: the last one; ``rests_at``); ChannelError when full
        or not finite.

        Single producer.  Safe in a cycle when given a numeric ndarray (a list is converted).
        """
        x = self._check_vector("set-point", setpoint)
        tail = atomic.load64(self._tail_addr)
        if tail - atomic.load64(self._head_addr) >= self._capacity:
            self._overflows[...] = int(self._overflows) + 1
            raise ChannelError(
                f"fifo '{self.key}' full: {self._capacity} of {self._capacity} set-points "
                f"unread; set-point refused, nothing overwritten"
            )
        slot = tail % self._capacity
        np.copyto(self._rows[slot], x)
        self._stamps[slot] = atomic.load64(self._push_addr)
        self._rests[slot] = rest
        atomic.store64(self._tail_addr, tail + 1)  # publish after the row and stamps

    def set_ratio(self, ratio: Fraction | tuple[int, int] | int) -> None:
        """Interpolate the set-points pushed from now on with ``ratio`` (servo rate / TG
        rate, >= 1); those already in the ring keep theirs.  ChannelError if invalid.

        Producer, when the TG's period changes; safe in a cycle (no array allocation).
        """
        atomic.store64(self._push_addr, _pack(_ratio(self.key, ratio)))

    # ---------------------------------------------------------------- the consumer (SIO)

    def reset(self, position: np.ndarray) -> None:
        """Hold at ``position`` (A = B = position), dropping set-points not yet taken.

        Consumer, at start or after a halt; safe in a cycle when given a float ndarray.
        """
        x = self._check_vector("position", position)
        seq = atomic.load64(self._resets_addr)  # this consumer is its only writer
        atomic.store64(self._resets_addr, seq + 1)  # odd: being written
        tail = atomic.load64(self._tail_addr)
        self._hold_index[...] = tail
        np.copyto(self._hold, x)
        atomic.store64(self._resets_addr, seq + 2)
        atomic.store64(self._head_addr, tail)
        np.copyto(self._cur, x)
        np.copyto(self._start, x)
        np.copyto(self._target, x)
        self._acc[...] = 0
        self._seg_ticks[...] = 0
        self._seg_done[...] = 0
        self._primed[...] = 1

    def pop_into(self, out: np.ndarray) -> bool:
        """Write this servo tick's demand into ``out`` (preallocated float64, ``width``).

        Returns True when the output moved along a segment (or took the first set-point),
        False when holding.  Before the first set-point or ``reset`` nothing is known: ``out``
        is left unchanged, the tick counts as an underrun and False is returned.
        Single consumer; safe in a cycle.

        A set-point that is not finite or not within ±``bound`` (written by something other
        than ``push``) is refused and counted in ``rejected``: its segment holds at the
        previous target B, keeping its timing, so later set-points (and the feed-forward rows
        keyed by their index) stay where they belong.  A ratio stamp below 1 or with a zero
        term is refused the same way and the segment keeps the ratio in force.
        """
        assert not self._compiled, f"fifo '{self.key}' is popped by its kernel (compiled_pop)"
        done = int(self._seg_done)
        ticks = int(self._seg_ticks)
        if done >= ticks:  # the segment is over: take the next set-point, if any
            head = atomic.load64(self._head_addr)
            if head == atomic.load64(self._tail_addr):
                self._underruns[...] = int(self._underruns) + 1
                if not self._primed:
                    return False
                np.copyto(self._cur, self._target)
                np.copyto(out, self._cur)
                return False
            slot = head % self._capacity
            row = self._rows[slot]
            stamp = int(self._stamps[slot])
            if stamp != self._stamp:  # the set-point was pushed under another ratio
                self._switch(stamp)
            np.abs(row, out=self._scratch)
            np.less(self._scratch, self._bound, out=self._finite)  # False for NaN and inf
            good = bool(self._finite.all())
            if not good:
                self._rejected[...] = int(self._rejected) + 1
            if not self._primed:
                atomic.store64(self._head_addr, head + 1)
                if not good:
                    return False
                np.copyto(self._cur, row)
                np.copyto(self._start, row)
                np.copyto(self._target, row)
                self._primed[...] = 1
                np.copyto(out, self._cur)
                return True
            np.copyto(self._start, self._target)
            if good:
                np.copyto(self._target, row)
            atomic.store64(self._head_addr, head + 1)
            acc = int(self._acc) + self._num
            ticks = acc // self._den
            self._acc[...] = acc % self._den
            self._seg_ticks[...] = ticks
            done = 0
        done += 1
        self._seg_done[...] = done
        if done >= ticks:
            np.copyto(self._cur, self._target)  # the last tick lands exactly on B
        else:
            s = self._scratch
            np.subtract(self._target, self._start, out=s)
            np.multiply(s, float(done * self._den), out=s)
            np.divide(s, self._num_f, out=s)
            np.add(self._start, s, out=self._cur)
        np.copyto(out, self._cur)
        return True

    def compiled_pop(self, out: np.ndarray) -> Kernel:
        """``pop_into(out)`` compiled (``csrc/fifo.c``'s ``kali_fifo_pop``): each call of the
        returned kernel writes this servo tick's demand into ``out`` (float64, ``width``,
        never moving) and returns 1 or 0 as ``pop_into`` returns True or False.  The
        consumer's ratio moves into the kernel, so from here on this FIFO is popped only by
        it (``pop_into`` refuses).  Consumer, outside the cycle."""
        assert out.dtype == np.float64 and out.shape == (self.width,), (out.dtype, out.shape)
        h = self._h
        ring = self._rows[0]
        assert all(
            r.ctypes.data == ring.ctypes.data + i * 8 * self.width for i, r in enumerate(self._rows)
        )
        kernel = Kernel(
            "kali_fifo_pop",
            (h, self._rows, self._stamps, self._cur, self._start, self._target),
            n=self.width,
            head=self._head_addr,
            tail=self._tail_addr,
            ring=ring.ctypes.data,
            stamps=self._stamps.ctypes.data,
            capacity=self._capacity,
            bound=self._bound,
            **{
                f: a.ctypes.data
                for f, a in (
                    ("cur", self._cur),
                    ("start", self._start),
                    ("target", self._target),
                    ("seg_ticks", self._seg_ticks),
                    ("seg_done", self._seg_done),
                    ("primed", self._primed),
                    ("rejected", self._rejected),
                    ("ratio_num", h["ratio_num"]),
                    ("ratio_den", h["ratio_den"]),
                    ("underruns", self._underruns),
                    ("phase_acc", self._acc),
                )
            },
            out=out,
            num=self._num,
            den=self._den,
            stamp=self._stamp,
        )
        self._compiled = True  # once bound: a binding that failed leaves pop_into to it
        return kernel

    def _switch(self, stamp: int) -> None:
        """Interpolate from now on with the ratio word ``stamp`` (consumer; in the cycle);
        a word no ``set_ratio`` writes (a zero term, a ratio below 1) is refused, counted."""
        num, den = stamp & 0xFFFFFFFF, stamp >> 32
        if not 1 <= den <= num:
            self._rejected[...] = int(self._rejected) + 1
            return
        self._num, self._den, self._num_f, self._stamp = num, den, float(num), stamp
        self._h["ratio_num"] = num
        self._h["ratio_den"] = den
        self._acc[...] = 0

    def target_index(self) -> int:
        """Index (0 = the first ever pushed) of the set-point the output moves to or holds:
        the last one taken, -1 before any.  After ``reset`` the output holds at the position
        it was given, not at that set-point.  Consumer; safe in a cycle."""
        return atomic.load64(self._head_addr) - 1

    def progress(self) -> float:
        """How far the output is along its segment, 0 < p <= 1 (1 when holding).  Consumer;
        safe in a cycle."""
        ticks = int(self._seg_ticks)
        done = int(self._seg_done)
        return done / ticks if 0 < done < ticks else 1.0

    def segment_addresses(self) -> tuple[int, int, int]:
        """The addresses of what ``target_index`` and ``progress`` read (the header's
        ``head``, u64, and ``seg_ticks``, ``seg_done``, u32), for a compiled reader on the
        consumer's side (``RobotFeedforward.compiled``)."""
        return self._head_addr, self._seg_ticks.ctypes.data, self._seg_done.ctypes.data

    # ---------------------------------------------------------------- observers (dynamics)

    def indices(self) -> tuple[int, int]:
        """(head, tail): the next set-point to take and the next to be pushed (a snapshot)."""
        head = atomic.load64(self._head_addr)
        return head, atomic.load64(self._tail_addr)

    def read(self, index: int, out: np.ndarray) -> bool:
        """Copy set-point ``index`` into ``out`` if it is still in the ring (pushed, and not
        yet overwritten by later pushes, also after the copy); False otherwise.  Any reader,
        without locking: a row is never written again until the ring wraps past it."""
        tail = atomic.load64(self._tail_addr)
        if index < 0 or index >= tail or index < tail - self._capacity:
            return False
        np.copyto(out, self._rows[index % self._capacity])
        return index >= atomic.load64(self._tail_addr) - self._capacity

    def ratio_of(self, index: int) -> float:
        """The ratio (servo ticks per TG period) set-point ``index`` was stamped with, i.e.
        the servo ticks of the segment that ends at it; meaningful while it is in the ring."""
        word = int(self._stamps[index % self._capacity])
        return (word & 0xFFFFFFFF) / (word >> 32) if word >> 32 else 1.0

    def rests_at(self, index: int) -> bool:
        """True if set-point ``index`` was pushed as the last of its motion (the demand stops
        there); meaningful while it is in the ring."""
        return bool(self._rests[index % self._capacity])

    def held_before(self, index: int, out: np.ndarray) -> bool:
        """If set-point ``index`` is the first pushed after the consumer's latest ``reset``,
        copy the position that reset held into ``out`` (the set-point's predecessor) and
        return True; False otherwise, or while a reset is being written.  Any reader, without
        locking (``resets`` is a sequence lock)."""
        seq = atomic.load64(self._resets_addr)
        if seq == 0 or seq & 1 or int(self._hold_index) != index:
            return False
        np.copyto(out, self._hold)
        return atomic.load64(self._resets_addr) == seq

    def held(self, out: np.ndarray) -> None:
        """Copy the segment's target B, where the output ends or holds, into ``out``."""
        np.copyto(out, self._target)

    def pending(self) -> int:
        """Set-points pushed and not yet taken (a snapshot).  Safe in a cycle."""
        head = atomic.load64(self._head_addr)
        return atomic.load64(self._tail_addr) - head

    @property
    def capacity(self) -> int:
        """Set-points the ring holds."""
        return self._capacity

    @property
    def ratio(self) -> Fraction:
        """The ratio the next set-point pushed is stamped with (outside the cycle)."""
        word = atomic.load64(self._push_addr)
        return Fraction(word & 0xFFFFFFFF, word >> 32)

    @property
    def segment_ratio(self) -> Fraction:
        """The ratio of the segment the consumer is in (outside the cycle)."""
        return Fraction(int(self._h["ratio_num"]), int(self._h["ratio_den"]))

    @property
    def underruns(self) -> int:
        """Servo ticks that found no set-point to move to.  Safe in a cycle."""
        return int(self._underruns)

    @property
    def overflows(self) -> int:
        """Pushes refused because the ring was full.  Safe in a cycle."""
        return int(self._overflows)

    @property
    def rejected(self) -> int:
        """Set-points and ratio stamps the consumer refused as garbage (``pop_into``)."""
        return int(self._rejected)


# --------------------------------------------------------------------------------------------
# Type 3


class FlagArray:
    """``count`` Type 3 test-and-set flags (``layout.FLAG``), e.g. SV dynamic-loading slots.

    A flag word is 0 when clear, else the pid of the process that set it.  Setting is one
    atomic compare-exchange 0 → pid, so a failed attempt never overwrites the holder's pid.
    """

    def __init__(self, arena: Arena, key: str, count: int) -> None:
        """Create or attach (outside the cycle)."""
        self.key = key
        if isinstance(count, bool) or not isinstance(count, int | np.integer) or count < 1:
            raise ChannelError(f"flags '{key}': count {count!r}, must be an integer >= 1")
        count = int(count)
        have = _existing_bytes(arena, key)
        if have is not None and have != count * layout.FLAG.itemsize:
            raise _mismatch("flags", key, "count", have // layout.FLAG.itemsize, count)
        self._words = arena.record(key, layout.FLAG, count)
        off = _block_offset(arena, key)
        self._addrs = [arena.address_of_field(off, layout.FLAG, "word", i) for i in range(count)]
        self._cas = atomic.CompareExchange32()

    def _addr(self, index: int) -> int:
        if not 0 <= index < len(self._addrs):
            raise ChannelError(f"flags '{self.key}': index {index}, allowed 0..{len(self) - 1}")
        return self._addrs[index]

    def test_and_set(self, index: int) -> bool:
        """Set flag ``index`` to this pid if it is clear; True if this call set it.
        Safe in a cycle."""
        ok, _ = self._cas(self._addr(index), 0, os.getpid())
        return ok

    def clear(self, index: int) -> None:
        """Clear flag ``index``, whoever set it (the inspector may clear).  Safe in a cycle."""
        atomic.store32(self._addr(index), 0)

    def is_set(self, index: int) -> bool:
        """True if flag ``index`` is set.  Safe in a cycle."""
        return atomic.load32(self._addr(index)) != 0

    def holder(self, index: int) -> int:
        """Pid that set flag ``index``, 0 if clear.  Safe in a cycle."""
        return atomic.load32(self._addr(index))

    def __len__(self) -> int:
        return len(self._addrs)


class Flag:
    """One Type 3 test-and-set flag (a :class:`FlagArray` of one)."""

    def __init__(self, arena: Arena, key: str) -> None:
        """Create or attach (outside the cycle)."""
        self.key = key
        self._flags = FlagArray(arena, key, 1)

    def test_and_set(self) -> bool:
        """Set the flag to this pid if it is clear; True if this call set it.  Safe in a cycle."""
        return self._flags.test_and_set(0)

    def clear(self) -> None:
        """Clear the flag, whoever set it.  Safe in a cycle."""
        self._flags.clear(0)

    def is_set(self) -> bool:
        """True if the flag is set.  Safe in a cycle."""
        return self._flags.is_set(0)

    def holder(self) -> int:
        """Pid that set the flag, 0 if clear.  Safe in a cycle."""
        return self._flags.holder(0)


# --------------------------------------------------------------------------------------------
# Type 4


class Record:
    """Type 4: ``count`` records of ``dtype`` (one 0-d record when None), no synchronisation.

    One writer, any number of readers; a reader may see a record half-updated (torn between
    fields), so use it for data like what the viewer shows, never for hand-offs.  ``data`` is
    the numpy view in the arena: reading and writing it is safe in a cycle.  Only the size is
    checked on attach: a different dtype of the same size cannot be detected.
    """

    def __init__(self, arena: Arena, key: str, dtype: np.dtype, count: int | None = None) -> None:
        """Create or attach (outside the cycle)."""
        self.key = key
        self.dtype = np.dtype(dtype)
        if count is not None and (isinstance(count, bool) or count < 1):
            raise ChannelError(f"record '{key}': count {count!r}, must be >= 1 or None")
        nbytes = (1 if count is None else int(count)) * self.dtype.itemsize
        have = _existing_bytes(arena, key)
        if have is not None and have != nbytes:
            raise _mismatch("record", key, "size", f"{have} B", f"{nbytes} B")
        self.data: np.ndarray = arena.record(key, self.dtype, count)
