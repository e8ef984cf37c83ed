"""The Zenoh bridge process (DESIGN 11): remote programs, telemetry and supervision, under
``kali/<instance>/`` (``protocol.Keys``).

Every deadline stays on the controller's machine.  The bridge is non-serious, SCHED_OTHER and
unlocked on its own CPU share (``bridge.cpu``), reads the arena as a Type 4 reader and never
takes a lock the servo level waits for: a bridge that dies or stalls leaves the cell running.
In real time it keeps its own clock, so it reports on after a halt; in lockstep the wall
clock steps it.  Requests arrive on Zenoh's threads: an e-stop is pressed there and then,
lock-free; every other request is counted against its user's rate and waits its user's turn
on one of the bridge's own threads (``admission``), so a Zenoh callback never waits and one
user's flood delays only that user.  Verbs and status run in the helper process
(``session.Helper``).  What it publishes and answers: docs/internals/motion-client-bridge.md.
"""

from __future__ import annotations

import contextlib
import threading
from collections.abc import Callable
from typing import Any

import zenoh
import zenoh.ext

from ..client import protocol
from ..client.protocol import BridgeError, Keys
from ..core.errors import DaemonError, KaliError
from ..hardware.camera import CameraRing, camera_index
from ..runtime.daemon import Daemon
from ..runtime.instance import estop_pressed, time_ms
from ..tools import launcher
from . import access
from .admission import Gates, Turns
from .sessions import Sessions, check_verb
from .streams import RemoteStreams
from .telemetry import Telemetry, Watch

JSON = zenoh.Encoding.APPLICATION_JSON
BYTES = zenoh.Encoding.APPLICATION_OCTET_STREAM
OWN = "bridge/"  # the bridge's own jobs wait their turns as users "bridge/...": no name has a /


