"""What the bridge, its session workers and remote programs say to each other.

``Keys`` names what the bridge publishes under ``kali/INST/`` and answers there; ``UserKeys``
what one user asks and declares under its own branch ``kali/INST/user/USER/`` (with
authentication Zenoh lets a user only its own).  Payloads are JSON, any language reads them,
with tagged forms for arrays, a session's objects, states and dataclasses (``encode``,
``decode``).  Only the methods ``METHODS`` lists can be called, each on the class it names:
the worker runs them on the real client objects, so a remote request meets every check a
local one does and is refused with the same exception and message (``ERRORS``).  The key
space and the tagged forms: docs/internals/motion-client-bridge.md.
"""

from __future__ import annotations

import dataclasses
import enum
import json
import math
from collections.abc import Callable
from typing import Any

import numpy as np

from ..core import errors
from ..core.errors import KaliError
from ..core.layout import CalibState, FfMode, FfState, PowerState, RequestState
from ..hardware.camera import Frame
from ..robots.scene import Clearance, Grasp, Scene, SceneObject
from ..runtime.config import USER_RE
from ..servo.loading import Loaded
from ..servo.shadow import Trial
from .common import Contact, MotionFailedError, RequestLostError
from .state import ArmState, ObjectState
from .truth import Truth

MAX_PAYLOAD_BYTES = 1 << 20  # a call's JSON; 16 poses of a path are ~6 KiB
MAX_ARRAY_VALUES = 4096  # numbers in one array argument
MAX_DEPTH = 8  # nesting of lists and mappings in one argument


class BridgeError(KaliError):
    """The bridge refused a request or could not carry it (naming what and why)."""

    subsystem = "bridge"


class Keys:
    """The key expressions of instance ``instance``: what the bridge publishes, and the
    wildcards of what it answers, one branch per user (``user`` gives one user's keys)."""

    def __init__(self, instance: str) -> None:
        self.root = f"kali/{instance}"
        self.alive = f"{self.root}/alive"
        self.timing = f"{self.root}/timing"
        self.events = f"{self.root}/events"
        self.robots = f"{self.root}/robots/*/state"
        self.motions = f"{self.root}/motion/*"
        users = f"{self.root}/user/*"
        self.status = f"{users}/status"
        self.config = f"{users}/config"
        self.verbs = f"{users}/verb/*"
        self.session_open = f"{users}/session/open"
        self.session_calls = f"{users}/session/*/call"
        self.session_stops = f"{users}/session/*/stop"
        self.session_close = f"{users}/session/*/close"
        self.clients = f"{users}/clients/*"
        self.cameras = f"{users}/camera/*"

    def state(self, robot: str) -> str:
        return f"{self.root}/robots/{robot}/state"

    def motion(self, seq: int) -> str:
        return f"{self.root}/motion/{seq}"

    def user(self, name: str) -> UserKeys:
        """The keys user ``name`` asks and declares."""
        return UserKeys(self.root, name)

    def parse(self, key: object) -> tuple[str, list[str]]:
        """(user, the chunks after ``kali/INST/user/USER/``) of a key the bridge answers;
        BridgeError when its user chunk is no user name (a wildcard, say)."""
        chunks = str(key).split("/")
        depth = self.root.count("/") + 1  # kali/INST/user/USER/...: "user" is chunk 2
        user = chunks[depth + 1] if chunks[depth : depth + 1] == ["user"] else ""
        if len(chunks) < depth + 3 or USER_RE.fullmatch(user) is None:
            raise BridgeError(f"{str(key)!r:.120} names no user (kali/INSTANCE/user/NAME/...)")
        return user, chunks[depth + 2 :]

    def session(self, key: object) -> tuple[str, str]:
        """(user, secret) of a key ``kali/INST/user/USER/session/SECRET/WHAT``; BridgeError
        for any other (a wildcard in place of the secret, say)."""
        user, rest = self.parse(key)
        if len(rest) != 3 or rest[0] != "session" or not rest[1].isalnum():
            raise BridgeError(f"{str(key)!r:.120} names no session")
        return user, rest[1]


