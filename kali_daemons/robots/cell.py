"""The tools' dimensions and the controller's arm model, without MuJoCo (see ``model.py``).

The world the arms stand in is the scene's (``scene.py``).  ``load_pinocchio`` is the arm
model of the dynamics process, the viewer and programs; ``check_clear_at_rest`` is ``kalictl
start``'s check that no two arms of a config stand in each other.  Pinocchio is imported where
a model is loaded, so the plant, which needs these dimensions, does not import it."""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from kali_daemons.core.errors import ConfigError, ModelError

if TYPE_CHECKING:
    import pinocchio as pin

    from kali_daemons.robots import RobotType
    from kali_daemons.robots.scene import Scene, SceneObject
    from kali_daemons.runtime.config import KaliConfig, RobotConfig

FLANGE_FRAME: Final = "flange"  # the URDF link of the flange (Pinocchio frame, MuJoCo body)

WORLD_OVERLAP_M: Final = 0.001  # an arm's link may start this deep in the scene's objects
TOOL_RADIUS_M: Final = 0.012  # each arm's tool: a pad, a sphere ending at the tool point
# The pad is a felt polishing pad, not steel: sliding friction 0.3 on the table, and soft
# (MuJoCo's contact time constant, s, and damping ratio: critically damped), softest at the
# first touch and stiffening as it is pressed (MuJoCo's impedance, from 0.3 at the surface to
# 0.95 two millimetres in), as felt is.  A rigid sphere on the rigid table chattered (lifting
# off 30 % of the time at 90 Hz, 0-37 N) whenever a soft impedance slid it, whatever the
# gains; a pad as stiff at the first touch as pressed let a 2 N press lift off.
PAD_FRICTION: Final = 0.3
PAD_SOLREF: Final = (0.05, 1.0)
PAD_SOLIMP: Final = (0.3, 0.95, 0.002, 0.5, 1.0)


def load_pinocchio(
    robot: RobotType,
    tool: tuple[float, tuple[float, float, float]] | None = None,
    gravity: bool = True,
) -> pin.Model:
    """An arm of type ``robot`` as a Pinocchio model, base at the origin, with its armature
    and gravity; with ``tool`` (mass in kg, centre of mass in the flange frame: the config's
    ``FtConfig``) the tool the plant's arm carries on its wrist sensor, so the dynamics
    process's feed-forward holds its weight too.

    ``rnea`` / ``crba`` / ``aba`` on it include the drive's rotor inertia.  The flange is the
    frame named ``FLANGE_FRAME``.  ``gravity`` False: the arm's hardware holds it against
    gravity itself (an FR3), so the model's gravity is zero and nothing Kali computes from it
    adds gravity a second time.
    """
    import pinocchio as pin  # here, not at load: the plant imports this module

    urdf = robot.urdf
    if not Path(urdf).is_file():
        raise ModelError(f"{urdf}: no such file")
    try:
        model = pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as exc:
        raise ModelError(f"{urdf}: Pinocchio cannot load it: {exc}") from None
    if model.nv != robot.n_joints or not model.existFrame(FLANGE_FRAME):
        raise ModelError(
            f"{urdf}: robot type {robot.name!r} expects {robot.n_joints} joints and a "
            f"{FLANGE_FRAME!r} frame, found {model.nv} joints"
        )
    model.armature = np.array(robot.drive.armature, dtype=float)
    if tool is not None and tool[0] > 0.0:
        mass, com = tool
        frame = model.frames[model.getFrameId(FLANGE_FRAME)]
        inertia = mass * TOOL_RADIUS_M**2 / 2.0  # as the plant's tool (model._add_tool)
        body = pin.Inertia(mass, np.asarray(com, dtype=float), np.eye(3) * inertia)
        model.appendBodyToJoint(frame.parentJoint, body, frame.placement)
    g = robot.gravity if gravity else 0.0
    model.gravity = pin.Motion(np.array([0.0, 0.0, -g]), np.zeros(3))
    return model


