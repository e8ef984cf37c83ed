"""A start's processes forked from one interpreter that has imported what every daemon
imports, so a start pays for those imports once.  The launcher writes one job per line (JSON:
module, instance, name, log) and an empty line, and reads back each child's pid, then
``exit PID CODE`` lines until it closes the spawner's input.  ``serve`` is a warm spawner
(``--serve SOCKET``) that has imported every hosted daemon's modules too and forks a start's
spawner per connection, for lockstep executives' starts when ``$KALI_SPAWNER`` names it.
Protocol and lifetime: docs/internals/architecture.md.
"""

from __future__ import annotations

import contextlib
import ctypes
import errno
import importlib
import json
import os
import runpy
import select
import signal
import socket
import sys
import traceback
from typing import IO, Any

import numpy  # noqa: F401  (imported for the children: what every daemon imports)

from ..runtime import daemon  # noqa: F401  (the base class, config, layout, kernels)

REAP_S = 0.02  # how often a child's exit is looked for while the start goes on
PACKAGE = os.path.dirname(os.path.dirname(os.path.realpath(__file__)))  # kali_daemons/
SERVE_REAP_S = 0.5  # how often a warm spawner reaps the start spawners it forked
# what a warm spawner imports besides: the modules of every daemon the executive hosts
WARM = (
    "lockstep.executive",
    "plant.daemon",
    "sio.daemon",
    "servo.sv.daemon",
    "tg.daemon",
    "dynamics.daemon",
    "viewer.daemon",
)


def name_as(argv: list[str]) -> None:
    """Make this process's command line (``/proc/PID/cmdline``, what ``ps`` shows and what
    ``launcher.is_kali_process`` reads) ``argv``, as if it had been started so: written over
    the spawner's own, which the launcher made long enough (``launcher.SPAWNER_ROOM``).  Left
    as it is if it does not fit."""
    with open("/proc/self/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    start, end = int(fields[45]), int(fields[46])  # arg_start, arg_end (proc(5): 48, 49)
    text = b"\0".join(a.encode() for a in argv) + b"\0"
    if len(text) <= end - start:
        ctypes.memmove(start, text.ljust(end - start, b"\0"), end - start)


def run_child(job: dict[str, Any]) -> int:
    """In the forked child: the module run as its own program; its exit status."""
    os.setsid()
    log = os.open(job["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    null = os.open(os.devnull, os.O_RDONLY)
    os.dup2(null, 0)  # over the spawner's pipes: the child holds neither
    os.dup2(log, 1)
    os.dup2(log, 2)
    os.close(null)
    os.close(log)
    module = f"kali_daemons.{job['module']}"
    args = ["--instance", job["instance"], "--name", job["name"]]
    name_as([sys.executable, "-m", module, *args])
    sys.argv = [module, *args]
    try:
        runpy.run_module(module, run_name="__main__", alter_sys=True)
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            return exc.code or 0
        print(exc.code, file=sys.stderr)
        return 1
    except BaseException:
        traceback.print_exc()
        return 1
    return 0


def spawn(jobs: IO[str], out: IO[str]) -> None:
    """Fork a child per job line read from ``jobs`` up to an empty line, each child's pid to
    ``out``; then each child's exit as it comes, until ``jobs`` ends."""
    children: set[int] = set()
    while line := jobs.readline().strip():
        job = json.loads(line)
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the child ends as an interpreter does (atexit, flushed streams), out
            sys.exit(run_child(job))  # of this loop: nothing here catches SystemExit
        children.add(pid)
        out.write(f"{pid}\n")
        out.flush()
    while True:
        ready, _, _ = select.select([jobs], [], [], REAP_S)
        for pid in list(children):
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                children.discard(pid)
                out.write(f"exit {pid} {os.waitstatus_to_exitcode(status)}\n")
                out.flush()
        if ready and not jobs.readline():
            return  # the start is over


def serve(path: str) -> None:
    """The warm spawner (the module's docstring): listen on Unix socket ``path`` and fork a
    start's spawner per connection (``start_from``) until standard input ends."""
    for module in WARM:
        importlib.import_module(f"kali_daemons.{module}")
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as probe:
        if probe.connect_ex(path) == errno.ECONNREFUSED:  # a socket no server holds any more
            os.unlink(path)
    server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    server.bind(path)
    server.listen(16)
    signal.signal(signal.SIGTERM, lambda *_: sys.exit(0))  # through ``finally``, as at EOF
    owner = os.getpid()  # a child leaves through here too (its SystemExit): it keeps the socket
    served = 0  # connections taken
    try:
        while True:
            ready, _, _ = select.select([server, sys.stdin], [], [], SERVE_REAP_S)
            with contextlib.suppress(ChildProcessError):
                while os.waitpid(-1, os.WNOHANG)[0]:
                    pass
            if sys.stdin in ready and not os.read(sys.stdin.fileno(), 4096):
                return  # the owner is gone
            if server in ready:
                conn, _ = server.accept()
                served += 1
                sys.stderr.flush()
                if os.fork() == 0:
                    signal.signal(signal.SIGTERM, signal.SIG_DFL)
                    server.close()
                    sys.exit(start_from(conn, served))  # as an interpreter ends, as daemons do
                conn.close()
    finally:
        if os.getpid() == owner:
            server.close()
            with contextlib.suppress(FileNotFoundError):
                os.unlink(path)


def start_from(conn: socket.socket, served: int) -> int:
    """In a warm spawner's child: one start's spawner on connection ``conn`` (the warm
    spawner's ``served``-th), its first line the start's ``env``, ``cwd``, ``instance`` and
    ``log``.  It exits when the start is over (its status returned only when it failed);
    each daemon it forks leaves through here with its own ``SystemExit``, as from ``spawn``."""
    try:
        os.setsid()
        os.dup2(conn.fileno(), 0)  # where a started spawner's pipes are: a child replaces them
        os.dup2(conn.fileno(), 1)
        conn.close()
        jobs, out = os.fdopen(0, "r"), os.fdopen(1, "w")
        out.write(json.dumps({"package": PACKAGE, "served": served}) + "\n")  # whose modules
        out.flush()
        head = json.loads(jobs.readline())
        log = os.open(head["log"], os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        os.dup2(log, 2)
        os.close(log)
        os.environ.clear()
        os.environ.update(head["env"])
        os.chdir(head["cwd"])
        instance = head["instance"]
        name_as([sys.executable, "-m", "kali_daemons.tools.spawner", "--instance", instance])
        spawn(jobs, out)
        out.flush()
        sys.stderr.flush()
        os._exit(0)  # gone before its connection ends: a stop after the start finds it gone
    except Exception:
        traceback.print_exc()
        return 1


if __name__ == "__main__":  # python -m kali_daemons.tools.spawner --instance I --room=...
    if sys.argv[1:2] == ["--serve"]:  # ... --serve SOCKET --room=...
        serve(sys.argv[2])
    else:
        spawn(sys.stdin, sys.stdout)
