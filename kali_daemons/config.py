"""The Kali configuration: one versioned YAML file, parsed once into frozen, typed dataclasses.

Every process reads the same config (its text is stored in the shared-memory arena), so it is
validated completely up front: nothing starts on a bad config.  Every error names the field as
a dotted path (``processes.sv.cpus[1]``), the value given and what is allowed, e.g.
``config: config/default.yaml: clock.servo_period_ms = 3: must be a multiple of
clock.base_tick_ms (2)``.

Periods are in ms and may be fractional: the base tick is a whole number of microseconds
(0.5 ms gives a 2 kHz servo) and every period a whole number of base ticks, compared in
integer nanoseconds by ``period_ticks``.  A whole-ms value is kept as an ``int``, so an
integer config reads exactly as it always did.

Validation is a handful of small explicit helpers (``_int``, ``_float``, ``_mapping`` ...)
rather than a schema library, so each message can say exactly what went wrong.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import os
import re
import stat
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import numpy as np
import yaml

from kali_daemons import layout
from kali_daemons.errors import ConfigError
from kali_daemons.ftsensor import SHEETS as FT_SHEETS
from kali_daemons.ftsensor import FtSheet
from kali_daemons.ftsensor import sheet as ft_sheet
from kali_daemons.joints import JointMap
from kali_daemons.pyfile import mirror
from kali_daemons.robots import RobotType, is_type_file, known_types, robot_type

CONFIG_VERSION = 1
PROCESS_NAMES = ("wallclock", "plant", "tg", "sio", "sv", "dynamics", "viewer")
DEFAULT_MODEL = "puma560"  # a robot entry without a model

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
MAX_YAML_DEPTH = 32  # the deepest real config is 4 levels
MAX_YAML_NODES = 100_000  # after alias expansion; the default config has ~600

_INSTANCE_RE = re.compile(r"[a-z0-9][a-z0-9_-]{0,23}")
_ROBOT_NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,15}")

# Default lockstep stage of each kind when ``stage`` is omitted (lower runs first in a tick).
_DEFAULT_STAGE = {
    "wallclock": 0,
    "plant": 0,
    "tg": 1,
    "sio": 2,
    "sv": 2,
    "dynamics": 3,
    "viewer": 4,
}

# The keys each process entry accepts; tg/sio/sv get their period from the clock section.
_PROCESS_KEYS = {
    "wallclock": ("cpu", "priority"),
    "plant": ("cpu", "priority", "period_ms", "serious", "stage"),
    "tg": ("cpu", "priority", "serious", "stage"),
    "sio": ("cpu", "priority", "serious", "stage"),
    "sv": ("count", "cpus", "priority", "serious", "stage", "poll_us", "rest_ms"),
    "dynamics": ("enabled", "cpu", "priority", "period_ms", "serious", "stage"),
    "viewer": ("enabled", "cpu", "priority", "period_ms", "serious", "stage"),
}
_CLOCK_PERIOD_FIELD = {"tg": "clock.tg_period_ms", "sio": "clock.servo_period_ms"}
_CLOCK_PERIOD_FIELD["sv"] = _CLOCK_PERIOD_FIELD["sio"]

_TOP_KEYS = (
    "version",
    "instance",
    "arena_kib",
    "startup_timeout_s",
    "clock",
    "processes",
    "robots",
    "plant",
    "plugins",
    "tg_functions",
    "feedforward",
    "dashboard",
    "bridge",
)
_PLANT_KEYS = ("substep_ms", "watchdog_ms", "enable_hold_ms", "brake_delay_ms", "conveyor_m_s")
MAX_CONVEYOR_M_S = 0.5  # a faster belt is a units mistake
_CLOCK_KEYS = (
    "base_tick_ms",
    "servo_period_ms",
    "tg_period_ms",
    "serious_miss_tolerance_ms",
    "lockstep_ack_timeout_s",
    "busy_wait_us",
)
_ROBOT_KEYS = (
    "name",
    "model",
    "base_xyz",
    "base_yaw_deg",
    "servo",
    "safe_rad",
    "current_fault_ms",
    "ff",
    "index_phases_deg",
    "grasp_yaw_deg",
    "ft",
    "robot_servos",
)
_FT_KEYS = (
    "sensor",
    "tool_mass_kg",
    "tool_com_m",
    "tool_tip_m",
    "cutoff_hz",
    "contact_limit_n",
    "stale_ms",
)
FF_MODES = ("off", "gravity", "full")  # layout.FfMode by name
_FEEDFORWARD_KEYS = ("stale_ms", "ramp_ms")
_DASHBOARD_KEYS = ("connect", "web", "web_port", "grpc_port", "record", "server_memory_mib")
DASHBOARD_WEB = ("auto", "on", "off")  # when the viewer serves the web viewer
# a rerun gRPC address: scheme, host (group 2) and port (group 3)
GRPC_URL_RE = re.compile(r"rerun(\+https?)?://(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(\d{1,5})/proxy")
MAX_RECORD_PATH = 200
_BRIDGE_KEYS = (
    "enabled",
    "listen",
    "cpu",
    "telemetry_hz",
    "timing_hz",
    "users_file",
    "operators",
    "readers",
    "tls",
    "max_requests_per_s",
    "max_sessions",
    "event_history",
)
_TLS_KEYS = ("certificate", "private_key", "root_ca")
# a Zenoh endpoint the bridge listens on: protocol, host (group 2), port (group 3)
ENDPOINT_RE = re.compile(r"(tcp|tls|udp|quic)/(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9.-]+):(\d{1,5})")
LOOPBACK_HOSTS = ("127.0.0.1", "localhost", "[::1]")
MAX_LISTEN = 4
MAX_BRIDGE_USERS = 64
BRIDGE_STAGE = 5  # after the viewer: it reads what the tick wrote
DEFAULT_SAFE_RAD = 0.15  # tracking-error tolerance before a runaway halt
DEFAULT_CURRENT_FAULT_MS = 100.0  # demand beyond the current limit this long halts
# a bridge user's name: one chunk of the key expressions under its name (Zenoh reads a chunk
# starting with @ verbatim, so none does)
USER_RE = re.compile(r"[A-Za-z0-9_.-][A-Za-z0-9_.@-]{0,63}")
_SERVO_NAME_RE = re.compile(r"[a-z][a-z0-9_]{0,23}")
_PLUGIN_RE = re.compile(r"[A-Za-z0-9_./-]{1,200}")
MAX_PLUGINS = 16

# Used when the file has no ``processes`` / ``robots`` section (same as config/default.yaml).
_DEFAULT_PROCESSES: dict[str, dict[str, Any]] = {
    "wallclock": {"cpu": 0, "priority": 90},
    "plant": {"cpu": 1, "priority": 83, "period_ms": 1, "serious": True, "stage": 0},
    "tg": {"cpu": 1, "priority": 80, "serious": True, "stage": 1},
    "sio": {"cpu": 0, "priority": 85, "serious": True, "stage": 2},
    "sv": {
        "count": 2,
        "cpus": [0, 1],
        "priority": 84,
        "serious": True,
        "stage": 2,
        "poll_us": 200,
    },
    "dynamics": {"cpu": 1, "priority": 40, "period_ms": 10, "serious": False, "stage": 3},
    "viewer": {"cpu": 1, "priority": 0, "period_ms": 40, "serious": False, "stage": 4},
}
# config/default.yaml's cell, feed-forward full as it writes it (an arm written without ``ff``
# starts without: RobotConfig.ff)
_DEFAULT_ROBOTS: list[dict[str, Any]] = [
    {"name": "left", "model": "puma560", "base_xyz": [-0.6, 0.0, 0.0], "base_yaw_deg": 0,
     "ff": "full"},
    {"name": "right", "model": "puma560", "base_xyz": [0.6, 0.0, 0.0], "base_yaw_deg": 180,
     "ff": "full"},
]  # fmt: skip

# Top-level fields ``with_overrides`` may change (each is re-validated).
_OVERRIDABLE = ("instance", "arena_kib", "startup_timeout_s")

_MISSING: Any = object()


# --------------------------------------------------------------------------------------------
# The typed, frozen result


@dataclass(frozen=True)
class ClockConfig:
    """Wall-clock rates; every period in the system is a multiple of ``base_tick_ms``.

    The periods are ms, ints when whole (``base_tick_ms: 0.5`` gives a 2 kHz servo).
    """

    base_tick_ms: float = 1
    servo_period_ms: float = 1
    tg_period_ms: float = 10
    serious_miss_tolerance_ms: int = 20
    lockstep_ack_timeout_s: float = 5.0
    busy_wait_us: int = 0


@dataclass(frozen=True)
class ProcessConfig:
    """One periodic process (or the wall clock), with its period already resolved."""

    name: str
    kind: str
    cpu: int | None
    priority: int
    period_ms: float  # a whole number of base ticks; an int when whole ms
    serious: bool
    stage: int
    # sv only: a worker bound to another CPU than SIO's wakes on its own timer at each due
    # tick and polls this long for the clock's signal, then for SIO's feed, before it sleeps
    # on them (``Daemon.poll_ns``); 0: it always sleeps
    poll_us: int = 0
    # sv only: such a polling worker, while the worker on SIO's CPU runs every servo on its
    # own, is signalled only every this many ms (it rests: sv/daemon.py); 0: every tick
    rest_ms: float = 0


@dataclass(frozen=True)
class PlantConfig:
    """The simulated world's timing (thesis 3.7, appendix C): fixed by the hardware it models."""

    substep_ms: float = 0.5  # MuJoCo step; the 500 Hz current loop needs at least 1 kHz
    watchdog_ms: float = 20.0  # I/O board safety timeout (appendix C.4)
    enable_hold_ms: float = 15.0  # enable bit must stay high this long (power switch relay)
    brake_delay_ms: float = 50.0  # brake solenoids engage/release this long after the amps
    # the stand's top is a conveyor belt carrying the bar at this velocity (world x, y; m/s)
    # while the first arm's I/O board drives its motor (``boards.run_conveyor``); 0: no belt
    conveyor_m_s: tuple[float, float] = (0.0, 0.0)


