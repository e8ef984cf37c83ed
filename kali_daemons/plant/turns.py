"""franky-sim's side of lockstep over libfranka's protocol (decision 0015): each FR3's link
and the plant take turns on every state packet (the link's side: ``kali_daemons.link.turns``).

While the cell starts, a thread serves franky-sim with the physics standing: connections, and a
state whenever a link not yet connected asks for one.  Each tick: let every link go, wait until
each is ready (it answered the last state, chose its next call) and what it announced (its
answer, a request) is on franky-sim's sockets, then step and send; and once sent, wait until
each link has taken its state.  A gripper command is waited for the same way, and its outcome
once franky-sim answers it.  A wait that outlasts its share of the lockstep timeout halts with
DEADLINE naming the link, a link that died with PROCESS_DIED, and the tick goes on for the
other links (they may be waiting in libfranka, whose receive gives up after 1 s).  franky-sim
keeps its sockets private: they are read by name (franky-sim is pinned to 1.0).
"""

from __future__ import annotations

import select
import threading
import time
from typing import Any

from ..core import futex, rt
from ..core.layout import FaultCode
from ..core.spinlock import pid_alive
from ..hardware.franka.arms import records
from ..hardware.franka.registers import LINK_CONNECTED, LS_TCP, LS_UDP
from ..runtime.instance import Instance

SERVE_S = 0.0005  # while the cell starts: franky-sim served this often
SLICE_S = 0.05  # a wait looks at the link's process this often
WAIT_SHARE = 0.5  # of the lockstep timeout, what one wait may take (the clock's watchdog: all)
ARRIVE_S = 0.5  # what a called link announced is on franky-sim's socket within this (loopback)


def _socket(server: Any, name: str) -> Any:
    """franky-sim's ``FrankaServer`` socket ``name`` (``tcp``, ``udp``): private there."""
    return getattr(server, f"_FrankaServer__{name}_socket")


