"""The cell's world from a scene file: fixtures and parts, their shapes, poses, masses and
where each part can be grasped (DESIGN.md section 6).

A scene file is YAML: a list of objects, each one primitive shape (box, cylinder, sphere,
capsule) at a pose, fixed to the world or free, with its mass, friction, colour and named
grasps; and the cameras watching the cell (``Camera``: where, looking at what, how wide, how
many pixels how often).  The plant builds its MuJoCo bodies from it (``model.build_world``),
the dashboard draws it, and the same primitives are coal's shapes for the controller's
collision model: one description the simulator, the viewer and the controller all read the
same way, which an MJCF fragment (a language of its own, with defaults, includes and compiler
options) would not be.  ``config/scenes/default.yaml`` is the shipped cell: a stand between
the arms, a square bar on it and a table in front.  No MuJoCo and no Pinocchio here: every
process that reads a config reads its scene.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Final

import numpy as np

from kali_daemons.core.errors import ConfigError
from kali_daemons.core.yamltext import parse_yaml

if TYPE_CHECKING:
    from kali_daemons.runtime.config import RobotConfig

SCENE_VERSION: Final = 1
DEFAULT_SCENE: Final = Path(__file__).resolve().parents[1] / "config" / "scenes" / "default.yaml"
MAX_SCENE_BYTES: Final = 256 << 10
MAX_OBJECTS: Final = 64
# how near a checked motion lets an arm come to another arm or an object its links touch
DEFAULT_CLEARANCE_M: Final = 0.01
MAX_CLEARANCE_M: Final = 0.5
MAX_GRASPS: Final = 16  # of one object
MAX_EXTENT_M: Final = 10.0  # no object further out, nor larger (the TG's poses: tg.profiles)
# the cell: its floor's half width (the plant's floor plane) and how high a camera may stand
CELL_HALF_M: Final = 3.0
CELL_HEIGHT_M: Final = 3.0
MAX_CAMERAS: Final = 4
CAMERA_PIXELS: Final = (16, 1280)  # a camera's width and height, each within these
VERTICAL: Final = 1e-6  # a view this near the vertical (sine of its angle) takes y as up
MAX_CAMERA_HZ: Final = 30.0
# what a frame (colour and depth) costs the camera process, rendered in software through EGL
# without shadows: CAMERA_FRAME_MS plus CAMERA_PIXEL_US a pixel; the cameras together may take
# CAMERA_SHARE of a core (docs/decisions/0018-camera.md has the measurements)
CAMERA_FRAME_MS: Final = 12.0
CAMERA_PIXEL_US: Final = 0.08
CAMERA_SHARE: Final = 0.3
# each shape's size list: what the numbers are (all metres, all > 0)
SHAPES: Final = {
    "box": ("length x", "length y", "length z"),
    "cylinder": ("radius", "length"),
    "capsule": ("radius", "length between the caps' centres"),
    "sphere": ("radius",),
}
_NAME = re.compile(r"^[a-z][a-z0-9_]{0,31}$")
_OBJECT_KEYS = (
    "name", "shape", "size", "at", "rpy_deg", "fixed", "tools_touch", "arms_touch", "mass",
    "friction", "color",
)  # fmt: skip
_KEYS = {
    "object": (*_OBJECT_KEYS, "grasps"),
    "grasp": ("name", "at", "rpy_deg"),
    "camera": ("name", "at", "look_at", "fovy_deg", "width", "height", "rate_hz"),
}


@dataclass(frozen=True)
class Grasp:
    """Where a flange may hold an object: a frame in the object's frame (the flange's z
    towards the object), ``xyz`` (m) and ``quat`` (w, x, y, z)."""

    name: str
    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]

    @property
    def pose(self) -> np.ndarray:
        """The grasp in the object's frame (4×4)."""
        return quaternion_pose(self.xyz, self.quat)