@dataclass(frozen=True)
class FtConfig:
    """A robot's wrist force/torque sensor and the tool on it (issue 27, ``ftsensor.py``).

    The sensor sits on the flange (its frame the flange's); the tool hangs on the sensor: its
    mass and centre of mass (sensor frame) are what SIO subtracts as gravity, and its tool
    point, ``tool_tip_m`` out along the sensor's z, is where the contact wrench is given.
    """

    sensor: str | None = "mini45"  # a data sheet of ftsensor.SHEETS; None: no sensor
    # a bare pad by default (the bar's grasp and every tuned gain stay as they were); a
    # researcher's tool, gripper or payload is given here, and the plant, SIO's gravity
    # compensation and the dynamics model all carry it
    tool_mass_kg: float = 0.0
    tool_com_m: tuple[float, float, float] = (0.0, 0.0, 0.0)
    tool_tip_m: float = 0.042
    cutoff_hz: float = 30.0  # SIO's low-pass on the contact wrench
    contact_limit_n: float = 150.0  # a contact force beyond this halts (FORCE)
    # no fresh sample this long halts (FORCE: the sensor is silent); above the clock's
    # serious-miss tolerance, so that a stalled plant (the board) is named as what it is
    stale_ms: float = 50.0

    @property
    def sheet(self) -> FtSheet | None:
        """The sensor's data sheet, or None without a sensor."""
        return None if self.sensor is None else ft_sheet(self.sensor)


