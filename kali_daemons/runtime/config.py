"""The Kali configuration: one versioned YAML file, parsed once into frozen, typed dataclasses.

Every process reads the same config (its text is in the arena), so it is validated completely
up front: nothing starts on a bad config, and every error names the field as a dotted path,
the value and what is allowed (``config: config/default.yaml: clock.servo_period_ms = 3: must
be a multiple of clock.base_tick_ms (2)``).  Each field is declared once, on its section's
pydantic dataclass (type, default, bounds, unit, description): the file is read from those
declarations (``_read``, with Kali's own messages), the JSON Schema generated from them
(``schema``) and a config written back with every default (``show``).  Periods are in ms, a
whole number of base ticks, compared in integer nanoseconds (``period_ticks``).

One module on purpose, however long: every field of the config declared once, beside the reading
and the checks that use it (DESIGN 9).
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import os
import re
import stat
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, NoReturn

import numpy as np
import yaml
from pydantic import ConfigDict, Field, TypeAdapter
from pydantic.dataclasses import dataclass
from pydantic.fields import FieldInfo

from kali_daemons.core import layout
from kali_daemons.core.errors import ConfigError
from kali_daemons.core.joints import JointMap
from kali_daemons.core.pyfile import mirror
from kali_daemons.core.yamltext import parse_yaml
from kali_daemons.hardware.ftsensor import SHEETS as FT_SHEETS
from kali_daemons.hardware.ftsensor import FtSheet
from kali_daemons.hardware.ftsensor import sheet as ft_sheet
from kali_daemons.hardware.mcgill.boards import retrigger_hold_ticks
from kali_daemons.hardware.registry import DEFAULT_KIND, KIND_NAME, hardware_kind, known_kinds
from kali_daemons.robots import RobotType, is_type_file, known_types, robot_type
from kali_daemons.robots.scene import DEFAULT_SCENE, Scene, load_scene
from kali_daemons.servo.algorithms.algorithm import MAX_DATA_BYTES
from kali_daemons.servo.algorithms.registry import Registry

CONFIG_VERSION = 1
PROCESS_NAMES = ("wallclock", "plant", "tg", "sio", "sv", "dynamics", "viewer")
DEFAULT_MODEL = "puma560"  # a robot entry without a model
# the shipped cell: its processes and robots sections are the defaults of a file without them
DEFAULT_FILE = Path(__file__).resolve().parents[1] / "config" / "default.yaml"  # package data

MAX_SV_WORKERS = 8
MAX_ROBOTS = 4
# A base further than this from the cell's origin along an axis (m) is a typo: the TG refuses
# any pose further than 10 m from its frame's origin (tg.profiles.MAX_POSE_M), so no target
# in the world could reach an arm based there, and arms that share a bar stand ~1 m apart
MAX_BASE_M = 10.0
MAX_STAGE = 15
MAX_POLL_US = 500  # an SV's poll for its signal and feed (processes.sv.poll_us)
DEFAULT_REST_MS = 4  # processes.sv.rest_ms left out: rounded up to whole servo periods
MAX_PRIORITY = 99
MAX_PERIOD_MS = 60_000  # one minute; anything longer is a typo, not a control period
MIN_BASE_TICK_MS = 0.1  # 10 kHz; the wall clock cannot keep a shorter tick
MAX_BASE_TICK_MS = 100
NS_PER_MS = 1_000_000
MAX_TIMEOUT_S = 600.0
VIEWER_PERIOD_MS = 40
MAX_CONFIG_BYTES = 1 << 20  # a config is a few KiB; /dev/zero or a log file is not one
MAX_CONVEYOR_M_S = 0.5  # a faster belt is a units mistake
# a rerun gRPC address: scheme, host (group 2) and port (group 3)
GRPC_URL_RE = re.compile(r"rerun(\+https?)?://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(\d{1,5})/proxy")
MAX_RECORD_PATH = 200
# a Zenoh endpoint the bridge listens on: protocol, host (group 2), port (group 3)
ENDPOINT_RE = re.compile(r"(tcp|tls|udp|quic)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(\d{1,5})")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")
MAX_LISTEN = 4
MAX_BRIDGE_USERS = 64
BRIDGE_STAGE = 5  # after the viewer: it reads what the tick wrote
DEFAULT_SAFE_RAD = 0.15  # tracking-error tolerance before a runaway halt
DEFAULT_CURRENT_FAULT_MS = 100.0  # demand beyond the current limit this long halts
_INSTANCE_RE = re.compile(r"[a-z0-9][a-z0-9_-]{0,23}")
_ROBOT_NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,15}")
# a bridge user's name: one chunk of the key expressions under its name (Zenoh reads a chunk
# starting with @ verbatim, so none does)
USER_RE = re.compile(r"[A-Za-z0-9_.-][A-Za-z0-9_.@-]{0,63}")
_ADDRESS_RE = re.compile(r"|[A-Za-z0-9][A-Za-z0-9.-]{0,62}")  # an IPv4 address or host name
_SERVO_NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,23}")
_PLUGIN_RE = re.compile(r"[A-Za-z0-9_./-]{1,200}")
MAX_PLUGINS = 16

# Which keys each process entry accepts (ProcessEntry declares them); tg/sio/sv get their
# period from the clock section.
_PROCESS_KEYS = {
    "wallclock": ("cpu", "priority"),
    "plant": ("enabled", "cpu", "priority", "nice", "period_ms", "serious", "stage"),
    "link": ("cpu", "priority", "serious", "stage"),
    "tg": ("cpu", "priority", "serious", "stage"),
    "sio": ("cpu", "priority", "serious", "stage"),
    "sv": ("count", "cpus", "priority", "serious", "stage", "poll_us", "rest_ms"),
    "dynamics": ("enabled", "cpu", "priority", "nice", "period_ms", "serious", "stage"),
    "viewer": ("enabled", "cpu", "priority", "nice", "period_ms", "serious", "stage"),
    "camera": ("cpu", "nice"),
}
# What a kind's entry takes when it leaves ``serious`` or ``stage`` out: the servo processes
# are serious (a user who leaves the key out never loses the halt on a dead or late servo
# process by accident); the lockstep stage orders a tick (lower runs first)
_KIND_DEFAULTS: dict[str, dict[str, Any]] = {
    "wallclock": {"serious": False, "stage": 0},
    "plant": {"serious": True, "stage": 0},
    "link": {"serious": True, "stage": 0},
    "tg": {"serious": True, "stage": 1},
    "sio": {"serious": True, "stage": 2},
    "sv": {"serious": True, "stage": 2},
    "dynamics": {"serious": False, "stage": 3},
    "viewer": {"serious": False, "stage": 4},
    "camera": {"serious": False, "stage": 0, "cpu": 1},
}
# processes a cell runs only with hardware (or a scene) that needs them: one link per
# networked arm; the camera process where the scene has cameras
OPTIONAL_PROCESSES = ("link", "camera")
# the hardware kinds whose arms Kali's own plant simulates: the cells its cameras can render
RENDERED_SIMULATOR = "plant:Plant"
_CLOCK_PERIOD_FIELD = {"tg": "clock.tg_period_ms", "sio": "clock.servo_period_ms"}
_CLOCK_PERIOD_FIELD["sv"] = _CLOCK_PERIOD_FIELD["sio"]

# Top-level fields ``with_overrides`` may change (each is re-validated).
_OVERRIDABLE = ("instance", "arena_kib", "startup_timeout_s")

_MISSING: Any = object()


# --------------------------------------------------------------------------------------------
# The declarations: each field once, with its type, default, bounds, unit and description.
# The sections are frozen pydantic dataclasses: attribute access, equality, hashing and
# ``dataclasses.replace`` as plain dataclasses, plus a JSON Schema (``schema``).  The file is
# read by ``_read`` from these declarations, so that every message keeps naming the dotted
# path, the value and what is allowed.


def _f(default: Any = ..., doc: str = "", unit: str | None = None, **bounds: Any) -> Any:
    """One field's declaration: its default (``...``: required), description, unit and bounds
    (``ge``, ``gt``, ``le``, ``pattern``)."""
    extra: dict[str, Any] | None = {"unit": unit} if unit else None
    return Field(default, description=doc, json_schema_extra=extra, **bounds)


def _cpu_field(default: Any = ..., doc: str = "CPU to bind to; null: no binding") -> Any:
    return _f(default, doc, ge=0)


def _priority(default: Any = ...) -> Any:
    doc = "0: normal scheduling (SCHED_OTHER); 1..99: real-time SCHED_FIFO priority"
    return _f(default, doc, ge=0, le=MAX_PRIORITY)


def _nice(default: Any = ...) -> Any:
    doc = (
        "priority 0 only: the process's weight against other programs' on its CPU, -20 the "
        "most to 19 the least (its session's: the kernel weighs a session's processes as one)"
    )
    return _f(default, doc, ge=-20, le=19)


def _serious(default: Any = ...) -> Any:
    doc = (
        "true: missing deadlines (beyond clock.serious_miss_tolerance_ms) or dying halts the "
        "system; a non-serious process that dies is left out, the rest runs on"
    )
    return _f(default, doc)


def _stage(default: Any = ...) -> Any:
    doc = "order within a tick in lockstep mode, lower first; sv shares sio's"
    return _f(default, doc, ge=0, le=MAX_STAGE)


def _poll_us(default: Any) -> Any:
    doc = (
        "sv only: a worker on another CPU than sio's polls this long for the clock's signal, "
        "then for sio's feed, before it sleeps on them (at most half a servo period is used); "
        "0: it sleeps on them"
    )
    return _f(default, doc, "us", ge=0, le=MAX_POLL_US)


def _rest_ms(default: Any, left_out: str = "") -> Any:
    doc = (
        "sv only: such a polling worker, while the worker on sio's CPU runs every servo on its "
        "own, is signalled only every this long: 0 (every tick) or whole servo periods up to "
        "clock.serious_miss_tolerance_ms" + left_out
    )
    return _f(default, doc, "ms", ge=0)


def _period_field(default: Any = ..., doc: str = "a whole number of base ticks") -> Any:
    return _f(default, doc, "ms", gt=0, le=MAX_PERIOD_MS)


_FROZEN = ConfigDict(extra="forbid", arbitrary_types_allowed=True)
FfMode = Literal["off", "gravity", "full"]  # layout.FfMode by name
DashboardWeb = Literal["auto", "on", "off"]  # when the viewer serves the web viewer
FF_MODES: tuple[str, ...] = typing.get_args(FfMode)
DASHBOARD_WEB: tuple[str, ...] = typing.get_args(DashboardWeb)


@dataclass(frozen=True, config=_FROZEN)
class ClockConfig:
    """Wall-clock rates; every period in the system is a multiple of ``base_tick_ms``.

    The periods are ms, ints when whole (``base_tick_ms: 0.5`` gives a 2 kHz servo).
    """

    base_tick_ms: int | float = _f(
        1,
        "the clock's tick, a whole number of microseconds (e.g. 0.5 or 0.25)",
        "ms",
        ge=MIN_BASE_TICK_MS,
        le=MAX_BASE_TICK_MS,
    )
    servo_period_ms: int | float = _period_field(1, "period of sio and the sv workers")
    tg_period_ms: int | float = _period_field(10, "period of the TG, >= servo_period_ms")
    serious_miss_tolerance_ms: int = _f(
        20,
        "how long a serious process may go unacknowledged before halting (the time the host "
        "stopped the clock itself not counted); above servo_period_ms",
        "ms",
        ge=0,
        le=1000,
    )
    lockstep_ack_timeout_s: float = _f(
        5.0,
        "in lockstep mode, how long the clock waits for each tick's acks",
        "s",
        gt=0,
        le=MAX_TIMEOUT_S,
    )
    busy_wait_us: int = _f(
        0, "busy-wait this long before each tick for sharper timing", "us", ge=0, le=500
    )


@dataclass(frozen=True, config=_FROZEN)
class ProcessEntry:
    """One ``processes.<kind>`` entry as written; each kind takes the keys of
    ``_PROCESS_KEYS``, and ``serious`` and ``stage`` left out are its kind's
    (``_KIND_DEFAULTS``); ``sv`` expands to ``count`` workers, ``sv.0`` .."""

    enabled: bool = _f(
        True,
        "plant, dynamics and viewer only: false leaves the process out; the servo level runs "
        "the same without dynamics and viewer, and without a plant on real hardware",
    )
    cpu: int | None = _cpu_field(None)
    count: int = _f(2, "sv only: servo workers", ge=1, le=MAX_SV_WORKERS)
    cpus: tuple[int | None, ...] | None = _f(
        None, "sv only: one CPU (or null) per worker; left out: none bound"
    )
    priority: int = _priority(0)
    nice: int = _nice(0)
    period_ms: int | float | None = _period_field(
        None,
        "plant, dynamics and viewer only; left out: the base tick (plant), the TG's period "
        "(dynamics), 40 ms in whole ticks (viewer)",
    )
    serious: bool = _serious(False)
    stage: int = _stage(0)
    poll_us: int = _poll_us(200)
    rest_ms: int | float | None = _rest_ms(
        None, f"; left out: {DEFAULT_REST_MS} ms rounded up to whole servo periods"
    )


@dataclass(frozen=True, config=_FROZEN)
class ProcessConfig:
    """One periodic process (or the wall clock), with its period already resolved."""

    name: str = _f(doc="the process: its kind, or sv.<i> for the i-th SV")
    kind: str = _f(doc="one of PROCESS_NAMES, or bridge")
    cpu: int | None = _cpu_field()
    priority: int = _priority()
    period_ms: int | float = _period_field(doc="a whole number of base ticks; an int when whole")
    serious: bool = _serious()
    stage: int = _stage()
    poll_us: int = _poll_us(0)
    rest_ms: int | float = _rest_ms(0)
    nice: int = _nice(0)


@dataclass(frozen=True, config=_FROZEN)
class PlantConfig:
    """The simulated world's timing (thesis 3.7, appendix C): fixed by the hardware it models."""

    substep_ms: float = _f(
        0.5,
        "MuJoCo step; divides processes.plant.period_ms (the current loop is 500 Hz)",
        "ms",
        gt=0,
        le=1,
    )
    watchdog_ms: float = _f(
        20.0,
        "the I/O board's safety timeout (thesis appendix C.4); longer than SIO's retrigger cycle",
        "ms",
        gt=0,
        le=1000,
    )
    enable_hold_ms: float = _f(
        15.0, "how long the enable bit must stay high for the power relay", "ms", gt=0, le=1000
    )
    brake_delay_ms: float = _f(
        50.0,
        "brake solenoids engage or release this long after the amplifiers",
        "ms",
        gt=0,
        le=1000,
    )
    conveyor_m_s: tuple[float, float] = _f(
        (0.0, 0.0),
        "the stand's top is a conveyor belt carrying the scene's belt object at this velocity "
        f"(world x, y; at most {MAX_CONVEYOR_M_S:g} m/s) while the first arm's I/O board runs "
        "it; [0, 0]: none",
        "m/s",
    )