def check_clear_at_rest(cfg: KaliConfig) -> None:
    """Refuse (ConfigError) a cell in which two arms' bodies overlap where they start, or an
    arm's moving links overlap the scene's objects: each arm's collision shapes from its URDF
    (what Pinocchio and coal load, the shapes the plant simulates), at its type's ``q_home``
    (where the simulated arm starts), placed at its base.  The message names both arms (or
    the arm and the object), the two links nearest each other and their distance (negative:
    how deep they interpenetrate).  Before any process runs: an arm started inside another
    or in a fixture halts the cell at its first tick with a contact force no sensor takes.
    Between arms touching counts as overlapping; against the world an overlap within
    ``WORLD_OVERLAP_M`` is allowed (a link resting on what it stands beside)."""
    import pinocchio as pin  # here, not at load: the plant imports this module

    world = pin.GeometryModel()
    owner: list[tuple[int, str, bool]] = []  # per shape: its robot, its link, whether it moves
    for k, robot in enumerate(cfg.robots):
        for placement, link, shape, moves in _shapes_at_rest(robot, cfg.source):
            world.addGeometryObject(pin.GeometryObject(f"{k}.{len(owner)}", 0, 0, placement, shape))
            owner.append((k, link, moves))
    arms = len(owner)
    for o in (o for o in cfg.scene.objects if o.arms_touch):  # the world the arms touch
        world.addGeometryObject(pin.GeometryObject(o.name, 0, 0, pin.SE3(o.pose), coal_shape(o)))
        owner.append((-1, o.name, not o.fixed))
    for i in range(arms):
        for j in range(i + 1, len(owner)):
            # arm against arm; a moving link against the world (a base stands on it)
            if owner[i][0] != owner[j][0] and (j < arms or owner[i][2]):
                world.addCollisionPair(pin.CollisionPair(i, j))
    if not world.collisionPairs:
        return
    data = pin.GeometryData(world)
    fixed = pin.Model()  # every shape hangs from the world at its place
    pin.computeDistances(fixed, fixed.createData(), world, data, np.zeros(0))
    pairs = world.collisionPairs
    overlaps = [  # arms must be apart; the world may be touched, within a tolerance
        (r.min_distance, i)
        for i, (r, p) in enumerate(zip(data.distanceResults, pairs, strict=True))
        if (r.min_distance <= 0.0 if p.second < arms else r.min_distance < -WORLD_OVERLAP_M)
    ]
    if not overlaps:
        return
    deepest, nearest = min(overlaps)
    pair = pairs[nearest]
    (a, link_a, _), (b, link_b, _) = owner[pair.first], owner[pair.second]
    ra = cfg.robots[a]
    if b < 0:
        raise ConfigError(
            f"{cfg.source}: robot '{ra.name}' ({ra.type.name}) starts in the scene's object "
            f"'{link_b}' ({cfg.scene.source}): its link '{link_a}' is {deepest:.3f} "
            f"m from it (negative: inside), at its starting joint angles (q_home) and base "
            f"{list(ra.base_xyz)} turned {ra.base_yaw_deg:g}°; move the base or the object"
        )
    rb = cfg.robots[b]
    raise ConfigError(
        f"{cfg.source}: robots '{ra.name}' ({ra.type.name}) and '{rb.name}' ({rb.type.name}) "
        f"overlap at rest: link '{link_a}' of '{ra.name}' and link '{link_b}' of '{rb.name}' "
        f"are {deepest:.3f} m apart (negative: one inside the other), at their "
        f"starting joint angles (q_home) and bases {list(ra.base_xyz)} turned "
        f"{ra.base_yaw_deg:g}° and {list(rb.base_xyz)} turned {rb.base_yaw_deg:g}°; their "
        f"bodies must be apart: move a base (base_xyz, base_yaw_deg)"
    )


