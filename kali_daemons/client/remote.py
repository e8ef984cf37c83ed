"""A robot program on another machine, through the instance's Zenoh bridge.

    from kali_daemons.client import Kali
    with Kali.connect("tcp/cell-pc:7447", "default") as kali:   # or Kali() under
        kali.ready(["left"])                                      # kalictl run --remote
        kali.robot("left").move_joints(q, speed=0.3)

``connect`` returns a ``RemoteKali`` with a local ``Kali``'s robots, motion systems, moves,
waits and reads, so a program runs unchanged.  Each call goes to the program's session on the
controller's machine (``bridge/session.py``), where a local client carries it out with every
check a local program meets; a refusal comes back as the same exception and message.
Periodic functions and TG functions stay on the controller's machine: their deadlines are the
wall clock's and the TG's, not the network's.  The program's liveliness token tells the
bridge it lives.  How calls, proxies and waits work: docs/internals/motion-client-bridge.md.

Long on purpose: the connection, the proxies it makes and the remote ``Kali`` are one
protocol's client side, each using the others' insides.
"""

from __future__ import annotations

import base64
import contextlib
import functools
import json
import os
import secrets
import ssl
import threading
import time
import weakref
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any

import zenoh
import zenoh.handlers

from ..core.errors import KaliError, ServoError
from ..core.layout import TERMINAL_STATES
from ..hardware.camera import camera_index
from ..robots import RobotType
from ..runtime.config import KaliConfig, parse_config
from . import protocol
from .camera import RemoteCamera
from .common import DEFAULT_INSTANCE, INSTANCE_ENV, program_name
from .protocol import METHODS, PROPERTIES, BridgeError, Keys
from .zenohconfig import client_config

REMOTE_ENV = "KALI_REMOTE"  # set by `kalictl run --remote ENDPOINT`: Kali() connects there
SESSION_ENV = "KALI_REMOTE_SESSION"  # and the session it opened, which Kali() adopts
USER_ENV = "KALI_REMOTE_USER"
PASSWORD_ENV = "KALI_REMOTE_PASSWORD"
TLS_ENV = ("KALI_REMOTE_CA", "KALI_REMOTE_CERT", "KALI_REMOTE_KEY")
CONNECT_TIMEOUT_S = 10.0  # to find the bridge and open the session
ALIVE_GRACE_S = 2.0  # an instance's token not seen within this: no such instance there
CALL_TIMEOUT_S = 30.0  # an answer beyond a call's own timeout, if it has one
POLL_S = 0.05  # how often a waiting call looks whether the bridge is still there
NO_DEADLINE_S = 7 * 24 * 3600.0  # a call without a timeout: until answered or the bridge goes


def connect(
    endpoint: str, instance: str | None = None, *, force: bool = False, **credentials: str
) -> RemoteKali:
    """Connect to instance ``instance`` (default: $KALI_INSTANCE, else 'default') through the
    bridge at Zenoh ``endpoint`` (e.g. ``tcp/HOST:7447``) and open this program's session;
    ``credentials`` (user, password, root_ca, certificate, private_key) as the bridge's
    config asks, by default from $KALI_REMOTE_USER, $KALI_REMOTE_PASSWORD and
    $KALI_REMOTE_CA/CERT/KEY.  BridgeError if nothing answers or the session is refused."""
    return RemoteKali(reach(endpoint, instance, **credentials), force)