@dataclass(frozen=True, config=_FROZEN)
class FtConfig:
    """A robot's wrist force/torque sensor and the tool on it (``ftsensor.py``).

    The sensor sits on the flange (its frame the flange's); the tool hangs on the sensor: its
    mass and centre of mass (sensor frame) are what SIO subtracts as gravity, and its tool
    point, ``tool_tip_m`` out along the sensor's z, is where the contact wrench is given.
    """

    sensor: str | None = _f("mini45", f"a data sheet: {', '.join(FT_SHEETS)}; none: no sensor")
    tool_mass_kg: float = _f(
        0.0,
        "the tool's mass, carried by the plant, SIO's gravity compensation and the dynamics "
        "model; 0: a bare pad",
        "kg",
        ge=0,
        le=50,
    )
    tool_com_m: tuple[float, float, float] = _f(
        (0.0, 0.0, 0.0), "the tool's centre of mass, sensor frame, each within ±1", "m"
    )
    tool_tip_m: float = _f(0.042, "the tool point, out along the sensor's z", "m", ge=0, le=1)
    cutoff_hz: float = _f(30.0, "SIO's low-pass on the contact wrench", "Hz", gt=0, le=1000)
    contact_limit_n: float = _f(
        150.0, "a contact force beyond this halts (FORCE)", "N", gt=0, le=10_000
    )
    stale_ms: float = _f(
        50.0,
        "no fresh sample this long halts (FORCE: the sensor is silent); above the clock's "
        "serious-miss tolerance, so that a stalled plant is named as what it is",
        "ms",
        gt=0,
        le=1000,
    )

    @property
    def sheet(self) -> FtSheet | None:
        """The sensor's data sheet, or None without a sensor."""
        return None if self.sensor is None else ft_sheet(self.sensor)


@dataclass(frozen=True, config=_FROZEN)
class HardwareConfig:
    """What stands behind a robot: a hardware kind (``kali_daemons.hardware``, DESIGN 6)."""

    kind: str = _f(
        DEFAULT_KIND,
        f"a hardware kind, a package of kali_daemons/hardware: {', '.join(known_kinds())}",
        pattern=KIND_NAME.pattern,
    )
    address: str = _f(
        "",
        "a networked robot's address (a kind with links: franka), an IPv4 address or a host "
        "name; 127.0.0.x reaches the simulator",
        pattern=_ADDRESS_RE.pattern,
    )
    simulator_address: str = _f(
        "",
        "a networked robot's: where the cell's simulator serves it, when something stands "
        "between (a proxy, a network emulator); left out: address",
        pattern=_ADDRESS_RE.pattern,
    )
    hand: bool = _f(
        False,
        "a kind with hands (franka): the arm has one (a Franka Hand), driven by its own "
        "process (hand.<robot>)",
    )


@dataclass(frozen=True, config=_FROZEN)
class RobotConfig:
    """One arm in the cell: its model and where its base sits in the world frame."""

    name: str = _f(doc="the arm's name, unique in the cell", pattern=_ROBOT_NAME_RE.pattern)
    model: str = _f(
        DEFAULT_MODEL,
        "a robot type (kalictl types lists them), or a .py file defining ROBOT, relative to "
        "the config file",
    )
    base_xyz: tuple[float, float, float] = _f(
        (0.0, 0.0, 0.0), f"where its base sits in the world frame, within ±{MAX_BASE_M:g}", "m"
    )
    base_yaw_deg: float = _f(0.0, "its base turned about the vertical", "deg")
    servo: str = _f(
        "pid",
        "the servo algorithm every joint starts with: pid, pd, or a plugin's",
        pattern=_SERVO_NAME_RE.pattern,
    )
    safe_rad: float | tuple[float, ...] = _f(
        (),
        "tracking-error tolerance before a runaway halt, one number in (0, π] or one per "
        f"joint; left out: {DEFAULT_SAFE_RAD}",
        "rad",
    )
    current_fault_ms: float = _f(
        DEFAULT_CURRENT_FAULT_MS,
        "a demand beyond the motor current limit this long halts",
        "ms",
        gt=0,
        le=10_000,
    )
    ff: FfMode = _f(
        "off",
        "feed-forward it starts with (kalictl ff changes it on line): off, gravity, or full "
        "(inverse dynamics of the demanded motion)",
    )
    index_phases_deg: tuple[float, ...] = _f(
        (),
        "its calibration sheet (thesis 3.5.1): each joint's index-pulse motor angle in "
        "[0, 360), measured once per arm; left out: its robot type's",
        "deg",
    )
    grasp_yaw_deg: float = _f(
        0.0,
        "how its flange holds the bar: its grasp site turned this much about the vertical "
        "through the grasp point",
        "deg",
        gt=-180,
        le=180,
    )
    ft: FtConfig = _f(FtConfig(), "its wrist force/torque sensor and tool")
    hardware: HardwareConfig = _f(HardwareConfig(), "what stands behind it")
    robot_servos: bool = _f(
        False,
        "whether it may run robot-level servos: the SVs then hold its model (~20 MB more "
        "each), so the lean default leaves it off",
    )

    def __post_init__(self) -> None:
        if not isinstance(self.safe_rad, tuple):
            object.__setattr__(self, "safe_rad", (float(self.safe_rad),) * self.n_joints)
        elif not self.safe_rad:
            object.__setattr__(self, "safe_rad", (DEFAULT_SAFE_RAD,) * self.n_joints)

    @property
    def index_phases(self) -> tuple[float, ...]:
        """Each joint's index-pulse motor angle, rad: ``index_phases_deg``, else the type's."""
        if self.index_phases_deg:
            return tuple(math.radians(v) for v in self.index_phases_deg)
        return tuple(float(v) for v in self.type.index_phases)

    @property
    def n_joints(self) -> int:
        """Joints of the arm: its robot type's."""
        return self.type.n_joints

    @property
    def type(self) -> RobotType:
        """The arm's robot type (``kali_daemons.robots``)."""
        return robot_type(self.model)

    @property
    def holds_gravity(self) -> bool:
        """Whether its hardware holds it against gravity itself (an FR3): the feed-forward
        and the robot-level servos' models then leave gravity out."""
        return hardware_kind(self.hardware.kind).compensates_gravity