@dataclass(frozen=True)
class SceneObject:
    """One thing in the cell: a primitive ``shape`` of ``size`` (``SHAPES`` says the numbers)
    centred at ``xyz`` (m, world) turned ``quat`` (w, x, y, z), fixed to the world or free (a
    free object has a ``mass``, kg, spread uniformly, and may have ``grasps``), with its
    sliding ``friction`` coefficient and ``color`` (r, g, b, a in 0..1).  A fixed object the
    arms' tools pass through has ``tools_touch`` False; one the arms' links pass through,
    ``arms_touch`` False."""

    name: str
    shape: str
    size: tuple[float, ...]
    xyz: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    fixed: bool
    mass: float
    friction: float
    color: tuple[float, float, float, float]
    grasps: tuple[Grasp, ...] = ()
    tools_touch: bool = True
    arms_touch: bool = True

    @property
    def pose(self) -> np.ndarray:
        """Where the object is built (4×4, world): a free one's rest pose."""
        return quaternion_pose(self.xyz, self.quat)

    @property
    def inertia(self) -> np.ndarray:
        """Its rotational inertia about its centre, in its own axes (kg·m², 3×3): its mass
        spread uniformly over its shape, as the simulator spreads it (zero if fixed)."""
        m, s = self.mass, self.size
        if self.shape == "box":
            a, b, c = (v * v for v in s)
            return np.diag([b + c, a + c, a + b]) * m / 12.0
        if self.shape == "sphere":
            return np.eye(3) * 0.4 * m * s[0] ** 2
        r, h = s
        if self.shape == "cylinder":
            side = m * (3.0 * r * r + h * h) / 12.0
            return np.diag([side, side, 0.5 * m * r * r])
        # a capsule: a cylinder of length h and two hemispheres, the mass shared by volume
        body, caps = math.pi * r * r * h, 4.0 / 3.0 * math.pi * r**3
        mc, ms = m * body / (body + caps), m * caps / (body + caps)
        side = mc * (3.0 * r * r + h * h) / 12.0 + ms * (
            0.4 * r * r + h * h / 4.0 + 3.0 * h * r / 8.0
        )
        return np.diag([side, side, mc * r * r / 2.0 + ms * 0.4 * r * r])

    def load_on(
        self, grasp: np.ndarray, share: float = 1.0
    ) -> tuple[float, np.ndarray, np.ndarray]:
        """What a flange holding it at ``grasp`` (the flange in its frame, 4×4) carries of it
        when it carries ``share`` of it: mass (kg), centre of mass in the flange frame (m),
        inertia about that centre in flange axes (kg·m²) (``robot.set_load``'s arguments)."""
        rotation, at = grasp[:3, :3], grasp[:3, 3]
        com = -rotation.T @ at  # the object's centre in the flange frame
        return self.mass * share, com, rotation.T @ self.inertia @ rotation * share

    def grasp(self, name: str) -> Grasp:
        """The grasp called ``name``; ConfigError naming the object's grasps."""
        for g in self.grasps:
            if g.name == name:
                return g
        known = ", ".join(g.name for g in self.grasps) or "none"
        raise ConfigError(f"scene: object {self.name!r} has no grasp {name!r}; grasps: {known}")


@dataclass(frozen=True)
class Camera:
    """A camera watching the cell: at ``xyz`` (m, world) looking at ``look_at`` with the
    world's z up in its image (the world's y, looking straight down or up), ``fovy_deg`` its
    vertical field of view, ``width`` × ``height`` pixels rendered ``rate_hz`` times a second.
    Square pixels, no distortion: a pinhole."""

    name: str
    xyz: tuple[float, float, float]
    look_at: tuple[float, float, float]
    fovy_deg: float
    width: int
    height: int
    rate_hz: float

    @property
    def pose(self) -> np.ndarray:
        """The camera in the world (4×4), in the image convention: x right, y down, z along
        the view (a point ``p`` in the camera's frame is at pixel ``K @ p / p[2]``)."""
        eye, at = np.asarray(self.xyz), np.asarray(self.look_at)
        z = (at - eye) / np.linalg.norm(at - eye)
        x = np.cross(z, (0.0, 0.0, 1.0))
        if np.linalg.norm(x) < VERTICAL:  # straight down or up: the image's up is the y axis
            x = np.cross(z, (0.0, 1.0, 0.0))
        x = x / np.linalg.norm(x)
        t = np.eye(4)
        t[:3, :3] = np.column_stack((x, np.cross(z, x), z))
        t[:3, 3] = eye
        return t

    @property
    def K(self) -> np.ndarray:  # noqa: N802 (the intrinsics' usual name)
        """The intrinsics (3×3): a pixel's centre at whole coordinates plus a half, so the image's
        centre is (width / 2, height / 2)."""
        f = self.height / 2.0 / math.tan(math.radians(self.fovy_deg) / 2.0)
        return np.array([[f, 0.0, self.width / 2.0], [0.0, f, self.height / 2.0], [0, 0, 1.0]])

    @property
    def frame_ms(self) -> float:
        """What one frame (colour and depth) is expected to cost the camera process."""
        return CAMERA_FRAME_MS + CAMERA_PIXEL_US * self.width * self.height / 1e3