def reach(
    endpoint: str,
    instance: str | None = None,
    *,
    user: str | None = None,
    password: str | None = None,
    root_ca: str | None = None,
    certificate: str | None = None,
    private_key: str | None = None,
) -> Connection:
    """A Zenoh session with the bridge of ``instance`` at ``endpoint``, its liveliness seen
    (no program session yet: ``kalictl run --remote`` checks the instance answers with it)."""
    name = os.environ.get(INSTANCE_ENV, DEFAULT_INSTANCE) if instance is None else instance
    env = [os.environ.get(v) for v in TLS_ENV]
    user = user if user is not None else os.environ.get(USER_ENV)
    certificate = certificate or env[1]
    try:
        config = client_config(
            endpoint,
            user=user,
            password=password if password is not None else os.environ.get(PASSWORD_ENV),
            root_ca=root_ca or env[0],
            certificate=certificate,
            private_key=private_key or env[2],
        )
    except (ValueError, zenoh.ZError) as exc:  # half the credentials, a bad endpoint
        raise BridgeError(f"cannot connect to {endpoint}: {exc}") from None
    if user is None and certificate is not None:
        user = common_name(certificate)
    handed = handed_over(endpoint, name)
    return Connection(endpoint, name, config, user if handed is None else handed["user"], handed)


def handed_over(endpoint: str, instance: str) -> dict[str, str] | None:
    """The session ``kalictl run --remote`` opened for this program ($KALI_REMOTE_SESSION:
    endpoint, instance, user, sid, secret) when it is one on ``endpoint``'s ``instance``, for
    its ``Kali()`` to adopt; None otherwise."""
    text = os.environ.get(SESSION_ENV)
    if not text:
        return None
    try:
        handed = json.loads(text)
        fields = {key: handed[key] for key in ("endpoint", "instance", "user", "sid", "secret")}
        if not all(isinstance(v, str) for v in fields.values()):
            raise ValueError(text)
    except (ValueError, TypeError, KeyError):
        raise BridgeError(f"${SESSION_ENV} holds no session kalictl handed over") from None
    return fields if (fields["endpoint"], fields["instance"]) == (endpoint, instance) else None


def common_name(certificate: str) -> str:
    """The common name of PEM certificate ``certificate``: the user name a bridge knows its
    holder by (read with CPython's own certificate decoder, ``ssl._ssl._test_decode_cert``:
    the standard library has no public one)."""
    try:
        subject = ssl._ssl._test_decode_cert(certificate).get("subject", ())  # type: ignore[attr-defined]
    except (OSError, ssl.SSLError) as exc:
        raise BridgeError(f"cannot read certificate {certificate}: {exc}") from None
    names = [value for rdn in subject for key, value in rdn if key == "commonName"]
    if not names:
        raise BridgeError(f"certificate {certificate} has no common name: the bridge's user name")
    return names[-1]