@dataclass(frozen=True, config=_FROZEN)
class FeedforwardConfig:
    """How SIO treats the dynamics process's feed-forward torques (thesis 3.3.6)."""

    stale_ms: float = _f(
        50.0,
        "silent or behind this long, the dynamics process's torques are dropped",
        "ms",
        gt=0,
        le=10_000,
    )
    ramp_ms: float = _f(
        200.0, "feed-forward fades in and out over this time: no torque step", "ms", ge=0, le=10_000
    )


@dataclass(frozen=True, config=_FROZEN)
class DashboardConfig:
    """Where the viewer's live rerun dashboard goes (thesis 3.3.7, DESIGN 8)."""

    connect: str | None = _f(
        "rerun+http://127.0.0.1:9876/proxy",
        "a rerun viewer to stream to when one listens there (a gRPC URL); null: never look",
    )
    web: DashboardWeb = _f(
        "auto", "serve the web viewer on 127.0.0.1: auto (when no live viewer is found), on, off"
    )
    web_port: int = _f(9090, "the web viewer's HTTP port; 0 or taken: a free one", ge=0, le=65535)
    grpc_port: int = _f(
        9877, "its data stream, not web_port; 0 or taken: a free one", ge=0, le=65535
    )
    record: str | None = _f(
        None,
        f"also record to this .rrd file (relative to the config file, 1..{MAX_RECORD_PATH} "
        "characters)",
    )
    server_memory_mib: int = _f(
        256,
        "what the web viewer's server keeps for browsers that connect late",
        "MiB",
        ge=16,
        le=65536,
    )


@dataclass(frozen=True, config=_FROZEN)
class TlsConfig:
    """The bridge's TLS files (absolute paths): its certificate and key, and the CA whose
    client certificates it accepts (a client's common name is its user name for the roles)."""

    certificate: str = _f(doc="the bridge's certificate, a PEM file")
    private_key: str = _f(doc="its private key, a PEM file")
    root_ca: str | None = _f(None, "the CA whose client certificates it accepts")


@dataclass(frozen=True, config=_FROZEN)
class BridgeConfig:
    """The Zenoh bridge (``kali_daemons/bridge``): where it listens, how often it publishes
    and who may do what.  Off by default; on, ``kalictl start`` starts process ``bridge``
    (non-serious, SCHED_OTHER, on ``cpu``).

    Without ``users_file`` or client-certificate TLS nobody is authenticated, so the bridge
    may listen on loopback only and every session there may command (as a local user can).
    With them, ``operators`` may command and ``readers`` only read (telemetry, events,
    status); anyone else is refused by Zenoh's access control."""

    enabled: bool = _f(False, "start the bridge")
    listen: tuple[str, ...] = _f(
        ("tcp/127.0.0.1:7447",),
        f"1..{MAX_LISTEN} Zenoh endpoints like tcp/127.0.0.1:7447; beyond loopback only with "
        "authentication",
    )
    cpu: int | None = _cpu_field(1, "its CPU (SCHED_OTHER, never the servo level's)")
    telemetry_hz: float = _f(
        100.0, "each robot's state, decimated from the servo rate", "Hz", gt=0, le=1000
    )
    timing_hz: float = _f(1.0, "per-process timing statistics", "Hz", gt=0, le=100)
    users_file: str | None = _f(
        None, "Zenoh's user:password dictionary (relative to the config file)"
    )
    operators: tuple[str, ...] = _f((), "users (or certificate common names) who may command")
    readers: tuple[str, ...] = _f((), "users who may only read (telemetry, events, status)")
    tls: TlsConfig | None = _f(None, "the TLS files, for tls/ endpoints")
    max_requests_per_s: int = _f(
        1000,
        "per user and kind of request; beyond, refused unread (never an e-stop)",
        "1/s",
        ge=1,
        le=100_000,
    )
    max_sessions: int = _f(8, "remote programs at once", ge=1, le=64)
    event_history: int = _f(256, "events a late subscriber is sent", ge=1, le=10_000)

    @property
    def authenticated(self) -> bool:
        """Whether sessions are told apart (user names or client certificates)."""
        return self.users_file is not None or (
            self.tls is not None and self.tls.root_ca is not None
        )


# The top-level scalars, shared by the file (ConfigFile) and the result (KaliConfig)


def _version() -> Any:
    return _f(doc=f"format version of the file; this Kali reads {CONFIG_VERSION}")


def _instance(default: Any = ...) -> Any:
    doc = (
        "the instance name: several instances run side by side on one machine; kalictl -i "
        "NAME gives it instead"
    )
    return _f(default, doc, pattern=_INSTANCE_RE.pattern)


def _arena_kib(default: Any = ...) -> Any:
    return _f(default, "size of the shared-memory arena", "KiB", ge=64, le=1_048_576)


def _startup_timeout_s(default: Any = ...) -> Any:
    doc = "how long kalictl start waits for every process to come up"
    return _f(default, doc, "s", gt=0, le=MAX_TIMEOUT_S)


def _plugins_field() -> Any:
    doc = (
        f"servo plugins, at most {MAX_PLUGINS}: Python files (relative to the config file) or "
        "module names, each defining register(registry)"
    )
    return _f((), doc)


def _tg_functions_field() -> Any:
    doc = (
        "TG function plugins, likewise: register(registry) adds transforms the TG computes "
        "every tick for tracking motions"
    )
    return _f((), doc)


@dataclass(frozen=True, config=_FROZEN)
class ProcessesFile:
    """The ``processes`` section: one entry per kind, all seven present; ``link`` places the
    links of networked arms (one per arm, ``link.<robot>``), ``camera`` the camera process
    of a scene with cameras (its CPU share: cpu and nice)."""

    wallclock: ProcessEntry
    plant: ProcessEntry
    tg: ProcessEntry
    sio: ProcessEntry
    sv: ProcessEntry
    dynamics: ProcessEntry
    viewer: ProcessEntry
    link: ProcessEntry | None = None
    camera: ProcessEntry | None = None


@dataclass(frozen=True, config=_FROZEN)
class ConfigFile:
    """A config file as written: what ``kalictl config schema`` prints and ``_build`` reads.
    A section left out takes its defaults; ``processes`` and ``robots`` left out are the
    shipped cell's (``DEFAULT_FILE``)."""

    version: int = _version()
    instance: str | None = _instance(None)
    arena_kib: int = _arena_kib(6144)
    startup_timeout_s: float = _startup_timeout_s(60.0)
    clock: ClockConfig = ClockConfig()
    processes: ProcessesFile | None = _f(None, "left out: config/default.yaml's")
    robots: tuple[RobotConfig, ...] | None = _f(
        None, f"the arms in the cell, 1..{MAX_ROBOTS}; left out: config/default.yaml's"
    )
    plant: PlantConfig = PlantConfig()
    scene: str | None = _f(
        None, "the cell's world, a scene file (relative to this file); null: the shipped cell's"
    )
    plugins: tuple[str, ...] = _plugins_field()
    tg_functions: tuple[str, ...] = _tg_functions_field()
    feedforward: FeedforwardConfig = FeedforwardConfig()
    dashboard: DashboardConfig = DashboardConfig()
    bridge: BridgeConfig = BridgeConfig()


@dataclass(frozen=True, config=_FROZEN)
class KaliConfig:
    """A whole, validated configuration plus the text it came from."""

    version: int = _version()
    instance: str = _instance()
    arena_kib: int = _arena_kib()
    startup_timeout_s: float = _startup_timeout_s()
    clock: ClockConfig = _f(doc="the wall clock's rates")
    processes: tuple[ProcessConfig, ...] = _f(doc="every process, sv expanded, in start order")
    robots: tuple[RobotConfig, ...] = _f(doc="the arms, in config order")
    source: str = _f(doc="where the text came from, for messages")
    text: str = _f(doc="the config's text, as stored in the arena")
    plant: PlantConfig = PlantConfig()
    scene: Scene = _f(load_scene(DEFAULT_SCENE), "the cell's world (robots.scene)")
    plugins: tuple[str, ...] = _plugins_field()
    tg_functions: tuple[str, ...] = _tg_functions_field()
    feedforward: FeedforwardConfig = FeedforwardConfig()
    dashboard: DashboardConfig = DashboardConfig()
    bridge: BridgeConfig = BridgeConfig()
    base_dir: str = _f(".", "the directory relative paths are taken from")
    files: str = _f(
        "",
        "where a running instance keeps the copies of its user files it loads instead of the "
        "originals (kali_daemons.tools.snapshot); '': the originals",
    )

    @functools.cached_property
    def joints(self) -> JointMap:
        """The cell's joints numbered flat, arm by arm in config order."""
        return JointMap(tuple(r.name for r in self.robots), tuple(r.n_joints for r in self.robots))

    def robot(self, name: str) -> RobotConfig:
        """The robot called ``name``; ConfigError naming the robots."""
        for robot in self.robots:
            if robot.name == name:
                return robot
        known = ", ".join(r.name for r in self.robots)
        raise ConfigError(f"{self.source}: no robot {name!r}; robots: {known}")

    def process(self, name: str) -> ProcessConfig:
        """The process called ``name`` (e.g. ``"sv.1"``); ConfigError naming the known ones."""
        for proc in self.processes:
            if proc.name == name:
                return proc
        known = ", ".join(p.name for p in self.processes)
        raise ConfigError(f"{self.source}: no process {name!r}; known processes: {known}")

    def periodic(self) -> tuple[ProcessConfig, ...]:
        """Every process the wall clock drives, i.e. all but the wall clock itself."""
        return tuple(p for p in self.processes if p.kind != "wallclock")

    @property
    def simulated(self) -> bool:
        """Whether the cell's arms are a simulated plant's (which has a truth), not hardware."""
        return any(p.kind == "plant" for p in self.processes)

    @property
    def hardware_kinds(self) -> tuple[str, ...]:
        """The hardware kinds behind the cell's arms, each once, in config order."""
        return tuple(dict.fromkeys(r.hardware.kind for r in self.robots))


# --------------------------------------------------------------------------------------------
# Public entry points


def parse_config(
    text: str,
    source: str = "<string>",
    base_dir: str | None = None,
    files: str = "",
    instance: str | None = None,
) -> KaliConfig:
    """Parse and fully validate YAML ``text``; ``source`` names it in every error message.

    ``base_dir`` is where relative plugin and robot type file paths are found (default: the
    current directory); ``files``, when given, where a running instance keeps its copies of
    them (``kali_daemons.tools.snapshot``), which are loaded instead.  ``instance``, when given
    (``kalictl -i``), names the instance: the file then needs no ``instance`` of its own.
    """
    if not isinstance(text, str):
        raise ConfigError(f"{source}: config text must be a str, not {type(text).__name__}")
    doc = parse_yaml(text, source)
    base = os.path.abspath(base_dir or ".")
    try:
        cfg = _build(doc, source, text, base, files, instance)
    except _InvalidError as exc:
        raise ConfigError(f"{source}: {exc}") from None
    check_arena(cfg)
    return cfg