@dataclass(frozen=True)
class RobotConfig:
    """One arm in the cell: its model and where its base sits in the world frame."""

    name: str
    model: str
    base_xyz: tuple[float, float, float]
    base_yaw_deg: float
    servo: str = "pid"  # the servo algorithm every joint starts with (builtin or plugin)
    safe_rad: tuple[float, ...] = ()  # tracking tolerance per joint; empty: DEFAULT_SAFE_RAD
    current_fault_ms: float = DEFAULT_CURRENT_FAULT_MS  # demand beyond the limit this long halts
    ff: str = "off"  # feed-forward it starts with: off, gravity or full (FF_MODES)
    # the arm's calibration sheet (thesis 3.5.1): each joint's index-pulse motor angle, rad;
    # the config's index_phases_deg, else (left empty) its robot type's
    index_phases: tuple[float, ...] = ()
    # how its flange holds the bar: its grasp site turned this much (deg, counter-clockwise
    # seen from above) about the vertical through the grasp point (kali_daemons.model)
    grasp_yaw_deg: float = 0.0
    ft: FtConfig = FtConfig()  # its wrist force/torque sensor and tool
    # whether it may run robot-level servos (issue 27): the SVs then hold its model (they
    # load Pinocchio for it, ~20 MB more PSS each), so the lean default leaves it off
    robot_servos: bool = False

    def __post_init__(self) -> None:
        if not self.index_phases:
            sheet = tuple(float(v) for v in self.type.index_phases)
            object.__setattr__(self, "index_phases", sheet)
        if not self.safe_rad:
            object.__setattr__(self, "safe_rad", (DEFAULT_SAFE_RAD,) * self.n_joints)

    @property
    def n_joints(self) -> int:
        """Joints of the arm: its robot type's."""
        return self.type.n_joints

    @property
    def type(self) -> RobotType:
        """The arm's robot type (``kali_daemons.robots``)."""
        return robot_type(self.model)


@dataclass(frozen=True)
class FeedforwardConfig:
    """How SIO treats the dynamics process's feed-forward torques (thesis 3.3.6)."""

    stale_ms: float = 50.0  # silent or behind this long: SIO drops the feed-forward
    ramp_ms: float = 200.0  # feed-forward fades in and out over this time: no torque step


@dataclass(frozen=True)
class DashboardConfig:
    """Where the viewer's live rerun dashboard goes (thesis 3.3.7, DESIGN 8)."""

    # a rerun viewer to stream to when one listens there (None: never look for one)
    connect: str | None = "rerun+http://127.0.0.1:9876/proxy"
    web: str = "auto"  # serve the web viewer on 127.0.0.1: auto (no live viewer found), on, off
    web_port: int = 9090  # its HTTP port; 0 or a taken port: a free one (kalictl view tells)
    grpc_port: int = 9877  # its data stream; not 9876, where a native viewer listens
    record: str | None = None  # an .rrd file to record to, relative to the config's directory
    server_memory_mib: int = 256  # data the web viewer's server keeps for late browsers


@dataclass(frozen=True)
class TlsConfig:
    """The bridge's TLS files (absolute paths): its certificate and key, and the CA whose
    client certificates it accepts (a client's common name is its user name for the roles)."""

    certificate: str
    private_key: str
    root_ca: str | None = None


@dataclass(frozen=True)
class BridgeConfig:
    """The Zenoh bridge (issue 29, ``kali_daemons/bridge``): where it listens, how often it
    publishes and who may do what.  Off by default; on, ``kalictl start`` starts process
    ``bridge`` (non-serious, SCHED_OTHER, on ``cpu``).

    Without ``users_file`` or client-certificate TLS nobody is authenticated, so the bridge
    may listen on loopback only and every session there may command (as a local user can).
    With them, ``operators`` may command and ``readers`` only read (telemetry, events,
    status); anyone else is refused by Zenoh's access control."""

    enabled: bool = False
    listen: tuple[str, ...] = ("tcp/127.0.0.1:7447",)
    cpu: int | None = 1
    telemetry_hz: float = 100.0  # each robot's state, decimated from the servo rate
    timing_hz: float = 1.0  # per-process timing statistics
    users_file: str | None = None  # Zenoh's user:password dictionary, absolute
    operators: tuple[str, ...] = ()
    readers: tuple[str, ...] = ()
    tls: TlsConfig | None = None
    max_requests_per_s: int = 1000  # per user and kind; beyond, refused unread (never an e-stop)
    max_sessions: int = 8  # remote programs at once
    event_history: int = 256  # events a late subscriber is sent

    @property
    def authenticated(self) -> bool:
        """Whether sessions are told apart (user names or client certificates)."""
        return self.users_file is not None or (
            self.tls is not None and self.tls.root_ca is not None
        )


@dataclass(frozen=True)
class KaliConfig:
    """A whole, validated configuration plus the text it came from."""

    version: int
    instance: str
    arena_kib: int
    startup_timeout_s: float
    clock: ClockConfig
    processes: tuple[ProcessConfig, ...]
    robots: tuple[RobotConfig, ...]
    source: str
    text: str
    plant: PlantConfig = PlantConfig()
    plugins: tuple[str, ...] = ()  # servo plugin files (relative to base_dir) or module names
    tg_functions: tuple[str, ...] = ()  # TG function plugins, likewise (tg.functions)
    feedforward: FeedforwardConfig = FeedforwardConfig()
    dashboard: DashboardConfig = DashboardConfig()
    bridge: BridgeConfig = BridgeConfig()
    base_dir: str = "."  # directory relative plugin paths are taken from
    # where a running instance keeps the copies of its user files it loads instead of the
    # originals (``kali_daemons.snapshot``; '' for none: a config read from its file)
    files: str = ""

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


