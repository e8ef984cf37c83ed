"""A hostile client for the soak (issue 24): a robot program that floods the TG's request queue
beside the demo and checks that no outcome is lost.  Run it as a program is run:

    kalictl -i INSTANCE run scripts/soak_flood.py

It puts STOP requests for the demo's arms as fast as the queue takes them (a full queue
refuses with QueueFullError, and it waits for its oldest outstanding request), keeps up to
``OUTSTANDING`` requests in flight and waits for every one's outcome.  A stop moves nothing
and gives no ownership, so while the demo owns the arms each is refused naming the owner,
and between the demo's iterations it is done at once: the flood never takes an arm from the
demo.  Every handle must end (DONE, REFUSED or HALTED); one that reads LOST, or does not end
within ``WAIT_S``, is counted.  On Ctrl-C (``kalictl run`` sends SIGINT) or SIGTERM it stops
putting, waits for what is in flight, and prints its counts as one JSON line:
``{"requests": N, "done": N, "refused": N, "halted": N, "queue_full": N, "lost": N,
"unresolved": N}``; exit status 0 if nothing was lost or left unresolved.
"""

from __future__ import annotations

import collections
import json
import signal
import sys
import time

from kali_daemons.client import Kali, MotionFailedError
from kali_daemons.client.common import RequestLostError
from kali_daemons.client.handle import MotionHandle
from kali_daemons.core import layout
from kali_daemons.core.errors import QueueFullError
from kali_daemons.core.layout import MotionKind, RequestState

ROBOTS = ("left", "right")  # the arms the soak's demo moves
OUTSTANDING = layout.STATUS_SHARE  # requests in flight: the unread outcomes a program keeps
WAIT_S = 30.0  # longest one outcome may take (a TG tick is 10 ms)
FULL_PAUSE_S = 0.002  # after a refused put, before the next


def main() -> int:
    running = True

    def leave(_sig: int, _frame: object) -> None:
        nonlocal running
        running = False

    signal.signal(signal.SIGINT, leave)
    signal.signal(signal.SIGTERM, leave)
    counts = dict.fromkeys(
        ("requests", "done", "refused", "halted", "queue_full", "lost", "unresolved"), 0
    )
    flight: collections.deque[MotionHandle] = collections.deque()

    def settle(handle: MotionHandle) -> None:
        """Wait for one outcome and count it."""
        try:
            handle.wait(WAIT_S)
        except RequestLostError:
            counts["lost"] += 1
            return
        except MotionFailedError:
            pass  # refused, stopped or halted: the state says which
        except TimeoutError:
            counts["unresolved"] += 1
            return
        state = handle.state
        key = {RequestState.DONE: "done", RequestState.REFUSED: "refused"}.get(state, "halted")
        counts[key] += 1

    with Kali() as kali:
        arms = [kali.robot(name) for name in ROBOTS]
        k = 0
        while running and not kali.inst.shutting_down:
            if len(flight) >= OUTSTANDING:
                settle(flight.popleft())
                continue
            arm = arms[k % len(arms)]
            try:
                flight.append(kali._request(MotionKind.STOP, [arm.index]))
            except QueueFullError:
                counts["queue_full"] += 1
                if flight:
                    settle(flight.popleft())
                time.sleep(FULL_PAUSE_S)
                continue
            except MotionFailedError:  # halted: nothing is taken until reset
                time.sleep(0.1)
                continue
            counts["requests"] += 1
            k += 1
        while flight:
            settle(flight.popleft())
    print(json.dumps(counts), flush=True)
    return 0 if not (counts["lost"] or counts["unresolved"]) else 1


if __name__ == "__main__":
    sys.exit(main())
