"""How the bridge admits requests: rate limits per user and kind, and bounded
queues per user served in turn.

A request is counted against its user's rate for its kind (``Gates``) on the Zenoh thread
that delivers it, and refused unread beyond it; then it waits its turn on one of the
bridge's threads (``Turns``), at most ``MAX_WAITING`` of one user's at once, each user's in
the order sent and the users taken round robin.  So a user's flood delays that user's own
requests; anyone else's wait for at most one of its requests per turn.  The e-stop takes
neither path: the bridge presses it on the Zenoh thread at once (``daemon.Bridge``).
"""

from __future__ import annotations

import collections
import threading
import time
from collections.abc import Callable

MAX_GATES = 256  # rate-limit buckets (user, kind) kept at once
MAX_WAITING = 16  # one user's requests waiting on one of the bridge's threads


class Gates:
    """At most ``rate`` requests a second per user and kind of request (a token bucket of one
    second's each): beyond it a request is refused before anything reads it, so a flood costs
    the bridge little CPU and another user's requests, or this user's of another kind, never
    notice it.  A bucket that has filled up again is forgotten; at most ``limit`` are kept
    (without authentication a client names itself, and made-up names must not grow them
    without bound): while that many users are busy, a new one is refused."""

    def __init__(self, rate: int, limit: int = MAX_GATES) -> None:
        self.rate = float(rate)
        self.limit = limit
        self.buckets: dict[tuple[str, str], list[float]] = {}  # (user, kind) -> [tokens, time]
        self.lock = threading.Lock()

    def admit(self, user: str, kind: str) -> str | None:
        """None if ``user`` may make one more request of ``kind`` now, else why not."""
        with self.lock:
            now = time.monotonic()
            bucket = self.buckets.get((user, kind))
            if bucket is None:
                if len(self.buckets) >= self.limit:
                    self._forget_full(now)
                if len(self.buckets) >= self.limit:
                    return (
                        f"user {user!r}: {self.limit} users and kinds of request are busy "
                        f"at once; refused unread"
                    )
                bucket = self.buckets[(user, kind)] = [self.rate, now]
            tokens = min(self.rate, bucket[0] + (now - bucket[1]) * self.rate)
            bucket[1] = now
            if tokens >= 1.0:
                bucket[0] = tokens - 1.0
                return None
            bucket[0] = tokens
            return (
                f"user {user!r}: more than {self.rate:g} requests a second of one kind ({kind}; "
                f"bridge.max_requests_per_s, per user and kind); refused unread"
            )

    def _forget_full(self, now: float) -> None:
        """Forget the buckets that have filled up again (their users quiet for a while)."""
        for key, (tokens, last) in list(self.buckets.items()):
            if tokens + (now - last) * self.rate >= self.rate:
                del self.buckets[key]


class Turns:
    """The jobs waiting for one of the bridge's threads (``what``: what they are, for the
    refusals), at most ``limit`` of each user's, taken each user's in order and the users in
    turn.  ``close`` takes no more; ``get`` gives the jobs still waiting, then None."""

    def __init__(self, what: str, limit: int = MAX_WAITING) -> None:
        self.what = what
        self.limit = limit
        self.jobs: dict[str, collections.deque[Callable[[], object]]] = {}
        self.turn: collections.deque[str] = collections.deque()  # users with jobs, in turn
        self.closed = False
        self.ready = threading.Condition()

    def put(self, user: str, job: Callable[[], object]) -> str | None:
        """Queue ``job`` of ``user``: None, or why it was refused (nothing queued)."""
        with self.ready:
            if self.closed:
                return f"{self.what}: the bridge takes no more (closing)"
            waiting = self.jobs.setdefault(user, collections.deque())
            if len(waiting) >= self.limit:
                return (
                    f"user {user!r}: {len(waiting)} of its {self.what} wait already (at most "
                    f"{self.limit} a user); refused unread"
                )
            if not waiting:
                self.turn.append(user)
            waiting.append(job)
            self.ready.notify()
            return None

    def get(self) -> Callable[[], object] | None:
        """The next job, waiting for one; None once closed with none left."""
        with self.ready:
            while not self.turn:
                if self.closed:
                    return None
                self.ready.wait()
            user = self.turn.popleft()
            waiting = self.jobs[user]
            job = waiting.popleft()
            if waiting:
                self.turn.append(user)  # its next one after everyone else's
            else:
                del self.jobs[user]
            return job

    def close(self) -> None:
        with self.ready:
            self.closed = True
            self.ready.notify_all()
