"""Which status record of ``tg.status`` holds which request (thesis 3.3.2: a program waits on
its request's outcome).

The TG gives each request it takes a record of its own (``StatusRecords.allocate``) and a
program finds it by the request's sequence number (``find``).  A record is the TG's while its
request is queued or running, then its program's until it reads the outcome or drops the
handle, so one program's unread outcomes cost only that program (``layout.STATUS_SHARE``,
``layout.LIVE_SHARE``); a record whose request is queued or running is never taken.  Never a
record by seq modulo the ring: one unread record would block every later request of every
program.  ``write_status`` writes in the order a polling client can trust.  Outside the servo
cycle; the eviction order: docs/internals/motion-client-bridge.md.
"""

from __future__ import annotations

import numpy as np

from ..core import layout
from ..core.layout import RequestState
from ..core.spinlock import pid_alive

_ENDED = np.zeros(256, dtype=bool)  # by state word: the request has ended
_ENDED[[int(s) for s in layout.TERMINAL_STATES]] = True


def find(records: np.ndarray, seq: int) -> int:
    """The index of the record holding request ``seq``, or -1 (not taken yet, or its record
    given to another request since)."""
    if seq <= 0:
        return -1
    hits = np.flatnonzero(records["seq"] == seq)
    return int(hits[0]) if hits.size else -1


class StatusRecords:
    """The TG's side of ``tg.status``: which records its queued and running requests hold,
    and which record a new request gets."""

    def __init__(self, records: np.ndarray) -> None:
        self.records = records
        self._of: dict[int, int] = {}  # seq -> record, of every request the TG holds
        self._held = np.zeros(len(records), dtype=bool)
        self.evicted = 0  # unread outcomes that gave way (their handles read LOST)

    def index(self, seq: int) -> int:
        """The record of request ``seq``, which the TG holds."""
        return self._of[seq]

    def __getitem__(self, seq: int) -> np.void:
        record: np.void = self.records[self._of[seq]]
        return record

    def holds(self, seq: int) -> bool:
        return seq in self._of

    def live(self, pid: int) -> int:
        """Requests of program ``pid`` the TG holds (queued or running)."""
        return int(np.count_nonzero(self._held & (self.records["client_pid"] == pid)))

    def allocate(self, seq: int, pid: int) -> int | None:
        """A record for request ``seq`` of program ``pid``, now held by the TG; None when
        every record holds a request that is queued or running (the TG waits)."""
        i = self._choose(pid)
        if i is None:
            return None
        self._of[seq] = i
        self._held[i] = True
        return i

    def release(self, seq: int) -> None:
        """Request ``seq`` has ended: its record is its program's until read."""
        i = self._of.pop(seq, None)
        if i is not None:
            self._held[i] = False

    def clear(self) -> None:
        """Nothing is held (the TG starts)."""
        self._of.clear()
        self._held[:] = False

    def _choose(self, pid: int) -> int | None:
        r = self.records
        seqs, pids = r["seq"], r["client_pid"]
        ended = _ENDED[r["state"]]
        spare = ~self._held
        unread = spare & ended & (r["read"] == 0) & (seqs != 0)
        mine = unread & (pids == pid)
        if pid > 0 and np.count_nonzero(mine) >= layout.STATUS_SHARE:
            return self._oldest(mine, evict=True)  # its own oldest outcome gives way
        # never used, read, or not ended yet no request here holds it (written by another)
        free = spare & ((seqs == 0) | ~unread)
        found = np.flatnonzero(free)
        if found.size:
            return int(found[0])
        if not unread.any():
            return None
        for p in np.unique(pids[unread]):
            if not pid_alive(int(p)):  # a dead program's outcomes: nobody will read them
                return self._oldest(unread & (pids == p), evict=False)
        holders, counts = np.unique(pids[unread], return_counts=True)
        most = holders[int(np.argmax(counts))]
        return self._oldest(unread & (pids == most), evict=True)

    def _oldest(self, mask: np.ndarray, evict: bool) -> int:
        idx = np.flatnonzero(mask)
        self.evicted += int(evict)
        return int(idx[int(np.argmin(self.records["seq"][idx]))])


def holders(records: np.ndarray) -> dict[int, tuple[int, int]]:
    """Per program pid: (its requests queued or running, its unread outcomes), from the
    records as they are (``kalictl status``: who holds the records)."""
    state = records["state"]
    ended = _ENDED[state]
    used = records["seq"] != 0
    live = used & ~ended & (state != RequestState.FREE)
    unread = used & ended & (records["read"] == 0)
    out: dict[int, tuple[int, int]] = {}
    for p in np.unique(records["client_pid"][live | unread]):
        mine = records["client_pid"] == p
        out[int(p)] = (int(np.count_nonzero(live & mine)), int(np.count_nonzero(unread & mine)))
    return out


def write_status(rec: np.void, seq: int, state: RequestState, message: str = "") -> None:
    """Write request ``seq``'s state into its status record ``rec`` (``records``).

    A waiting client reads the seq, then the state, then the message, while this writes, so
    the state goes last, after its message; and a record given over from an earlier request
    first has that request's state withdrawn (FREE), before the new seq appears.  Else a
    client that polls early would see its seq with the old request's DONE and think its
    motion over before it began.
    """
    if int(rec["seq"]) != seq:
        rec["state"] = RequestState.FREE
        rec["duration_s"] = 0.0
        rec["progress"] = 0.0
        rec["read"] = 0
        rec["client_pid"] = 0
    rec["seq"] = seq
    rec["message"] = message.encode()[: layout.MESSAGE_BYTES]
    rec["state"] = state
