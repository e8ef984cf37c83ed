"""SIO's acknowledgement of the SVs whose servos are done (thesis 3.3.4: SIO and the SVs run
as one gang; docs/decisions/0008-sio-acknowledges-for-the-svs.md).

The SV that finishes a tick's last servo wakes SIO, which, above it on the same CPU, preempts
it at once: the SV's own acknowledgement would wait behind SIO's output.  Once every fed
servo is done, SIO acknowledges the tick, before its own, for the SVs it can vouch for:

- an SV that took this tick's feed (``sv_fed_tick``);
- an SV on SIO's own CPU that took the previous tick's feed: its lateness is SIO's CPU, not
  its own.  SIO notes the tick in its slot's ``vouched_tick``, and the clock checks at the
  next tick that the SV is alive (``WallClock._died``).

Never an SV on another CPU that has not taken its feed.  Real time only: in lockstep every SV
acknowledges for itself.  The reasoning in full: docs/internals/sio-viewer-core.md.
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
