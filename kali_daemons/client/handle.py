"""A motion request's handle (``MotionHandle``): its state and message as the TG writes them in
its status record, waiting for its end, cancelling it (thesis 3.3.2).  The request protocol:
docs/internals/motion-client-bridge.md."""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from ..core import layout
from ..core.layout import TERMINAL_STATES, MotionKind, RequestState
from ..runtime.instance import decode
from ..tg import records
from ..tg.profiles import MotionError
from .common import (
    Contact,
    MotionFailedError,
    RequestLostError,
    _timeout_arg,
    fault_since,
)

if TYPE_CHECKING:
    from .motion import Kali


_ENDED = frozenset(int(s) for s in TERMINAL_STATES if s != RequestState.LOST)


class MotionHandle:
    """One request: ``done``, ``state``, ``wait(timeout)``, ``cancel()``."""

    def __init__(self, kali: Kali, seq: int, robots: list[int], epoch: int | None = None) -> None:
        self.kali = kali
        self.seq = seq
        self.robots = robots
        # the fault count when it was put (None: now); a fault counted after it halts it
        self.epoch = int(kali.inst.fault["count"]) if epoch is None else epoch
        self._final: tuple[RequestState, str] | None = None  # the TG's last word, once read
        self._contact: Contact | None = None  # where a guarded move touched, once read
        self._released = False  # the TG was told it may reuse the status record
        self._rec = -1  # its status record, once found (the TG gives it one: tg/records.py)

    def _record(self) -> np.void | None:
        """This request's status record, or None: not taken by the TG yet, or given to
        another request since."""
        status = self.kali.status
        if self._rec < 0:
            self._rec = records.find(status, self.seq)
            if self._rec < 0:
                return None
        rec = status[self._rec]
        return rec if int(rec["seq"]) == self.seq else None

    def _read(self) -> tuple[RequestState, str]:
        """(state, message) as the TG wrote them, or HALTED with the fault when one has been
        raised since the request was put and the TG has not ended it yet (the TG cannot tick
        while halted; the process raising the fault does not know the requests)."""
        if self._final is not None:
            return self._final
        if self.seq == 0:  # made in a together() block that has not ended
            return RequestState.QUEUED, "not sent yet: its together() block has not ended"
        # the TG writes a request's record, then counts it taken: read in the other order, so
        # a request it takes between the two reads is not taken for one whose record is gone
        taken = int(self.kali.tg_state["taken_seq"])
        rec = self._record()
        state = RequestState.QUEUED  # still in the queue, or taken and not yet written
        if rec is not None:
            raw = int(rec["state"])
            message = decode(rec["message"])  # the TG writes the message before the state
            if raw in _ENDED and int(rec["seq"]) == self.seq:
                if raw == RequestState.CONTACT:  # read before the record is released
                    k = int(rec["contact_robot"])
                    self._contact = Contact(
                        self.kali.names[k],
                        rec["contact_xyz"].copy(),
                        float(rec["contact_force"]),
                        rec["contact_wrench"].copy(),
                    )
                self._final = (RequestState(raw), message)
                self._release()
                return self._final
            if raw in (RequestState.QUEUED, RequestState.RUNNING):
                state = RequestState(raw)
        elif self._rec >= 0 or self.seq <= taken:
            self._final = (
                RequestState.LOST,
                f"its outcome was not kept: the TG gave its status record to another request "
                f"(a program keeps at most {layout.STATUS_SHARE} outcomes unread, and when "
                f"every record is needed the oldest unread ones give way); read outcomes "
                f"(handle.state, wait) or drop the handles",
            )
            return self._final
        fault = fault_since(self.kali.inst, self.epoch)
        if fault is not None:
            return RequestState.HALTED, f"halted: {fault}"
        return state, ""

    def _release(self) -> None:
        """Tell the TG this program is done with the status record (once, and only while the
        record still holds this request: the TG cannot have reused it before)."""
        if self._released or self.seq == 0:
            return
        self._released = True
        if self.kali.status is not None:
            rec = self._record()
            if rec is not None:
                rec["read"] = 1

    def __del__(self) -> None:
        try:
            self._release()  # nobody can read it any more
        except Exception:
            pass

    @property
    def state(self) -> RequestState:
        """Where the request is (QUEUED until the TG has taken it; HALTED at once on a halt;
        LOST if its record was reused)."""
        return self._read()[0]

    @property
    def message(self) -> str:
        """Why it was refused, stopped or halted ('' otherwise)."""
        return self._read()[1]

    @property
    def contact(self) -> Contact | None:
        """Where a guarded move touched (it ended CONTACT), else None."""
        self._read()
        return self._contact

    @property
    def limited(self) -> int:
        """A tracking motion's ticks so far whose target moved faster than its limits allow
        (rate-limited); 0 for other motions."""
        rec = self._record()
        return 0 if rec is None else int(rec["limited"])

    @property
    def done(self) -> bool:
        """True once the request is over, however it ended."""
        return self.state in TERMINAL_STATES

    def wait(self, timeout: float | None = None) -> None:
        """Block until the motion has arrived, or a guarded one touched (``contact`` says
        where); MotionFailedError if it ended any other way (refused, stopped, aborted,
        halted: the message says why), TimeoutError after ``timeout`` s."""
        timeout = _timeout_arg(f"wait: request {self.seq}", timeout)
        if self.seq == 0:
            raise MotionError("wait: the request is sent when its together() block ends")
        deadline = None if timeout is None else time.monotonic() + timeout
        inst = self.kali.inst
        while (state := self.state) not in TERMINAL_STATES:  # one read: judged as it was seen
            if inst.shutting_down:  # nothing is left to finish it, or to say so
                raise MotionFailedError(
                    f"request {self.seq} {state.name.lower()}: instance '{inst.name}' was "
                    f"stopped (kalictl stop)"
                )
            if deadline is not None and time.monotonic() > deadline:
                raise TimeoutError(
                    f"motion: request {self.seq} not done within {timeout:g} s "
                    f"({state.name.lower()})"
                )
            self.kali.pause()
        if state == RequestState.LOST:
            raise RequestLostError(f"request {self.seq} lost: {self.message}")
        if state not in (RequestState.DONE, RequestState.CONTACT):
            raise MotionFailedError(f"request {self.seq} {state.name.lower()}: {self.message}")

    def cancel(self) -> None:
        """Stop the motion smoothly on its path (a queued one never starts)."""
        self.kali._order(MotionKind.STOP, self.robots)
