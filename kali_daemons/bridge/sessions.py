"""Remote programs' sessions and kalictl's verbs, as the bridge carries them out.

A session is a worker process (``session.py``) standing in for one remote program: the bridge
starts it when the program opens the session, hands it the program's calls one at a time and
returns its answers, and kills it when the program's liveliness token goes (it died, or its
machine left the network), so the cell treats that program as a local one that died.  A
worker runs SCHED_OTHER at a lower priority than the bridge, on the bridge's CPU.  A session
belongs to the user who opened it and is addressed by a secret only its opener learns
(``Sessions``).

Verbs are kalictl's own commands, run one at a time by the bridge's helper process (a worker
with ``--helper``), so a remote ``enable`` or ``servo set`` meets kalictl's checks and
answers with kalictl's words, and its Python never holds the bridge's interpreter lock.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import secrets
import subprocess
import sys
import threading
from typing import Any

from ..client import protocol
from ..client.protocol import BridgeError
from ..client.remote import REMOTE_ENV
from ..core.errors import KaliError
from ..tools import launcher

SID_RE = re.compile(r"[0-9a-f]{16,32}")
PROGRAM_RE = re.compile(r"[^\x00-\x1f]{1,64}")
START_TIMEOUT_S = 30.0  # a worker attaches its Kali within this
WORKER_NICE = 5  # below the bridge: a busy remote program does not slow telemetry
# kalictl verbs a remote operator may run: each verb's allowed first arguments (None: any)
VERBS: dict[str, frozenset[str] | None] = {
    "enable": None,
    "disable": None,
    "estop": None,
    "reset": None,
    "calibrate": None,
    "ff": None,
    "rate": None,
    "status": frozenset({"--json"}),
    "servo": frozenset({"list", "select", "set", "get", "compare"}),
}
SECRET_BYTES = 16  # a session's secret: 128 random bits, 32 hex digits
STOP_WAIT_S = 10.0  # a session's stop waits this long (wall time) for its arms to rest
MAX_VERB_ARGS = 16
MAX_ARG_CHARS = 200


class Worker:
    """One session's worker process and the lock its calls take turns on."""

    def __init__(
        self, sid: str, program: str, proc: subprocess.Popen, kali: Any, owner: str = ""
    ) -> None:
        self.sid = sid  # public: the program's liveliness token carries it
        self.program = program
        self.proc = proc
        self.kali = kali  # the reference to its Kali, as the remote program gets it
        self.owner = owner  # the user who opened the session
        self.lock = threading.Lock()
        self.next_id = 0
        self.control: tuple[Any, Any] | None = None  # the pipe of its stops: (to it, from it)
        self.control_lock = threading.Lock()
        self.interrupted = False  # its arms were stopped: it takes no more calls

    def call(self, request: dict[str, Any]) -> bytes:
        """Send one call, return the worker's answer line (BridgeError if it has died)."""
        with self.lock:
            self.next_id += 1
            request["id"] = self.next_id
            try:
                assert self.proc.stdin is not None and self.proc.stdout is not None
                self.proc.stdin.write(protocol.dumps(request) + b"\n")
                self.proc.stdin.flush()
                line = self.proc.stdout.readline()
            except (BrokenPipeError, ValueError, OSError):
                line = b""
            if not line:
                raise BridgeError(f"session {self.sid[:8]} ({self.program}) has ended")
            return line.rstrip(b"\n")

    def stop_arms(self, timeout: float) -> dict[str, Any]:
        """Have the worker stop the arms its program owns and say once they are at rest
        (``session.Stopper``), over its control pipe: whatever call its program's pipe is
        busy with.  ``{"robots", "at_rest", "halted", "waited_s"}``; BridgeError if it has
        died."""
        with self.control_lock:
            line = b""
            if self.control is not None:
                try:
                    self.control[0].write(protocol.dumps({"timeout": timeout}) + b"\n")
                    self.control[0].flush()
                    line = self.control[1].readline()
                except (BrokenPipeError, ValueError, OSError):
                    line = b""
            if not line:
                raise BridgeError(f"session {self.sid[:8]} ({self.program}) has ended")
            reply = protocol.loads(line, "stop")
            protocol.raise_reply(reply)
            return reply["value"]

    def stop(self) -> None:
        """End the worker: SIGTERM (it closes its Kali), SIGKILL after a second; reaped."""
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(1.0)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        for f in (self.proc.stdin, self.proc.stdout, *(self.control or ())):
            if f is not None:
                with contextlib.suppress(OSError):
                    f.close()


