"""A remote program's stand-in on the controller's machine.

    python -m kali_daemons.bridge.session --instance NAME --sid SID --program NAME [--force]
    python -m kali_daemons.bridge.session --instance NAME --helper

The bridge starts one per remote program's session.  It is a local client program like any
other: its ``Kali`` (its pid owns the arms the remote program moves, its name is the remote
program's) carries out that program's calls, one JSON line each on standard input, one answer
line each on the descriptor given as standard output.  Only ``protocol.METHODS`` can be
called, so a remote request meets every check a local one does.  The bridge's stops come on a
second pipe (``--control``), served by a thread of their own (``Stopper``), so a stop never
waits behind a call.  When the remote program disappears the bridge kills this process and
the cell treats the program as a local one that died.  ``--helper``: kalictl's verbs and the
status document instead (``Helper``).  The line formats: docs/internals/motion-client-bridge.md.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
from typing import Any

from ..client import protocol
from ..client.motion import Kali
from ..client.protocol import ATTRIBUTES, METHODS, PROPERTIES, BridgeError
from ..core.layout import PROGRAM_BYTES
from ..runtime.instance import Instance
from ..tools import introspect
from .sessions import run_verb

log = logging.getLogger("kali.bridge.session")
SETTLE_TG_PERIODS = 3  # a stop is done when the arms have been still this long


class Session:
    """The objects of one remote program's session (0: its ``Kali``) and its calls."""

    def __init__(self, kali: Kali) -> None:
        self.objects: dict[int, object] = {0: kali}
        self.ids: dict[int, int] = {id(kali): 0}  # id(object) -> its number
        self.next_id = 1

    def register(self, obj: object) -> dict[str, Any]:
        """``obj``'s tagged reference, numbered the first time it crosses."""
        oid = self.ids.get(id(obj))
        if oid is None:
            oid, self.next_id = self.next_id, self.next_id + 1
            self.objects[oid] = obj
            self.ids[id(obj)] = oid
        return {"__obj__": oid, "class": type(obj).__name__, "attrs": self.attrs(obj)}

    def attrs(self, obj: object) -> dict[str, Any]:
        """The plain attributes a proxy of ``obj`` holds (``protocol.ATTRIBUTES``)."""
        names = ATTRIBUTES.get(type(obj).__name__, ())
        return {n: protocol.encode(getattr(obj, n), self.register) for n in names}

    def resolve(self, oid: int, cls: str, attrs: dict[str, Any] | None = None) -> object:
        """The object numbered ``oid`` of this session, which must be a ``cls`` (the
        attributes a reference carries are the proxy's, not taken)."""
        obj = self.objects.get(oid)
        if obj is None or type(obj).__name__ != cls:
            raise BridgeError(f"no {cls} {oid} in this session")
        return obj

    def adopt(self, options: Any) -> dict[str, Any]:
        """A program takes up this session another opened for it (``kalictl run --remote``
        opens it, the program's ``Kali()`` adopts it): ``{"force": bool}`` as its ``Kali``
        asks; the Kali's reference."""
        force = options.get("force") if isinstance(options, dict) else None
        if not isinstance(force, bool):
            raise BridgeError(f"adopt takes {{force: true or false}}, not {options!r:.60}")
        kali = self.objects[0]
        assert isinstance(kali, Kali)
        kali.force = force
        return {"value": self.register(kali), "attrs": self.attrs(kali)}

    def drop(self, oids: list[Any]) -> None:
        """Forget objects the remote program no longer holds (a handle dropped releases its
        status record, as a local one's)."""
        for oid in oids:
            if isinstance(oid, int) and oid != 0:
                obj = self.objects.pop(oid, None)
                if obj is not None:
                    self.ids.pop(id(obj), None)

    def call(self, request: Any) -> dict[str, Any]:
        """Carry out one call; its value or its exception as a reply."""
        if not isinstance(request, dict):
            raise BridgeError("a call must be a JSON object")
        if "adopt" in request:
            return self.adopt(request["adopt"])
        self.drop(request.get("drop") or [])
        target = request.get("target", 0)
        if isinstance(target, bool) or not isinstance(target, int):
            raise BridgeError(f"target {target!r:.40} is not an object number")
        obj = self.objects.get(target)
        if obj is None:
            raise BridgeError(f"no object {target} in this session")
        cls = type(obj).__name__
        method: Any = request.get("method")  # a name only if PROPERTIES or METHODS has it
        args = protocol.decode(request.get("args") or [], self.resolve)
        kwargs = protocol.decode(request.get("kwargs") or {}, self.resolve)
        if not isinstance(args, list) or not isinstance(kwargs, dict):
            raise BridgeError("args must be a list and kwargs a mapping")
        if method in PROPERTIES.get(cls, ()):
            value = getattr(obj, method)
        elif method in METHODS.get(cls, ()):
            value = getattr(obj, method)(*args, **kwargs)
        else:
            allowed = ", ".join(sorted(METHODS.get(cls, set()) | PROPERTIES.get(cls, set())))
            raise BridgeError(
                f"{cls}.{method!s:.40} cannot be called from another machine; "
                f"a remote {cls} has: {allowed}"
            )
        return {"value": protocol.encode(value, self.register), "attrs": self.attrs(obj)}