class Connection:
    """One remote program's Zenoh session with a bridge: its user name (``user``, else its
    Zenoh session's id), its session's public id and token, its secret, its calls.  With
    ``adopt`` (``handed_over``) the session is one ``kalictl run --remote`` opened and holds:
    this connection calls it, and neither declares its token nor closes it."""

    def __init__(
        self,
        endpoint: str,
        instance: str,
        config: zenoh.Config,
        user: str | None = None,
        adopt: dict[str, str] | None = None,
    ) -> None:
        self.endpoint = endpoint
        self.instance = instance
        self.keys = Keys(instance)
        try:
            self.session = zenoh.open(config)
        except zenoh.ZError as exc:  # its words, without the Rust source it came from
            reason = str(exc).split("!  at /")[0].split(" at /")[0].rstrip("!. ")
            raise BridgeError(f"cannot connect to {endpoint}: {reason}") from None
        try:
            self.mine = self.keys.user(str(self.session.zid()) if user is None else user)
        except BridgeError:
            self.session.close()
            raise
        self.sid = secrets.token_hex(8)  # public: its liveliness token carries it
        self.secret = ""  # its session's address, the bridge's answer to its open
        self.adopted = adopt is not None
        if adopt is not None:
            self.sid, self.secret = adopt["sid"], adopt["secret"]
        self.proxies: weakref.WeakValueDictionary[int, Proxy] = weakref.WeakValueDictionary()
        self.dropped: list[int] = []  # handles this program let go: the session forgets them
        self.lock = threading.Lock()
        self.bridge_alive = threading.Event()
        self.closed = False
        self.opened = self.adopted  # a program's session is open on the bridge
        self.kali: RemoteKali | None = None
        try:
            self.watch = self.session.liveliness().declare_subscriber(
                self.keys.alive, self._on_alive, history=True
            )
            found = self.session.liveliness().get(self.keys.alive, timeout=CONNECT_TIMEOUT_S)
            if any(r.ok is not None for r in found):  # the router answers at once
                self.bridge_alive.set()
            # a session just opened may see the token only as its subscriber's history
            if not self.bridge_alive.wait(ALIVE_GRACE_S):
                seen = self.instances()
                there = (
                    f"; instances answering there: {', '.join(seen)} (-i NAME)"
                    if seen
                    else "; no instance answers there"
                )
                raise BridgeError(
                    f"no Kali instance '{instance}' answers at {endpoint} (no "
                    f"liveliness token {self.keys.alive} within {ALIVE_GRACE_S:g} s: is its "
                    f"bridge enabled, and may this user read it?){there}"
                )
            if not self.adopted:  # an adopted session's token is its opener's
                self.token = self.session.liveliness().declare_token(self.mine.client(self.sid))
        except BaseException:
            self.session.close()
            raise

    def instances(self) -> list[str]:
        """The Kali instances whose bridges this session sees (their liveliness tokens
        ``kali/<instance>/alive``), sorted; those this user may not read are not seen."""
        try:
            replies = self.session.liveliness().get("kali/*/alive", timeout=ALIVE_GRACE_S)
            keys = [str(r.ok.key_expr) for r in replies if r.ok is not None]
        except zenoh.ZError:
            return []
        return sorted({k.split("/")[1] for k in keys if k.count("/") == 2})

    def open(self, program: str, force: bool = False) -> dict[str, Any]:
        """Open this program's session (its worker attaches a Kali named ``program``,
        ``force`` as ``Kali(force=...)``); its Kali's reference."""
        opened = self.get(
            self.mine.session_open,
            {"sid": self.sid, "program": program, "force": bool(force)},
            timeout=CONNECT_TIMEOUT_S + 30.0,
        )
        self.secret, self.opened = opened["session"], True
        return opened["kali"]

    def adopt(self, force: bool = False) -> dict[str, Any]:
        """Take up the session handed over (``force`` as ``Kali(force=...)``); its Kali's
        reference."""
        request = protocol.dumps({"adopt": {"force": bool(force)}})
        answer = self._ask(self.mine.call(self.secret), request, CONNECT_TIMEOUT_S, "adopt")
        return answer["value"]

    def stop(self) -> dict[str, Any]:
        """Have the bridge stop the arms this session's program owns on their paths, whatever
        the program is doing, and answer once they are at rest; the session takes no more
        calls then.  ``{"robots": [names], "at_rest": bool, "halted": fault or None,
        "waited_s": its longest wait}`` (``session.Stopper``)."""
        return self.get(self.mine.stop(self.secret), {}, timeout=CALL_TIMEOUT_S)

    def handover(self) -> str:
        """This connection's session for a program to adopt ($KALI_REMOTE_SESSION)."""
        return json.dumps(
            {
                "endpoint": self.endpoint,
                "instance": self.instance,
                "user": self.mine.name,
                "sid": self.sid,
                "secret": self.secret,
            }
        )

    def _on_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.bridge_alive.set()
        else:
            self.bridge_alive.clear()

    def get(self, key: str, value: Any, timeout: float = CALL_TIMEOUT_S) -> Any:
        """Ask ``key`` with JSON ``value``; the reply's value, or its exception raised."""
        return self._ask(key, protocol.dumps(value), timeout, key).get("value")

    def _ask(self, key: str, payload: bytes, timeout: float, what: str) -> dict[str, Any]:
        """One query and its one answer (a mapping); the exception it carries raised, a
        BridgeError if none comes within ``timeout`` s or the bridge goes meanwhile."""
        answer = protocol.loads(self.ask_bytes(key, payload, timeout, what), what)
        if not isinstance(answer, dict):
            raise BridgeError(f"{what}: a malformed answer")
        protocol.raise_reply(answer)
        return answer

    def ask_bytes(self, key: str, payload: bytes, timeout: float, what: str) -> bytes:
        """One query and its one answer's bytes, as they came; a BridgeError if none comes
        within ``timeout`` s or the bridge goes meanwhile."""
        if self.closed:
            raise BridgeError(f"the connection to {self.endpoint} is closed")
        replies: list[zenoh.Reply] = []
        over = threading.Event()  # the query is finished: answered, refused or timed out

        def on_reply(reply: zenoh.Reply) -> None:
            replies.append(reply)
            over.set()

        handler = zenoh.handlers.Callback(on_reply, over.set)
        self.session.get(key, handler, payload=payload, timeout=timeout)
        while not over.wait(POLL_S):
            if not self.bridge_alive.is_set():
                raise BridgeError(
                    f"instance '{self.instance}' at {self.endpoint} went away during {what}"
                )
        if not replies:
            raise BridgeError(
                f"no answer to {what} from instance '{self.instance}' at {self.endpoint}: "
                f"this user may not ask it (bridge.operators / bridge.readers), or the "
                f"answer took longer than {timeout:g} s"
            )
        reply = replies[0]
        if reply.ok is None:
            assert reply.err is not None  # zenoh: a reply is either ok or err
            text = reply.err.payload.to_bytes().decode(errors="replace")
            raise BridgeError(f"{what}: {text}")
        return bytes(reply.ok.payload.to_bytes())

    def call(
        self, oid: int, method: str, args: Sequence[Any], kwargs: dict[str, Any]
    ) -> tuple[Any, dict[str, Any]]:
        """Call ``method`` of the session's object ``oid``: (value, its attributes now)."""
        timeout = kwargs.get("timeout")
        limit = (
            min(NO_DEADLINE_S, max(0.0, float(timeout)) + CALL_TIMEOUT_S)
            if isinstance(timeout, int | float) and not isinstance(timeout, bool)
            else NO_DEADLINE_S
        )
        with self.lock:
            dropped, self.dropped = self.dropped, []
        request = {
            "target": oid,
            "method": method,
            "args": protocol.encode(list(args), _reference),
            "kwargs": protocol.encode(kwargs, _reference),
            "drop": dropped,
        }
        answer = self._ask(self.mine.call(self.secret), protocol.dumps(request), limit, method)
        value = protocol.decode(answer.get("value"), self.proxy)
        attrs = protocol.decode(answer.get("attrs") or {}, self.proxy)
        return value, attrs

    def proxy(self, oid: int, cls: str, attrs: dict[str, Any] | None = None) -> Proxy:
        """The proxy of the session's object ``oid`` (one per object), attributes updated."""
        p = self.proxies.get(oid)
        if p is None:
            p = PROXIES.get(cls, Proxy)(self, oid, cls)
            self.proxies[oid] = p
        if attrs:
            p._attrs.update(attrs)
        return p

    def forget(self, oid: int) -> None:
        with self.lock:
            self.dropped.append(oid)

    def close(self) -> None:
        """End the session (the bridge ends its worker) and the Zenoh session."""
        if self.closed:
            return
        try:
            if self.opened and not self.adopted and self.bridge_alive.is_set():
                self.get(self.mine.close(self.secret), {}, timeout=5.0)
        except Exception:  # the token going ends it anyway
            pass
        self.closed = True
        self.session.close()