class Sessions:
    """The open sessions of one instance, at most ``limit``, each addressed by its secret:
    a random number the bridge makes when the session opens and tells its opener only, in
    the answer to the open, and which is published nowhere (the program's liveliness token
    and the status document carry its public id).  A session belongs to the user who opened
    it: a call or a close from another user is refused even with the secret."""

    def __init__(self, instance: str, limit: int, cpu: int | None, log_dir: str) -> None:
        self.instance = instance
        self.limit = limit
        self.cpu = cpu
        self.log_dir = log_dir
        self.workers: dict[str, Worker | None] = {}  # by secret; None while it starts
        self.lock = threading.Lock()
        self.helper: Worker | None = None  # verbs and status (ask_helper)
        self.helper_lock = threading.Lock()
        self.closed = False

    def open(self, request: Any, owner: str) -> tuple[str, dict[str, Any]]:
        """Start a session of user ``owner`` for ``{"sid", "program", "force"}``: its secret
        and its Kali's reference."""
        if not isinstance(request, dict):
            raise BridgeError("session/open takes {sid, program, force}")
        sid, program = request.get("sid"), request.get("program", "remote")
        force = request.get("force", False)
        if not isinstance(sid, str) or SID_RE.fullmatch(sid) is None:
            raise BridgeError(f"session id {sid!r:.40} is not 16..32 hex digits")
        if not isinstance(program, str) or PROGRAM_RE.fullmatch(program) is None:
            raise BridgeError(f"program name {program!r:.70} (1..64 printable characters)")
        if not isinstance(force, bool):
            raise BridgeError(f"force {force!r:.20} is not true or false")
        with self.lock:
            if self.closed:
                raise BridgeError(f"instance '{self.instance}' is stopping")
            if self.of(owner, sid):
                raise BridgeError(f"session {sid[:8]} is open already")
            if len(self.workers) >= self.limit:
                raise BridgeError(
                    f"{len(self.workers)} remote programs are connected, the "
                    f"config's bridge.max_sessions; refused"
                )
            secret = secrets.token_hex(SECRET_BYTES)
            self.workers[secret] = None  # reserved while it starts
        try:
            worker = self._start(sid, program, force)
        except BaseException:
            with self.lock:
                self.workers.pop(secret, None)
            raise
        worker.owner = owner
        with self.lock:
            self.workers[secret] = worker
        return secret, worker.kali

    def find(self, secret: str, user: str) -> Worker:
        """The session ``secret`` addresses, which must be ``user``'s (BridgeError)."""
        worker = self.workers.get(secret)
        if worker is None:
            raise BridgeError("no such session; open one first")
        if worker.owner != user:
            raise BridgeError(
                f"session {worker.sid[:8]} ({worker.program}) belongs to user "
                f"{worker.owner!r}; refused to user {user!r}"
            )
        return worker

    def of(self, owner: str, sid: str) -> list[str]:
        """The secrets of the sessions user ``owner`` opened with public id ``sid``."""
        return [
            secret
            for secret, w in list(self.workers.items())
            if w is not None and (w.owner, w.sid) == (owner, sid)
        ]

    def _start(self, sid: str, program: str, force: bool) -> Worker:
        """A session's worker, with the control pipe of its stops (``Worker.stop_arms``)."""
        stops, its_stops = os.pipe()  # the worker reads, the bridge writes
        its_answers, answers = os.pipe()  # the bridge reads, the worker writes
        options = [
            "--sid", sid, "--program", program, *(["--force"] if force else []),
            "--control", f"{stops},{answers}",
        ]  # fmt: skip
        try:
            worker = self._spawn(
                sid, program, options, f"bridge.session.{sid[:8]}.log", (stops, answers)
            )
        except BaseException:
            os.close(its_stops)
            os.close(its_answers)
            raise
        finally:
            os.close(stops)
            os.close(answers)
        worker.control = (os.fdopen(its_stops, "wb"), os.fdopen(its_answers, "rb"))
        return worker

    def _spawn(
        self,
        sid: str,
        program: str,
        options: list[str],
        log_name: str,
        pass_fds: tuple[int, ...] = (),
    ) -> Worker:
        """Start a worker process (``session.py``) with ``options`` (and the descriptors
        ``pass_fds``) and wait for its first line: a program's Kali reference, or the
        helper's ready."""
        args = [
            sys.executable, "-m", "kali_daemons.bridge.session", "--instance", self.instance,
            "--nice", str(WORKER_NICE), *(["--cpu", str(self.cpu)] if self.cpu is not None else []),
            *options,
        ]  # fmt: skip
        log_path = os.path.join(self.log_dir, log_name)
        with open(log_path, "wb") as log:
            proc = subprocess.Popen(
                args,
                stdin=subprocess.PIPE,
                stdout=subprocess.PIPE,
                stderr=log,
                close_fds=True,
                pass_fds=pass_fds,
                env={
                    **{k: v for k, v in os.environ.items() if k != REMOTE_ENV},
                    **launcher.SINGLE_THREADED,
                },  # its Kali is a local one, whatever the bridge's environment says
                start_new_session=True,  # kalictl stop finds it by its instance argument
            )
        worker = Worker(sid, program, proc, None)
        assert proc.stdout is not None
        ready = threading.Event()
        first: list[bytes] = []

        def read_first() -> None:
            first.append(proc.stdout.readline())  # type: ignore[union-attr]
            ready.set()

        threading.Thread(target=read_first, daemon=True).start()
        if not ready.wait(START_TIMEOUT_S) or not first[0]:
            worker.stop()
            raise BridgeError(f"the worker for {program} did not start: {_tail(log_path)}")
        reply = protocol.loads(first[0], "worker start")
        protocol.raise_reply(reply)
        worker.kali = reply["value"]
        return worker

    def start_helper(self) -> Worker:
        """The helper process (verbs and status), started now if it is not running (the
        bridge starts it at once; it is started again if it has died)."""
        with self.helper_lock:
            if self.closed:
                raise BridgeError(f"instance '{self.instance}' is stopping")
            if self.helper is None or self.helper.proc.poll() is not None:
                if self.helper is not None:
                    self.helper.stop()
                self.helper = self._spawn("helper", "verbs", ["--helper"], "bridge.helper.log")
            return self.helper

    def ask_helper(self, request: dict[str, Any]) -> bytes:
        """The helper's answer line to ``request`` (a verb, or the status)."""
        return self.start_helper().call(request)

    def call(self, secret: str, user: str, payload: bytes) -> bytes:
        """Forward one call of ``user`` to session ``secret``; the worker's answer."""
        worker = self.find(secret, user)
        if worker.interrupted:
            raise BridgeError(
                f"session {worker.sid[:8]} ({worker.program}): its arms were stopped for an "
                f"interrupt (kalictl run --remote's Ctrl-C); it takes no more calls"
            )
        request = protocol.loads(payload, "call")
        if not isinstance(request, dict):
            raise BridgeError("a call must be a JSON object")
        return worker.call(request)

    def stop(self, secret: str, user: str) -> dict[str, Any]:
        """Stop the arms of ``user``'s session ``secret`` on their paths and wait until they
        are at rest (``Worker.stop_arms``, at most ``STOP_WAIT_S``); from then on the session
        takes no more calls, so its program cannot start them again."""
        worker = self.find(secret, user)
        worker.interrupted = True
        return worker.stop_arms(STOP_WAIT_S)

    def close(self, secret: str) -> bool:
        """End session ``secret`` (its program left); False if there was none."""
        with self.lock:
            if secret in self.workers and self.workers[secret] is None:
                return False  # still starting: open() finds its program gone and ends it
            worker = self.workers.pop(secret, None)
        if worker is None:
            return False
        worker.stop()
        return True

    def close_all(self) -> None:
        with self.lock, self.helper_lock:
            self.closed = True
            workers = [w for w in self.workers.values() if w is not None]
            if self.helper is not None:
                workers.append(self.helper)
            self.workers.clear()
        for w in workers:
            w.stop()

    def describe(self) -> list[dict[str, Any]]:
        """The open sessions: public id, user, program, worker pid (never a secret)."""
        with self.lock:
            return [
                {"sid": w.sid[:8], "user": w.owner, "program": w.program, "pid": w.proc.pid}
                for w in self.workers.values()
                if w is not None
            ]