# --------------------------------------------------------------------------------------------
# Public entry points


def parse_config(
    text: str, source: str = "<string>", base_dir: str | None = None, files: str = ""
) -> KaliConfig:
    """Parse and fully validate YAML ``text``; ``source`` names it in every error message.

    ``base_dir`` is where relative plugin and robot type file paths are found (default: the
    current directory); ``files``, when given, where a running instance keeps its copies of
    them (``kali_daemons.snapshot``), which are loaded instead.
    """
    if not isinstance(text, str):
        raise ConfigError(f"{source}: config text must be a str, not {type(text).__name__}")
    try:
        doc = yaml.load(text, Loader=_Loader)  # _Loader is a SafeLoader
    except yaml.MarkedYAMLError as exc:
        raise ConfigError(f"{source}: {_yaml_error_text(exc)}") from None
    except yaml.reader.ReaderError as exc:  # a control character or bad code point
        line = text.count("\n", 0, exc.position) + 1
        code = exc.character if isinstance(exc.character, int) else ord(exc.character)
        reason = f"character U+{code:04X} is not allowed in YAML"
        raise ConfigError(f"{source}: line {line}: YAML does not parse: {reason}") from None
    except yaml.YAMLError as exc:
        raise ConfigError(f"{source}: YAML does not parse: {exc}") from None
    base = os.path.abspath(base_dir or ".")
    try:
        cfg = _build(doc, source, text, base, files)
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


def load_config(path: str | os.PathLike[str]) -> KaliConfig:
    """Read and parse the config file at ``path``; a missing or unreadable file is a ConfigError."""
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
    return parse_config(text, source, os.path.dirname(os.path.abspath(source)))