@dataclass(frozen=True)
class Scene:
    """The cell's world, in the file's order; ``belt`` the free object the stand's conveyor
    belt carries (``plant.conveyor_m_s``), if any."""

    source: str
    objects: tuple[SceneObject, ...]
    belt: str | None = None
    clearance_m: float = DEFAULT_CLEARANCE_M
    cameras: tuple[Camera, ...] = ()

    @property
    def free(self) -> tuple[SceneObject, ...]:
        """The objects that move, in order: the plant's free bodies and their truth records."""
        return tuple(o for o in self.objects if not o.fixed)

    @property
    def graspable(self) -> tuple[SceneObject, ...]:
        """The free objects with a grasp, in order: what a gripper can hold."""
        return tuple(o for o in self.free if o.grasps)

    def object(self, name: str) -> SceneObject:
        """The object called ``name``; ConfigError naming the file and its objects."""
        for o in self.objects:
            if o.name == name:
                return o
        known = ", ".join(o.name for o in self.objects) or "none"
        raise ConfigError(f"{self.source}: no object {name!r} in the scene; objects: {known}")

    def camera(self, name: str) -> Camera:
        """The camera called ``name``; ConfigError naming the file and its cameras."""
        for c in self.cameras:
            if c.name == name:
                return c
        known = ", ".join(c.name for c in self.cameras) or "none"
        raise ConfigError(f"{self.source}: no camera {name!r} in the scene; cameras: {known}")

    def grasp_for(self, name: str, robot: RobotConfig) -> np.ndarray:
        """Where ``robot``'s flange holds object ``name``, in the object's frame (4×4): of its
        grasps the one nearest the robot's base as the object lies at rest, turned about the
        object's vertical through the grasp by the robot's ``grasp_yaw_deg`` (for an arm whose
        last joint cannot turn the flange that way: the Panda's joint 7 stops at ±166°)."""
        obj = self.object(name)
        if not obj.grasps:
            raise ConfigError(f"{self.source}: object {name!r} has no grasps: it cannot be held")
        base = np.asarray(robot.base_xyz, dtype=float)
        rest = obj.pose

        def reach(g: Grasp) -> float:
            return float(np.linalg.norm(rest[:3, :3] @ g.xyz + rest[:3, 3] - base))

        nearest = min(obj.grasps, key=reach)
        turned = _quat_mul(_quat_rpy(0.0, 0.0, robot.grasp_yaw_deg), nearest.quat)
        return quaternion_pose(nearest.xyz, turned)


@dataclass(frozen=True)
class Clearance:
    """How far apart two bodies are: ``distance`` (m; negative: how deep they overlap), the
    two shapes nearest each other (``"left/link3"``, ``"table"``) and their nearest points
    (world, m)."""

    distance: float
    near_a: str
    near_b: str
    point_a: np.ndarray
    point_b: np.ndarray

    def within(self, clearance: float) -> str:
        """A refusal's words for this pair within ``clearance`` (m): the two bodies, the
        distance and where."""
        at = "(" + ", ".join(f"{float(v):.3f}" for v in self.point_a) + ") m"
        how = (
            f"would overlap {self.near_b!r} by {-self.distance * 1e3:.1f} mm"
            if self.distance < 0.0
            else f"would come within {self.distance * 1e3:.1f} mm of {self.near_b!r}"
        )
        return f"{self.near_a!r} {how} (clearance {clearance * 1e3:g} mm) at {at}"


def load_scene(path: str | Path) -> Scene:
    """Read and check the scene file at ``path``; ConfigError naming the file, the object,
    the field, the value and the rule."""
    source = str(path)
    try:
        data = Path(path).read_bytes()
    except OSError as exc:
        raise ConfigError(f"{source}: cannot read the scene file: {exc.strerror}") from None
    if len(data) > MAX_SCENE_BYTES:
        raise ConfigError(f"{source}: scene file larger than {MAX_SCENE_BYTES >> 10} KiB")
    try:
        text = data.decode()
    except UnicodeDecodeError as exc:
        raise ConfigError(f"{source}: scene file is not UTF-8 text: {exc.reason}") from None
    return parse_scene(text, source)