def check_scene_apart(scene: Scene) -> None:
    """Refuse (ConfigError) a scene in which two fixed objects overlap: the simulator would
    push nothing apart (neither moves) but every free object and tool between them would be
    caught, and the controller's collision model would hold a world that cannot be.  The
    message names the file, both objects and how deep they interpenetrate.  Touching is
    allowed (a stand on a plinth)."""
    import pinocchio as pin  # here, not at load: the plant imports this module

    fixed = [o for o in scene.objects if o.fixed]
    world = pin.GeometryModel()
    for o in fixed:
        world.addGeometryObject(pin.GeometryObject(o.name, 0, 0, pin.SE3(o.pose), coal_shape(o)))
    for i in range(len(fixed)):
        for j in range(i + 1, len(fixed)):
            world.addCollisionPair(pin.CollisionPair(i, j))
    if not world.collisionPairs:
        return
    data = pin.GeometryData(world)
    still = pin.Model()
    pin.computeDistances(still, still.createData(), world, data, np.zeros(0))
    distance = [r.min_distance for r in data.distanceResults]
    nearest = int(np.argmin(distance))
    if distance[nearest] >= -1e-9:
        return
    pair = world.collisionPairs[nearest]
    a, b = fixed[pair.first].name, fixed[pair.second].name
    raise ConfigError(
        f"{scene.source}: fixed objects {a!r} and {b!r} overlap by {-distance[nearest]:.4f} m; "
        "fixed objects must be apart or touch (move one: its 'at' or 'size')"
    )


def coal_shape(obj: SceneObject) -> object:
    """A scene object's shape as coal's (the controller's collision model), about its centre;
    the same sizes MuJoCo builds (``model._MJ_SHAPE``)."""
    import coal  # with Pinocchio: only where a collision model is built

    s = obj.size
    if obj.shape == "box":
        return coal.Box(*s)
    if obj.shape == "cylinder":
        return coal.Cylinder(s[0], s[1])
    if obj.shape == "capsule":
        return coal.Capsule(s[0], s[1])
    return coal.Sphere(s[0])


def _shapes_at_rest(robot: RobotConfig, source: str) -> list[tuple[pin.SE3, str, object, bool]]:
    """Robot ``robot``'s collision shapes (URDF ``<collision>``) at its type's ``q_home``, in
    the world: (placement, link, coal geometry, whether a joint moves it) each; ConfigError if
    they cannot be loaded."""
    import pinocchio as pin  # here, not at load: the plant imports this module

    urdf = str(robot.type.urdf)
    try:
        model = pin.buildModelFromUrdf(urdf)
        shapes = pin.buildGeomFromUrdf(model, urdf, pin.COLLISION)
    except (RuntimeError, ValueError) as exc:
        raise ConfigError(
            f"{source}: robot '{robot.name}': the collision shapes of {urdf} do not load in "
            f"Pinocchio: {exc}"
        ) from None
    data, shape_data = model.createData(), shapes.createData()
    pin.updateGeometryPlacements(model, data, shapes, shape_data, np.asarray(robot.type.q_home))
    yaw = np.radians(robot.base_yaw_deg)
    base = pin.SE3(pin.utils.rotate("z", yaw), np.asarray(robot.base_xyz, dtype=float))
    return [
        (base * shape_data.oMg[i], model.frames[g.parentFrame].name, g.geometry, g.parentJoint > 0)
        for i, g in enumerate(shapes.geometryObjects)
    ]


def base_transform(xyz: Sequence[float], yaw_deg: float) -> np.ndarray:
    """The 4×4 pose of a robot's base in the world: at ``xyz`` (m), turned ``yaw_deg`` about z."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    t = np.eye(4)
    t[:2, :2] = ((c, -s), (s, c))
    t[:3, 3] = xyz
    return t


def inverse(t: np.ndarray) -> np.ndarray:
    """The inverse of a rigid 4×4 transform (Rᵀ, −Rᵀp)."""
    out = np.eye(4)
    out[:3, :3] = t[:3, :3].T
    out[:3, 3] = -t[:3, :3].T @ t[:3, 3]
    return out