def with_overrides(cfg: KaliConfig, **changes: Any) -> KaliConfig:
    """``dataclasses.replace`` for top-level scalar fields (e.g. ``instance`` from the CLI).

    Each new value is validated like the file's own.  ``text`` is left as parsed, so a
    process that re-parses it sees the file's values, not the overrides.
    """
    checked: dict[str, Any] = {}
    for key, value in changes.items():
        try:
            if key == "instance":
                checked[key] = _identifier(value, "instance", _INSTANCE_RE)
            elif key == "arena_kib":
                checked[key] = _int(value, "arena_kib", 64, 1_048_576)
            elif key == "startup_timeout_s":
                checked[key] = _float(value, "startup_timeout_s", 0.0, MAX_TIMEOUT_S)
            else:
                allowed = ", ".join(_OVERRIDABLE)
                raise _InvalidError(f"{key}: cannot be overridden; overridable fields: {allowed}")
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
    servos, each in registry order."""
    return layout.Cell(
        robots=tuple(r.name for r in cfg.robots),
        joints=cfg.joints.counts,
        flight_rows=layout.flight_rows(ms_to_ns(cfg.clock.servo_period_ms)),
        algorithms=algorithms,
        arms=arms,
        config_bytes=len(cfg.text.encode()),
        config_dir_bytes=len(cfg.base_dir.encode()),
        config_files_bytes=len(cfg.files.encode()),
    )


def arena_need(cfg: KaliConfig) -> tuple[int, int, list[tuple[str, int]]]:
    """(bytes, blocks, the parts' bytes by key, the largest first) the cell's arena must hold:
    the header and directory plus every block of ``layout.blocks``, each rounded up to
    ``ALIGN``, and a directory entry for the free space after them.

    A plugin's private data is counted at its largest (``MAX_DATA_BYTES`` a joint, and as
    much a robot for a robot-level servo it may register): its dtype is known only once the
    plugin is imported, which parsing does not do.  Outside anything real-time."""
    from .servo import MAX_DATA_BYTES, Registry

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


def retrigger_hold_ticks(servo_period_ms: float, plant_period_ms: float) -> int:
    """How many servo ticks SIO holds the board's watchdog retrigger bit high, and then low
    ("one must set high state then low state to perform a retrigger", thesis C.5): the
    fewest that last two plant periods.  The simulated board reads its registers once a
    plant period, so a level held one 1 ms servo tick can fall between two reads, and when
    the plant reads as SIO writes, every falling edge can for 20 ms: a soak halted so, SIO
    on time at every tick.  Held two reads long, each level is read at least once."""
    servo_ns, plant_ns = ms_to_ns(servo_period_ms), ms_to_ns(plant_period_ms)
    return max(1, -(-2 * plant_ns // servo_ns))


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
# YAML loading


class _Loader(yaml.SafeLoader):
    """A SafeLoader that rejects duplicate mapping keys (PyYAML silently keeps the last),
    nesting deeper than MAX_YAML_DEPTH (Python's recursion limit would end it with a
    traceback) and aliases expanding to more than MAX_YAML_NODES nodes ("billion laughs":
    PyYAML shares aliased objects, but every walk of the document, an error message's
    rendering of a value included, would visit each of the 10**9 leaves)."""

    _depth = 0

    def compose_node(self, parent: yaml.Node | None, index: Any) -> yaml.Node:
        if self._depth >= MAX_YAML_DEPTH:
            raise yaml.composer.ComposerError(
                None,
                None,
                f"nested deeper than {MAX_YAML_DEPTH} levels",
                self.peek_event().start_mark,
            )
        self._depth += 1
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1

    def compose_document(self) -> yaml.Node:
        node = super().compose_document()
        sizes: dict[int, int] = {}  # id(node) -> expanded size: an alias is its anchor's node

        def size(n: yaml.Node) -> int:  # depth bounded by MAX_YAML_DEPTH
            if id(n) not in sizes:
                if isinstance(n, yaml.SequenceNode):
                    children = n.value
                elif isinstance(n, yaml.MappingNode):
                    children = [c for pair in n.value for c in pair]
                else:
                    children = []
                total = 1
                for c in children:
                    total += size(c)
                    if total > MAX_YAML_NODES:
                        raise yaml.composer.ComposerError(
                            None,
                            None,
                            f"aliases expand to more than {MAX_YAML_NODES} nodes",
                            n.start_mark,
                        )
                sizes[id(n)] = total
            return sizes[id(n)]

        if node is not None:
            size(node)
        return node

    def construct_mapping(self, node: yaml.Node, deep: bool = False) -> dict[Any, Any]:
        seen: set[tuple[str, str]] = set()
        if isinstance(node, yaml.MappingNode):
            for key_node, _ in node.value:
                if not isinstance(key_node, yaml.ScalarNode) or key_node.tag.endswith(":merge"):
                    continue
                ident = (key_node.tag, key_node.value)
                if ident in seen:
                    raise yaml.constructor.ConstructorError(
                        None, None, f"duplicate key {key_node.value!r}", key_node.start_mark
                    )
                seen.add(ident)
        return super().construct_mapping(node, deep=deep)


def _yaml_error_text(exc: yaml.MarkedYAMLError) -> str:
    """``line L, column C: YAML does not parse: <problem>`` (1-based, as editors count)."""
    mark = exc.problem_mark or exc.context_mark
    problem = exc.problem or exc.context or "syntax error"
    if mark is None:
        return f"YAML does not parse: {problem}"
    return f"line {mark.line + 1}, column {mark.column + 1}: YAML does not parse: {problem}"


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


def _build(doc: Any, source: str, text: str, base_dir: str, files: str) -> KaliConfig:
    """Turn the parsed YAML document into a KaliConfig, or raise _InvalidError; relative
    paths are taken from ``base_dir`` (absolute), user files read from ``files`` if given."""
    if not isinstance(doc, dict):
        empty = " (the file is empty)" if doc is None else ""
        _fail("the top level", doc, f"must be a mapping{empty}, not {_kind_of(doc)}")
    # The version first: a file for another version may legitimately have other keys.
    version = doc.get("version", _MISSING)
    if version is _MISSING:
        raise _InvalidError(f"version: missing; required, this Kali reads version {CONFIG_VERSION}")
    if type(version) is not int or version != CONFIG_VERSION:
        _fail("version", version, f"unsupported; this Kali reads version {CONFIG_VERSION}")
    _mapping(doc, "", _TOP_KEYS)
    if "instance" not in doc:
        raise _InvalidError(
            f"instance: missing; required, a string matching {_INSTANCE_RE.pattern}"
        )
    instance = _identifier(doc["instance"], "instance", _INSTANCE_RE)
    arena_kib = _int(doc.get("arena_kib", 6144), "arena_kib", 64, 1_048_576)
    startup = _float(doc.get("startup_timeout_s", 60), "startup_timeout_s", 0.0, MAX_TIMEOUT_S)
    clock = _clock(doc.get("clock", {}))
    if "processes" in doc:
        processes = _processes(doc["processes"], clock)
    else:
        try:
            processes = _processes(_DEFAULT_PROCESSES, clock)
        except _InvalidError as exc:
            raise _InvalidError(f"{exc} (in the built-in default processes section)") from None
    robots = _robots(doc.get("robots", _DEFAULT_ROBOTS), base_dir, files)
    bridge = _bridge(doc.get("bridge", {}), base_dir)
    if bridge.enabled:  # not in ``processes``: its section holds everything about it
        processes = (*processes, bridge_process(bridge, clock))
    plant_period = next(p.period_ms for p in processes if p.kind == "plant")
    plant = _plant(doc.get("plant", {}), plant_period, clock.servo_period_ms)
    plugins = tuple(
        _identifier(p, f"plugins[{i}]", _PLUGIN_RE)
        for i, p in enumerate(_list(doc.get("plugins", []), "plugins", 0, MAX_PLUGINS))
    )
    tg_functions = tuple(
        _identifier(p, f"tg_functions[{i}]", _PLUGIN_RE)
        for i, p in enumerate(_list(doc.get("tg_functions", []), "tg_functions", 0, MAX_PLUGINS))
    )
    return KaliConfig(
        version=CONFIG_VERSION,
        instance=instance,
        arena_kib=arena_kib,
        startup_timeout_s=startup,
        clock=clock,
        processes=processes,
        robots=robots,
        source=source,
        text=text,
        plant=plant,
        plugins=plugins,
        tg_functions=tg_functions,
        feedforward=_feedforward(doc.get("feedforward", {})),
        dashboard=_dashboard(doc.get("dashboard", {})),
        bridge=bridge,
        base_dir=base_dir,
        files=files,
    )


def _bridge(node: Any, base_dir: str) -> BridgeConfig:
    """The ``bridge`` section (issue 29): listening endpoints, rates, users and roles, TLS."""
    m = _mapping(node, "bridge", _BRIDGE_KEYS)
    d = BridgeConfig()
    enabled = _bool(m.get("enabled", d.enabled), "bridge.enabled")
    listen_node = m.get("listen", list(d.listen))
    if isinstance(listen_node, str):
        listen_node = [listen_node]
    listen = []
    for i, e in enumerate(_list(listen_node, "bridge.listen", 1, MAX_LISTEN)):
        found = ENDPOINT_RE.fullmatch(e) if isinstance(e, str) else None
        if found is None or not 0 < int(found.group(3)) < 65536:
            _fail(f"bridge.listen[{i}]", e, "must be a Zenoh endpoint like tcp/127.0.0.1:7447")
        listen.append(e)
    tls = None
    if m.get("tls") is not None:
        t = _mapping(m["tls"], "bridge.tls", _TLS_KEYS)
        files = {}
        for key in _TLS_KEYS:
            if t.get(key) is None:
                if key == "root_ca":
                    continue
                raise _InvalidError(f"bridge.tls.{key}: missing; a PEM file path")
            files[key] = _file(t[key], f"bridge.tls.{key}", base_dir)
        tls = TlsConfig(**files)
    users_file = m.get("users_file")
    if users_file is not None:
        users_file = _file(users_file, "bridge.users_file", base_dir)
    roles = {}
    for key in ("operators", "readers"):
        names = _list(m.get(key, []), f"bridge.{key}", 0, MAX_BRIDGE_USERS)
        roles[key] = tuple(
            _identifier(n, f"bridge.{key}[{i}]", USER_RE) for i, n in enumerate(names)
        )
    both = set(roles["operators"]) & set(roles["readers"])
    if both:
        _fail("bridge.readers", sorted(both)[0], "is an operator too; give each user one role")
    cfg = BridgeConfig(
        enabled=enabled,
        listen=tuple(listen),
        cpu=_cpu(m.get("cpu", d.cpu), "bridge.cpu"),
        telemetry_hz=_float(
            m.get("telemetry_hz", d.telemetry_hz), "bridge.telemetry_hz", 0.0, 1000.0
        ),
        timing_hz=_float(m.get("timing_hz", d.timing_hz), "bridge.timing_hz", 0.0, 100.0),
        users_file=users_file,
        operators=roles["operators"],
        readers=roles["readers"],
        tls=tls,
        max_requests_per_s=_int(
            m.get("max_requests_per_s", d.max_requests_per_s),
            "bridge.max_requests_per_s",
            1,
            100_000,
        ),
        max_sessions=_int(m.get("max_sessions", d.max_sessions), "bridge.max_sessions", 1, 64),
        event_history=_int(
            m.get("event_history", d.event_history), "bridge.event_history", 1, 10_000
        ),
    )
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
    if any(e.startswith("tls/") for e in listen) and tls is None:
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
    return ProcessConfig("bridge", "bridge", bridge.cpu, 0, period, False, BRIDGE_STAGE)


def _dashboard(node: Any) -> DashboardConfig:
    """The ``dashboard`` section: the viewer's live viewer address, web viewer and recording."""
    m = _mapping(node, "dashboard", _DASHBOARD_KEYS)
    d = DashboardConfig()
    connect = m.get("connect", d.connect)
    if connect is not None:
        url = "a rerun gRPC URL like rerun+http://127.0.0.1:9876/proxy, or null"
        if not isinstance(connect, str):
            _fail("dashboard.connect", connect, f"must be {url}, not {_kind_of(connect)}")
        found = GRPC_URL_RE.fullmatch(connect)
        if len(connect) > MAX_RECORD_PATH or found is None or not 0 < int(found.group(3)) < 65536:
            _fail("dashboard.connect", connect, f"must be {url}")
    web = m.get("web", d.web)
    web = {True: "on", False: "off"}.get(web, web) if isinstance(web, bool) else web
    web = _choice(web, "dashboard.web", DASHBOARD_WEB)
    web_port = _int(m.get("web_port", d.web_port), "dashboard.web_port", 0, 65535)
    grpc_port = _int(m.get("grpc_port", d.grpc_port), "dashboard.grpc_port", 0, 65535)
    if grpc_port and grpc_port == web_port:
        _fail("dashboard.grpc_port", grpc_port, "must differ from dashboard.web_port")
    record = m.get("record", d.record)
    if record is not None:
        allowed = f"must be null or a file path of 1..{MAX_RECORD_PATH} characters"
        if not isinstance(record, str):
            _fail("dashboard.record", record, f"{allowed}, not {_kind_of(record)}")
        if not 0 < len(record) <= MAX_RECORD_PATH or any(c in record for c in "\0\n\r"):
            _fail("dashboard.record", record, allowed)
    memory = m.get("server_memory_mib", d.server_memory_mib)
    return DashboardConfig(
        connect=connect,
        web=web,
        web_port=web_port,
        grpc_port=grpc_port,
        record=record,
        server_memory_mib=_int(memory, "dashboard.server_memory_mib", 16, 65536),
    )