class PlantTurns:
    """The plant's turns with every FR3's link (and hand) of a lockstep cell."""

    def __init__(self, inst: Instance, servers: list[Any], arm_index: list[int]) -> None:
        from franky_sim.franka_server import FrankaServer  # only an FR3 cell's plant loads it

        self._send_arm_state = FrankaServer.send_state  # an arm's state, not its hand's
        cfg = inst.config
        self._inst, self._servers = inst, servers
        arms = records(inst.arena, len(cfg.robots))
        self._arms = [arms[k : k + 1].reshape(()) for k in arm_index]
        self._links = [f"link.{cfg.robots[k].name}" for k in arm_index]
        self._hands = [
            f"hand.{cfg.robots[k].name}" if cfg.robots[k].hardware.hand else "" for k in arm_index
        ]
        self._slot = {n: inst.slot_of(n) for n in (*self._links, *self._hands) if n}
        self._timeout_s = WAIT_SHARE * cfg.clock.lockstep_ack_timeout_s
        self._futex = futex.Waiter(SLICE_S)
        self._grip_seen = [int(a["grip_cmd"]) for a in self._arms]
        self._grip_busy = [False] * len(servers)
        self._failed: set[int] = set()  # the arms whose link failed its turn this tick
        self.sending: list[Any] = servers  # the robot servers sent a state this tick
        for server in servers:  # franky-sim 1.0's names, checked once
            _socket(server, "tcp"), _socket(server, "udp")
        self._stop = threading.Event()
        self._thread: threading.Thread | None = threading.Thread(
            target=self._serve, name="franky-sim start", daemon=True
        )
        self._thread.start()

    # ------------------------------------------------------------------ the start

    def _serve(self) -> None:
        """Until the first tick: connections taken, a standing state for each link that
        asks while it connects (``LinkTurns.ask``); the hands' states as they come."""
        while not self._stop.wait(SERVE_S):
            for server, arm in zip(self._servers, self._arms, strict=True):
                server.process_commands()
                asked = int(arm["ls_ready"]) > int(arm["ls_sent"])
                if asked and server.udp_connected and not int(arm["status"]) & LINK_CONNECTED:
                    arm["ls_sent"] += 1
                    self._send_arm_state(server)
                if server.gripper_server is not None:
                    server.gripper_server.send_state()

    def _end_start(self) -> None:
        if self._thread is not None:
            self._stop.set()
            self._thread.join()
            self._thread = None

    # ------------------------------------------------------------------ each tick

    def before_step(self, tick: int) -> None:
        """A new gripper command sent; each link let go (the tick before ran whole), ready
        (it answered the last state and chose its next call) and what it announced on
        franky-sim's sockets.  A process late or dead halts the cell, its fault saying why,
        and the tick goes on without it: the other links may be waiting in libfranka
        already, and take their states (a late one takes its own when it comes)."""
        self._end_start()
        self._failed.clear()
        for i, server in enumerate(self._servers):  # first: the links wait outside libfranka
            if self._hands[i]:
                self._grip_sent(i, server, tick)
        live = [
            i for i, server in enumerate(self._servers) if server.udp_connected and not self._off(i)
        ]
        for i in live:  # the tick before ran whole: choose
            self._set(i, "ls_go", int(self._arms[i]["ls_sent"]) + 1)
        for i in live:
            state, link = int(self._arms[i]["ls_sent"]) + 1, self._links[i]
            if not self._await(i, "ls_ready", state, link, "was not ready for", tick):
                self._failed.add(i)
        for i in live:  # every link ready: call (none enters libfranka while one is late)
            if i not in self._failed:
                self._set(i, "ls_call", int(self._arms[i]["ls_sent"]) + 1)
        for i in live:
            server, expect = self._servers[i], int(self._arms[i]["ls_expect"])
            wanted = [_socket(server, "udp")] if expect & LS_UDP else []
            if expect & LS_TCP:
                wanted.append(_socket(server, "tcp"))
            arrived = i in self._failed or not wanted
            if not arrived and not self._arrive(wanted, self._links[i], "a command", tick):
                self._failed.add(i)
        self._grip_busy = [
            s.gripper_server is not None and s.gripper_server._motion_state.value != "idle"
            for s in self._servers
        ]
        self.sending = self._servers  # a link not ready is sent nothing: it takes its turn up
        if self._failed:  # later (a list built only then)
            self.sending = [s for i, s in enumerate(self._servers) if i not in self._failed]
        for server, arm in zip(self._servers, self._arms, strict=True):
            if server in self.sending and server.udp_connected:
                arm["ls_sent"] += 1  # before the send: the link may take it at once

    def after_step(self, tick: int) -> None:
        """Each link has taken the state just sent, each hand reported an outcome franky-sim
        just answered; one late or dead halts the cell, as in ``before_step``."""
        for i, (server, arm) in enumerate(zip(self._servers, self._arms, strict=True)):
            if not server.udp_connected or i in self._failed:
                continue  # nobody to send to, or late already: the fault says so
            sent, link = int(arm["ls_sent"]), self._links[i]
            self._await(i, "ls_taken", sent, link, "did not take the state of", tick)
            gripper = server.gripper_server
            if self._grip_busy[i] and gripper._motion_state.value == "idle":
                self._await_grip(i, tick)  # franky-sim answered the hand's command

    def _grip_sent(self, i: int, server: Any, tick: int) -> bool:
        """A gripper command asked for and not yet in franky-sim: once the hand is free of
        the last, wait until it has sent this one (``grip_sent``) and franky-sim's gripper
        socket has it (unless franky-sim is carrying it out already)."""
        arm = self._arms[i]
        cmd = int(arm["grip_cmd"])
        if cmd == self._grip_seen[i] or not int(arm["hand_up"]):
            return True
        if int(arm["grip_sent"]) != cmd:
            if int(arm["grip_done"]) != int(arm["grip_sent"]):
                return True  # busy with the last: it takes this one once free
            hand, what = self._hands[i], "sent no gripper command at"
            if not self._await(i, "grip_sent", cmd, hand, what, tick):
                return False
        self._grip_seen[i] = cmd
        gripper = server.gripper_server
        if int(arm["grip_done"]) == cmd or gripper._motion_state.value != "idle":
            return True  # done, or being carried out
        return self._arrive([_socket(gripper, "tcp")], self._hands[i], "a gripper command", tick)

    def _await_grip(self, i: int, tick: int) -> bool:
        arm = self._arms[i]
        if not int(arm["hand_up"]):
            return True
        sent, what = int(arm["grip_sent"]), "did not report the gripper's outcome at"
        return self._await(i, "grip_done", sent, self._hands[i], what, tick)

    # ------------------------------------------------------------------ waiting

    def _set(self, i: int, field: str, value: int) -> None:
        self._arms[i][field] = value
        futex.wake(self._arms[i][field].ctypes.data)

    def _off(self, i: int) -> bool:
        return bool(int(self._arms[i]["ls_off"]))

    def _await(self, i: int, field: str, value: int, who: str, doing: str, tick: int) -> bool:
        """Wait until arm ``i``'s ``field`` holds ``value`` (a futex word that process ``who``
        wakes); False, with the cell halted naming it, if it does not in time or died.  A
        link out of the turns is waited for no more."""
        word = self._arms[i][field]
        addr, slot = word.ctypes.data, self._slot[who]
        deadline = rt.monotonic_ns() + int(self._timeout_s * 1e9)
        while (now := int(word)) != value:
            if self._off(i) and who == self._links[i]:
                return True
            if rt.monotonic_ns() > deadline:
                limit = f"{self._timeout_s:g} s (half of clock.lockstep_ack_timeout_s)"
                return self._late(who, f"{doing} tick {tick} within {limit}", tick)
            self._futex.wait(addr, now)
            pid = int(self._inst.procs[slot]["pid"])
            if pid > 0 and not pid_alive(pid):
                return self._died(who, pid, tick)
        return True

    def _arrive(self, sockets: list[Any], who: str, what: str, tick: int) -> bool:
        """Wait until each of ``sockets`` has something to read (what ``who`` sent, on
        loopback, at once: ``ARRIVE_S`` is shorter than libfranka's receive, so the other
        links still take their states)."""
        deadline = time.monotonic() + ARRIVE_S
        while True:
            left = deadline - time.monotonic()
            readable, _, _ = select.select(sockets, [], [], max(0.0, min(left, SLICE_S)))
            sockets = [s for s in sockets if s not in readable]
            if not sockets:
                return True
            if left <= 0:
                what = f"announced {what} for tick {tick}, none came within {ARRIVE_S:g} s"
                return self._late(who, what, tick)

    def _died(self, who: str, pid: int, tick: int) -> bool:
        """Process ``who`` died: a link halts the cell (nobody else can: it is not clocked),
        a hand (not serious) is waited for no more.  False if halted."""
        if who.startswith("hand."):
            return True
        self._inst.raise_fault(
            FaultCode.PROCESS_DIED,
            who,
            f"process '{who}' (pid {pid}) died at tick {tick}: the plant's lockstep turns with "
            "it cannot go on",
            tick=tick,
        )
        return False

    def _late(self, who: str, what: str, tick: int) -> bool:
        self._inst.raise_fault(FaultCode.DEADLINE, who, f"lockstep: {who} {what}", tick=tick)
        return False

    def close(self) -> None:
        self._end_start()


__all__ = ["PlantTurns"]