class UserKeys:
    """What user ``name`` asks and declares, all under ``kali/INST/user/NAME``.  With
    authentication Zenoh's access control lets each user ask and declare under its own name
    only (``access.py``), so the key tells the bridge who asks; without it, a client goes by
    a name of its own choosing (a remote ``Kali``: its Zenoh session's id)."""

    def __init__(self, root: str, name: str) -> None:
        if USER_RE.fullmatch(name) is None:
            raise BridgeError(
                f"user name {name!r:.70}: 1..64 of A-Z a-z 0-9 _ . - @, not starting with @"
            )
        self.name = name
        self.home = f"{root}/user/{name}"
        self.status = f"{self.home}/status"
        self.config = f"{self.home}/config"
        self.session_open = f"{self.home}/session/open"

    def verb(self, verb: str) -> str:
        return f"{self.home}/verb/{verb}"

    def call(self, secret: str) -> str:
        return f"{self.home}/session/{secret}/call"

    def stop(self, secret: str) -> str:
        return f"{self.home}/session/{secret}/stop"

    def close(self, secret: str) -> str:
        return f"{self.home}/session/{secret}/close"

    def client(self, sid: str) -> str:
        return f"{self.home}/clients/{sid}"

    def camera(self, name: str) -> str:
        return f"{self.home}/camera/{name}"


# The calls a remote program may make, by the class of the object it calls (methods, then
# properties read as attributes).  A remote stream or shared transform is one its session
# holds, under the same lifetime and stale-stop rule as a local one's; the bridge writes it
# on each send (``bridge.streams``).  Periodic functions and TG functions stay on the
# controller's machine (their deadlines are the wall clock's and the TG's), as do the live
# views of shared memory (``kali.servo.level``, ``kali.ft``).
METHODS: dict[str, frozenset[str]] = {
    "Kali": frozenset(
        {
            "robot",
            "motion_system",
            "ready",
            "sleep",
            "pause",
            "run_conveyor",
            "together",
            "idle",
            "start_point",
            "owner",
            "flange_pose",
            "stop_own",
            "record_in_log_dir",
            "stop_recording",
            "recorded_bytes",
            "shared_transform",
            "find_transform",
            "distance",
        }
    ),
    "Robot": frozenset(
        {
            "read_joints",
            "read_state",
            "read_t6",
            "read_pose",
            "grip",
            "settle",
            "read_wrench",
            "tare",
            "joints_at",
            "set_tool",
            "set_load",
            "move_line",
            "move_arc",
            "move_path",
            "move_joints",
            "feedforward",
            "select_servo",
            "select_joint_servos",
            "set_servo",
            "shadow_servo",
            "trials",
            "servo_params",
            "stop",
            "abort",
            "stream",
            "stream_joints",
            "track",
        }
    ),
    "MotionSystem": frozenset(
        {
            "read_pose",
            "read_state",
            "move_line",
            "move_path",
            "set_internal_force",
            "track",
            "stop",
            "abort",
        }
    ),
    "ServoClient": frozenset(
        {
            "select",
            "set_params",
            "get_params",
            "active",
            "shadow",
            "shadow_arm",
            "trials",
            "arm_active",
            "select_arm",
            "set_arm_params",
            "get_arm_params",
            "power_state",
            "feedforward",
            "feedforward_state",
            "calibration",
            "calibrated",
            "load_source",
            "loaded",
        }
    ),
    "MotionHandle": frozenset({"wait", "cancel"}),
    "SimTruth": frozenset({"truth"}),
    "Together": frozenset({"__enter__", "__exit__", "wait"}),
    "Stream": frozenset({"send", "send_twist", "close"}),
    "JointStream": frozenset({"send", "close"}),
    "SharedTransform": frozenset({"set", "set_joints", "close", "live"}),
}
PROPERTIES: dict[str, frozenset[str]] = {
    "Kali": frozenset({"scene"}),
    "MotionHandle": frozenset({"state", "message", "done", "contact", "limited"}),
    "SharedTransform": frozenset({"value"}),
}
# the plain attributes a proxy holds, read when the object crosses (and after each call)
ATTRIBUTES: dict[str, tuple[str, ...]] = {
    "Kali": ("names", "tg_dt", "force", "servo", "sim"),
    "ServoClient": ("names",),
    "Robot": ("index", "name", "n_joints", "base", "tool"),
    "MotionSystem": ("names", "indices", "grasps"),
    "MotionHandle": ("seq", "robots"),
    "Together": (),
    "SimTruth": ("simulated",),
    "Stream": ("handle", "frame"),
    "JointStream": ("handle", "frame"),
    "SharedTransform": ("index", "name", "lifetime"),
}
# the exceptions a call may raise remotely, by name; any other comes back as BridgeError
ERRORS: dict[str, type[Exception]] = {
    cls.__name__: cls
    for cls in (
        *(c for c in vars(errors).values() if isinstance(c, type) and issubclass(c, KaliError)),
        errors.MotionError,
        MotionFailedError,
        RequestLostError,
        BridgeError,
        TimeoutError,
        TypeError,
        ValueError,
    )
}
ENUMS: dict[str, type[enum.IntEnum]] = {
    e.__name__: e for e in (RequestState, PowerState, CalibState, FfMode, FfState)
}
DATACLASSES: dict[str, type] = {
    "Contact": Contact, "Trial": Trial, "ArmState": ArmState, "ObjectState": ObjectState,
    "Truth": Truth, "Loaded": Loaded, "Scene": Scene, "SceneObject": SceneObject, "Grasp": Grasp,
    "Clearance": Clearance,
}  # fmt: skip