def _feedforward(node: Any) -> FeedforwardConfig:
    """The ``feedforward`` section: staleness limit and fade time, in ms."""
    m = _mapping(node, "feedforward", _FEEDFORWARD_KEYS)
    d = FeedforwardConfig()
    return FeedforwardConfig(
        stale_ms=_float(m.get("stale_ms", d.stale_ms), "feedforward.stale_ms", 0.0, 10_000.0),
        ramp_ms=_float(m.get("ramp_ms", d.ramp_ms), "feedforward.ramp_ms", 0.0, 10_000.0, False),
    )


def _plant(node: Any, period_ms: float, servo_ms: float) -> PlantConfig:
    """The ``plant`` section; the substep must divide the plant's period (``period_ms``).

    The plant advances one whole period per cycle, in ``period_ms / substep_ms`` MuJoCo steps.
    The watchdog must outlast SIO's retrigger cycle (``retrigger_hold_ticks``).
    """
    d = PlantConfig()
    m = _mapping(node, "plant", _PLANT_KEYS)
    sub = _float(m.get("substep_ms", d.substep_ms), "plant.substep_ms", 0.0, 1.0)
    n = period_ms / sub
    if round(n) < 1 or abs(n - round(n)) > 1e-9 * n:
        _fail(
            "plant.substep_ms",
            sub,
            f"must divide processes.plant.period_ms = {period_ms} "
            "(the plant advances one period per cycle, in whole substeps)",
        )
    watchdog = _float(m.get("watchdog_ms", d.watchdog_ms), "plant.watchdog_ms", 0.0, 1000.0)
    cycle = 2 * retrigger_hold_ticks(servo_ms, period_ms) * servo_ms
    if watchdog <= cycle:
        _fail(
            "plant.watchdog_ms",
            watchdog,
            f"must be > {cycle:g}: SIO retriggers the board every {cycle:g} ms (each level "
            f"held for the whole {servo_ms:g} ms servo periods that last two plant periods, "
            f"{period_ms:g} ms, so that the board reads it)",
        )
    return PlantConfig(
        substep_ms=sub,
        watchdog_ms=watchdog,
        enable_hold_ms=_float(
            m.get("enable_hold_ms", d.enable_hold_ms), "plant.enable_hold_ms", 0.0, 1000.0
        ),
        brake_delay_ms=_float(
            m.get("brake_delay_ms", d.brake_delay_ms), "plant.brake_delay_ms", 0.0, 1000.0
        ),
        conveyor_m_s=_conveyor(m.get("conveyor_m_s", list(d.conveyor_m_s))),
    )