def _tail(path: str, lines: int = 5) -> str:
    try:
        with open(path, errors="replace") as f:
            return " | ".join(f.read().strip().splitlines()[-lines:]) or "no output"
    except OSError:
        return "no log"


_verb_lock = threading.Lock()


def check_verb(verb: str, args: Any) -> None:
    """BridgeError unless ``kalictl VERB ARGS...`` is one a remote operator may run."""
    if verb not in VERBS:
        raise BridgeError(f"unknown verb {verb!r:.40}; verbs: {', '.join(sorted(VERBS))}")
    if not isinstance(args, list) or len(args) > MAX_VERB_ARGS:
        raise BridgeError(f"{verb}: args must be a list of at most {MAX_VERB_ARGS} strings")
    for i, a in enumerate(args):
        if not isinstance(a, str) or not 0 < len(a) <= MAX_ARG_CHARS or "\0" in a:
            raise BridgeError(f"{verb}: args[{i}] {a!r:.40} is not a short string")
    first = VERBS[verb]
    if first is not None and args and args[0] not in first:
        raise BridgeError(
            f"{verb} {args[0]!r:.40} is not open to remote programs; "
            f"{verb}: {', '.join(sorted(first))}"
        )


def run_verb(instance: str, verb: str, args: Any) -> dict[str, Any]:
    """Run ``kalictl -i INSTANCE VERB ARGS...`` in this process (one at a time; the bridge's
    helper does): ``{"ok", "output"}`` with what kalictl printed, its error line when it
    refused."""
    check_verb(verb, args)
    from ..tools.cli import main  # here: the daemons never need click

    out, err = io.StringIO(), io.StringIO()
    with _verb_lock, contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        try:
            main.main(
                args=["-i", instance, verb, *args], prog_name="kalictl", standalone_mode=False
            )
            code = 0
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else 1
        except KaliError as exc:
            err.write(f"kalictl: {exc}\n")
            code = 1
        except Exception as exc:  # click's usage errors and the like
            err.write(f"kalictl: {verb}: {exc}\n")
            code = 2
    return {"ok": code == 0, "code": code, "output": out.getvalue(), "error": err.getvalue()}