class Stopper:
    """Stops the arms this worker's program owns, on the bridge's word (``kalictl run
    --remote``'s Ctrl-C), from a thread of its own with a ``Kali`` of its own: the same
    process, so the same arms, whatever the program's call on the main thread is doing (a
    wait, a ``together`` block being written).  Answers once they are at rest."""

    def __init__(self, instance: str) -> None:
        self.instance = instance
        self.kali: Kali | None = None

    def call(self, request: Any) -> dict[str, Any]:
        if not isinstance(request, dict) or not isinstance(request.get("timeout"), int | float):
            raise BridgeError("a stop request is {timeout: seconds}")
        return {"value": self.stop(float(request["timeout"]))}

    def stop(self, timeout: float) -> dict[str, Any]:
        """Stop every arm this process owns on its path, each motion it starts meanwhile too
        (a request the TG takes after the stop), until for ``SETTLE_TG_PERIODS`` TG periods
        none of them moves, or ``timeout`` s (wall time) pass; stepping the clock as a
        program's wait does in lockstep.  ``{"robots": [names stopped], "at_rest": bool,
        "halted": the fault or None, "waited_s": timeout}``."""
        if self.kali is None:
            self.kali = Kali(self.instance)
        kali = self.kali
        clock = kali.inst.clock
        cfg = kali.inst.config.clock
        settle = round(SETTLE_TG_PERIODS * cfg.tg_period_ms / cfg.base_tick_ms)
        pid, deadline = os.getpid(), time.monotonic() + timeout
        stopped: dict[int, int] = {}  # robot -> the motion stopped on it
        busy: dict[int, int] = {}  # robot -> the motion moving it
        quiet_since = int(clock["tick"])
        while (halted := kali.inst.fault_text()) is None:
            busy = {k: int(kali.tg_robots["busy_seq"][k]) for k in kali.owned_by(pid)}
            busy = {k: seq for k, seq in busy.items() if seq != 0}
            new = [k for k, seq in busy.items() if stopped.get(k) != seq]
            if new:
                kali.stop_robots(new)
                stopped.update((k, busy[k]) for k in new)
            if busy:
                quiet_since = int(clock["tick"])
            elif int(clock["tick"]) - quiet_since >= settle:
                break
            if time.monotonic() > deadline:
                break
            kali.pause()
        return {
            "robots": [kali.names[k] for k in sorted(stopped)],
            "at_rest": halted is not None or not busy,
            "halted": halted,
            "waited_s": timeout,
        }

    def close(self) -> None:
        if self.kali is not None:
            self.kali.close()


class Helper:
    """The bridge's helper process: kalictl's verbs (``sessions.run_verb``) and the status
    document, off the bridge's own process, where their Python would hold the interpreter
    lock for tens of milliseconds and delay the telemetry behind them."""

    def __init__(self, instance: str) -> None:
        self.instance = instance
        self.inst = Instance.attach(instance)

    def call(self, request: Any) -> dict[str, Any]:
        if not isinstance(request, dict):
            raise BridgeError("a helper request must be a JSON object")
        if request.get("status"):
            doc = introspect.snapshot(self.inst)
            return {"value": json.loads(json.dumps(doc, default=str))}
        return {"value": run_verb(self.instance, str(request.get("verb")), request.get("args"))}


def serve(session: Session | Helper, lines: Any, out: Any) -> None:
    """Answer every call line of ``lines`` on ``out`` until the input ends."""
    for line in lines:
        reply: dict[str, Any]
        rid = None
        try:
            request = protocol.loads(line, "call")
            rid = request.get("id") if isinstance(request, dict) else None
            reply = session.call(request)
        except Exception as exc:  # every refusal goes back to the remote program
            reply = protocol.error_reply(exc)
        reply["id"] = rid
        try:
            out.write(protocol.dumps(reply) + b"\n")
        except ValueError as exc:  # a value JSON cannot hold
            out.write(protocol.dumps({"id": rid, **protocol.error_reply(exc)}) + b"\n")
        out.flush()


def _control(stopper: Stopper, fds: str) -> threading.Thread:
    """Serve ``stopper`` on the control pipe ``fds`` ("IN,OUT", descriptors the bridge
    passed) from a thread of its own."""
    fd_in, fd_out = (int(fd) for fd in fds.split(","))
    lines, out = os.fdopen(fd_in, "rb"), os.fdopen(fd_out, "wb")
    thread = threading.Thread(target=serve, args=(stopper, lines, out), daemon=True)
    thread.start()
    return thread


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="kali_daemons.bridge.session")
    parser.add_argument("--instance", required=True)
    parser.add_argument("--helper", action="store_true", help="verbs and status, no program")
    parser.add_argument("--sid", default="")
    parser.add_argument("--program", default="remote")
    parser.add_argument("--force", action="store_true")
    parser.add_argument("--nice", type=int, default=0)
    parser.add_argument("--cpu", type=int, default=None)
    parser.add_argument("--control", default="", help="IN,OUT: the pipe of the bridge's stops")
    a = parser.parse_args(argv)
    os.nice(a.nice)  # below the bridge, on its CPU: a remote program never slows the cell
    if a.cpu is not None:
        os.sched_setaffinity(0, {a.cpu})
    logging.basicConfig(level=logging.INFO, stream=sys.stderr)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # close the Kali on the way out
    out = os.fdopen(os.dup(1), "wb")  # the answers; print() in the client code goes to stderr
    os.dup2(2, 1)
    if a.helper:
        helper = Helper(a.instance)
        try:
            out.write(protocol.dumps({"id": None, "value": None}) + b"\n")
            out.flush()
            serve(helper, sys.stdin.buffer, out)
        finally:
            helper.inst.close()
        return 0
    kali = Kali(a.instance, force=a.force)
    label = f"{a.program} (remote {a.sid[:8]})"
    kali.program = label.encode()[:PROGRAM_BYTES]
    session = Session(kali)
    stopper = Stopper(a.instance)
    if a.control:
        _control(stopper, a.control)
    try:
        out.write(protocol.dumps({"id": None, "value": session.register(kali)}) + b"\n")
        out.flush()
        serve(session, sys.stdin.buffer, out)
    finally:
        kali.close()
        stopper.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
