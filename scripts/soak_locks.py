"""A hostile client for the soak (issue 24): it attaches to an instance and takes and releases
every one of the instance's arena locks in turn (the directory, the process table, the clock
command, the motion queue's producers, each servo mailbox), forever.  The soak stops and
continues it at random (SIGSTOP / SIGCONT), so now and then it sits stopped holding a lock,
as a program under a debugger or Ctrl-Z would: nothing on the safety path may wait for it.

It holds each lock for ``--hold-us`` (50) µs, then sleeps ``--gap-us`` (200) µs.  On SIGTERM
or SIGINT it releases what it holds and prints its counts as one JSON line:
``{"cycles": N, "taken": N, "busy": N}`` (busy: a lock another process held past its wait).

    .venv/bin/python scripts/soak_locks.py INSTANCE
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time

from kali_daemons.core.errors import LockError
from kali_daemons.core.spinlock import SpinLock
from kali_daemons.runtime.instance import Instance

WAIT_S = 0.05  # longest it waits for a lock someone else holds before it moves on


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("instance")
    ap.add_argument("--hold-us", type=float, default=50.0, help="µs each lock is held")
    ap.add_argument("--gap-us", type=float, default=200.0, help="µs between two locks")
    args = ap.parse_args(argv)
    running = True

    def leave(_sig: int, _frame: object) -> None:
        nonlocal running
        running = False

    signal.signal(signal.SIGTERM, leave)
    signal.signal(signal.SIGINT, leave)
    counts = {"cycles": 0, "taken": 0, "busy": 0}
    with Instance.attach(args.instance) as inst:
        locks = [SpinLock(addr, name) for name, addr in inst.lock_words()]
        print(json.dumps({"locks": [lock.name for lock in locks]}), flush=True)
        while running and not inst.shutting_down:
            for lock in locks:
                try:
                    lock.acquire(timeout=WAIT_S)
                except LockError:
                    counts["busy"] += 1
                    continue
                try:
                    time.sleep(args.hold_us / 1e6)
                finally:
                    lock.release()
                counts["taken"] += 1
                time.sleep(args.gap_us / 1e6)
                if not running:
                    break
            counts["cycles"] += 1
    print(json.dumps(counts), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