def parse_scene(text: str, source: str) -> Scene:
    """The scene in YAML ``text``; ``source`` names it in every message."""
    doc = parse_yaml(text, source)
    if not isinstance(doc, dict):
        raise ConfigError(f"{source}: a scene file is a mapping (version, objects, belt)")
    _known(doc, ("version", "objects", "belt", "clearance_m", "cameras"), source, "the top level")
    if doc.get("version") != SCENE_VERSION:
        raise ConfigError(
            f"{source}: version = {doc.get('version')!r}: this Kali reads scene files of "
            f"version {SCENE_VERSION}"
        )
    objects = _named(doc, "objects", MAX_OBJECTS, _object, source)
    clearance = doc.get("clearance_m", DEFAULT_CLEARANCE_M)
    if isinstance(clearance, bool) or not isinstance(clearance, int | float):
        clearance = -1.0
    if not 0.0 <= clearance <= MAX_CLEARANCE_M:
        raise ConfigError(
            f"{source}: clearance_m = {doc.get('clearance_m')!r}: a distance in metres, 0 .. "
            f"{MAX_CLEARANCE_M:g} (how near a checked motion lets an arm come to another arm "
            "or to an object its links touch)"
        )
    scene = Scene(source, tuple(objects), doc.get("belt"), float(clearance), _cameras(doc, source))
    if scene.belt is not None and (
        not isinstance(scene.belt, str) or scene.object(scene.belt).fixed
    ):
        raise ConfigError(
            f"{source}: belt = {scene.belt!r}: must name a free object the conveyor carries"
        )
    return scene


def _named(
    doc: dict[str, Any], key: str, most: int, read: Callable[[Any, str], Any], source: str
) -> list[Any]:
    """The list at ``key``: at most ``most`` entries, each read by ``read`` (an entry and
    where it is), no name given twice."""
    nodes = doc.get(key, [])
    if not isinstance(nodes, list) or len(nodes) > most:
        raise ConfigError(f"{source}: {key}: must be a list of at most {most} {key}")
    out: list[Any] = []
    for i, node in enumerate(nodes):
        entry = read(node, f"{source}: {key}[{i}]")
        if any(e.name == entry.name for e in out):
            raise ConfigError(f"{source}: {key}[{i}]: name {entry.name!r} given twice")
        out.append(entry)
    return out


def _cameras(doc: dict[str, Any], source: str) -> tuple[Camera, ...]:
    cameras: list[Camera] = _named(doc, "cameras", MAX_CAMERAS, _camera, source)
    share = sum(c.rate_hz * c.frame_ms / 1e3 for c in cameras)
    if share > CAMERA_SHARE:
        each = ", ".join(f"{c.name!r} {c.rate_hz * c.frame_ms / 10:.0f} %" for c in cameras)
        raise ConfigError(
            f"{source}: cameras: would take {share:.0%} of a core ({each}), more than the "
            f"camera process's budget of {CAMERA_SHARE:.0%}: a frame costs about "
            f"{CAMERA_FRAME_MS:g} ms + {CAMERA_PIXEL_US:g} µs a pixel; lower a rate or a "
            "resolution"
        )
    return tuple(cameras)