_FILE_KINDS = {
    stat.S_IFIFO: "a FIFO",
    stat.S_IFCHR: "a character device",
    stat.S_IFBLK: "a block device",
    stat.S_IFSOCK: "a socket",
    stat.S_IFDIR: "a directory",
}


def load_config(path: str | os.PathLike[str], instance: str | None = None) -> KaliConfig:
    """Read and parse the config file at ``path`` (``instance`` as for ``parse_config``); a
    missing or unreadable file is a ConfigError."""
    source = os.fspath(path)
    try:
        # non-blocking: opening a FIFO for reading would wait for a writer forever
        fd = os.open(source, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
    except OSError as exc:
        reason = exc.strerror or exc.__class__.__name__
        raise ConfigError(f"{source}: cannot read config file: {reason}") from None
    mode = os.fstat(fd).st_mode
    if not stat.S_ISREG(mode):
        os.close(fd)
        kind = _FILE_KINDS.get(stat.S_IFMT(mode), "not a file")
        raise ConfigError(f"{source}: cannot read config file: not a regular file ({kind})")
    with os.fdopen(fd, "rb") as f:
        try:
            data = f.read(MAX_CONFIG_BYTES + 1)
        except OSError as exc:
            reason = exc.strerror or exc.__class__.__name__
            raise ConfigError(f"{source}: cannot read config file: {reason}") from None
    if len(data) > MAX_CONFIG_BYTES:
        raise ConfigError(
            f"{source}: config file larger than {MAX_CONFIG_BYTES // 1024} KiB; "
            "a config is a few KiB of YAML"
        )
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{source}: config file is not UTF-8 text: {exc.reason}") from None
    return parse_config(text, source, os.path.dirname(os.path.abspath(source)), instance=instance)


def with_overrides(cfg: KaliConfig, **changes: Any) -> KaliConfig:
    """``dataclasses.replace`` for top-level scalar fields (e.g. ``instance`` from the CLI).

    Each new value is validated like the file's own.  ``text`` is left as parsed, so a
    process that re-parses it sees the file's values, not the overrides.
    """
    checked: dict[str, Any] = {}
    declared = KaliConfig.__pydantic_fields__  # type: ignore[attr-defined]
    for key, value in changes.items():
        try:
            if key not in _OVERRIDABLE:
                allowed = ", ".join(_OVERRIDABLE)
                raise _InvalidError(f"{key}: cannot be overridden; overridable fields: {allowed}")
            checked[key] = _check(value, key, declared[key])
        except _InvalidError as exc:
            raise ConfigError(f"{cfg.source} (override): {exc}") from None
    out = dataclasses.replace(cfg, **checked)
    check_arena(out)
    return out


def cell_of(
    cfg: KaliConfig, algorithms: tuple[np.dtype, ...], arms: tuple[np.dtype, ...] = ()
) -> layout.Cell:
    """What ``cfg``'s arena layout depends on (``layout.blocks``), with ``algorithms`` the
    servo registry's private-data dtypes of its joint servos and ``arms`` of its robot-level
    servos, each in registry order; after them the spares of servos loaded while running
    (``layout.SERVO_LOADABLE``, ``ARM_LOADABLE``)."""
    spare = layout.LOADED_RECORD
    return layout.Cell(
        robots=tuple(r.name for r in cfg.robots),
        joints=cfg.joints.counts,
        flight_rows=layout.flight_rows(ms_to_ns(cfg.clock.servo_period_ms)),
        algorithms=(*algorithms, *(spare,) * layout.SERVO_LOADABLE),
        arms=(*arms, *(spare,) * layout.ARM_LOADABLE),
        config_bytes=len(cfg.text.encode()),
        config_dir_bytes=len(cfg.base_dir.encode()),
        config_files_bytes=len(cfg.files.encode()),
        hardware=tuple(
            dict.fromkeys(rec for kind in cfg.hardware_kinds for rec in hardware_kind(kind).records)
        ),
        objects=len(cfg.scene.free),
        cameras=tuple(c.width * c.height for c in cfg.scene.cameras),
    )


def arena_need(cfg: KaliConfig) -> tuple[int, int, list[tuple[str, int]]]:
    """(bytes, blocks, the parts' bytes by key, the largest first) the cell's arena must hold:
    the header and directory plus every block of ``layout.blocks``, each rounded up to
    ``ALIGN``, and a directory entry for the free space after them.

    A plugin's private data is counted at its largest (``MAX_DATA_BYTES`` a joint, and as
    much a robot for a robot-level servo it may register): its dtype is known only once the
    plugin is imported, which parsing does not do.  Outside anything real-time."""

    def rounded(nbytes: int) -> int:
        return -(-nbytes // layout.ALIGN) * layout.ALIGN

    builtins = Registry()
    largest = (np.dtype(("u1", MAX_DATA_BYTES)),) * len(cfg.plugins)
    algorithms = tuple(a.dtype for a in builtins) + largest
    arms = tuple(a.dtype for a in builtins.arms) + largest
    laid = layout.blocks(cell_of(cfg, algorithms, arms))
    by_key: dict[str, int] = {}
    for b in laid:  # servo.3.1 → servo.*.* : the parts a reader can act on
        part = re.sub(r"\.\d+", ".*", b.key) if b.key.startswith("servo.") else b.key
        by_key[part] = by_key.get(part, 0) + rounded(b.nbytes)
    parts = [("header and directory", layout.header_bytes()), *by_key.items()]
    parts.sort(key=lambda p: -p[1])
    return sum(size for _, size in parts), len(laid) + 1, parts


def check_arena(cfg: KaliConfig) -> None:
    """ConfigError if ``arena_kib`` cannot hold the cell (``arena_need``): the size needed,
    in KiB, and its largest parts; before this, a small arena started and failed seconds
    later in whichever daemon allocated last."""
    need, blocks, parts = arena_need(cfg)
    have = cfg.arena_kib * 1024
    if need > have:
        kib = -(-need // 1024)
        biggest = parts[:3]
        detail = ", ".join(f"{what} {size // 1024} KiB" for what, size in biggest)
        raise ConfigError(
            f"{cfg.source}: arena_kib = {cfg.arena_kib}: the cell needs {kib} KiB "
            f"({detail}, ...); set arena_kib to at least {kib}"
        )
    if blocks > layout.MAX_BLOCKS:
        raise ConfigError(
            f"{cfg.source}: the cell needs {blocks} arena blocks, the directory holds "
            f"{layout.MAX_BLOCKS} (robots x joints x servo algorithms: fewer plugins or robots)"
        )


def ms_to_ns(ms: float) -> int:
    """``ms`` in whole nanoseconds (rounded), the unit periods are compared in."""
    return round(ms * NS_PER_MS)


def ns_to_ms(ns: int) -> float:
    """``ns`` in ms: an int when whole, else the nearest float (``500_000`` -> ``0.5``)."""
    return ns // NS_PER_MS if ns % NS_PER_MS == 0 else ns / NS_PER_MS


def period_ticks(period_ms: float, base_tick_ms: float, *, round_up: bool = False) -> int:
    """The whole number of base ticks in ``period_ms``, compared in integer nanoseconds.

    The one place a period is divided by the tick.  ValueError unless the period is a whole
    multiple of the tick, at least one; ``round_up`` takes the next multiple instead.
    """
    if not (math.isfinite(period_ms) and math.isfinite(base_tick_ms)):
        raise ValueError(f"period {period_ms!r} ms, base tick {base_tick_ms!r} ms: not finite")
    tick_ns = ms_to_ns(base_tick_ms)
    if tick_ns <= 0:
        raise ValueError(f"base tick {base_tick_ms!r} ms: must be at least 1 ns")
    ticks, rest = divmod(ms_to_ns(period_ms), tick_ns)
    if rest and round_up:
        ticks, rest = ticks + 1, 0
    if rest or ticks < 1:
        raise ValueError(
            f"period {period_ms!r} ms is not a whole multiple of the {base_tick_ms!r} ms base tick"
        )
    return ticks


# --------------------------------------------------------------------------------------------
# Validation helpers: each takes the parsed YAML node and its dotted path, returns a typed value


class _InvalidError(Exception):
    """A validation failure; ``parse_config`` prefixes the source and raises ConfigError."""


def _fail(path: str, value: Any, allowed: str) -> NoReturn:
    """Raise ``<path> = <value>: <allowed>``."""
    raise _InvalidError(f"{path} = {_show(value)}: {allowed}")


def _show(value: Any, limit: int = 60) -> str:
    """A short, YAML-flavoured rendering of a value for an error message."""
    if value is None:
        text = "null"
    elif isinstance(value, bool):
        text = "true" if value else "false"
    elif isinstance(value, str):
        text = repr(value)
    elif isinstance(value, list | tuple):
        text = "[" + ", ".join(_show(v, limit) for v in value) + "]"
    elif isinstance(value, dict):
        text = "{" + ", ".join(f"{_show(k, limit)}: {_show(v, limit)}" for k, v in value.items())
        text += "}"
    else:
        text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _kind_of(value: Any) -> str:
    """``a bool``, ``a string`` ... for 'must be X, not Y' messages."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "a bool"
    if isinstance(value, int):
        return "an integer"
    if isinstance(value, float):
        return "a number"
    if isinstance(value, str):
        return "a string"
    if isinstance(value, list):
        return "a list"
    if isinstance(value, dict):
        return "a mapping"
    return f"a {type(value).__name__}"


def _join(path: str, key: Any) -> str:
    """Dotted child path; non-string keys are shown as written."""
    key_text = key if isinstance(key, str) else _show(key)
    return f"{path}.{key_text}" if path else key_text


def _int_range(lo: int, hi: int | None) -> str:
    return f"must be an integer >= {lo}" + ("" if hi is None else f" and <= {hi}")


def _int(value: Any, path: str, lo: int, hi: int | None = None) -> int:
    """An integer in ``lo..hi``; a bool is not an integer (YAML ``true`` is not ``1``)."""
    allowed = _int_range(lo, hi)
    if isinstance(value, bool) or not isinstance(value, int):
        _fail(path, value, f"{allowed}, not {_kind_of(value)}")
    if value < lo or (hi is not None and value > hi):
        _fail(path, value, allowed)
    return value


def _float(value: Any, path: str, lo: float, hi: float, lo_open: bool = True) -> float:
    """A finite number in ``(lo, hi]`` (or ``[lo, hi]``); an int is accepted, a bool is not."""
    allowed = f"must be a number {'>' if lo_open else '>='} {lo:g} and <= {hi:g}"
    if isinstance(value, bool) or not isinstance(value, int | float):
        _fail(path, value, f"{allowed}, not {_kind_of(value)}")
    number = float(value)
    if not math.isfinite(number) or number > hi or number < lo or (lo_open and number == lo):
        _fail(path, value, allowed)
    return number


def _per_joint(
    value: Any, path: str, n: int, lo: float, hi: float, per_joint_only: bool = False
) -> tuple[float, ...]:
    """One number for every joint, or a list of ``n`` numbers in ``[lo, hi)``
    (``per_joint_only``: the list only)."""
    form = f"a list of {n} numbers" if per_joint_only else f"a number or a list of {n} numbers"
    if not isinstance(value, list):
        if per_joint_only:
            _fail(path, value, f"must be {form}")
        value = [value] * n
    elif len(value) != n:
        _fail(path, value, f"must be {form} (one per joint), not {len(value)}")
    out = tuple(_float(v, f"{path}[{j}]", lo, hi, lo_open=False) for j, v in enumerate(value))
    for j, v in enumerate(out):
        if v == hi:
            _fail(f"{path}[{j}]", v, f"must be >= {lo:g} and < {hi:g}")
    return out


def _finite(value: Any, path: str) -> float:
    """Any finite number (an int is accepted, a bool is not)."""
    if isinstance(value, bool) or not isinstance(value, int | float):
        _fail(path, value, f"must be a finite number, not {_kind_of(value)}")
    if not math.isfinite(value):
        _fail(path, value, "must be a finite number")
    return float(value)


def _base_coordinate(value: Any, path: str) -> float:
    """A coordinate of a robot's base: a finite number within ±MAX_BASE_M."""
    number = _finite(value, path)
    if abs(number) > MAX_BASE_M:
        _fail(
            path,
            value,
            f"must be within ±{MAX_BASE_M:g} m of the cell's origin (no pose the TG accepts "
            f"lies further out)",
        )
    return number


def _bool(value: Any, path: str) -> bool:
    """``true`` or ``false`` (not 0/1)."""
    if not isinstance(value, bool):
        _fail(path, value, f"must be true or false, not {_kind_of(value)}")
    return value


def _identifier(value: Any, path: str, pattern: re.Pattern[str]) -> str:
    """A string matching ``pattern`` in full."""
    allowed = f"must be a string matching {pattern.pattern}"
    if not isinstance(value, str):
        _fail(path, value, f"{allowed}, not {_kind_of(value)}")
    if pattern.fullmatch(value) is None:
        _fail(path, value, allowed)
    return value


def _choice(value: Any, path: str, choices: tuple[str, ...]) -> str:
    """One of a fixed set of strings."""
    if not isinstance(value, str) or value not in choices:
        _fail(path, value, "must be one of: " + ", ".join(choices))
    return value


def _mapping(
    value: Any, path: str, allowed: tuple[str, ...], hints: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """A mapping whose keys are all in ``allowed``; ``hints`` explain specific forbidden keys."""
    where = path or "the top level"
    if not isinstance(value, dict):
        _fail(where, value, f"must be a mapping with keys from: {', '.join(allowed)}")
    for key in value:
        if isinstance(key, str) and key in allowed:
            continue
        if hints and key in hints:
            _fail(_join(path, key), value[key], hints[key])
        close = difflib.get_close_matches(key, allowed, n=1) if isinstance(key, str) else []
        guess = f" (did you mean {close[0]!r}?)" if close else ""
        raise _InvalidError(
            f"{_join(path, key)}: unknown key{guess}; allowed keys: {', '.join(allowed)}"
        )
    return value


def _list(value: Any, path: str, lo: int, hi: int) -> list[Any]:
    """A list of ``lo..hi`` entries."""
    if not isinstance(value, list):
        _fail(path, value, f"must be a list of {lo}..{hi} entries, not {_kind_of(value)}")
    if not lo <= len(value) <= hi:
        _fail(path, value, f"must be a list of {lo}..{hi} entries, not {len(value)}")
    return value


def _cpu_count() -> int:
    """CPUs on this machine (a function so tests can pretend otherwise)."""
    return os.cpu_count() or 1


def _cpu(value: Any, path: str) -> int | None:
    """A CPU index to bind to, or null for no binding."""
    if value is None:
        return None
    ncpu = _cpu_count()
    allowed = f"must be null or a CPU index 0..{ncpu - 1} (this machine has {ncpu} CPUs)"
    if isinstance(value, bool) or not isinstance(value, int):
        _fail(path, value, f"{allowed}, not {_kind_of(value)}")
    if not 0 <= value < ncpu:
        _fail(path, value, allowed)
    return value


def _base_tick(value: Any, path: str) -> float:
    """The base tick in ms: a whole number of microseconds in MIN..MAX_BASE_TICK_MS."""
    allowed = (
        f"must be a number >= {MIN_BASE_TICK_MS:g} and <= {MAX_BASE_TICK_MS:g} that is a whole "
        "number of microseconds (e.g. 0.5 or 0.25)"
    )
    if isinstance(value, bool) or not isinstance(value, int | float):
        _fail(path, value, f"{allowed}, not {_kind_of(value)}")
    if not (math.isfinite(value) and MIN_BASE_TICK_MS <= value <= MAX_BASE_TICK_MS):
        _fail(path, value, allowed)
    us = value * 1000
    if abs(us - round(us)) > 1e-6:
        _fail(path, value, allowed)
    return ns_to_ms(round(us) * 1000)


def _period(
    value: Any, path: str, tick: float, lo: float | None = None, lo_name: str = ""
) -> float:
    """A period in ms: a whole multiple of the base tick, at least ``lo`` (default: one tick)."""
    period = _float(value, path, 0.0, MAX_PERIOD_MS)
    try:
        ticks = period_ticks(period, tick)
    except ValueError:
        _fail(path, value, f"must be a multiple of clock.base_tick_ms ({tick})")
    period = ns_to_ms(ticks * ms_to_ns(tick))
    floor = tick if lo is None else lo
    if period < floor:
        _fail(path, value, f"must be >= {lo_name or 'clock.base_tick_ms'} ({floor})")
    return period


# --------------------------------------------------------------------------------------------
# Section builders


# --------------------------------------------------------------------------------------------
# Reading a section from its declaration


def _bounds(info: FieldInfo) -> dict[str, Any]:
    """A declared field's bounds: ``ge``, ``gt``, ``le``, ``lt``, ``pattern`` as given."""
    out: dict[str, Any] = {}
    for item in info.metadata:
        for key in ("ge", "gt", "le", "lt", "pattern"):
            if getattr(item, key, None) is not None:
                out[key] = getattr(item, key)
    return out


def _check(value: Any, path: str, info: FieldInfo) -> Any:
    """``value`` checked against its declaration when that is a bool, a bounded int or
    number, a pattern or a choice; any other value is returned as written, for its section's
    own check."""
    kind, bounds = info.annotation, _bounds(info)
    if kind is bool:
        return _bool(value, path)
    if kind is int and "ge" in bounds:
        return _int(value, path, bounds["ge"], bounds.get("le"))
    if kind is float and "le" in bounds:
        lo_open = "gt" in bounds
        return _float(value, path, bounds["gt" if lo_open else "ge"], bounds["le"], lo_open)
    if kind is float:
        return _finite(value, path)
    if kind is str and "pattern" in bounds:
        return _identifier(value, path, re.compile(bounds["pattern"]))
    if typing.get_origin(kind) is Literal:
        return _choice(value, path, typing.get_args(kind))
    return value


def _read(
    cls: type,
    node: Any,
    path: str,
    keys: tuple[str, ...] | None = None,
    hints: Mapping[str, str] | None = None,
    defaults: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Section ``node`` at ``path`` read by ``cls``'s declarations (only ``keys`` of them when
    given): an unknown key refused with a suggestion, each value given checked (``_check``),
    each left out given its default (``defaults``, else the declared one; ``_MISSING`` for a
    required field)."""
    fields: dict[str, FieldInfo] = cls.__pydantic_fields__  # type: ignore[attr-defined]
    allowed = keys or tuple(fields)
    given = _mapping(node, path, allowed, hints)
    out: dict[str, Any] = {}
    for key in allowed:
        info = fields[key]
        if key in given:
            out[key] = _check(given[key], _join(path, key), info)
        elif defaults is not None and key in defaults:
            out[key] = defaults[key]
        else:
            out[key] = _MISSING if info.is_required() else info.get_default()
    return out


@functools.cache
def _shipped() -> dict[str, Any]:
    """``DEFAULT_FILE``'s document: its ``processes`` and ``robots`` are those of a file that
    leaves them out."""
    return parse_yaml(DEFAULT_FILE.read_text(encoding="utf-8"), str(DEFAULT_FILE))


# --------------------------------------------------------------------------------------------
# Section builders


def _build(
    doc: Any, source: str, text: str, base_dir: str, files: str, instance: str | None
) -> KaliConfig:
    """Turn the parsed YAML document into a KaliConfig, or raise _InvalidError; relative
    paths are taken from ``base_dir`` (absolute), user files read from ``files`` if given;
    ``instance``, when given, names the instance instead of the file."""
    if not isinstance(doc, dict):
        empty = " (the file is empty)" if doc is None else ""
        _fail("the top level", doc, f"must be a mapping{empty}, not {_kind_of(doc)}")
    # The version first: a file for another version may legitimately have other keys.
    version = doc.get("version", _MISSING)
    if version is _MISSING:
        raise _InvalidError(f"version: missing; required, this Kali reads version {CONFIG_VERSION}")
    if type(version) is not int or version != CONFIG_VERSION:
        _fail("version", version, f"unsupported; this Kali reads version {CONFIG_VERSION}")
    top = _read(ConfigFile, doc, "")
    if top["instance"] is not None:
        top["instance"] = _identifier(top["instance"], "instance", _INSTANCE_RE)
    if instance is not None:
        top["instance"] = _identifier(instance, "instance", _INSTANCE_RE)
    if top["instance"] is None:
        raise _InvalidError(
            f"instance: missing; required, a string matching {_INSTANCE_RE.pattern} "
            "(or name the instance with kalictl -i NAME)"
        )
    clock = _clock(doc.get("clock", {}))
    procs_node = doc["processes"] if "processes" in doc else _shipped()["processes"]
    try:
        processes = _processes(procs_node, clock)
    except _InvalidError as exc:
        if "processes" in doc:
            raise
        raise _InvalidError(f"{exc} (in {DEFAULT_FILE}, the default processes)") from None
    robots = _robots(
        doc["robots"] if "robots" in doc else _shipped()["robots"], base_dir, files, clock
    )
    links = _links(procs_node.get("link"), robots, clock)
    if links:  # after the plant (a simulator they connect to), before the rest
        after = max(i for i, p in enumerate(processes) if p.kind in ("wallclock", "plant"))
        processes = (*processes[: after + 1], *links, *processes[after + 1 :])
    bridge = _bridge(doc.get("bridge", {}), base_dir)
    if bridge.enabled:  # not in ``processes``: its section holds everything about it
        processes = (*processes, bridge_process(bridge, clock))
    plant_period = next(
        (p.period_ms for p in processes if p.kind == "plant"), clock.base_tick_ms
    )
    plant = _plant(doc.get("plant", {}), plant_period, clock.servo_period_ms)
    scene = _scene(top["scene"], base_dir, files)
    if any(plant.conveyor_m_s) and scene.belt is None:
        _fail(
            "plant.conveyor_m_s",
            list(plant.conveyor_m_s),
            f"a belt needs an object to carry: the scene ({scene.source}) names none (belt)",
        )
    if scene.cameras:
        processes = (*processes, _camera_process(procs_node.get("camera"), scene, robots, clock))
    return KaliConfig(
        version=CONFIG_VERSION,
        instance=top["instance"],
        arena_kib=top["arena_kib"],
        startup_timeout_s=top["startup_timeout_s"],
        clock=clock,
        processes=processes,
        robots=robots,
        source=source,
        text=text,
        plant=plant,
        scene=scene,
        plugins=_plugins(top["plugins"], "plugins"),
        tg_functions=_plugins(top["tg_functions"], "tg_functions"),
        feedforward=FeedforwardConfig(
            **_read(FeedforwardConfig, doc.get("feedforward", {}), "feedforward")
        ),
        dashboard=_dashboard(doc.get("dashboard", {})),
        bridge=bridge,
        base_dir=base_dir,
        files=files,
    )


def _scene(node: Any, base_dir: str, files: str) -> Scene:
    """``scene``: the scene file it names, or the shipped cell's.  A running instance reads
    its copy under ``files`` (a user's file is copied at start; Kali's own are not); the
    scene's own errors name the file."""
    if node is None:
        return load_scene(DEFAULT_SCENE)
    if files and isinstance(node, str):
        copy = mirror(files, Path(os.path.realpath(os.path.join(base_dir, node))))
        if copy.is_file():
            return load_scene(copy)
    return load_scene(_file(node, "scene", base_dir))


def _plugins(node: Any, path: str) -> tuple[str, ...]:
    """``plugins`` or ``tg_functions``: file paths or module names."""
    entries = _list(list(node) if isinstance(node, tuple) else node, path, 0, MAX_PLUGINS)
    return tuple(_identifier(p, f"{path}[{i}]", _PLUGIN_RE) for i, p in enumerate(entries))


def _bridge(node: Any, base_dir: str) -> BridgeConfig:
    """The ``bridge`` section: listening endpoints, rates, users and roles, TLS."""
    v = _read(BridgeConfig, node, "bridge")
    listen_node = v["listen"]
    if isinstance(listen_node, str):
        listen_node = [listen_node]
    elif isinstance(listen_node, tuple):
        listen_node = list(listen_node)
    listen = []
    for i, e in enumerate(_list(listen_node, "bridge.listen", 1, MAX_LISTEN)):
        found = ENDPOINT_RE.fullmatch(e) if isinstance(e, str) else None
        if found is None or not 0 < int(found.group(3)) < 65536:
            _fail(f"bridge.listen[{i}]", e, "must be a Zenoh endpoint like tcp/127.0.0.1:7447")
        listen.append(e)
    v["listen"] = tuple(listen)
    if v["tls"] is not None:
        t = _read(TlsConfig, v["tls"], "bridge.tls")
        for key, value in t.items():
            if value is _MISSING:
                raise _InvalidError(f"bridge.tls.{key}: missing; a PEM file path")
            if value is not None:
                t[key] = _file(value, f"bridge.tls.{key}", base_dir)
        v["tls"] = TlsConfig(**t)
    if v["users_file"] is not None:
        v["users_file"] = _file(v["users_file"], "bridge.users_file", base_dir)
    for key in ("operators", "readers"):
        given = list(v[key]) if isinstance(v[key], tuple) else v[key]  # the default: a tuple
        names = _list(given, f"bridge.{key}", 0, MAX_BRIDGE_USERS)
        v[key] = tuple(_identifier(n, f"bridge.{key}[{i}]", USER_RE) for i, n in enumerate(names))
    both = set(v["operators"]) & set(v["readers"])
    if both:
        _fail("bridge.readers", sorted(both)[0], "is an operator too; give each user one role")
    v["cpu"] = _cpu(v["cpu"], "bridge.cpu")
    cfg = BridgeConfig(**v)
    if cfg.authenticated and not (cfg.operators or cfg.readers):
        _fail(
            "bridge.operators",
            [],
            "name at least one user (or certificate name) who may "
            "connect: with authentication on, a user in no role is refused",
        )
    if not cfg.authenticated:
        if cfg.operators or cfg.readers:
            _fail(
                "bridge.operators",
                list(cfg.operators or cfg.readers),
                "roles need authentication: set bridge.users_file (or bridge.tls with a root_ca)",
            )
        for i, e in enumerate(listen):
            host = ENDPOINT_RE.fullmatch(e).group(2)  # type: ignore[union-attr]
            if host not in LOOPBACK_HOSTS:
                _fail(
                    f"bridge.listen[{i}]",
                    e,
                    "is not loopback: listening beyond this machine "
                    "needs authentication (bridge.users_file, or bridge.tls with a root_ca)",
                )
    if any(e.startswith("tls/") for e in listen) and cfg.tls is None:
        _fail("bridge.listen", list(listen), "a tls/ endpoint needs bridge.tls")
    return cfg


def _file(value: Any, path: str, base_dir: str) -> str:
    """A file the config names (relative to its directory), returned absolute; it must exist."""
    if not isinstance(value, str) or not 0 < len(value) <= MAX_RECORD_PATH or "\0" in value:
        _fail(path, value, f"must be a file path of 1..{MAX_RECORD_PATH} characters")
    full = os.path.realpath(os.path.join(base_dir, os.path.expanduser(value)))
    if not os.path.isfile(full):
        _fail(path, value, f"no such file ({full})")
    return full


def bridge_process(bridge: BridgeConfig, clock: ClockConfig) -> ProcessConfig:
    """The bridge's process entry: its period one telemetry sample, in whole base ticks."""
    tick = clock.base_tick_ms
    ticks = period_ticks(1000.0 / bridge.telemetry_hz, tick, round_up=True)
    period = ns_to_ms(ticks * ms_to_ns(tick))
    return ProcessConfig(
        name="bridge",
        kind="bridge",
        cpu=bridge.cpu,
        priority=0,
        period_ms=period,
        serious=False,
        stage=BRIDGE_STAGE,
    )


def _dashboard(node: Any) -> DashboardConfig:
    """The ``dashboard`` section: the viewer's live viewer address, web viewer and recording."""
    if isinstance(node, dict) and isinstance(node.get("web"), bool):  # YAML 1.1 reads on/off
        node = {**node, "web": "on" if node["web"] else "off"}
    v = _read(DashboardConfig, node, "dashboard")
    connect = v["connect"]
    if connect is not None:
        url = "a rerun gRPC URL like rerun+http://127.0.0.1:9876/proxy, or null"
        if not isinstance(connect, str):
            _fail("dashboard.connect", connect, f"must be {url}, not {_kind_of(connect)}")
        found = GRPC_URL_RE.fullmatch(connect)
        if len(connect) > MAX_RECORD_PATH or found is None or not 0 < int(found.group(3)) < 65536:
            _fail("dashboard.connect", connect, f"must be {url}")
    if v["grpc_port"] and v["grpc_port"] == v["web_port"]:
        _fail("dashboard.grpc_port", v["grpc_port"], "must differ from dashboard.web_port")
    record = v["record"]
    if record is not None:
        allowed = f"must be null or a file path of 1..{MAX_RECORD_PATH} characters"
        if not isinstance(record, str):
            _fail("dashboard.record", record, f"{allowed}, not {_kind_of(record)}")
        if not 0 < len(record) <= MAX_RECORD_PATH or any(c in record for c in "\0\n\r"):
            _fail("dashboard.record", record, allowed)
    return DashboardConfig(**v)


def _plant(node: Any, period_ms: float, servo_ms: float) -> PlantConfig:
    """The ``plant`` section; the substep must divide the plant's period (``period_ms``).

    The plant advances one whole period per cycle, in ``period_ms / substep_ms`` MuJoCo steps.
    The watchdog must outlast SIO's retrigger cycle (``retrigger_hold_ticks``).
    """
    v = _read(PlantConfig, node, "plant")
    sub = v["substep_ms"]
    n = period_ms / sub
    if round(n) < 1 or abs(n - round(n)) > 1e-9 * n:
        _fail(
            "plant.substep_ms",
            sub,
            f"must divide processes.plant.period_ms = {period_ms} "
            "(the plant advances one period per cycle, in whole substeps)",
        )
    watchdog = v["watchdog_ms"]
    cycle = 2 * retrigger_hold_ticks(servo_ms, period_ms) * servo_ms
    if watchdog <= cycle:
        _fail(
            "plant.watchdog_ms",
            watchdog,
            f"must be > {cycle:g}: SIO retriggers the board every {cycle:g} ms (each level "
            f"held for the whole {servo_ms:g} ms servo periods that last two plant periods, "
            f"{period_ms:g} ms, so that the board reads it)",
        )
    v["conveyor_m_s"] = _conveyor(v["conveyor_m_s"])
    return PlantConfig(**v)


def _conveyor(node: Any) -> tuple[float, float]:
    """``plant.conveyor_m_s``: the belt's velocity [vx, vy], at most MAX_CONVEYOR_M_S."""
    path = "plant.conveyor_m_s"
    if not isinstance(node, list | tuple) or len(node) != 2:
        _fail(path, node, "must be a list of 2 numbers [vx, vy] in m/s (the belt is level)")
    v = tuple(_finite(x, f"{path}[{j}]") for j, x in enumerate(node))
    if math.hypot(*v) > MAX_CONVEYOR_M_S:
        _fail(path, node, f"a belt faster than {MAX_CONVEYOR_M_S:g} m/s is a units mistake")
    return v  # type: ignore[return-value]


def _clock(node: Any) -> ClockConfig:
    """The ``clock`` section: rates first, then the periods that depend on them."""
    v = _read(ClockConfig, node, "clock")
    given: dict[str, Any] = node
    tick = _base_tick(v["base_tick_ms"], "clock.base_tick_ms")
    v["base_tick_ms"] = tick
    v["servo_period_ms"] = servo = _clock_period(v, given, "servo_period_ms", tick, "base_tick_ms")
    v["tg_period_ms"] = _clock_period(v, given, "tg_period_ms", servo, "servo_period_ms")
    clock = ClockConfig(**v)
    if clock.serious_miss_tolerance_ms <= servo:  # a serious servo would halt at its first miss
        _fail(
            "clock.serious_miss_tolerance_ms",
            clock.serious_miss_tolerance_ms,
            f"must exceed clock.servo_period_ms = {servo:g} (at or below one period a serious "
            "servo-rate process halts the system at its first late tick)",
        )
    return clock


def _clock_period(
    v: dict[str, Any], given: dict[str, Any], key: str, lo: float, lo_key: str
) -> float:
    """``clock.<key>``; when the default is what fails (e.g. a 3 ms tick), the message says so."""
    try:
        return _period(v[key], f"clock.{key}", v["base_tick_ms"], lo, f"clock.{lo_key}")
    except _InvalidError as exc:
        if key in given:
            raise
        raise _InvalidError(f"{exc} (the default; set clock.{key} explicitly)") from None


def _default_period(kind: str, clock: ClockConfig) -> float:
    """The period a kind runs at when its entry has no ``period_ms``."""
    tick = clock.base_tick_ms
    if kind in ("tg", "dynamics"):
        return clock.tg_period_ms
    if kind in ("sio", "sv"):
        return clock.servo_period_ms
    if kind == "viewer":  # 40 ms, rounded up to a whole number of ticks
        ticks = period_ticks(VIEWER_PERIOD_MS, tick, round_up=True)
        return ns_to_ms(ticks * ms_to_ns(tick))
    return tick  # wallclock, plant


def _processes(node: Any, clock: ClockConfig) -> tuple[ProcessConfig, ...]:
    """The ``processes`` section, expanded (``sv`` -> ``sv.0`` ..) in PROCESS_NAMES order."""
    m = _mapping(node, "processes", PROCESS_NAMES + OPTIONAL_PROCESSES)
    missing = [k for k in PROCESS_NAMES if k not in m]
    if missing:
        raise _InvalidError(
            f"processes.{missing[0]}: missing; every one of {', '.join(PROCESS_NAMES)} "
            "must be configured"
        )
    out: list[ProcessConfig] = []
    for kind in PROCESS_NAMES:
        out.extend(_process(kind, m[kind], clock))
    _check_servo_stage(out)
    return tuple(out)


def _links(node: Any, robots: tuple[RobotConfig, ...], clock: ClockConfig) -> list[ProcessConfig]:
    """One link process per arm of a networked kind (``link.<robot>``), placed by the
    ``processes.link`` entry: the arm's connection, ticking with its robot; then one hand
    process per arm with a hand (``hand.<robot>``: non-serious, SCHED_OTHER, unbound)."""
    entry = _process("link", node, clock)[0] if node is not None else None
    links = [
        ProcessConfig(
            name=f"link.{r.name}",
            kind="link",
            cpu=entry.cpu if entry else None,
            priority=entry.priority if entry else 0,
            period_ms=clock.base_tick_ms,
            serious=entry.serious if entry else True,
            stage=entry.stage if entry else 0,
        )
        for r in robots
        if hardware_kind(r.hardware.kind).links
    ]
    hands = [
        ProcessConfig(
            name=f"hand.{r.name}",
            kind="hand",
            cpu=None,
            priority=0,
            period_ms=clock.base_tick_ms,
            serious=False,
            stage=0,
        )
        for r in robots
        if r.hardware.hand
    ]
    return links + hands


def _camera_process(
    node: Any, scene: Scene, robots: tuple[RobotConfig, ...], clock: ClockConfig
) -> ProcessConfig:
    """The camera process of a scene with cameras, placed by ``processes.camera`` (its CPU and
    nice; always at normal scheduling, never serious), its period the fastest camera's in whole
    base ticks.  Only a cell Kali's own plant simulates can be rendered."""
    for r in robots:
        if hardware_kind(r.hardware.kind).simulator != RENDERED_SIMULATOR:
            _fail(
                "scene",
                scene.source,
                f"declares cameras, which render the cell Kali's own plant simulates; robot "
                f"'{r.name}' is on {r.hardware.kind} hardware, simulated elsewhere if at all",
            )
    keys, defaults = _PROCESS_KEYS["camera"], _KIND_DEFAULTS["camera"]
    v = _read(ProcessEntry, node or {}, "processes.camera", keys, {}, defaults)
    fastest = ms_to_ns(1e3 / max(c.rate_hz for c in scene.cameras))
    ticks = max(1, round(fastest / ms_to_ns(clock.base_tick_ms)))
    return ProcessConfig(
        name="camera",
        kind="camera",
        cpu=_cpu(v["cpu"], "processes.camera.cpu"),
        priority=0,
        nice=v.get("nice", 0),
        period_ms=ns_to_ms(ticks * ms_to_ns(clock.base_tick_ms)),
        serious=False,
        stage=0,
    )


def _check_servo_stage(processes: list[ProcessConfig]) -> None:
    """The SVs share SIO's lockstep stage (thesis 3.3.4: one gang each servo tick).  SIO
    waits inside its tick for the SVs' servos, and a lockstep stage ends only when all of
    its processes have acknowledged, so SVs in an earlier stage would wait for a feed that
    never comes, and in a later one SIO would wait for them (a deadline halt that names the
    symptom, not the config)."""
    sio = next(p for p in processes if p.kind == "sio")
    sv = next(p for p in processes if p.kind == "sv")
    if sv.stage != sio.stage:
        _fail(
            "processes.sv.stage",
            sv.stage,
            f"must equal processes.sio.stage ({sio.stage}): SIO waits within its tick for "
            "the SVs' servos, so in lockstep they run in one stage",
        )


def _process(kind: str, node: Any, clock: ClockConfig) -> list[ProcessConfig]:
    """One ``processes.<kind>`` entry (a list because ``sv`` expands to several workers)."""
    path = f"processes.{kind}"
    hints: dict[str, str] = {}
    if kind in _CLOCK_PERIOD_FIELD:
        hints["period_ms"] = (
            f"not allowed: the {kind} period comes from {_CLOCK_PERIOD_FIELD[kind]}; set it there"
        )
    if kind == "sv":
        hints["cpu"] = "not allowed: sv has one worker per entry of cpus, e.g. cpus: [0, 1]"
    if kind == "wallclock":
        hints["period_ms"] = "not allowed: the wall clock ticks every clock.base_tick_ms"
    v = _read(ProcessEntry, node, path, _PROCESS_KEYS[kind], hints, _KIND_DEFAULTS[kind])
    v = {**_KIND_DEFAULTS[kind], **v}
    if not v.get("enabled", True):
        return []  # an optional process (dynamics, viewer) left out: Kali runs without it
    if v.get("period_ms") is not None:
        period = _period(v["period_ms"], f"{path}.period_ms", clock.base_tick_ms)
    else:
        period = _default_period(kind, clock)
    nice = v.get("nice", 0)
    if nice and v["priority"]:
        _fail(
            f"{path}.nice",
            nice,
            f"applies to normal scheduling (priority 0); at SCHED_FIFO priority "
            f"{v['priority']} the process outranks every normal one already",
        )
    common = {
        "kind": kind,
        "priority": v["priority"],
        "nice": nice,
        "period_ms": period,
        "serious": v["serious"],
        "stage": v["stage"],
    }
    if kind != "sv":
        return [ProcessConfig(name=kind, cpu=_cpu(v.get("cpu"), f"{path}.cpu"), **common)]
    rest = v["rest_ms"]
    rest = _rest_of(clock) if rest is None else _rest(rest, f"{path}.rest_ms", clock)
    count = v["count"]
    if v["cpus"] is not None:
        cpus_node = v["cpus"]
        if not isinstance(cpus_node, list) or len(cpus_node) != count:
            got = (
                f"{len(cpus_node)} entries" if isinstance(cpus_node, list) else _kind_of(cpus_node)
            )
            _fail(
                f"{path}.cpus",
                cpus_node,
                f"must be a list of {count} entries (one per worker, sv.count = {count}), "
                f"each a CPU index or null; got {got}",
            )
        cpus = [_cpu(c, f"{path}.cpus[{i}]") for i, c in enumerate(cpus_node)]
    else:
        cpus = [None] * count
    return [
        ProcessConfig(name=f"sv.{i}", cpu=cpu, poll_us=v["poll_us"], rest_ms=rest, **common)
        for i, cpu in enumerate(cpus)
    ]


def _rest_of(clock: ClockConfig) -> float:
    """An SV's rest period left out of the config: ``DEFAULT_REST_MS`` rounded up to whole
    servo periods, or 0 (never rest) beyond the serious tolerance."""
    servo_ns = ms_to_ns(clock.servo_period_ms)
    rest_ns = -(-ms_to_ns(DEFAULT_REST_MS) // servo_ns) * servo_ns
    return ns_to_ms(rest_ns) if rest_ns <= ms_to_ns(clock.serious_miss_tolerance_ms) else 0


def _rest(value: Any, path: str, clock: ClockConfig) -> float:
    """An SV's rest period (``processes.sv.rest_ms``): 0, or a whole number of servo periods
    up to the serious tolerance (a resting SV that dies is found within two of them)."""
    if value == 0 and not isinstance(value, bool):
        return 0
    servo, most = clock.servo_period_ms, clock.serious_miss_tolerance_ms
    rest = _period(value, path, clock.base_tick_ms, servo, "clock.servo_period_ms")
    if ms_to_ns(rest) % ms_to_ns(servo) or rest > most:
        _fail(
            path,
            value,
            f"must be 0 or a whole multiple of clock.servo_period_ms ({servo}) "
            f"up to clock.serious_miss_tolerance_ms ({most})",
        )
    return rest


def _model(value: Any, path: str, base_dir: str, files: str) -> tuple[str, RobotType]:
    """A robot's ``model``: a shipped type's name, or a ``.py`` file defining ``ROBOT``
    (relative to ``base_dir``; its copy under ``files`` when given, ``pyfile.mirror``),
    returned absolute with its type, loaded and checked (``kali_daemons.robots.typefile``)
    so that a bad file stops ``kalictl start``."""
    names = tuple(known_types())
    if isinstance(value, str) and value in names:
        return value, robot_type(value)
    if not isinstance(value, str) or not is_type_file(value):
        _fail(path, value, f"must be one of: {', '.join(names)}, or a .py file defining ROBOT")
    given = os.path.expanduser(value)
    resolved = os.path.realpath(os.path.join(base_dir, given))
    if files:
        resolved = str(mirror(files, Path(resolved)))
    try:
        return resolved, robot_type(resolved)
    except ConfigError as exc:
        relative = ""
        if not os.path.isabs(given) and not os.path.isfile(resolved):
            relative = f" (a relative path is taken from the config file's directory, {base_dir})"
        text = str(exc).removeprefix("config: ")
        raise _InvalidError(f"{path} = {_show(value, 200)}: {text}{relative}") from None


def _robots(
    node: Any, base_dir: str, files: str, clock: ClockConfig
) -> tuple[RobotConfig, ...]:
    """The ``robots`` list: 1..MAX_ROBOTS arms with unique names; a ``model`` that is a file
    path is taken from ``base_dir`` when relative and stored absolute."""
    entries = _list(node, "robots", 1, MAX_ROBOTS)
    robots: list[RobotConfig] = []
    first_index: dict[str, int] = {}
    for i, entry in enumerate(entries):
        path = f"robots[{i}]"
        if isinstance(entry, dict) and entry.get("ff") is False:  # YAML 1.1 reads off as false
            entry = {**entry, "ff": "off"}
        if isinstance(entry, dict) and "name" not in entry:
            # pydantic's dataclass decorator is typed as returning the class unchanged; the
            # class it returns has __pydantic_fields__
            _mapping(entry, path, tuple(RobotConfig.__pydantic_fields__))  # type: ignore[attr-defined]
            raise _InvalidError(
                f"{path}.name: missing; required, a string matching {_ROBOT_NAME_RE.pattern}"
            )
        v = _read(RobotConfig, entry, path)
        name = v["name"]
        if name in first_index:
            _fail(
                f"{path}.name",
                name,
                f"duplicate; robot names must be unique (also robots[{first_index[name]}])",
            )
        first_index[name] = i
        v["model"], rtype = _model(v["model"], f"{path}.model", base_dir, files)
        xyz = v["base_xyz"]
        if not isinstance(xyz, list | tuple) or len(xyz) != 3:
            _fail(f"{path}.base_xyz", xyz, "must be a list of 3 numbers [x, y, z] in metres")
        v["base_xyz"] = tuple(
            _base_coordinate(c, f"{path}.base_xyz[{j}]") for j, c in enumerate(xyz)
        )
        nj = rtype.n_joints
        safe = v["safe_rad"]
        if safe == ():
            safe = DEFAULT_SAFE_RAD
        if isinstance(safe, list):
            if len(safe) != nj:
                _fail(
                    f"{path}.safe_rad",
                    safe,
                    f"must be a number or a list of {nj} numbers (one per joint of a "
                    f"{v['model']}), not {len(safe)}",
                )
            v["safe_rad"] = tuple(
                _float(s, f"{path}.safe_rad[{j}]", 0.0, math.pi) for j, s in enumerate(safe)
            )
        else:
            v["safe_rad"] = (_float(safe, f"{path}.safe_rad", 0.0, math.pi),) * nj
        if "index_phases_deg" in entry:
            v["index_phases_deg"] = _per_joint(
                entry["index_phases_deg"],
                f"{path}.index_phases_deg",
                nj,
                0.0,
                360.0,
                per_joint_only=True,
            )
        v["ft"] = _ft(entry.get("ft", {}), f"{path}.ft")
        v["hardware"] = _hardware(
            entry.get("hardware", {}), f"{path}.hardware", v["model"], rtype, clock
        )
        sheet, kind = v["ft"].sheet, hardware_kind(v["hardware"].kind)
        if sheet is not None and sheet.source not in kind.wrist:
            takes = [s.name for s in FT_SHEETS.values() if s.source in kind.wrist]
            _fail(
                f"{path}.ft.sensor",
                v["ft"].sensor,
                f"{kind.name} hardware takes a wrist wrench from "
                f"{', '.join(takes) or 'nothing'}; or none",
            )
        robots.append(RobotConfig(**v))
    return tuple(robots)


def _hardware(
    node: Any, path: str, model: str, rtype: RobotType, clock: ClockConfig
) -> HardwareConfig:
    """A robot's ``hardware`` section: a known kind that carries all of the arm's joints and
    can drive its type, with an address if (and only if) the kind is networked."""
    n_joints = rtype.n_joints
    v = _read(HardwareConfig, node, path)
    try:
        kind = hardware_kind(v["kind"])
    except ConfigError as exc:
        raise _InvalidError(
            f"{path}.kind = {_show(v['kind'])}: {str(exc).removeprefix('config: ')}"
        ) from None
    if n_joints > kind.channels:
        _fail(
            f"{path}.kind",
            v["kind"],
            f"carries {kind.channels} joints per arm; a {model} has {n_joints}",
        )
    why = kind.refuses(rtype, clock.servo_period_ms / 1000.0)
    if why:
        _fail(f"{path}.kind", v["kind"], f"cannot drive a {model}: {why}")
    if kind.links and not v["address"]:
        _fail(f"{path}.address", "", f"required: the {kind.name} robot's network address")
    if v["hand"] and not kind.hands:
        _fail(f"{path}.hand", True, f"a {kind.name} arm's gripper is a line of its hardware")
    if not kind.links and v["simulator_address"]:
        _fail(f"{path}.simulator_address", v["simulator_address"], "only for a networked robot")
    if not kind.links and v["address"]:
        _fail(
            f"{path}.address",
            v["address"],
            f"only for a networked robot (a {kind.name} arm is reached through its boards)",
        )
    return HardwareConfig(**v)


def _ft(node: Any, path: str) -> FtConfig:
    """A robot's ``ft`` section: its wrist sensor (``sensor: none`` for none) and tool."""
    v = _read(FtConfig, node, path)
    if v["sensor"] == "none":
        v["sensor"] = None
    if v["sensor"] is not None:
        v["sensor"] = _choice(v["sensor"], f"{path}.sensor", (*FT_SHEETS, "none"))
    com = v["tool_com_m"]
    if not isinstance(com, list | tuple) or len(com) != 3:
        _fail(f"{path}.tool_com_m", com, "must be a list of 3 numbers [x, y, z] in metres")
    v["tool_com_m"] = tuple(
        _float(c, f"{path}.tool_com_m[{j}]", -1.0, 1.0) for j, c in enumerate(com)
    )
    return FtConfig(**v)


# --------------------------------------------------------------------------------------------
# The schema and a resolved file (kalictl config schema, kalictl config show)


def schema() -> dict[str, Any]:
    """The JSON Schema of a config file, from the declarations (``ConfigFile``): each process
    kind's entry holds only its keys, with its kind's defaults."""
    out = TypeAdapter(ConfigFile).json_schema()
    defs = out["$defs"]
    entry = defs.pop("ProcessEntry")
    section = defs["ProcessesFile"]
    for kind in PROCESS_NAMES + OPTIONAL_PROCESSES:
        keys = _PROCESS_KEYS[kind]
        props = {k: dict(entry["properties"][k]) for k in keys}
        for key, value in _KIND_DEFAULTS[kind].items():
            if key in props:
                props[key]["default"] = value
        defs[f"Process_{kind}"] = {
            **entry,
            "title": f"processes.{kind}",
            "properties": props,
        }
        section["properties"][kind] = {"$ref": f"#/$defs/Process_{kind}"}
    out["$schema"] = "https://json-schema.org/draft/2020-12/schema"
    _json_bounds(out)
    return out


_JSON_BOUNDS = {
    "ge": "minimum",
    "gt": "exclusiveMinimum",
    "le": "maximum",
    "lt": "exclusiveMaximum",
}


def _json_bounds(node: Any) -> None:
    """Write, in place, the bounds pydantic leaves under their Python names where a field is
    an int or a float (``ms`` periods: ints when whole) as JSON Schema's on a number."""
    if isinstance(node, dict):
        if any(key in node for key in _JSON_BOUNDS):
            if node.get("anyOf") == [{"type": "integer"}, {"type": "number"}]:
                del node["anyOf"]
                node["type"] = "number"
            for key, name in _JSON_BOUNDS.items():
                if key in node:
                    node[name] = node.pop(key)
        for value in node.values():
            _json_bounds(value)
    elif isinstance(node, list):
        for value in node:
            _json_bounds(value)


def _plain(value: Any) -> Any:
    """``value`` with tuples as lists and dataclasses as dicts, for ``yaml.safe_dump``."""
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: _plain(getattr(value, f.name)) for f in dataclasses.fields(value)}
    if isinstance(value, list | tuple):
        return [_plain(v) for v in value]
    return value


def resolved(cfg: KaliConfig) -> dict[str, Any]:
    """``cfg`` as a config file with every default written out (``kalictl config show``);
    read again it gives the same config."""
    processes: dict[str, Any] = {}
    for kind in PROCESS_NAMES:
        procs = [p for p in cfg.processes if p.kind == kind]
        if not procs:
            processes[kind] = {"enabled": False}
            continue
        p = procs[0]
        entry = {
            "enabled": True,
            "cpu": p.cpu,
            "count": len(procs),
            "cpus": [q.cpu for q in procs],
            "priority": p.priority,
            "nice": p.nice,
            "period_ms": p.period_ms,
            "serious": p.serious,
            "stage": p.stage,
            "poll_us": p.poll_us,
            "rest_ms": p.rest_ms,
        }
        processes[kind] = {k: entry[k] for k in _PROCESS_KEYS[kind]}
    camera = next((p for p in cfg.processes if p.kind == "camera"), None)
    if camera is not None:
        processes["camera"] = {"cpu": camera.cpu, "nice": camera.nice}
    robots = []
    for r in cfg.robots:
        robot = _plain(r)
        # the sheet as read: the type's, in degrees, when the file gives none
        robot["index_phases_deg"] = [round(math.degrees(p), 9) for p in r.index_phases]
        robots.append(robot)
    doc: dict[str, Any] = {}
    for name in ConfigFile.__pydantic_fields__:  # type: ignore[attr-defined]  # as above
        doc[name] = _plain(getattr(cfg, name))
    doc["processes"] = processes
    doc["robots"] = robots
    doc["scene"] = cfg.scene.source  # the file it was read from, absolute
    return doc


class _ShowDumper(yaml.SafeDumper):
    """A SafeDumper writing a list of scalars on one line, as the shipped files do."""


def _represent_list(dumper: yaml.SafeDumper, data: list[Any]) -> yaml.Node:
    flow = not any(isinstance(v, dict | list) for v in data)
    return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flow)


_ShowDumper.add_representer(list, _represent_list)


def show(cfg: KaliConfig) -> str:
    """``resolved(cfg)`` as YAML, headed by where it came from."""
    head = f"# {cfg.source}, every default written out (kalictl config show)\n"
    text = yaml.dump(resolved(cfg), Dumper=_ShowDumper, sort_keys=False, allow_unicode=True)
    return head + text