def encode(value: Any, register: Callable[[object], dict[str, Any]] | None = None) -> Any:
    """``value`` as JSON-ready data; ``register`` turns an object of a ``METHODS`` class
    (or a remote program's proxy of one) into its tagged reference (the worker's table),
    else such an object is a BridgeError."""
    if isinstance(value, enum.IntEnum) and type(value).__name__ in ENUMS:  # before int
        return {"__enum__": type(value).__name__, "name": value.name}
    if value is None or isinstance(value, bool | int | float | str):
        return value
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return {"__nd__": value.tolist()}
    if dataclasses.is_dataclass(value) and type(value).__name__ in DATACLASSES:
        fields = {f.name: encode(getattr(value, f.name)) for f in dataclasses.fields(value)}
        return {"__dc__": type(value).__name__, **fields}
    if isinstance(value, list | tuple):
        return [encode(v, register) for v in value]
    if isinstance(value, dict):
        return {str(k): encode(v, register) for k, v in value.items()}
    if register is not None and (
        type(value).__name__ in METHODS or getattr(type(value), "stands_for_remote", False)
    ):
        return register(value)  # a session's object, or a remote proxy given back
    raise BridgeError(f"a {type(value).__name__} cannot cross the bridge")


def decode(
    value: Any, resolve: Callable[[int, str, Any], object] | None = None, depth: int = 0
) -> Any:
    """JSON data back to values: arrays, states, dataclasses; ``resolve(id, cls, attrs)``
    turns a reference into the object (the worker's own, or the remote program's proxy).  Anything
    deeper than MAX_DEPTH or an array larger than MAX_ARRAY_VALUES is a BridgeError."""
    if depth > MAX_DEPTH:
        raise BridgeError(f"an argument nested deeper than {MAX_DEPTH} levels")
    if isinstance(value, list):
        return [decode(v, resolve, depth + 1) for v in value]
    if not isinstance(value, dict):
        return value
    if "__nd__" in value:
        try:
            array = np.array(value["__nd__"], dtype=np.float64)
        except (TypeError, ValueError):
            raise BridgeError("an array argument is not all numbers") from None
        if array.size > MAX_ARRAY_VALUES:
            raise BridgeError(f"an array of {array.size} values (at most {MAX_ARRAY_VALUES})")
        return array
    if "__enum__" in value:
        enum = ENUMS.get(value["__enum__"])
        if enum is None or value.get("name") not in enum.__members__:
            raise BridgeError(f"unknown state {value!r:.80}")
        return enum[value["name"]]
    if "__dc__" in value:
        cls = DATACLASSES.get(value["__dc__"])
        if cls is None:
            raise BridgeError(f"unknown value kind {value['__dc__']!r:.40}")
        fields = {k: decode(v, resolve, depth + 1) for k, v in value.items() if k != "__dc__"}
        return cls(**fields)
    if "__obj__" in value:
        if resolve is None:
            raise BridgeError("an object reference where none is allowed")
        oid, cls = value["__obj__"], value.get("class")
        if isinstance(oid, bool) or not isinstance(oid, int) or not isinstance(cls, str):
            raise BridgeError(f"a malformed object reference {value!r:.80}")
        attrs = decode(value.get("attrs") or {}, resolve, depth + 1)
        return resolve(oid, cls, attrs)
    return {str(k): decode(v, resolve, depth + 1) for k, v in value.items()}


