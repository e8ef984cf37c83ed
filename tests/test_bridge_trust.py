"""Issue 51 items 3-6, the bridge's: rate limits per client and kind, the e-stop's own path,
sessions that belong to their opener, Ctrl-C under ``kalictl run --remote``.  Real bridges
and real Zenoh clients on loopback, lockstep instances; programs are real subprocesses."""

from __future__ import annotations

import contextlib
import json
import select
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest
import zenoh

from kali_daemons.bridge.access import client_config
from kali_daemons.bridge.protocol import Keys
from kali_daemons.client import Kali

from . import test_bridge
from .test_bridge import bridge_edit, free_port

bridged = test_bridge.bridged  # its fixtures, here too
listener = test_bridge.listener

USERS = {"op": "op-secret", "op2": "op2-secret", "viewer": "viewer-secret"}
ESTOP_GOAL_S = 0.050  # an e-stop through the bridge reaches the arena within this


@pytest.fixture
def authenticated(kali: Callable[..., str], tmp_path: Path) -> Callable[..., tuple[str, str]]:
    """Start a lockstep instance whose bridge authenticates (operators op and op2, reader
    viewer), the other keys of its section as ``extra`` sets: (instance, endpoint)."""

    def start(extra: dict[str, str] | None = None) -> tuple[str, str]:
        users = tmp_path / "users.txt"
        users.write_text("".join(f"{u}:{p}\n" for u, p in USERS.items()))
        port = free_port()
        edits = {"users_file": str(users), "operators": "[op, op2]", "readers": "[viewer]"}
        name = kali(lockstep=True, edits=bridge_edit(port, {**edits, **(extra or {})}))
        return name, f"tcp/127.0.0.1:{port}"

    return start


def _line(proc: subprocess.Popen, stream: str = "stdout", timeout: float = 60.0) -> str:
    """The next line ``proc`` prints on ``stream`` (a pipe); AssertionError after ``timeout``."""
    pipe = getattr(proc, stream)
    ready, _, _ = select.select([pipe], [], [], timeout)
    assert ready, f"no {stream} from pid {proc.pid} within {timeout:g} s"
    return pipe.readline().strip()


def login(endpoint: str, user: str) -> zenoh.Session:
    return zenoh.open(client_config(endpoint, user, USERS[user]))


def answer(reply: zenoh.Reply) -> dict:
    return json.loads(reply.ok.payload.to_bytes())


def ask(session: zenoh.Session, key: str, value: object, timeout: float = 10.0) -> dict | None:
    """One query's answer as JSON; None when nothing answers (refused by access control)."""
    replies = list(session.get(key, payload=json.dumps(value).encode(), timeout=timeout))
    return answer(replies[0]) if replies else None


def test_a_readers_flood_never_gets_an_operators_estop_refused(
    authenticated: Callable[..., tuple[str, str]],
) -> None:
    """A reader sends 2,000 status queries a second, ten times its rate: its own are refused
    beyond the rate, and the operator's e-stop, status and verbs meanwhile are carried out
    (before: one gate for all, and the operator's e-stop was refused, "more than 200
    requests a second")."""
    name, endpoint = authenticated({"max_requests_per_s": "200"})
    keys = Keys(name)
    with (
        Kali.connect(endpoint, name, user="op", password=USERS["op"]) as op,
        flooding(endpoint, keys.user("viewer").status, {}, 2000, 3.0, "viewer") as flood,
    ):
        time.sleep(0.5)  # the reader's budget is spent
        said = op.verb("estop")
        assert said.startswith("e-stop pressed: left, right"), said
        assert op.status()["fault"]["active"]
        assert "released" in op.verb("estop", "--release")
    assert flood["refused for rate"] > 1000, flood


FLOODER = """
import json, sys, time, zenoh
from kali_daemons.bridge.access import client_config
endpoint, key, payload, rate, seconds, *login = sys.argv[1:]
s = zenoh.open(client_config(endpoint, *login) if login else client_config(endpoint))
answers = []
print("flooding", flush=True)
t0 = time.monotonic()
sent = 0
while (now := time.monotonic() - t0) < float(seconds):
    while sent < now * float(rate):
        s.get(key, lambda r: answers.append(json.loads(r.ok.payload.to_bytes())),
              payload=payload.encode(), timeout=60.0)
        sent += 1
    time.sleep(0.001)
errors = [a["error"]["message"] for a in answers if "error" in a]
print(json.dumps({
    "sent": sent,
    "answered by the end": len(answers),
    "refused for rate": sum("requests a second" in m for m in errors),
    "refused, others": len(errors) - sum("requests a second" in m for m in errors),
}), flush=True)
s.close()
"""


@contextlib.contextmanager
def flooding(
    endpoint: str, key: str, value: object, rate: float, seconds: float, user: str | None = None
) -> Iterator[dict]:
    """A client process sending queries ``key`` with ``value`` at ``rate`` a second for
    ``seconds`` (as ``user``), started when the block starts; its figures when it ends."""
    login = [user, USERS[user]] if user else []
    args = [endpoint, key, json.dumps(value), str(rate), str(seconds), *login]
    proc = subprocess.Popen(
        [sys.executable, "-c", FLOODER, *args], stdout=subprocess.PIPE, text=True
    )
    figures: dict = {}
    try:
        assert _line(proc) == "flooding"
        yield figures
        figures.update(json.loads(proc.communicate(timeout=120)[0]))
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