def _reference(obj: object) -> dict[str, Any]:
    """A proxy given back as an argument: the session's object it stands for."""
    if isinstance(obj, Proxy):
        return {"__obj__": obj._oid, "class": obj._cls}
    raise BridgeError(f"a {type(obj).__name__} cannot cross the bridge")


class Proxy:
    """A session object on the controller's machine: its attributes, its methods as calls."""

    stands_for_remote = True  # given back as an argument, it crosses as its reference

    def __init__(self, conn: Connection, oid: int, cls: str) -> None:
        self._conn = conn
        self._oid = oid
        self._cls = cls
        self._attrs: dict[str, Any] = {}

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        attrs = self.__dict__.get("_attrs", {})
        if name in attrs:
            return attrs[name]
        if name in PROPERTIES.get(self._cls, ()):
            return self._call(name)
        if name in METHODS.get(self._cls, ()):
            return functools.partial(self._call, name)
        raise BridgeError(
            f"a remote {self._cls} has no {name!r}: periodic functions, TG functions "
            f"and live views of shared memory stay on the controller's machine; remote: "
            f"{', '.join(sorted(METHODS.get(self._cls, set()) | set(attrs)))}"
        )

    def _call(self, method: str, *args: Any, **kwargs: Any) -> Any:
        value, attrs = self._conn.call(self._oid, method, args, kwargs)
        self._attrs.update(attrs)
        return value

    def __del__(self) -> None:
        try:
            if self._oid and not self._conn.closed:
                self._conn.forget(self._oid)
        except Exception:
            pass

    def __repr__(self) -> str:
        return f"<remote {self._cls} {self._oid} of {self._conn.instance}@{self._conn.endpoint}>"


