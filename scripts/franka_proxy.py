"""A relay of libfranka's robot protocol on loopback that drops or delays its UDP packets: the
network between Kali and an FR3 gone bad, for the fault matrix and the benchmarks.

    link --TCP 1337--> proxy (--listen) --TCP--> robot or franky-sim (--upstream)
    link <--UDP state-- proxy <--UDP state-- robot       (drops, delays, blackouts here)
    link --UDP command--> proxy --UDP command--> robot

libfranka's Connect request carries the client's UDP port: the proxy puts its own upstream
port there and remembers the client's, to send it the states.  Faults from the command line,
or toggled while it runs: SIGUSR1 blacks the states out (every one dropped) until the next
SIGUSR1, SIGUSR2 drops each state with probability --drop-p until the next SIGUSR2.  It also
counts, per state that shows the robot in motion, the commands that answered it (by message
id): outside both ends, whether each was answered once.  SIGTERM prints the counts as JSON.

    python scripts/franka_proxy.py --listen 127.0.0.5 --upstream 127.0.0.1
"""

from __future__ import annotations

import argparse
import heapq
import json
import random
import select
import signal
import socket
import struct
import sys
import time

ROBOT_PORT = 1337
HEADER = struct.Struct("<III")  # libfranka's TCP message header: command, id, size
CONNECT = 0  # the Connect command: then <HH version, the client's UDP port
MOVE_MODE = 2  # RobotMode Move, the byte before a state's success rate
SLICE_S = 0.05