def _camera(node: Any, where: str) -> Camera:
    if not isinstance(node, dict):
        raise ConfigError(f"{where}: a camera is a mapping ({', '.join(_KEYS['camera'])})")
    name = _name(node, where)
    where = f"{where} ({name!r})"
    _known(node, _KEYS["camera"], where, "a camera")
    xyz = _numbers(node.get("at"), f"{where}: at", 3, "x, y, z in metres")
    look_at = _numbers(node.get("look_at"), f"{where}: look_at", 3, "x, y, z in metres")
    x, y, z = xyz
    if not (abs(x) <= CELL_HALF_M and abs(y) <= CELL_HALF_M and 0.0 < z <= CELL_HEIGHT_M):
        raise ConfigError(
            f"{where}: at = {list(xyz)}: outside the cell (within ±{CELL_HALF_M:g} m of the "
            f"origin in x and y, above the floor and at most {CELL_HEIGHT_M:g} m up)"
        )
    view = np.subtract(look_at, xyz)
    length = float(np.linalg.norm(view))
    if length < 0.01:
        raise ConfigError(f"{where}: look_at = {list(look_at)}: must lie 1 cm from it or more")
    fovy = node.get("fovy_deg", 45.0)
    if isinstance(fovy, bool) or not isinstance(fovy, int | float) or not 5.0 <= fovy <= 150.0:
        raise ConfigError(f"{where}: fovy_deg = {fovy!r}: a vertical field of view, 5 .. 150°")
    lo, hi = CAMERA_PIXELS
    size = []
    for key, default in (("width", 160), ("height", 120)):
        v = node.get(key, default)
        if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
            raise ConfigError(f"{where}: {key} = {v!r}: whole pixels, {lo} .. {hi}")
        size.append(v)
    rate = node.get("rate_hz", 5.0)
    if isinstance(rate, bool) or not isinstance(rate, int | float) or not 0 < rate <= MAX_CAMERA_HZ:
        raise ConfigError(
            f"{where}: rate_hz = {rate!r}: frames a second, > 0 and at most {MAX_CAMERA_HZ:g}"
        )
    return Camera(name, xyz, look_at, float(fovy), size[0], size[1], float(rate))  # type: ignore[arg-type]


def _object(node: Any, where: str) -> SceneObject:
    if not isinstance(node, dict):
        raise ConfigError(f"{where}: an object is a mapping ({', '.join(_KEYS['object'])})")
    name = _name(node, where)
    where = f"{where} ({name!r})"
    _known(node, _KEYS["object"], where, "an object")
    shape = node.get("shape")
    if shape not in SHAPES:
        raise ConfigError(f"{where}: shape = {shape!r}: one of {', '.join(SHAPES)}")
    what = SHAPES[shape]
    size = _numbers(node.get("size"), f"{where}: size", len(what), f"a {shape}'s {', '.join(what)}")
    if not all(0.0 < s <= MAX_EXTENT_M for s in size):
        raise ConfigError(f"{where}: size = {list(size)}: each > 0 and at most {MAX_EXTENT_M:g} m")
    xyz, quat = _pose(node, where)
    fixed = node.get("fixed", False)
    if not isinstance(fixed, bool):
        raise ConfigError(f"{where}: fixed = {fixed!r}: true or false")
    tools_touch = node.get("tools_touch", fixed)
    if not isinstance(tools_touch, bool) or (tools_touch and not fixed):
        raise ConfigError(
            f"{where}: tools_touch = {tools_touch!r}: true or false, for a fixed object (the "
            "tools touch the fixtures; a free object they hold or pass)"
        )
    arms_touch = node.get("arms_touch", True)
    if not isinstance(arms_touch, bool):
        raise ConfigError(f"{where}: arms_touch = {arms_touch!r}: true or false")
    mass = node.get("mass")
    if fixed and mass is not None:
        raise ConfigError(f"{where}: mass = {mass!r}: a fixed object has no mass (it never moves)")
    if not fixed and (isinstance(mass, bool) or not isinstance(mass, int | float) or mass <= 0):
        raise ConfigError(
            f"{where}: mass = {mass!r}: a free object needs a mass > 0 kg (the simulator "
            "cannot move a body without one)"
        )
    friction = node.get("friction", 1.0)
    number = not isinstance(friction, bool) and isinstance(friction, int | float)
    if not number or not 0 <= friction <= 10:
        raise ConfigError(f"{where}: friction = {friction!r}: a sliding friction within 0..10")
    rgba = node.get("color", [0.6, 0.6, 0.6])
    color = _numbers(rgba, f"{where}: color", None, "r, g, b (and a) in 0..1")
    if len(color) not in (3, 4) or not all(0.0 <= c <= 1.0 for c in color):
        raise ConfigError(f"{where}: color = {rgba!r}: r, g, b (and a) in 0..1")
    grasps = node.get("grasps", [])
    if fixed and grasps:
        raise ConfigError(f"{where}: grasps: a fixed object cannot be held")
    if not isinstance(grasps, list) or len(grasps) > MAX_GRASPS:
        raise ConfigError(f"{where}: grasps: must be a list of at most {MAX_GRASPS} grasps")
    held: list[Grasp] = []
    for j, g in enumerate(grasps):
        at = f"{where}: grasps[{j}]"
        if not isinstance(g, dict):
            raise ConfigError(f"{at}: a grasp is a mapping (name, at, rpy_deg)")
        _known(g, _KEYS["grasp"], at, "a grasp")
        gname = _name(g, at)
        if any(h.name == gname for h in held):
            raise ConfigError(f"{at}: name {gname!r} given twice")
        held.append(Grasp(gname, *_pose(g, f"{at} ({gname!r})")))
    return SceneObject(
        name=name,
        shape=shape,
        size=size,
        xyz=xyz,
        quat=quat,
        fixed=fixed,
        mass=0.0 if fixed else float(mass),  # type: ignore[arg-type]  # checked above
        friction=float(friction),
        color=(*color, 1.0) if len(color) == 3 else color,  # type: ignore[arg-type]
        grasps=tuple(held),
        tools_touch=tools_touch,
        arms_touch=arms_touch,
    )