def dumps(value: Any) -> bytes:
    """JSON bytes (NaN and infinities as JSON5 writes them: a bad number is refused by the
    check it meets, with that check's message, not by the transport)."""
    return json.dumps(value, separators=(",", ":")).encode()


def loads(payload: bytes, what: str) -> Any:
    """Parse a payload; BridgeError naming ``what`` for anything but a JSON document within
    MAX_PAYLOAD_BYTES."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise BridgeError(f"{what}: payload of {len(payload)} bytes (at most {MAX_PAYLOAD_BYTES})")
    try:
        return json.loads(payload)
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BridgeError(f"{what}: payload is not JSON ({exc})") from None
    except RecursionError:
        raise BridgeError(f"{what}: payload nested too deep") from None


def error_reply(exc: BaseException) -> dict[str, Any]:
    """A call's exception as a reply: its class name (one of ``ERRORS``) and message."""
    name = type(exc).__name__ if type(exc).__name__ in ERRORS else "BridgeError"
    return {"error": {"type": name, "message": str(exc)}}


def raise_reply(reply: dict[str, Any]) -> None:
    """Raise the exception a reply carries, as the local call would have raised it."""
    err = reply.get("error")
    if err is None:
        return
    cls = ERRORS.get(str(err.get("type")), BridgeError)
    message = str(err.get("message", ""))
    if issubclass(cls, KaliError):  # it adds its subsystem's prefix again
        message = message.removeprefix(f"{cls.subsystem}: ")
    raise cls(message)


# A camera's frame on the wire (a reply to ``UserKeys.camera``): FRAME_MAGIC, the header's
# length (4 bytes, little-endian), the header (JSON: camera, tick, sim_time_s, stamp_ns, K,
# pose, height, width), the image's bytes (RGB, row by row), the depth (float32, little-endian).
FRAME_MAGIC = b"KALI-FRAME-1\n"


def encode_frame(frame: Frame) -> bytes:
    """``frame`` as one binary reply (a 320 x 240 frame: 0.5 MB, too big for JSON's)."""
    height, width = frame.depth.shape
    head = dumps(
        {
            "camera": frame.camera,
            "tick": frame.tick,
            "sim_time_s": frame.sim_time_s,
            "stamp_ns": frame.stamp_ns,
            "K": frame.K.tolist(),
            "pose": frame.pose.tolist(),
            "height": height,
            "width": width,
        }
    )
    return b"".join(
        (
            FRAME_MAGIC,
            len(head).to_bytes(4, "little"),
            head,
            frame.image.astype(np.uint8, copy=False).tobytes(),
            frame.depth.astype("<f4", copy=False).tobytes(),
        )
    )


def decode_frame(data: bytes, what: str) -> Frame:
    """The frame ``encode_frame`` made; BridgeError naming ``what`` if it is not one."""
    start = len(FRAME_MAGIC) + 4
    if not data.startswith(FRAME_MAGIC) or len(data) < start:
        raise BridgeError(f"{what}: not a camera frame")
    end = start + int.from_bytes(data[start - 4 : start], "little")
    head = loads(data[start:end], what)
    try:
        height, width = int(head["height"]), int(head["width"])
        pixels = height * width
        if len(data) != end + 3 * pixels + 4 * pixels:
            raise ValueError(f"{len(data)} bytes for {width} x {height} pixels")
        image = np.frombuffer(data, np.uint8, 3 * pixels, end).reshape(height, width, 3)
        depth = np.frombuffer(data, "<f4", pixels, end + 3 * pixels).reshape(height, width)
        return Frame(
            str(head["camera"]),
            image.copy(),
            depth.astype(np.float32),
            int(head["tick"]),
            None if head["sim_time_s"] is None else float(head["sim_time_s"]),
            int(head["stamp_ns"]),
            np.array(head["K"], dtype=float).reshape(3, 3),
            np.array(head["pose"], dtype=float).reshape(4, 4),
        )
    except (KeyError, TypeError, ValueError) as exc:
        raise BridgeError(f"{what}: a malformed camera frame ({exc})") from None


def finite_or_none(x: float) -> float | None:
    """A telemetry number as JSON holds it: NaN and infinities as null."""
    return x if math.isfinite(x) else None
