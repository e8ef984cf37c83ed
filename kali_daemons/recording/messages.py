"""The ROS 2 messages a recording holds (``recorder``): their definitions, written into the
file so any MCAP reader decodes them without Kali or ROS, and the CDR encoder the recorder
lays them out with."""

from __future__ import annotations

import struct

import numpy as np

from ..core import layout
from .events import TRUTH_FIELDS
from .log import SERVO_FIELDS

TIME = "================================================================================\n"
HEADER_DEF = (
    f"{TIME}MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
    f"{TIME}MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
)
JOINT_STATE_DEF = (
    "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
    f"float64[] effort\n{HEADER_DEF}"
)
WRENCH_DEF = (
    "std_msgs/Header header\ngeometry_msgs/Wrench wrench\n"
    f"{TIME}MSG: geometry_msgs/Wrench\ngeometry_msgs/Vector3 force\ngeometry_msgs/Vector3 torque\n"
    f"{TIME}MSG: geometry_msgs/Vector3\nfloat64 x\nfloat64 y\nfloat64 z\n{HEADER_DEF}"
)
# each ServoTick array's column of the flight row
ROW_COLUMNS = dict(zip(SERVO_FIELDS, layout.FLIGHT_FIELDS, strict=True))
SERVO_DEF = (
    "std_msgs/Header header\nint64 tick\n"
    + "".join(f"float64[] {f}\n" for f in SERVO_FIELDS)
    + HEADER_DEF
)
GAP_DEF = f"std_msgs/Header header\nint64 first_tick\nint64 ticks\n{HEADER_DEF}"
REQUEST_DEF = (
    "std_msgs/Header header\nuint64 seq\nstring state\nint32 client_pid\nfloat64 duration_s\n"
    f"float64 progress\nstring message\n{HEADER_DEF}"
)
SETPOINT_DEF = f"std_msgs/Header header\nint64 tg_tick\nfloat64[] q\n{HEADER_DEF}"
FAULT_DEF = (
    f"std_msgs/Header header\nint64 tick\nstring code\nstring process\nstring message\n{HEADER_DEF}"
)
SERVO_CHANGE_DEF = (
    "std_msgs/Header header\nint64 tick\nint32 joint\nstring kind\nstring servo\n"
    f"string[] names\nfloat64[] values\n{HEADER_DEF}"
)
IMAGE_DEF = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring encoding\nuint8 is_bigendian\n"
    f"uint32 step\nuint8[] data\n{HEADER_DEF}"
)
CAMERA_INFO_DEF = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nstring distortion_model\n"
    "float64[] d\nfloat64[9] k\nfloat64[9] r\nfloat64[12] p\nuint32 binning_x\n"
    "uint32 binning_y\nsensor_msgs/RegionOfInterest roi\n"
    f"{TIME}MSG: sensor_msgs/RegionOfInterest\nuint32 x_offset\nuint32 y_offset\n"
    f"uint32 height\nuint32 width\nbool do_rectify\n{HEADER_DEF}"
)
SIM_TRUTH_DEF = (
    "std_msgs/Header header\nint64 tick\nfloat64 sim_time_s\nuint64 plant_ticks\n"
    + "".join(f"float64[] {f}\n" for f in TRUTH_FIELDS)
    + f"float64[6] contact_wrench\nfloat64[6] grasp_wrench\nbool grasped\n{HEADER_DEF}"
)


class Cdr:
    """A ROS 2 message encoded as little-endian CDR, for the recording's few fixed message
    types: each field appended at its alignment (relative to the payload after the 4-byte
    encapsulation header), into one reused buffer.  mcap-ros2-support's generic encoder
    (a dict per message) cost the recorder a quarter of a core at two arms and 1 kHz."""

    def __init__(self) -> None:
        self.buf = bytearray(b"\x00\x01\x00\x00")  # CDR, little endian

    def reset(self) -> None:
        del self.buf[4:]

    def _align(self, n: int) -> None:
        pad = -(len(self.buf) - 4) % n
        if pad:
            self.buf += bytes(pad)

    def header(self, ns: int, frame: bytes = b"") -> None:
        """std_msgs/Header: builtin_interfaces/Time stamp, string frame_id."""
        self._align(4)
        self.buf += struct.pack("<iI", ns // 1_000_000_000, ns % 1_000_000_000)
        self.string(frame)

    def string(self, text: bytes) -> None:
        self._align(4)
        self.buf += struct.pack("<I", len(text) + 1) + text + b"\x00"

    def strings(self, texts: list[bytes]) -> None:
        self._align(4)
        self.buf += struct.pack("<I", len(texts))
        for t in texts:
            self.string(t)

    def int64(self, v: int) -> int:
        """An int64; its offset in the message."""
        self._align(8)
        at = len(self.buf)
        self.buf += struct.pack("<q", v)
        return at

    def uint64(self, v: int) -> int:
        """A uint64; its offset in the message."""
        self._align(8)
        at = len(self.buf)
        self.buf += struct.pack("<Q", v)
        return at

    def int32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<i", v)

    def uint32(self, v: int) -> None:
        self._align(4)
        self.buf += struct.pack("<I", v)

    def octets(self, data: np.ndarray) -> None:
        """uint8[] (a sequence) of ``data``'s bytes, as they lie."""
        self._align(4)
        raw = np.ascontiguousarray(data).view(np.uint8).reshape(-1)
        self.buf += struct.pack("<I", len(raw))
        self.buf += raw.tobytes()

    def uint8(self, v: int) -> int:
        """A uint8 or bool; its offset in the message."""
        at = len(self.buf)
        self.buf += struct.pack("<B", v)
        return at

    def float64(self, v: float) -> int:
        """A float64; its offset in the message."""
        self._align(8)
        at = len(self.buf)
        self.buf += struct.pack("<d", v)
        return at

    def float64s(self, values: np.ndarray) -> int:
        """float64[] (a sequence); the offset of its values in the message."""
        self._align(4)
        self.buf += struct.pack("<I", len(values))
        self._align(8)
        at = len(self.buf)
        self.buf += np.ascontiguousarray(values, dtype="<f8").tobytes()
        return at

    def float64_fixed(self, values: np.ndarray) -> int:
        """Consecutive float64 fields (a Wrench's six); the offset of the first."""
        self._align(8)
        at = len(self.buf)
        self.buf += np.ascontiguousarray(values, dtype="<f8").tobytes()
        return at

    def bytes(self) -> bytes:
        return bytes(self.buf)


STAMP_AT = 4  # every message's header stamp, right after the CDR encapsulation


class Laid:
    """A message of fixed layout, laid out once by a ``Cdr`` and refilled in place before
    each write (the truth, the set-points: a few a drain, where encoding each field anew cost
    the recorder a third of its time): ``stamp(ns)`` its header's stamp, ``field(at, dtype,
    count)`` a view of the field ``Cdr`` gave the offset of, to assign into."""

    def __init__(self, cdr: Cdr) -> None:
        self.buf = bytearray(cdr.buf)
        self._sec = self.field(STAMP_AT, "<i4")
        self._nsec = self.field(STAMP_AT + 4, "<u4")

    def field(self, at: int, dtype: str, count: int = 1) -> np.ndarray:
        return np.frombuffer(self.buf, dtype, count, at)

    def stamp(self, ns: int) -> None:
        self._sec[0], self._nsec[0] = divmod(ns, 1_000_000_000)

    def bytes(self) -> bytes:
        return bytes(self.buf)