def _known(node: dict[str, Any], keys: Sequence[str], where: str, what: str) -> None:
    for key in node:
        if key not in keys:
            raise ConfigError(f"{where}: {key!r} is not a key of {what}; keys: {', '.join(keys)}")


def _name(node: dict[str, Any], where: str) -> str:
    name = node.get("name")
    if not isinstance(name, str) or not _NAME.match(name):
        raise ConfigError(f"{where}: name = {name!r}: required, matching {_NAME.pattern}")
    return name


def _numbers(node: Any, where: str, count: int | None, what: str) -> tuple[float, ...]:
    ok = isinstance(node, list) and (count is None or len(node) == count)
    if ok:
        ok = all(not isinstance(v, bool) and isinstance(v, int | float) for v in node)
    if not ok or not all(math.isfinite(v) for v in node):
        raise ConfigError(f"{where} = {node!r}: a list of {count or 'the'} finite numbers: {what}")
    return tuple(float(v) for v in node)


def _pose(node: dict[str, Any], where: str) -> tuple[Any, Any]:
    """``at`` (m) and ``rpy_deg`` (fixed axes x, y, z; default 0) as xyz and a quaternion."""
    xyz = _numbers(node.get("at"), f"{where}: at", 3, "x, y, z in metres")
    if any(abs(v) > MAX_EXTENT_M for v in xyz):
        raise ConfigError(f"{where}: at = {list(xyz)}: within ±{MAX_EXTENT_M:g} m of the origin")
    rpy = _numbers(node.get("rpy_deg", [0, 0, 0]), f"{where}: rpy_deg", 3, "roll, pitch, yaw")
    return xyz, _quat_rpy(*rpy)


def _cos_sin(deg: float) -> tuple[float, float]:
    """cos and sin of ``deg``, exact at whole quarter turns (a half turn's cos is 0, not
    6e-17: a grasp written as 180° is the exact half turn)."""
    quarters = deg / 90.0
    if quarters == round(quarters):
        return ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))[round(quarters) % 4]
    rad = math.radians(deg)
    return math.cos(rad), math.sin(rad)


def _quat_rpy(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """The quaternion (w, x, y, z) of turning ``roll`` about x, then ``pitch`` about y, then
    ``yaw`` about z, all fixed axes (degrees): qz·qy·qx."""
    (cr, sr), (cp, sp), (cy, sy) = (_cos_sin(a / 2.0) for a in (roll, pitch, yaw))
    return (
        cy * cp * cr + sy * sp * sr,
        cy * cp * sr - sy * sp * cr,
        cy * sp * cr + sy * cp * sr,
        sy * cp * cr - cy * sp * sr,
    )


def _quat_mul(a: Sequence[float], b: Sequence[float]) -> tuple[float, float, float, float]:
    aw, ax, ay, az = a
    bw, bx, by, bz = b
    return (
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    )


def quaternion_pose(xyz: Sequence[float], quat: Sequence[float]) -> np.ndarray:
    """A 4×4 pose at ``xyz`` turned by the unit quaternion ``quat`` (w, x, y, z), as MuJoCo
    and the scene files give them."""
    w, x, y, z = quat
    t = np.eye(4)
    t[:3, :3] = [
        [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
        [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
        [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
    ]
    t[:3, 3] = xyz
    return t
