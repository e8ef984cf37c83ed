"""Where the viewer's dashboard goes (DESIGN 8): a live rerun viewer, the web viewer, a file.

- A **live viewer**: a rerun viewer already listening at ``dashboard.connect`` (a native
  ``rerun`` started by the user; found with one short TCP connect, so start-up never blocks).
- The **web viewer**: ``rerun --serve-web`` bound to 127.0.0.1 only, run as the viewer's child.
  It serves the viewer's HTML/wasm over HTTP and a gRPC proxy the viewer logs to, which keeps
  ``dashboard.server_memory_mib`` of data for browsers that connect later.  The SDK's own
  ``serve_web_viewer`` cannot be used: it always binds every interface.  The child dies with
  the viewer, also when the viewer is killed with -9: it is started through util-linux's
  ``setpriv --pdeathsig KILL`` (a ``preexec_fn`` is not safe once rerun has started threads).
- A **recording**: an ``.rrd`` file (``rerun FILE`` replays it).

Everything here runs outside the cycle, in ``on_configure`` and ``on_shutdown``.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import socket
import subprocess
import time
import urllib.parse
from pathlib import Path

from ..core.errors import DaemonError
from ..runtime.config import GRPC_URL_RE

LIVE_PROBE_S = 0.2  # one TCP connect to the live viewer's address; longer means "not there"
WEB_START_S = 10.0  # how long the web viewer's server may take to listen
WEB_STOP_S = 2.0  # how long it gets to leave on SIGTERM before SIGKILL
LOCALHOST = "127.0.0.1"


def grpc_address(url: str) -> tuple[str, int]:
    """(host, port) of a ``rerun+http://HOST:PORT/proxy`` URL (config.py validated its form)."""
    m = GRPC_URL_RE.fullmatch(url)
    if m is None:
        raise DaemonError(f"viewer: {url!r} is not a rerun gRPC URL like {grpc_url(9876)}")
    return m.group(2).strip("[]"), int(m.group(3))


def grpc_url(port: int, host: str = LOCALHOST) -> str:
    """The rerun gRPC URL of a proxy at ``host:port``."""
    return f"rerun+http://{host}:{port}/proxy"


def web_url(web_port: int, grpc: str) -> str:
    """The address a browser opens: the web viewer, told where its data comes from."""
    return f"http://{LOCALHOST}:{web_port}/?url={urllib.parse.quote(grpc, safe='')}"


def reachable(host: str, port: int, timeout_s: float = LIVE_PROBE_S) -> bool:
    """True if something accepts a TCP connection at ``host:port`` within ``timeout_s``."""
    try:
        with socket.create_connection((host, port), timeout=timeout_s):
            return True
    except OSError:
        return False


H2_PREFACE = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n"  # a client's first bytes (RFC 9113 3.4)
H2_SETTINGS = 4  # the frame type an HTTP/2 server's own preface starts with


def grpc_answers(host: str, port: int, timeout_s: float = LIVE_PROBE_S) -> bool | None:
    """Whether a gRPC server (a rerun viewer) listens at ``host:port``: None if nothing
    accepts a connection there, True if it answers HTTP/2's preface with its SETTINGS frame,
    False if something else holds the port (a rerun sink streaming to it would block)."""
    try:
        conn = socket.create_connection((host, port), timeout=timeout_s)
    except OSError:
        return None
    with conn:
        try:
            conn.sendall(H2_PREFACE)
            head = conn.recv(9)
        except OSError:  # silent, or hung up on the preface: not a gRPC server
            return False
    return len(head) >= 4 and head[3] == H2_SETTINGS


def pick_port(wanted: int) -> tuple[int, bool]:
    """``wanted`` if it can be bound on 127.0.0.1, else a free port; and whether it was taken.

    ``wanted`` 0 means any free port.  (A small race remains: the port is free when looked at.)
    """
    if wanted:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as the server binds
            try:
                s.bind((LOCALHOST, wanted))
                return wanted, False
            except OSError:
                pass
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((LOCALHOST, 0))
        return int(s.getsockname()[1]), bool(wanted)


def rerun_binary() -> Path:
    """The ``rerun`` command-line binary shipped in the rerun-sdk wheel (package rerun_cli)."""
    import rerun_cli  # the package holds only the binary; importing it is cheap

    path = Path(rerun_cli.__file__).parent / "rerun"
    if not path.is_file():
        raise DaemonError(f"viewer: no rerun binary at {path} (reinstall rerun-sdk)")
    return path


class WebViewer:
    """``rerun --serve-web`` on 127.0.0.1 as the viewer's child process."""

    def __init__(self, web_port: int, grpc_port: int, memory_mib: int) -> None:
        self.web_port = web_port
        self.grpc_port = grpc_port
        self.memory_mib = memory_mib
        self.proc: subprocess.Popen[bytes] | None = None

    @property
    def grpc_url(self) -> str:
        """Where the viewer logs to (the proxy in the child)."""
        return grpc_url(self.grpc_port)

    @property
    def url(self) -> str:
        """What a browser opens."""
        return web_url(self.web_port, self.grpc_url)

    def start(self) -> None:
        """Start the server and wait until both ports listen; DaemonError saying why not."""
        setpriv = shutil.which("setpriv")
        if setpriv is None:
            raise DaemonError(
                "viewer: no setpriv (Debian package util-linux): the web viewer's server "
                "could outlive the viewer"
            )
        args = [
            setpriv,
            "--pdeathsig",
            "KILL",
            "--",
            str(rerun_binary()),
            "--serve-web",
            "--bind",
            LOCALHOST,
            "--port",
            str(self.grpc_port),
            "--web-viewer-port",
            str(self.web_port),
            "--server-memory-limit",
            f"{self.memory_mib}MiB",
        ]
        env = {**os.environ, "RUST_LOG": "warn"}
        self.proc = subprocess.Popen(
            args,
            stdin=subprocess.DEVNULL,  # its warnings go to the viewer's log
            env=env,
            close_fds=True,
        )
        deadline = time.monotonic() + WEB_START_S
        while not (reachable(LOCALHOST, self.web_port) and reachable(LOCALHOST, self.grpc_port)):
            if self.proc.poll() is not None:
                code = self.proc.returncode
                self.proc = None
                raise DaemonError(
                    f"viewer: rerun --serve-web (web port {self.web_port}, gRPC port "
                    f"{self.grpc_port}) exited with {code} at start; see the viewer log"
                )
            if time.monotonic() > deadline:
                self.stop()
                raise DaemonError(
                    f"viewer: rerun --serve-web did not listen on ports {self.web_port} and "
                    f"{self.grpc_port} within {WEB_START_S:g} s"
                )
            time.sleep(0.02)

    def stop(self) -> None:
        """Terminate the server and reap it; safe to call twice."""
        proc, self.proc = self.proc, None
        if proc is None:
            return
        with contextlib.suppress(ProcessLookupError):
            proc.terminate()
        try:
            proc.wait(WEB_STOP_S)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