class Bridge(Daemon):
    """The bridge process: non-serious, priority 0, on ``bridge.cpu``."""

    kind = "bridge"
    self_timed_in_realtime = True  # reports on after a halt has stopped the wall clock

    def __init__(self, instance: str, name: str, **kw: object) -> None:
        kw.setdefault("lock_memory", False)  # not real-time: Zenoh's buffers need no locking
        super().__init__(instance, name, **kw)  # type: ignore[arg-type]
        self.session: zenoh.Session | None = None
        self.threads: list[threading.Thread] = []
        self.queues: list[Turns] = []
        self.n_events = 0
        self.errors = 0
        self.refused = 0  # requests refused unread

    # ------------------------------------------------------------------ set-up

    def on_configure(self) -> None:
        inst = self.inst
        cfg = inst.config.bridge
        self.keys = keys = Keys(inst.name)
        self.telemetry = Telemetry(inst)
        self.watch = Watch(inst)
        self.every_timing = max(1, round(cfg.telemetry_hz / cfg.timing_hz))
        self.cycles = 0
        try:
            self.session = zenoh.open(access.bridge_config(cfg, inst.name))
        except zenoh.ZError as exc:
            raise DaemonError(
                f"{self.name}: cannot listen on {', '.join(cfg.listen)}: {exc}"
            ) from None
        s = self.session
        self.state_pubs = [
            s.declare_publisher(
                keys.state(name), encoding=JSON, congestion_control=zenoh.CongestionControl.DROP
            )
            for name in self.telemetry.names
        ]
        self.timing_pub = s.declare_publisher(
            keys.timing, encoding=JSON, congestion_control=zenoh.CongestionControl.DROP
        )
        self.event_pub = zenoh.ext.declare_advanced_publisher(
            s,
            keys.events,
            encoding=JSON,
            cache=zenoh.ext.CacheConfig(max_samples=cfg.event_history),
            # zenoh's stubs require sporadic_heartbeat too; it defaults to None
            sample_miss_detection=zenoh.ext.MissDetectionConfig(heartbeat=0.5),  # type: ignore[call-arg]
            publisher_detection=True,
        )
        log_dir = str(launcher.log_dir(inst.name))
        self.sessions = Sessions(inst.name, cfg.max_sessions, cfg.cpu, log_dir)
        self.gates = Gates(cfg.max_requests_per_s)
        self.streams = RemoteStreams(inst)
        reads, sessions = "status and config requests", "session opens and closes"
        self.reads = self._worker("bridge-reads", reads)
        self.verbs = self._worker("bridge-verbs", "verbs")
        self.admin = self._worker("bridge-sessions", sessions)
        frames = "camera frames"
        self.frames = self._worker("bridge-cameras", frames)
        self.rings: dict[str, CameraRing] = {}
        self.stops = self._worker("bridge-stops", "session stops")
        self.admin.put(OWN + "helper", self.sessions.start_helper)  # ready before the first verb
        self.session_queues: dict[str, Turns] = {}
        self.queryables = [
            s.declare_queryable(keys.status, self._gated(reads, self.reads, self._status)),
            s.declare_queryable(keys.config, self._gated(reads, self.reads, self._config)),
            s.declare_queryable(keys.cameras, self._gated(frames, self.frames, self._frame)),
            s.declare_queryable(keys.verbs, self._on_verb),
            s.declare_queryable(keys.session_open, self._gated(sessions, self.admin, self._open)),
            s.declare_queryable(keys.session_close, self._gated(sessions, self.admin, self._close)),
            s.declare_queryable(keys.session_calls, self._on_call),
            s.declare_queryable(keys.session_stops, self._on_stop),
        ]
        self.clients = s.liveliness().declare_subscriber(keys.clients, self._on_client)
        self.token = s.liveliness().declare_token(keys.alive)

    def _worker(self, name: str, what: str) -> Turns:
        """A thread of the bridge's own taking ``what`` (jobs: callables) from its turns."""
        turns = Turns(what)

        def run() -> None:
            while (job := turns.get()) is not None:
                try:
                    job()
                except Exception:  # a reply that cannot be sent: the asker has gone
                    self.log.exception("%s: a request failed", name)

        t = threading.Thread(target=run, name=name, daemon=True)
        t.start()
        self.threads = [*(t for t in self.threads if t.is_alive()), t]
        self.queues.append(turns)
        return turns

    # ------------------------------------------------------------------ requests

    def _gated(
        self, kind: str, work: Turns, handler: Callable[[zenoh.Query], Any]
    ) -> Callable[[zenoh.Query], None]:
        """A queryable's callback: ``_admit`` with these."""
        return lambda query: self._admit(query, kind, work, handler)

    def _admit(
        self, query: zenoh.Query, kind: str, work: Turns, handler: Callable[[zenoh.Query], Any]
    ) -> None:
        """Count ``query`` against its user's rate for ``kind``, then queue ``handler(query)``
        in the user's turn on the ``work`` thread, its value the JSON reply (a KaliError: the
        error reply); refused at once, unread, beyond the rate or the user's waiting."""
        try:
            user, _ = self.keys.parse(query.key_expr)
        except BridgeError as exc:
            self._refuse(query, exc)
            return
        why = self.gates.admit(user, kind) or work.put(user, lambda: self._answer(query, handler))
        if why is not None:
            self._refuse(query, BridgeError(why))

    def _on_verb(self, query: zenoh.Query) -> None:
        """A kalictl verb: pressing the e-stop carried out at once, here on the Zenoh thread
        that delivered it (it never waits behind another request, nor counts against a
        rate); any other in its user's turn on the verbs thread."""
        try:
            user, (_, verb) = self.keys.parse(query.key_expr)
            robots = self._pressing(query) if verb == "estop" else None
        except (BridgeError, ValueError) as exc:  # ValueError: not kali/INST/user/USER/verb/V
            self._refuse(query, BridgeError(str(exc)))
            return
        if robots is None:
            self._admit(query, "verbs", self.verbs, self._verb)
        else:
            self._answer(query, lambda _: self._press_estop(robots[0] if robots else None, user))

    def _pressing(self, query: zenoh.Query) -> list[str] | None:
        """The arguments of verb ``estop`` when they press a button (``[]``: every robot's,
        ``[ROBOT]``); None for any other use of the verb (``--release``, a mistake: kalictl's
        to answer, in its words)."""
        request = self._payload(query, "estop")
        args = request.get("args", []) if isinstance(request, dict) else request
        check_verb("estop", args)
        if args == [] or (
            isinstance(args, list)
            and len(args) == 1
            and isinstance(args[0], str)
            and not args[0].startswith("-")
        ):
            return args
        return None

    def _press_estop(self, robot: str | None, user: str) -> dict[str, Any]:
        """Press the e-stop as ``kalictl estop [ROBOT]`` does, answered in its words."""
        try:
            pressed = self.inst.press_estop(robot, f"bridge {user}")
        except KaliError as exc:  # an unknown robot: nothing pressed
            return {"ok": False, "code": 1, "output": "", "error": f"kalictl: {exc}\n"}
        return {"ok": True, "code": 0, "output": estop_pressed(pressed) + "\n", "error": ""}

    def _answer(self, query: zenoh.Query, handler: Callable[[zenoh.Query], Any]) -> None:
        encoding = JSON
        try:
            value = handler(query)
            payload = value if isinstance(value, bytes) else protocol.dumps({"value": value})
            if payload.startswith(protocol.FRAME_MAGIC):
                encoding = BYTES
        except Exception as exc:  # KaliError: its words; anything else named for what it is
            payload = protocol.dumps(protocol.error_reply(exc))
        with contextlib.suppress(zenoh.ZError):
            query.reply(query.key_expr, payload, encoding=encoding)
        query.drop()

    def _refuse(self, query: zenoh.Query, error: BridgeError) -> None:
        """Answer ``query`` with ``error`` at once, unread (counted)."""
        self.refused += 1
        with contextlib.suppress(zenoh.ZError):
            query.reply(query.key_expr, protocol.dumps(protocol.error_reply(error)), encoding=JSON)
        query.drop()

    @staticmethod
    def _payload(query: zenoh.Query, what: str) -> Any:
        data = query.payload.to_bytes() if query.payload is not None else b"{}"
        return protocol.loads(data, what)

    def _status(self, query: zenoh.Query) -> dict[str, Any]:
        answer = protocol.loads(self.sessions.ask_helper({"status": True}), "status")
        protocol.raise_reply(answer)
        doc = answer["value"]
        doc["bridge"] = {
            "sessions": self.sessions.describe(),
            "events": self.n_events,
            "refused": self.refused,
            "errors": self.errors,
            "stream_writes": self.streams.written,
        }
        return doc

    def _config(self, query: zenoh.Query) -> dict[str, Any]:
        cfg = self.inst.config
        return {
            "instance": self.inst.name,
            "text": cfg.text,
            "source": cfg.source,
            "base_dir": cfg.base_dir,
            "lockstep": bool(self.inst.lockstep),
        }

    def _frame(self, query: zenoh.Query) -> bytes | None:
        """Camera ``NAME``'s latest frame (``kali/INST/user/USER/camera/NAME``), read from its
        ring as a local program reads it (``protocol.encode_frame``); None when there is none
        yet or it is the one whose stamp the asker sends (``{"since_stamp": ns}``)."""
        name = str(query.key_expr).rsplit("/", 1)[-1]
        request = self._payload(query, f"camera {name!r:.40}")
        since = request.get("since_stamp") if isinstance(request, dict) else None
        ring = self.rings.get(name)
        if ring is None:
            cameras = self.inst.config.scene.cameras
            ring = CameraRing(self.inst.arena, cameras, camera_index(cameras, name, self.inst.name))
            self.rings[name] = ring
        if since is not None and ring.stamp() == since:
            return None
        frame = ring.read()
        return None if frame is None else protocol.encode_frame(frame)

    def _verb(self, query: zenoh.Query) -> bytes:  # the helper's answer line, as it is
        verb = str(query.key_expr).rsplit("/", 1)[-1]
        request = self._payload(query, verb)
        args = request.get("args", []) if isinstance(request, dict) else request
        check_verb(verb, args)  # refused here, unread by the helper
        return self.sessions.ask_helper({"verb": verb, "args": args})

    def _open(self, query: zenoh.Query) -> dict[str, Any]:
        """Open a session of the user who asks: ``{"session": its secret, "kali": its Kali's
        reference}``, in the answer to the opener only (Zenoh sends a reply to its query's
        sender alone)."""
        user, _ = self.keys.parse(query.key_expr)
        token = self.keys.user(user).client
        request = self._payload(query, "session/open")
        sid = request.get("sid") if isinstance(request, dict) else None
        if isinstance(sid, str) and not self._client_alive(token(sid)):
            raise BridgeError(
                f"session {sid[:8]}: no liveliness token {token(sid)}; "
                f"declare it before opening the session"
            )
        secret, kali = self.sessions.open(request, user)
        sid = request["sid"]
        self.session_queues[secret] = self._worker(
            f"bridge-session-{sid[:8]}", f"calls to session {sid[:8]}"
        )
        if not self._client_alive(token(sid)):  # it left while its worker started
            self._end_session(secret)
            raise BridgeError(f"session {sid[:8]}: the program left while it opened")
        return {"session": secret, "kali": kali}

    def _client_alive(self, token: str) -> bool:
        """Whether a program holds its liveliness token ``token``: how the bridge learns that
        it left."""
        assert self.session is not None  # opened at configure, closed once the workers are joined
        replies = self.session.liveliness().get(token, timeout=2.0)
        return any(r.ok is not None for r in replies)

    def _close(self, query: zenoh.Query) -> bool:
        """Close the session whose secret the key holds, the asking user's."""
        user, secret = self.keys.session(query.key_expr)
        self.sessions.find(secret, user)
        return self._end_session(secret)

    def _end_session(self, secret: str) -> bool:
        self.streams.forget(secret)
        q = self.session_queues.pop(secret, None)
        if q is not None:
            q.close()  # its thread ends once the calls waiting are answered (refused)
            self.queues.remove(q)
        return self.sessions.close(secret)

    def _on_call(self, query: zenoh.Query) -> None:
        """A remote program's call, to the session whose secret the key holds (the asking
        user's): on the session's own thread, in the order sent."""
        try:
            user, secret = self.keys.session(query.key_expr)
            worker = self.sessions.find(secret, user)
        except BridgeError as exc:
            self._refuse(query, exc)
            return
        q = self.session_queues.get(secret)
        if q is None:
            self._refuse(query, BridgeError("no such session; open one first"))
            return
        payload = query.payload.to_bytes() if query.payload is not None else b""
        why = self.gates.admit(user, q.what)
        if why is None and not worker.interrupted:  # a stream's send: written here and now
            written = self.streams.call(secret, worker.proc.pid, payload)
            if written is not None:
                self._answer(query, lambda _: written)
                return
        job = lambda: self._answer(query, lambda _: self._call(secret, user, payload))  # noqa: E731
        why = why or q.put(user, job)
        if why is not None:
            self._refuse(query, BridgeError(why))

    def _call(self, secret: str, user: str, payload: bytes) -> bytes:
        """A call carried out by the session, whose answer may hand over a stream."""
        answer = self.sessions.call(secret, user, payload)
        self.streams.learn(secret, payload, answer)
        return answer

    def _on_stop(self, query: zenoh.Query) -> None:
        """Stop the arms of the session whose secret the key holds, the asking user's, and
        answer once they are at rest (``Sessions.stop``): on a thread of its own, never
        behind the session's calls, and never refused for rate."""
        try:
            user, secret = self.keys.session(query.key_expr)
            self.sessions.find(secret, user)
        except BridgeError as exc:
            self._refuse(query, exc)
            return
        why = self.stops.put(
            user, lambda: self._answer(query, lambda _: self.sessions.stop(secret, user))
        )
        if why is not None:
            self._refuse(query, BridgeError(why))

    def _on_client(self, sample: zenoh.Sample) -> None:
        """A remote program's token went: it died or left; end its session as a local
        program's death would (its worker killed)."""
        if sample.kind == zenoh.SampleKind.DELETE:
            with contextlib.suppress(BridgeError, ValueError):
                user, (_, sid) = self.keys.parse(sample.key_expr)
                if self.sessions.of(user, sid):  # in a turn of its own: never refused
                    self.admin.put(f"{OWN}{user}/{sid}", lambda: self._client_left(user, sid))

    def _client_left(self, user: str, sid: str) -> None:
        """End user ``user``'s sessions of public id ``sid`` unless a token of that id is
        still there (another client's token of the same key coming and going proves
        nothing)."""
        if not self._client_alive(self.keys.user(user).client(sid)):
            for secret in self.sessions.of(user, sid):
                self._end_session(secret)

    # ------------------------------------------------------------------ the cycle

    def cycle(self, tick: int) -> None:
        """Inside the cycle, not real-time (it allocates; Zenoh does): one telemetry sample
        per robot, the timing every ``every_timing`` cycles, the events found.  A failure is
        counted and logged once; the bridge never halts the system."""
        try:
            self._publish()
        except Exception:
            self.errors += 1
            if self.errors == 1:
                self.log.exception("bridge: publishing failed (later failures only counted)")

    def _publish(self) -> None:
        if self.session is None:
            return
        for k, pub in enumerate(self.state_pubs):
            pub.put(protocol.dumps(self.telemetry.sample(k)))
        if self.cycles % self.every_timing == 0:
            self.timing_pub.put(protocol.dumps(self.telemetry.timing()))
        self.cycles += 1
        for event in self.watch.changes():
            self.n_events += 1
            event = {
                "n": self.n_events,
                "tick": int(self.inst.clock["tick"]),
                "time_ms": time_ms(self.inst.clock),
                **event,
            }
            data = protocol.dumps(event)
            self.event_pub.put(data)
            if event["kind"] == "motion":
                self.session.put(self.keys.motion(event["seq"]), data, encoding=JSON)

    # ------------------------------------------------------------------ shutdown

    def on_deactivate(self) -> None:
        """Last events as the instance stops (in lockstep a halt stops the clock first)."""
        self.cycle(-1)

    def on_shutdown(self) -> None:
        """End every session (their workers), the threads and the Zenoh session."""
        sessions = getattr(self, "sessions", None)
        if sessions is not None:
            sessions.close_all()
        for q in self.queues:
            q.close()
        for t in self.threads:
            t.join(timeout=2.0)
        session, self.session = self.session, None
        if session is not None:
            with contextlib.suppress(zenoh.ZError):
                session.close()


__all__ = ["Bridge"]
