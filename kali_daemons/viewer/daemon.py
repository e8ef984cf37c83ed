"""Viewer (thesis 3.3.7, DESIGN 8): the live rerun dashboard at 25 Hz.

"A separate asynchronous process called the 'viewer' runs on a separate CPU and simply picks
the relevant data from shared memory and displays it at about 25 Hz refresh so that the user
can monitor the system status like robot position, tracking error, etc." (3.3.7)

Each cycle it reads the arena without locking (Type 4 records: a torn read costs one frame,
never a command) and logs to rerun (``sinks.py`` says where, ``dashboard.py`` what).  It is not
a real-time process: its cycle allocates, and a frame that fails is counted and logged, never
raised, for the dashboard must not halt the system.  What it draws:
docs/internals/sio-viewer-core.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from ..core import layout, rt
from ..core.errors import DaemonError
from ..runtime.daemon import Daemon
from ..runtime.instance import decode
from .sinks import WebViewer, grpc_address, grpc_answers, pick_port

if TYPE_CHECKING:
    from .dashboard import Dashboard

READY_TIMEOUT_S = 30.0  # how long the viewer waits at start for SIO's and the plant's records


class Viewer(Daemon):
    """The dashboard process: non-serious, priority 0, on its own CPU (config)."""

    kind = "viewer"
    self_timed_in_realtime = True  # keeps drawing while a halt has stopped the wall clock

    def __init__(self, instance: str, name: str, **kw: object) -> None:
        kw.setdefault("lock_memory", False)  # not real-time: rerun's buffers need not be locked
        super().__init__(instance, name, **kw)  # type: ignore[arg-type]
        self.board: Dashboard | None = None  # what it draws, once it has somewhere to draw
        self.web: WebViewer | None = None
        self._errors = 0

    # ------------------------------------------------------------------ set-up

    def on_configure(self) -> None:
        """Wait for SIO's and the plant's records, set the sinks up and, if there is one, load
        the arms' shapes and log everything that never changes."""
        inst = self.inst
        self.dash = inst.arena.existing(layout.KEY_DASHBOARD, layout.DASHBOARD)
        deadline = rt.monotonic_ns() + int(READY_TIMEOUT_S * 1e9)
        while not self._records_ready():
            if rt.monotonic_ns() > deadline:
                raise DaemonError(f"{self.name}: SIO and the plant did not lay out their records")
            if inst.shutting_down:
                return
            rt.AbsoluteSleeper().until(rt.monotonic_ns() + 5_000_000)
        self._open_sinks()

    def _records_ready(self) -> bool:
        arena = self.inst.arena
        if arena.lookup(layout.KEY_WORLD_TRUTH) is None or arena.lookup(layout.KEY_ROBOTS) is None:
            return False
        if arena.lookup(layout.KEY_SERVO_CTRL) is None:
            return False
        return bool(arena.existing(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)["ready"])

    def _open_sinks(self) -> None:
        """A live viewer if one listens, else the web viewer (``dashboard.web``); a recording
        file if kalictl start was given one.  Published in the dashboard record."""
        d = self.inst.config.dashboard
        dash = self.dash
        grpc: list[str] = []  # where the dashboard streams
        files: list[str] = []  # and records
        notes: list[str] = []
        live = ""
        found = None if d.connect is None else grpc_answers(*grpc_address(d.connect))
        if found:
            assert d.connect is not None  # found: its answer
            live = d.connect
            grpc.append(live)
            self.log.info("dashboard: streaming to the live rerun viewer at %s", live)
        elif found is not None:  # streaming there would block the viewer for good
            port = grpc_address(d.connect)[1]  # type: ignore[arg-type]
            notes.append(
                f"dashboard.connect {d.connect}: port {port} is in use by something that is "
                f"not a rerun viewer (it does not answer gRPC); not streaming there"
            )
        if d.web == "on" or (d.web == "auto" and not live):
            web_port, web_taken = pick_port(d.web_port)
            grpc_port, grpc_taken = pick_port(d.grpc_port)
            while grpc_port == web_port:
                grpc_port, _ = pick_port(0)
            if web_taken:
                notes.append(f"dashboard.web_port {d.web_port} taken, serving on {web_port}")
            if grpc_taken:
                notes.append(f"dashboard.grpc_port {d.grpc_port} taken, using {grpc_port}")
            web = WebViewer(web_port, grpc_port, d.server_memory_mib)
            try:
                web.start()
                self.web = web
                grpc.append(web.grpc_url)
                dash["web_pid"] = web.proc.pid if web.proc else 0
                dash["web_url"] = web.url.encode()
                self.log.info("dashboard: open %s (kalictl view)", web.url)
            except DaemonError as exc:
                notes.append(str(exc))
        record = decode(dash["record"])
        if record:
            files.append(record)
            self.log.info("dashboard: recording to %s (replay: rerun %s)", record, record)
        for note in notes:
            self.log.warning("%s", note)
        dash["live"] = int(bool(live))
        dash["live_url"] = live.encode()
        if not grpc and not files:
            notes.append("no sink: no live viewer, dashboard.web off and no record")
            self.log.warning("dashboard: %s", notes[-1])
        dash["message"] = "; ".join(notes).encode()[: layout.MESSAGE_BYTES - 1]
        if grpc or files:
            from .dashboard import Dashboard, open_recording  # rerun: only where one watches

            self.board = Dashboard(self.inst, open_recording(self.inst, grpc, files))
            self.board.log_static()
        dash["ready"] = 1

    # ------------------------------------------------------------------ the cycle

    def cycle(self, tick: int) -> None:
        """Inside the cycle, but not real-time: one dashboard frame (it allocates; rerun does).

        A frame that raises is counted in the dashboard record and logged once; it never
        halts the system.
        """
        if self.board is None:
            return
        try:
            self.board.frame()
            self.dash["frames"] += 1
        except Exception as exc:  # the dashboard must not halt the system
            self._errors += 1
            self.dash["errors"] = self._errors
            if self._errors == 1:
                self.log.exception("dashboard frame failed (later failures only counted)")
                self.dash["message"] = f"frame failed: {exc}".encode()[: layout.MESSAGE_BYTES - 1]

    # ------------------------------------------------------------------ shutdown

    def on_deactivate(self) -> None:
        """A last frame as the instance stops: in lockstep mode a halt stops the clock before
        the viewer's stage, so this is where the recording gets the fault and the final
        state."""
        self.cycle(-1)

    def on_shutdown(self) -> None:
        """Flush and close the sinks (the recording gets its footer), then stop the web
        viewer's server; leaves no process or port behind."""
        board, self.board = self.board, None
        if board is not None:
            try:
                board.rec.flush(timeout_sec=1.0)
            except Exception:  # a slow sink must not keep the viewer alive
                self.log.warning("dashboard: flush did not finish within 1 s")
            board.rec.disconnect()
        if self.web is not None:
            self.web.stop()
            self.web = None


__all__ = ["Viewer"]
