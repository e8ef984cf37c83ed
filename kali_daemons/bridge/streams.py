"""Remote streams written by the bridge itself.

A remote program's stream sends (``send``, ``send_twist``) and its shared transforms' sets
go from the Zenoh thread that delivers them straight into the record its session holds, with
a local send's checks, rather than through the session's process: that path is two wake-ups
of normal-priority processes each way on a machine whose cores carry the servo level.  The
session still holds the record (its pid, the lifetime and stale-stop rule, ``close``) and
creates it.  A call this path does not carry out (a value refused, the record no longer the
session's, keyword arguments, objects to drop) goes to the session as before, which answers
it in a local call's words; a program's calls come one at a time, so the two never write the
record at once.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..client import protocol
from ..client.streams import twisted, write_pose
from ..core import layout
from ..core.errors import KaliError
from ..runtime.instance import Instance, decode
from ..tg.tracking import write_frame

CREATES = frozenset({"stream", "stream_joints", "shared_transform"})  # calls that hold one
WRITES = {  # the calls carried out here, by the class of the object called
    "Stream": frozenset({"send", "send_twist"}),
    "JointStream": frozenset({"send"}),
    "SharedTransform": frozenset({"set", "set_joints"}),
}


@dataclass(frozen=True)
class Held:
    """A record a session holds, as its reference crossed: what the call's reply carries."""

    cls: str
    index: int
    name: str
    lifetime: float
    robot: str  # a stream's robot ("" for a shared transform)
    attrs: dict[str, Any]


class RemoteStreams:
    """The records remote programs' sessions hold, by session and object number."""

    def __init__(self, inst: Instance) -> None:
        self.inst = inst
        self.frames = inst.arena.record(
            layout.KEY_TG_FRAMES, layout.SHARED_FRAME, layout.MAX_FRAMES
        )
        self.tick_s = inst.config.clock.base_tick_ms / 1000.0
        self._held: dict[str, dict[int, Held]] = {}  # secret -> object number -> record
        self._lock = threading.Lock()
        self.written = 0  # writes carried out here (the bridge's status says)

    def learn(self, secret: str, payload: bytes, answer: bytes) -> None:
        """Note the record a call that creates one (``CREATES``) answered with; an answer
        not of that shape is left to the session (this path only spares it work)."""
        if not any(m.encode() in payload for m in CREATES):
            return  # no such call: nothing parsed
        try:
            request = protocol.loads(payload, "call")
            if not isinstance(request, dict) or request.get("method") not in CREATES:
                return
            value = protocol.loads(answer, "answer").get("value")
            if not isinstance(value, dict) or value.get("class") not in WRITES:
                return
            attrs = value["attrs"]
            frame = attrs["frame"]["attrs"] if "frame" in attrs else attrs
            name = str(frame["name"])
            robot = "" if value["class"] == "SharedTransform" else robot_of(name)
            held = Held(
                value["class"], int(frame["index"]), name, float(frame["lifetime"]), robot, attrs
            )
            oid = int(value["__obj__"])
        except (KaliError, KeyError, TypeError, ValueError, IndexError, AttributeError):
            return
        with self._lock:
            mine = self._held.setdefault(secret, {})
            for earlier in [o for o, h in mine.items() if h.index == held.index]:
                del mine[earlier]  # that record's earlier holder: closed, since taken again
            mine[oid] = held

    def forget(self, secret: str) -> None:
        """The session ended."""
        with self._lock:
            self._held.pop(secret, None)

    def call(self, secret: str, pid: int, payload: bytes) -> bytes | None:
        """Carry out a write to a record session ``secret`` (process ``pid``) holds and
        answer it as the session would; None: not one this path carries out whole."""
        mine = self._held.get(secret)
        if not mine:
            return None
        try:
            request = protocol.loads(payload, "call")
        except KaliError:
            return None
        if not isinstance(request, dict) or request.get("drop") or request.get("kwargs"):
            return None
        held = mine.get(request.get("target"))  # type: ignore[arg-type]
        method = request.get("method")
        args = request.get("args")
        if held is None or method not in WRITES[held.cls] or not isinstance(args, list):
            return None
        record = self.frames[held.index : held.index + 1].reshape(())
        if int(record["owner_pid"]) != pid or decode(record["name"]) != held.name:
            return None  # closed: the session says so
        if len(args) != 1:
            return None
        with self._lock:  # Zenoh's threads: one writer at a time
            return self._write(held, record, method, args[0], request.get("id"))

    def _write(
        self, held: Held, record: np.ndarray, method: str, arg: Any, rid: Any
    ) -> bytes | None:
        try:
            value = protocol.decode(arg)
            tick = int(self.inst.clock["tick"])
            if method == "set_joints" or held.cls == "JointStream":
                if not isinstance(value, np.ndarray) or value.ndim != 1:
                    return None
                if value.size > record["joints"].shape[0]:
                    return None
                write_frame(record, tick, None, value)  # unchecked, as a local one's
            else:
                if method == "send_twist":
                    value = twisted(record, held.robot, value, tick, self.tick_s, held.lifetime)
                write_pose(record, held.name, tick, value)
        except KaliError:
            return None  # refused: the session refuses it in its own words
        self.written += 1
        reply = {"value": None, "attrs": held.attrs, "id": rid}
        return protocol.dumps(reply)


def robot_of(name: str) -> str:
    """A stream's robot, from its record's name (``stream.ROBOT.PID``, ``joints.ROBOT.PID``)."""
    return name.split(".", 1)[1].rsplit(".", 1)[0]