def _conveyor(node: Any) -> tuple[float, float]:
    """``plant.conveyor_m_s``: the belt's velocity [vx, vy], at most MAX_CONVEYOR_M_S."""
    path = "plant.conveyor_m_s"
    if not isinstance(node, list) or len(node) != 2:
        _fail(path, node, "must be a list of 2 numbers [vx, vy] in m/s (the belt is level)")
    v = tuple(_finite(x, f"{path}[{j}]") for j, x in enumerate(node))
    if math.hypot(*v) > MAX_CONVEYOR_M_S:
        _fail(path, node, f"a belt faster than {MAX_CONVEYOR_M_S:g} m/s is a units mistake")
    return v  # type: ignore[return-value]


def _clock(node: Any) -> ClockConfig:
    """The ``clock`` section: rates first, then the periods that depend on them."""
    d = ClockConfig()
    m = _mapping(node, "clock", _CLOCK_KEYS)
    tick = _base_tick(m.get("base_tick_ms", d.base_tick_ms), "clock.base_tick_ms")
    servo = _clock_period(m, "servo_period_ms", d.servo_period_ms, tick, tick, "base_tick_ms")
    tg = _clock_period(m, "tg_period_ms", d.tg_period_ms, tick, servo, "servo_period_ms")
    clock = ClockConfig(
        base_tick_ms=tick,
        servo_period_ms=servo,
        tg_period_ms=tg,
        serious_miss_tolerance_ms=_int(
            m.get("serious_miss_tolerance_ms", d.serious_miss_tolerance_ms),
            "clock.serious_miss_tolerance_ms",
            0,
            1000,
        ),
        lockstep_ack_timeout_s=_float(
            m.get("lockstep_ack_timeout_s", d.lockstep_ack_timeout_s),
            "clock.lockstep_ack_timeout_s",
            0.0,
            MAX_TIMEOUT_S,
        ),
        busy_wait_us=_int(m.get("busy_wait_us", d.busy_wait_us), "clock.busy_wait_us", 0, 500),
    )
    if clock.serious_miss_tolerance_ms <= servo:  # a serious servo would halt at its first miss
        _fail(
            "clock.serious_miss_tolerance_ms",
            clock.serious_miss_tolerance_ms,
            f"must exceed clock.servo_period_ms = {servo:g} (at or below one period a serious "
            "servo-rate process halts the system at its first late tick)",
        )
    return clock


def _clock_period(
    m: dict[str, Any], key: str, default: float, tick: float, lo: float, lo_key: str
) -> float:
    """``clock.<key>``; when the default is what fails (e.g. a 3 ms tick), the message says so."""
    try:
        return _period(m.get(key, default), f"clock.{key}", tick, lo=lo, lo_name=f"clock.{lo_key}")
    except _InvalidError as exc:
        if key in m:
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
    m = _mapping(node, "processes", PROCESS_NAMES)
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


def _check_servo_stage(processes: list[ProcessConfig]) -> None:
    """The SVs share SIO's lockstep stage (thesis 3.3.4: one gang each servo tick).  SIO
    waits inside its tick for the SVs' servos, and a lockstep stage ends only when all of
    its processes have acknowledged, so SVs in an earlier stage would wait for a feed that
    never comes, and in a later one SIO would wait for them: the first powered tick then
    halted after 4 s (0.8 of the lockstep timeout) with "DEADLINE in sio: servos not done
    ... (unclaimed)" for every joint, which names the symptom, not the config."""
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
    m = _mapping(node, path, _PROCESS_KEYS[kind], hints)
    if not _bool(m.get("enabled", True), f"{path}.enabled"):
        return []  # an optional process (dynamics, viewer) left out: Kali runs without it

    priority = _int(m.get("priority", 0), f"{path}.priority", 0, MAX_PRIORITY)
    # omitted: serious as in the default config (the plant, tg, sio and sv are; a user who
    # leaves the key out never loses the halt on a dead or late servo process by accident)
    serious = _bool(
        m.get("serious", _DEFAULT_PROCESSES[kind].get("serious", False)), f"{path}.serious"
    )
    stage = _int(m.get("stage", _DEFAULT_STAGE[kind]), f"{path}.stage", 0, MAX_STAGE)
    if "period_ms" in m:
        period = _period(m["period_ms"], f"{path}.period_ms", clock.base_tick_ms)
    else:
        period = _default_period(kind, clock)

    def make(name: str, cpu: int | None, poll_us: int = 0, rest: float = 0) -> ProcessConfig:
        return ProcessConfig(name, kind, cpu, priority, period, serious, stage, poll_us, rest)

    if kind != "sv":
        return [make(kind, _cpu(m.get("cpu"), f"{path}.cpu"))]
    poll = _int(
        m.get("poll_us", _DEFAULT_PROCESSES["sv"]["poll_us"]), f"{path}.poll_us", 0, MAX_POLL_US
    )
    rest = _rest(m["rest_ms"], f"{path}.rest_ms", clock) if "rest_ms" in m else _rest_of(clock)
    count = _int(m.get("count", 2), f"{path}.count", 1, MAX_SV_WORKERS)
    if "cpus" in m:
        cpus_node = m["cpus"]
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
    return [make(f"sv.{i}", cpu, poll, rest) for i, cpu in enumerate(cpus)]


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