class Relay:
    """One client at a time; its faults set from the command line and the signals."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.rng = random.Random(args.seed)
        self.blackout = args.blackout
        self.dropping = args.dropping
        self.stop = False
        self.listener = socket.create_server((args.listen, ROBOT_PORT), reuse_port=False)
        self.up = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # faces the robot
        self.up.bind((args.upstream, 0))
        self.down = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)  # faces the client
        self.down.bind((args.listen, 0))
        self.client: socket.socket | None = None
        self.robot: socket.socket | None = None
        self.buffer = b""
        self.client_udp: tuple[str, int] | None = None
        self.robot_udp: tuple[str, int] | None = None
        self.pending: list[tuple[float, int, socket.socket, bytes, tuple[str, int]]] = []
        self.serial = 0
        self.moving: set[int] = set()  # ids of states forwarded showing Move
        self.answers: dict[int, int] = {}  # a command's message id: how many carried it
        self.counts = dict.fromkeys(("states", "forwarded", "dropped", "commands"), 0)

    def toggle_blackout(self, *_: object) -> None:
        self.blackout = not self.blackout

    def toggle_dropping(self, *_: object) -> None:
        self.dropping = not self.dropping

    def run(self) -> None:
        print(f"READY {self.args.listen}", flush=True)
        while not self.stop:
            socks = [self.listener, self.up, self.down]
            socks += [s for s in (self.client, self.robot) if s is not None]
            wait = max(0.0, self.pending[0][0] - time.monotonic()) if self.pending else SLICE_S
            try:
                ready, _, _ = select.select(socks, [], [], wait)
            except InterruptedError:
                continue
            now = time.monotonic()
            while self.pending and self.pending[0][0] <= now:
                _, _, sock, data, addr = heapq.heappop(self.pending)
                sock.sendto(data, addr)
            for s in ready:
                self._serve(s)

    def _serve(self, s: socket.socket) -> None:
        if s is self.listener:
            conn, _ = self.listener.accept()
            if self.client is not None:
                conn.close()  # one client at a time, as a robot takes one
                return
            try:
                # from the upstream address: the robot sends its states to the TCP peer's
                # address, at the UDP port the Connect request names (``self.up``'s)
                upstream = self.args.upstream
                self.robot = socket.create_connection((upstream, ROBOT_PORT), None, (upstream, 0))
            except OSError:
                conn.close()  # nothing there yet (a simulator still loading): the link retries
                return
            self.client, self.buffer = conn, b""
        elif s is self.client:
            self._from_client(s.recv(65536))
        elif s is self.robot:
            data = s.recv(65536)
            if not data:
                self._drop_client()
            elif self.client is not None:
                self.client.sendall(data)
        elif s is self.up:
            data, self.robot_udp = self.up.recvfrom(65536)
            self._state(data)
        elif s is self.down:
            data, _ = self.down.recvfrom(65536)
            self.counts["commands"] += 1
            mid = struct.unpack_from("<Q", data)[0]
            self.answers[mid] = self.answers.get(mid, 0) + 1
            if self.robot_udp is not None:
                self._send(self.up, data, self.robot_udp, self.args.delay_command_ms)

    def _from_client(self, data: bytes) -> None:
        """Whole TCP messages on to the robot, the Connect request's UDP port made ours."""
        if not data:
            self._drop_client()
            return
        assert self.client is not None and self.robot is not None
        self.buffer += data
        while len(self.buffer) >= HEADER.size:
            command, _, size = HEADER.unpack_from(self.buffer)
            if len(self.buffer) < size:
                break
            message, self.buffer = self.buffer[:size], self.buffer[size:]
            if command == CONNECT:
                version, port = struct.unpack_from("<HH", message, HEADER.size)
                self.client_udp = (self.client.getpeername()[0], port)
                ours = struct.pack("<HH", version, self.up.getsockname()[1])
                message = message[: HEADER.size] + ours + message[HEADER.size + 4 :]
            self.robot.sendall(message)

    def _state(self, data: bytes) -> None:
        self.counts["states"] += 1
        if self.client_udp is None:
            return
        if self.blackout or (self.dropping and self.rng.random() < self.args.drop_p):
            self.counts["dropped"] += 1
            return
        self.counts["forwarded"] += 1
        if data[-5] == MOVE_MODE:
            self.moving.add(struct.unpack_from("<Q", data)[0])
        self._send(self.down, data, self.client_udp, self.args.delay_state_ms)

    def _send(self, sock: socket.socket, data: bytes, addr: tuple[str, int], ms: float) -> None:
        if ms <= 0:
            sock.sendto(data, addr)
            return
        self.serial += 1
        heapq.heappush(self.pending, (time.monotonic() + ms / 1e3, self.serial, sock, data, addr))

    def _drop_client(self) -> None:
        for s in (self.client, self.robot):
            if s is not None:
                s.close()
        self.client = self.robot = None
        self.client_udp = None

    def report(self) -> dict[str, int]:
        answered = [self.answers.get(i, 0) for i in self.moving]
        return {
            **self.counts,
            "moving_states": len(self.moving),
            "answered_once": sum(1 for n in answered if n == 1),
            "answered_twice_or_more": sum(1 for n in answered if n > 1),
            "unanswered": sum(1 for n in answered if n == 0),
        }


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--listen", default="127.0.0.5", help="where the link connects")
    ap.add_argument("--upstream", default="127.0.0.1", help="the robot or franky-sim")
    ap.add_argument("--drop-p", type=float, default=0.1, help="states dropped while dropping")
    ap.add_argument("--dropping", action="store_true", help="start dropping (SIGUSR2 toggles)")
    ap.add_argument("--blackout", action="store_true", help="start blacked out (SIGUSR1)")
    ap.add_argument("--delay-state-ms", type=float, default=0.0)
    ap.add_argument("--delay-command-ms", type=float, default=0.0)
    ap.add_argument("--seed", type=int, default=1)
    relay = Relay(ap.parse_args(argv))

    def stop(*_: object) -> None:
        relay.stop = True

    signal.signal(signal.SIGTERM, stop)
    signal.signal(signal.SIGINT, stop)
    signal.signal(signal.SIGUSR1, relay.toggle_blackout)
    signal.signal(signal.SIGUSR2, relay.toggle_dropping)
    relay.run()
    print("PROXY " + json.dumps(relay.report()), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
