"""SIO's acknowledgement of the SVs whose servos are done (thesis 3.3.4: SIO and the SVs run
as one gang).

The SV that finishes a tick's last servo posts SIO's done semaphore, and SIO, above it on the
same CPU, preempts it at once to write the DACs: the SV's own acknowledgement waits behind
SIO's output.  On a tick SIO finishes just in time the clock would count that SV late though
its servos were long done (three such misses in a 30-minute soak, SIO on time in each).  So
once every fed servo is done, SIO acknowledges the tick for the SVs it can vouch for, before
its own; what is left of their cycle is bookkeeping.  For the SV on its CPU to take its feed
before that, SIO sleeps on the done semaphore right after feeding (computing feed-forward
first, sv.1 on the other CPU ran every servo while sv.0 waited, and sv.0, never fed in time,
missed alone in two soaks with SIO on time).

Whom it vouches for:

- an SV that took this tick's feed (``sv_fed_tick``, written before it claims any slot);
- an SV on SIO's own CPU that took the previous tick's feed.  Below SIO's priority it runs
  only while SIO sleeps on the done semaphore, right after feeding: a few µs of context switch
  before it takes the feed, in which the SV on the other CPU, polling, may run every servo
  (with the compiled units, two arms' in ~10 µs; or while SIO's vCPU pauses after a wake-up
  IPI, docs/decisions/sv-placement.md).  Its lateness is then SIO's CPU, not its own, and it
  was on time a tick ago.  SIO notes the tick it vouched for such an SV (its slot's
  ``vouched_tick``), and
  the clock, at the next tick, looks whether that SV is alive (``WallClock._died``, after the
  tick's signals, as for one that missed): a dead one halts with PROCESS_DIED as soon as if it
  had missed, within the two servo periods of the fault matrix.  A stalled one is not
  acknowledged the tick after, so the clock names it one tick later, within the serious
  tolerance.

An SV on another CPU that has not taken its feed is never vouched for: it has a CPU of its
own, and its lateness is its own (a stalled or dead one misses, and the clock names it).
Real time only: lockstep has no deadlines, and its clock counts one acknowledgement post per
process, so there every SV acknowledges for itself.
"""

from __future__ import annotations

import numpy as np


class GangAcknowledger:
    """Acknowledges a tick for the SVs SIO can vouch for; driven once a tick by SIO (and by
    a test) after every fed servo is done."""

    __slots__ = ("_ack", "_fed", "_gang", "_sig", "_vouched")

    def __init__(
        self,
        sv_fed_tick: np.ndarray,
        signal_tick: np.ndarray,
        ack_tick: np.ndarray,
        vouched_tick: np.ndarray,
        sv_slots: list[int],
        on_sio_cpu: list[bool],
    ) -> None:
        """``sv_fed_tick[k]``: the tick whose feed SV ``k`` took last; ``signal_tick``,
        ``ack_tick`` and ``vouched_tick``: the process records' per-slot words;
        ``sv_slots[k]``: SV ``k``'s slot; ``on_sio_cpu[k]``: whether SV ``k`` is bound to
        SIO's CPU."""
        if len(sv_slots) != len(on_sio_cpu):
            raise ValueError(f"sio gang: {len(sv_slots)} SV slots but {len(on_sio_cpu)} CPU flags")
        self._fed, self._sig, self._ack = sv_fed_tick, signal_tick, ack_tick
        self._vouched = vouched_tick
        # (SV number, its slot, how many ticks old its last feed may be)
        self._gang = [
            (k, slot, 1 if same else 0)
            for k, (slot, same) in enumerate(zip(sv_slots, on_sio_cpu, strict=True))
        ]

    def members(self) -> list[tuple[int, int, int]]:
        """(SV number, its slot, how many ticks old its last feed may be) for every SV it may
        vouch for: what SIO's compiled tick (``kali_sio_back``) steps as ``acknowledge``."""
        return list(self._gang)

    def acknowledge(self, tick: int) -> None:
        """Inside the cycle: every servo of ``tick`` is done; acknowledge it for each SV
        signalled for it that took its feed, or, on SIO's CPU, the previous tick's."""
        fed, sig, ack = self._fed, self._sig, self._ack
        for k, slot, lag in self._gang:
            if sig[slot] != tick:
                continue
            took = fed[k]
            if took == tick:
                ack[slot] = tick  # the same tick the SV itself writes when it gets the CPU
            elif took >= tick - lag:
                self._vouched[slot] = tick  # first: the clock then looks whether it lives
                ack[slot] = tick