def _robots(node: Any, base_dir: str, files: str) -> tuple[RobotConfig, ...]:
    """The ``robots`` list: 1..MAX_ROBOTS arms with unique names; a ``model`` that is a file
    path is taken from ``base_dir`` when relative and stored absolute."""
    entries = _list(node, "robots", 1, MAX_ROBOTS)
    robots: list[RobotConfig] = []
    first_index: dict[str, int] = {}
    for i, entry in enumerate(entries):
        path = f"robots[{i}]"
        m = _mapping(entry, path, _ROBOT_KEYS)
        if "name" not in m:
            raise _InvalidError(
                f"{path}.name: missing; required, a string matching {_ROBOT_NAME_RE.pattern}"
            )
        name = _identifier(m["name"], f"{path}.name", _ROBOT_NAME_RE)
        if name in first_index:
            _fail(
                f"{path}.name",
                name,
                f"duplicate; robot names must be unique (also robots[{first_index[name]}])",
            )
        first_index[name] = i
        model, rtype = _model(m.get("model", DEFAULT_MODEL), f"{path}.model", base_dir, files)
        xyz_node = m.get("base_xyz", [0.0, 0.0, 0.0])
        if not isinstance(xyz_node, list) or len(xyz_node) != 3:
            _fail(f"{path}.base_xyz", xyz_node, "must be a list of 3 numbers [x, y, z] in metres")
        x, y, z = (_base_coordinate(v, f"{path}.base_xyz[{j}]") for j, v in enumerate(xyz_node))
        yaw = _finite(m.get("base_yaw_deg", 0.0), f"{path}.base_yaw_deg")
        servo = _identifier(m.get("servo", "pid"), f"{path}.servo", _SERVO_NAME_RE)
        safe_node = m.get("safe_rad", DEFAULT_SAFE_RAD)
        nj = rtype.n_joints
        if isinstance(safe_node, list):
            if len(safe_node) != nj:
                _fail(
                    f"{path}.safe_rad",
                    safe_node,
                    f"must be a number or a list of {nj} numbers (one per joint of a {model}), "
                    f"not {len(safe_node)}",
                )
            safe = tuple(
                _float(v, f"{path}.safe_rad[{j}]", 0.0, math.pi) for j, v in enumerate(safe_node)
            )
        else:
            safe = (_float(safe_node, f"{path}.safe_rad", 0.0, math.pi),) * nj
        fault_ms = _float(
            m.get("current_fault_ms", DEFAULT_CURRENT_FAULT_MS),
            f"{path}.current_fault_ms",
            0.0,
            10_000.0,
        )
        ff_node = m.get("ff", "off")
        if ff_node is False:  # YAML 1.1 reads a bare off as false
            ff_node = "off"
        ff = _choice(ff_node, f"{path}.ff", FF_MODES)
        sheet: tuple[float, ...] = ()  # the type's
        if "index_phases_deg" in m:
            phases = _per_joint(
                m["index_phases_deg"],
                f"{path}.index_phases_deg",
                rtype.n_joints,
                0.0,
                360.0,
                per_joint_only=True,
            )
            sheet = tuple(math.radians(v) for v in phases)
        grasp_yaw = _float(m.get("grasp_yaw_deg", 0.0), f"{path}.grasp_yaw_deg", -180.0, 180.0)
        ft = _ft(m.get("ft", {}), f"{path}.ft")
        robot_servos = _bool(m.get("robot_servos", False), f"{path}.robot_servos")
        robots.append(
            RobotConfig(
                name,
                model,
                (x, y, z),
                yaw,
                servo,
                safe,
                fault_ms,
                ff,
                sheet,
                grasp_yaw,
                ft,
                robot_servos,
            )
        )
    return tuple(robots)


def _ft(node: Any, path: str) -> FtConfig:
    """A robot's ``ft`` section: its wrist sensor (``sensor: none`` for none) and tool."""
    m = _mapping(node, path, _FT_KEYS)
    d = FtConfig()
    sensor_node = m.get("sensor", d.sensor)
    if sensor_node is None or sensor_node == "none":
        sensor = None
    else:
        sensor = _choice(sensor_node, f"{path}.sensor", (*FT_SHEETS, "none"))
    com_node = m.get("tool_com_m", list(d.tool_com_m))
    if not isinstance(com_node, list) or len(com_node) != 3:
        _fail(f"{path}.tool_com_m", com_node, "must be a list of 3 numbers [x, y, z] in metres")
    cx, cy, cz = (_float(v, f"{path}.tool_com_m[{j}]", -1.0, 1.0) for j, v in enumerate(com_node))
    return FtConfig(
        sensor=sensor,
        tool_mass_kg=_float(
            m.get("tool_mass_kg", d.tool_mass_kg), f"{path}.tool_mass_kg", 0.0, 50.0, False
        ),
        tool_com_m=(cx, cy, cz),
        tool_tip_m=_float(m.get("tool_tip_m", d.tool_tip_m), f"{path}.tool_tip_m", 0.0, 1.0, False),
        cutoff_hz=_float(m.get("cutoff_hz", d.cutoff_hz), f"{path}.cutoff_hz", 0.0, 1000.0),
        contact_limit_n=_float(
            m.get("contact_limit_n", d.contact_limit_n), f"{path}.contact_limit_n", 0.0, 10_000.0
        ),
        stale_ms=_float(m.get("stale_ms", d.stale_ms), f"{path}.stale_ms", 0.0, 1000.0),
    )