class RemoteRobot(Proxy):
    """A robot: ``type`` (its robot type, from the instance's config) beside the calls."""

    @property
    def type(self) -> RobotType:
        kali = self._conn.kali
        assert kali is not None
        return kali.inst.config.robots[self.index].type


class RemoteHandle(Proxy):
    """A request's handle; ``wait`` follows its state as the bridge publishes it."""

    def wait(self, timeout: float | None = None) -> None:
        """As ``MotionHandle.wait``: returns once it arrived (or touched), raises the same
        MotionFailedError / TimeoutError otherwise."""
        kali = self._conn.kali
        assert kali is not None
        if kali.inst.lockstep:  # the session steps the clock, as a local program's wait
            self._call("wait", timeout=timeout)
            return
        changed = threading.Event()
        sub = self._conn.session.declare_subscriber(
            self._conn.keys.motion(self.seq), lambda _sample: changed.set()
        )
        deadline = None if timeout is None else time.monotonic() + timeout
        try:
            while True:
                changed.clear()
                if self.state in TERMINAL_STATES:
                    self._call("wait", timeout=0.0)  # its outcome, in the local words
                    return
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise TimeoutError(
                        f"motion: request {self.seq} not done within {timeout:g} s "
                        f"({self.state.name.lower()})"
                    )
                # a state the bridge publishes wakes it; a halt or a lost record it cannot see
                # (the session reads them) within a second
                changed.wait(1.0 if left is None else min(1.0, left))
        finally:
            sub.undeclare()


class RemoteTogether(Proxy):
    """A ``with kali.together()`` block held on the session."""

    def __enter__(self) -> RemoteTogether:
        self._call("__enter__")
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        failed = exc_type is not None
        self._call("__exit__", True if failed else None, None, None)  # it reads the type only

    def wait(self, timeout: float | None = None, any: bool = False) -> Any:
        return self._call("wait", timeout=timeout, any=any)


class RemoteStream(Proxy):
    """A pose or joint stream its session holds (``Robot.stream``): each ``send`` a call the
    session carries out at once; leaving ``with`` closes it, stopping the arm."""

    def __enter__(self) -> RemoteStream:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self._call("close")


class RemoteServo(Proxy):
    """The servo level: ``load`` reads the plugin file on this machine and sends its text."""

    def load(self, path: str | os.PathLike[str]) -> list[str]:
        """As ``ServoClient.load``: the file is read here, loaded there."""
        file = Path(path).expanduser().resolve()
        try:
            source = file.read_text()
        except (OSError, UnicodeDecodeError) as exc:
            raise ServoError(f"load {str(path)!r}: cannot read it: {exc}") from None
        return self._call("load_source", source, str(file))


class RemoteInstance:
    """What a program reads of ``kali.inst`` remotely: name, config, lockstep."""

    def __init__(self, name: str, config: KaliConfig, lockstep: bool) -> None:
        self.name = name
        self.config = config
        self.lockstep = lockstep


