"""A start's processes forked from one interpreter that has already imported what every daemon
imports (numpy, the daemon base, the config, the layout, the kernels): a start pays for those
imports once, not once per process (they were most of a real-time start's time).

The launcher runs ``python -m kali_daemons.tools.spawner`` and writes one job per line (JSON:
``module``, ``instance``, ``name``, ``log``), then an empty line; for each job it reads back a
line with the child's pid.  Each child leaves the spawner's session, writes to its log and
runs its module as ``python -m kali_daemons.<module> --instance I --name N`` would.  Until
the launcher closes the spawner's input (the start is over, either way), the spawner reaps a
child that exits and writes ``exit PID CODE``; then it exits, and the children it leaves are
the init process's.
"""

from __future__ import annotations

import ctypes
import json
import os
import runpy
import select
import sys
import traceback
from typing import IO, Any

import numpy  # noqa: F401  (imported for the children: what every daemon imports)

from ..runtime import daemon  # noqa: F401  (the base class, config, layout, kernels)

REAP_S = 0.02  # how often a child's exit is looked for while the start goes on


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


if __name__ == "__main__":  # python -m kali_daemons.tools.spawner --instance I --room=...
    spawn(sys.stdin, sys.stdout)
