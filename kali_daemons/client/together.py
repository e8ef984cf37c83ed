"""Motion systems started together (thesis 3.1: a motion is specified by
"synchronization, destination, velocity, and force").

    with kali.together() as group:
        left.move_line(target_a, speed=0.05)     # queued with the group, not yet sent
        right.move_joints(q_b)
    group.wait()                                 # all of them; group.wait(any=True): the first

Requests made inside the block do not wait (``wait=True`` is not honoured there: nothing is
sent yet); leaving the block sends them at once, each marked with the group's id and size
(``MOTION_REQUEST.group``).  The TG plans (and checks) each as usual and starts them all on
one tick, once every one is planned and checked and its arms are free; if one is refused or
cancelled before they start, the others are refused with the reason and none moves.
"""

from __future__ import annotations

import itertools
import os
import time
from types import TracebackType
from typing import TYPE_CHECKING

import numpy as np

from ..core.errors import MotionError, QueueFullError
from ..core.layout import TERMINAL_STATES, MotionKind

if TYPE_CHECKING:
    from .handle import MotionHandle
    from .motion import Kali

_COUNT = itertools.count(1)  # this program's groups (the low 32 bits of a group's id)


class Together:
    """The requests of one ``with kali.together()`` block, and their handles."""

    def __init__(self, kali: Kali) -> None:
        self.kali = kali
        self.handles: list[MotionHandle] = []
        self._requests: list[np.ndarray] = []

    def __enter__(self) -> Together:
        if self.kali.grouping is not None:
            raise MotionError("together: already inside a together() block")
        self.kali.grouping = self
        return self

    def add(self, req: np.ndarray, handle: MotionHandle) -> None:
        """Keep a request made inside the block (``Kali._request``) until it ends."""
        self._requests.append(req)
        self.handles.append(handle)

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.kali.grouping = None
        if exc_type is not None:  # the block failed: nothing of it is sent
            return
        n = len(self._requests)
        group = ((os.getpid() & 0xFFFFFFFF) << 32 | next(_COUNT)) if n > 1 else 0
        sent: list[int] = []
        try:
            for req, handle in zip(self._requests, self.handles, strict=True):
                req["group"] = group
                req["group_size"] = n if group else 0
                handle.seq = self.kali.queue.put(req)
                sent.extend(handle.robots)
        except QueueFullError:
            if sent:  # a group missing members never starts: take back what was sent
                self.kali._order(MotionKind.ABORT, sorted(set(sent)))
            raise

    def wait(self, timeout: float | None = None, any: bool = False) -> MotionHandle | None:
        """Block until every motion of the group is over (``MotionHandle.wait`` each:
        MotionFailedError if one did not arrive), or with ``any`` until the first is (its
        handle).  TimeoutError after ``timeout`` s."""
        if any:
            deadline = None if timeout is None else time.monotonic() + timeout
            while True:
                for h in self.handles:
                    if h.state in TERMINAL_STATES:
                        return h
                if deadline is not None and time.monotonic() > deadline:
                    raise TimeoutError(f"together: no motion of the group over in {timeout:g} s")
                self.kali.pause()
        end = None if timeout is None else time.monotonic() + timeout
        for h in self.handles:
            h.wait(None if end is None else max(0.0, end - time.monotonic()))
        return None