class RemoteKali(Proxy):
    """A remote program's ``Kali`` (``connect``)."""

    def __init__(self, conn: Connection, force: bool = False) -> None:
        super().__init__(conn, 0, "Kali")
        conn.kali = self
        try:
            cfg = conn.get(conn.mine.config, {}, timeout=CONNECT_TIMEOUT_S)
            try:
                source = f"{cfg['source']} (remote)"
                name = cfg["instance"]
                config = parse_config(cfg["text"], source, cfg["base_dir"], instance=name)
            except Exception as exc:
                raise BridgeError(
                    f"instance '{conn.instance}''s config does not parse on this machine: {exc}"
                ) from None
            self.inst = RemoteInstance(cfg["instance"], config, bool(cfg["lockstep"]))
            if conn.adopted:
                ref = conn.adopt(force)
            else:
                ref = conn.open(program_name().decode(errors="replace"), force)
        except BaseException:
            conn.close()
            raise
        conn.proxies[0] = self
        self._attrs.update(protocol.decode(ref.get("attrs", {}), conn.proxy))

    def together(self, *moves: Callable[[], object]) -> RemoteTogether:
        """As ``Kali.together``: the block form, or the moves as functions."""
        group = self._call("together")
        if moves:
            with group:
                for move in moves:
                    move()
        return group

    def camera(self, name: str) -> RemoteCamera:
        """As ``Kali.camera``: camera ``name``'s frames, fetched through the bridge."""
        cameras = self.inst.config.scene.cameras
        return RemoteCamera(self._conn, name, cameras[camera_index(cameras, name, self.inst.name)])

    def control(self, *args: Any, **kwargs: Any) -> None:
        raise BridgeError(
            "control: a periodic function runs on the controller's machine (its deadline is "
            "the wall clock's); run this program there with kalictl run"
        )

    @contextlib.contextmanager
    def record(self, path: str | os.PathLike[str]) -> Iterator[dict[str, Any]]:
        """As ``Kali.record``: the recording is made on the controller's machine (its log
        directory) and fetched to ``path`` here when the block ends."""
        target = Path(path).absolute()
        if target.exists():
            raise BridgeError(f"record: {target} exists: a recording is never written over")
        if not target.parent.is_dir():
            raise BridgeError(f"record: {target.parent} is not a directory")
        there = self._call("record_in_log_dir")
        status: dict[str, Any] = {}
        try:
            yield status
        finally:
            status.update(self._call("stop_recording"))
            with open(target, "xb") as out:
                while chunk := base64.b64decode(self._call("recorded_bytes", out.tell())):
                    out.write(chunk)
            status["there"], status["path"] = there, str(target)

    def verb(self, verb: str, *args: str) -> str:
        """Run kalictl verb ``verb`` (enable, disable, estop, reset, calibrate, servo, ff,
        rate, status) on the instance; what kalictl printed.  BridgeError with kalictl's own
        error line if it refused."""
        result = self._conn.get(
            self._conn.mine.verb(verb), {"args": list(args)}, CALL_TIMEOUT_S + 60
        )
        if not result["ok"]:
            raise BridgeError(result["error"].strip() or f"kalictl {verb} failed")
        return result["output"]

    def status(self) -> dict[str, Any]:
        """``kalictl status --json``'s document, and the bridge's sessions."""
        return self._conn.get(self._conn.mine.status, {})

    def close(self) -> None:
        self._conn.close()

    def __enter__(self) -> RemoteKali:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close; on Ctrl-C (``kalictl run --remote``) stop this program's arms first."""
        if exc_type is KeyboardInterrupt and not self._conn.closed:
            with contextlib.suppress(KaliError):
                self.stop_own()
        self.close()


PROXIES: dict[str, type[Proxy]] = {
    "Robot": RemoteRobot,
    "MotionHandle": RemoteHandle,
    "Together": RemoteTogether,
    "Stream": RemoteStream,
    "JointStream": RemoteStream,
    "ServoClient": RemoteServo,
}
