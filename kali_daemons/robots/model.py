"""Arm models, loaded from each robot type's one URDF by both sides (DESIGN.md section 6).

``load_pinocchio`` gives the controller an arm model; ``build_world`` gives the plant a MuJoCo
cell of one or more arms, each from its robot type's URDF (``kali_daemons.robots``), plus a
stand and a bar the arms can carry together.  Neither loader reads rotor inertia from URDF,
so both set the drive's armature here; that, the motors and the world's layout are the only
things added on top of the file.  Everything runs outside the cycle (it allocates and reads
files).  The cell's dimensions and ``load_pinocchio`` live in ``cell.py``, without MuJoCo
(re-exported here), so the dynamics process and the viewer do not import MuJoCo, nor the
plant Pinocchio.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import mujoco
import numpy as np
import numpy.typing as npt

from kali_daemons.core import layout
from kali_daemons.core.errors import ModelError
from kali_daemons.robots import RobotType
from kali_daemons.robots.cell import (
    FLANGE_FRAME,
    PAD_FRICTION,
    PAD_SOLIMP,
    PAD_SOLREF,
    TOOL_RADIUS_M,
    load_pinocchio,
)
from kali_daemons.robots.scene import (
    CELL_HALF_M,
    DEFAULT_SCENE,
    Camera,
    Scene,
    SceneObject,
    load_scene,
)

if TYPE_CHECKING:
    from kali_daemons.runtime.config import RobotConfig

IntArray = npt.NDArray[np.int64]

# The weld's time constant in timesteps.  MuJoCo's default 0.02 s lets the held bar sag 3.8 mm
# at the grasp pose; 8 steps (4 ms at 0.5 ms) gives 0.17 mm and stays 4x above the 2-step
# floor below which MuJoCo's 'refsafe' would clamp it.
WELD_TIMECONST_STEPS: Final = 8
# Contact bits (MuJoCo's contype / conaffinity: two geoms touch if either's type meets the
# other's affinity).  The floor and the fixtures the arms touch are bit 1 (WORLD_CONTACT), those
# they pass through (``arms_touch: false``) PASSED_CONTACT; the tools' pads and the fixtures
# they touch bit 2; arm k's collision shapes ARM_CONTACT << k, touching the world and the
# other arms, never their own; the free objects OBJECT_CONTACT, touching the fixtures, the
# floor, each other and (unless ``arms_touch: false``) every arm (an arm holding one stops
# touching it: ``World.activate_weld``).
WORLD_CONTACT: Final = 1
TOOL_CONTACT: Final = 2
ARM_CONTACT: Final = 4
ARMS_CONTACT: Final = sum(ARM_CONTACT << k for k in range(layout.MAX_ROBOTS))
OBJECT_CONTACT: Final = ARM_CONTACT << layout.MAX_ROBOTS
PASSED_CONTACT: Final = OBJECT_CONTACT << 1
# MuJoCo's geom size from a scene shape's (robots.scene.SHAPES): half lengths
_MJ_SHAPE = {
    "box": (mujoco.mjtGeom.mjGEOM_BOX, lambda s: [s[0] / 2, s[1] / 2, s[2] / 2]),
    "cylinder": (mujoco.mjtGeom.mjGEOM_CYLINDER, lambda s: [s[0], s[1] / 2, 0.0]),
    "capsule": (mujoco.mjtGeom.mjGEOM_CAPSULE, lambda s: [s[0], s[1] / 2, 0.0]),
    "sphere": (mujoco.mjtGeom.mjGEOM_SPHERE, lambda s: [s[0], 0.0, 0.0]),
}


@dataclass(frozen=True)
class World:
    """A compiled MuJoCo cell and the indices the plant needs, per robot in config order and
    per free object of the scene in the scene's order.

    Every per-robot field is a tuple indexed like ``robots`` (``index(name)`` maps a name).

    The arms carry no joint damping or friction loss and no actuators: the plant's motor model
    applies motor torque, viscous and asymmetric Coulomb friction and the brakes through
    ``data.qfrc_applied[dof_adr[k]]``.  Each arm's collision shapes (its URDF's
    ``<collision>``, the shapes the controller's collision model loads) touch the other arms,
    the fixtures, the floor and the free objects, never the same arm; its visual shapes touch
    nothing.  The free objects touch the fixtures, the floor and each other, the tools' pads
    only the fixtures (``TOOL_CONTACT``).  The free objects are the world's first bodies:
    their free joints' qpos are ``qpos[0 : 7 * len(objects)]``, object by object.

    Grasping.  ``weld[k][g]`` is a MuJoCo weld equality between robot ``k``'s ``tool`` body
    (body1; it sits at the flange frame, on the wrist force/torque sensor, so the sensor feels
    the object) and graspable object ``g`` (body2; ``graspable[g]`` its index in
    ``objects``), inactive at start; the equalities are these welds only, arm by arm
    (``k * len(graspable) + g``).  A weld's ``eq_data`` row (MuJoCo 4) is
    ``[anchor(3), relpos(3), relquat(4), torquescale, from_qpos0]``: with anchor 0 the weld
    holds the object's origin at ``relpos`` and its orientation at ``relquat`` in the flange
    frame; ``from_qpos0 = 1`` would let ``mj_setConst`` overwrite relpose, so it stays 0.  To
    grasp without a jump the plant writes the *current* relative pose and then activates:
    after ``mj_kinematics`` (or a step), ``relpos = R1ᵀ(x2 - x1)``, ``relquat = q1⁻¹·q2``
    from ``data.xpos``/``data.xquat``, ``model.eq_data[weld, 3:10] = relpos, relquat``, then
    ``data.eq_active[weld] = 1``; the method ``activate_weld`` does exactly this.  Releasing is
    ``data.eq_active[weld] = 0``.  ``grasp_site`` are every graspable object's grasps as
    sites (``grasp_object`` the object of each), where a closing gripper looks for one within
    reach.
    """

    model: mujoco.MjModel
    robots: tuple[str, ...]  # names, in config order
    qpos_adr: tuple[IntArray, ...]  # per robot: qpos indices of its joints j1..jn (n_joints)
    dof_adr: tuple[IntArray, ...]  # per robot: dof indices (qvel, qacc, qfrc_*) of j1..jn
    flange_site: tuple[int, ...]  # per robot: site at the flange frame (the last DH frame)
    weld: tuple[tuple[int, ...], ...]  # per robot, per graspable object: its weld, inactive
    objects: tuple[str, ...] = ()  # the free objects, in the scene's order
    object_body: tuple[int, ...] = ()  # per free object
    object_qpos_adr: tuple[int, ...] = ()  # per free object: its 7 qpos (position, quaternion)
    object_dof_adr: tuple[int, ...] = ()  # per free object: its 6 dofs
    object_geom: tuple[int, ...] = ()  # per free object: its shape
    object_affinity: tuple[int, ...] = ()  # per free object: its shape's, as built
    graspable: tuple[int, ...] = ()  # the objects with grasps (indices into objects)
    grasp_site: tuple[int, ...] = ()  # every grasp of a graspable object, as a site
    grasp_object: tuple[int, ...] = ()  # per grasp site: its object (index into objects)
    motor: tuple[IntArray, ...] = ()  # per robot: its n_joints motor actuator ids, j1..jn
    motor_act_adr: tuple[IntArray, ...] = ()  # per robot: their activations (currents) in data.act
    tool_body: tuple[int, ...] = ()  # per robot: its tool, on the flange through the F/T sensor
    # per robot: sensordata address of its F/T sensor's force (3) then torque (3), -1 if none
    ft_adr: tuple[int, ...] = ()

    def index(self, robot: int | str) -> int:
        """The position of ``robot`` (a name, or already an index) in ``robots``."""
        if isinstance(robot, str):
            if robot not in self.robots:
                raise ModelError(f"world: no robot {robot!r}; robots: {', '.join(self.robots)}")
            return self.robots.index(robot)
        if not 0 <= robot < len(self.robots):
            raise ModelError(f"world: robot index {robot} out of range 0..{len(self.robots) - 1}")
        return robot

    def object_index(self, name: str) -> int:
        """The position of free object ``name`` in ``objects``."""
        if name not in self.objects:
            known = ", ".join(self.objects) or "none"
            raise ModelError(f"world: no free object {name!r}; free objects: {known}")
        return self.objects.index(name)

    def activate_weld(self, data: mujoco.MjData, robot: int | str, obj: int | str) -> None:
        """Grasp: hold object ``obj`` (a name or an index into ``objects``) where it is now
        relative to ``robot``'s flange, then activate; the object stops touching that arm's
        links (its flange rests on it).

        Uses ``data.xpos``/``data.xquat``, so call it after ``mj_kinematics`` (or any step).
        Writes ``model.eq_data`` of that weld: anchor 0, relpose = the object's pose in the
        flange frame, torquescale 1, from_qpos0 0.  Outside the cycle: it allocates.
        """
        o = self.object_index(obj) if isinstance(obj, str) else obj
        if o not in self.graspable:
            raise ModelError(f"world: object {self.objects[o]!r} has no grasps: it cannot be held")
        model = self.model
        eq = self.weld[self.index(robot)][self.graspable.index(o)]
        b1, b2 = model.eq_obj1id[eq], model.eq_obj2id[eq]
        q1inv = np.empty(4)
        mujoco.mju_negQuat(q1inv, data.xquat[b1])
        relpos = np.empty(3)
        mujoco.mju_rotVecQuat(relpos, data.xpos[b2] - data.xpos[b1], q1inv)
        relquat = np.empty(4)
        mujoco.mju_mulQuat(relquat, q1inv, data.xquat[b2])
        model.eq_data[eq, 0:3] = 0.0
        model.eq_data[eq, 3:6] = relpos
        model.eq_data[eq, 6:10] = relquat
        model.eq_data[eq, 10] = 1.0
        model.eq_data[eq, 11] = 0.0
        data.eq_active[eq] = 1
        self.model.geom_conaffinity[self.object_geom[o]] &= ~(ARM_CONTACT << self.index(robot))

    def release(self, data: mujoco.MjData, robot: int | str) -> None:
        """Let go: ``robot``'s welds off, and the objects touch it again."""
        k = self.index(robot)
        for eq in self.weld[k]:
            data.eq_active[eq] = 0
        own = ARM_CONTACT << k
        for g, affinity in zip(self.object_geom, self.object_affinity, strict=True):
            self.model.geom_conaffinity[g] |= affinity & own


def build_world(
    robots: Sequence[RobotConfig], timestep: float = 0.0005, scene: Scene | None = None
) -> World:
    """The plant's MuJoCo cell: each robot's type's URDF attached once per robot, in the world
    of ``scene`` (None: the shipped cell's, ``scene.DEFAULT_SCENE``).

    Each arm is its type's URDF loaded with ``MjSpec.from_file`` and attached under the name
    prefix ``"<robot>/"`` at its ``base_xyz``, turned ``base_yaw_deg`` about z; every arm dof
    gets its drive's armature.  Arms may differ in joint count: every per-robot index of the
    ``World`` has that robot type's ``n_joints`` entries.  Integrator: ``implicitfast``.  The
    plant's friction torques are explicit (``qfrc_applied``), which is stable here with a wide
    margin: the stiffest ratio of viscous friction to joint inertia (the PUMA's joint 1,
    5.8 N·m·s / 0.78 kg·m²) gives dt·b/I ≈ 0.004 at 0.5 ms against the explicit bound of 2.
    ``implicitfast`` costs no more than Euler with no damping in the model, and keeps any
    damping or actuator added later implicit.
    """
    if not robots:
        raise ModelError("build_world: no robots; the cell needs at least one arm")
    if not (0.0 < timestep <= 0.01):
        raise ModelError(f"build_world: timestep = {timestep} s: must be > 0 and <= 0.01")
    names = tuple(r.name for r in robots)
    if len(set(names)) != len(names):
        raise ModelError(f"build_world: robot names must be unique, got {list(names)}")
    types = [r.type for r in robots]
    if len({t.gravity for t in types}) != 1:
        raise ModelError(f"build_world: robot types disagree on gravity: {types}")

    spec = mujoco.MjSpec()
    spec.modelname = "kali_cell"
    spec.option.timestep = timestep
    spec.option.gravity = [0.0, 0.0, -types[0].gravity]
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    # friction as a cone, not MuJoCo's faster pyramid: a pad sliding on the table under a
    # soft impedance chattered (lifting off 7 % of the time) with the pyramid's edges
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    scene = scene or load_scene(DEFAULT_SCENE)
    _add_scenery(spec, scene)
    for k, (r, t) in enumerate(zip(robots, types, strict=True)):
        _attach_arm(spec, r, t, k)
        _add_tool(spec, r)
        _add_motors(spec, r.name, t)
    for r in robots:  # after every arm's tool: weld k * graspable + g
        for obj in scene.graspable:
            _add_weld(spec, r.name, obj.name, WELD_TIMECONST_STEPS * timestep)

    try:
        model = spec.compile()
    except ValueError as exc:
        urdfs = ", ".join(sorted({str(t.urdf) for t in types}))
        raise ModelError(f"{urdfs}: MuJoCo cannot build the cell: {exc}") from None
    joints = {r.name: t.n_joints for r, t in zip(robots, types, strict=True)}

    def jid(robot: str, j: int) -> int:
        return mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, f"{robot}/j{j + 1}")

    def oid(kind: mujoco.mjtObj, name: str) -> int:
        return mujoco.mj_name2id(model, kind, name)

    def adr(table: np.ndarray, robot: str) -> IntArray:
        out = np.array([table[jid(robot, j)] for j in range(joints[robot])], dtype=np.int64)
        out.setflags(write=False)
        return out

    def motors(robot: str, table: np.ndarray | None = None) -> IntArray:
        ids = [
            oid(mujoco.mjtObj.mjOBJ_ACTUATOR, f"{robot}/motor{j + 1}") for j in range(joints[robot])
        ]
        out = np.array(ids if table is None else [table[i] for i in ids], dtype=np.int64)
        out.setflags(write=False)
        return out

    def ft_address(robot: str) -> int:
        sid = oid(mujoco.mjtObj.mjOBJ_SENSOR, f"{robot}/ft_force")
        return -1 if sid < 0 else int(model.sensor_adr[sid])

    free = [o.name for o in scene.free]
    bodies = [oid(mujoco.mjtObj.mjOBJ_BODY, o) for o in free]
    graspable = tuple(free.index(o.name) for o in scene.graspable)
    sites = [(oid(mujoco.mjtObj.mjOBJ_SITE, f"{o.name}/grasp/{g.name}"), free.index(o.name))
             for o in scene.graspable for g in o.grasps]  # fmt: skip
    qpos = tuple(int(model.jnt_qposadr[model.body_jntadr[b]]) for b in bodies)
    assert qpos == tuple(range(0, 7 * len(free), 7)), "the free objects' qpos lead, in order"
    return World(
        model=model,
        robots=names,
        qpos_adr=tuple(adr(model.jnt_qposadr, n) for n in names),
        dof_adr=tuple(adr(model.jnt_dofadr, n) for n in names),
        flange_site=tuple(oid(mujoco.mjtObj.mjOBJ_SITE, f"{n}/flange") for n in names),
        weld=tuple(
            tuple(oid(mujoco.mjtObj.mjOBJ_EQUALITY, f"{n}/grasp/{o.name}") for o in scene.graspable)
            for n in names
        ),
        objects=tuple(free),
        object_body=tuple(bodies),
        object_qpos_adr=qpos,
        object_dof_adr=tuple(int(model.jnt_dofadr[model.body_jntadr[b]]) for b in bodies),
        object_geom=tuple(oid(mujoco.mjtObj.mjOBJ_GEOM, o) for o in free),
        object_affinity=tuple(
            int(model.geom_conaffinity[oid(mujoco.mjtObj.mjOBJ_GEOM, o)]) for o in free
        ),
        graspable=graspable,
        grasp_site=tuple(site for site, _ in sites),
        grasp_object=tuple(o for _, o in sites),
        motor=tuple(motors(n) for n in names),
        motor_act_adr=tuple(motors(n, model.actuator_actadr) for n in names),
        tool_body=tuple(oid(mujoco.mjtObj.mjOBJ_BODY, f"{n}/tool") for n in names),
        ft_adr=tuple(ft_address(n) for n in names),
    )


# --------------------------------------------------------------------------------------------
# World pieces


def _yaw_quat(yaw_deg: float) -> list[float]:
    half = math.radians(yaw_deg) / 2.0
    return [math.cos(half), 0.0, 0.0, math.sin(half)]


def _add_scenery(spec: mujoco.MjSpec, scene: Scene) -> None:
    """Floor, light and the scene's objects, in its order, each a body of the world: a fixed
    one colliding with the free ones (and the tools' pads unless they pass through it), a free
    one on a free joint with its mass spread over its shape and a site at each of its
    grasps."""
    world = spec.worldbody
    world.add_light(name="sun", pos=[0.0, -1.0, 3.0], dir=[0.0, 0.3, -1.0])
    world.add_geom(
        name="floor",
        type=mujoco.mjtGeom.mjGEOM_PLANE,
        size=[CELL_HALF_M, CELL_HALF_M, 0.05],
        rgba=[0.55, 0.57, 0.6, 1.0],
    )
    for cam in scene.cameras:
        _add_camera(spec, cam)
    for obj in scene.objects:
        if obj.fixed:
            _add_geom(world, obj, pos=list(obj.xyz), quat=list(obj.quat))
            continue
        body = world.add_body(name=obj.name, pos=list(obj.xyz), quat=list(obj.quat))
        body.add_freejoint(name=obj.name)
        _add_geom(body, obj)
        for g in obj.grasps:
            body.add_site(
                name=f"{obj.name}/grasp/{g.name}",
                pos=list(g.xyz),
                quat=list(g.quat),
                size=[0.01, 0.01, 0.01],
                rgba=[0.1, 0.8, 0.2, 0.6],
            )


def _add_camera(spec: mujoco.MjSpec, cam: Camera) -> None:
    """Camera ``cam`` fixed in the world as ``camera/<name>``, its offscreen buffer large
    enough.  MuJoCo's camera looks along its -z with y up: the scene's pose (x right, y down,
    z along the view) turned a half turn about x."""
    rotation = cam.pose[:3, :3] * [1.0, -1.0, -1.0]
    quat = np.empty(4)
    mujoco.mju_mat2Quat(quat, rotation.flatten())
    spec.worldbody.add_camera(
        name=f"camera/{cam.name}", pos=list(cam.xyz), quat=list(quat), fovy=cam.fovy_deg
    )
    glob = spec.visual.global_
    glob.offwidth, glob.offheight = max(glob.offwidth, cam.width), max(glob.offheight, cam.height)


def _add_geom(parent: mujoco.MjsBody, obj: SceneObject, **placed: list[float]) -> None:
    """Object ``obj``'s shape on ``parent`` (the world for a fixed one, at its pose)."""
    kind, size = _MJ_SHAPE[obj.shape]
    if obj.fixed:
        kind_bits = WORLD_CONTACT if obj.arms_touch else PASSED_CONTACT
        kind_bits = affinity = kind_bits | (TOOL_CONTACT if obj.tools_touch else 0)
    else:
        kind_bits = OBJECT_CONTACT
        affinity = WORLD_CONTACT | PASSED_CONTACT | OBJECT_CONTACT
        affinity |= ARMS_CONTACT if obj.arms_touch else 0
    parent.add_geom(
        name=obj.name,
        type=kind,
        size=size(obj.size),
        contype=kind_bits,
        conaffinity=affinity,
        friction=[obj.friction, 0.005, 0.0001],
        rgba=list(obj.color),
        **({"mass": obj.mass} if not obj.fixed else {}),
        **placed,
    )


def _attach_arm(spec: mujoco.MjSpec, robot: RobotConfig, rtype: RobotType, k: int) -> None:
    """Attach the type's URDF arm at the robot's base; set armature; its collision shapes
    touch the world, the free objects and the other arms (arm ``k``'s bit), its visuals
    nothing.

    The file must have exactly the type's ``n_joints`` moving joints, named ``j1``..``jn``.
    """
    urdf = rtype.urdf
    if not Path(urdf).is_file():
        raise ModelError(f"{urdf}: no such file")
    try:
        arm = mujoco.MjSpec.from_file(str(urdf))
    except ValueError as exc:
        raise ModelError(f"{urdf}: MuJoCo cannot load it: {exc}") from None
    found = [j.name for j in arm.joints]
    if len(found) != rtype.n_joints:  # one more would move unactuated, one fewer unmodelled
        raise ModelError(
            f"{urdf}: robot type {rtype.name!r} expects {rtype.n_joints} moving joints, "
            f"the file has {len(found)}: {', '.join(found)}"
        )
    frame = spec.worldbody.add_frame(pos=list(robot.base_xyz), quat=_yaw_quat(robot.base_yaw_deg))
    prefix = f"{robot.name}/"
    spec.attach(arm, prefix=prefix, frame=frame)
    armature = rtype.drive.armature
    for j in range(rtype.n_joints):
        joint = spec.joint(f"{prefix}j{j + 1}")
        if joint is None:
            raise ModelError(f"{urdf}: no joint 'j{j + 1}'")
        joint.armature = float(armature[j])
        joint.damping = np.zeros(3)  # MuJoCo 4: damping polynomial coefficients
        joint.frictionloss = 0.0
    own = ARM_CONTACT << k
    for geom in spec.geoms:
        if geom.name.startswith(prefix):
            geom.contype = 0
            geom.conaffinity = 0
            if geom.group == 0:  # the URDF <collision> copies: hide under the coloured visuals
                geom.group = 3
                geom.contype = own
                geom.conaffinity = WORLD_CONTACT | (ARMS_CONTACT & ~own)
    # the first moving link turns in place on the base, whose mount it may dip below (the
    # UR5's shoulder housing does, by 6.5 cm): it touches nothing of the world
    for body in spec.bodies:
        if body.name.startswith(prefix) and any(j.name == f"{prefix}j1" for j in body.joints):
            exclude = spec.add_exclude()
            exclude.bodyname1, exclude.bodyname2 = "world", body.name
    flange = spec.body(f"{prefix}{FLANGE_FRAME}")
    if flange is None:
        raise ModelError(f"{urdf}: no {FLANGE_FRAME!r} link")
    flange.add_site(name=f"{prefix}flange", size=[0.008, 0.008, 0.008], rgba=[0.9, 0.1, 0.1, 1])


def _add_tool(spec: mujoco.MjSpec, robot: RobotConfig) -> None:
    """The robot's tool on its flange, through a wrist force/torque sensor.

    A child body ``<robot>/tool`` at the flange frame with the config's tool mass and centre
    of mass (``FtConfig``), a round pad whose tip is the tool point (``tool_tip_m`` out along
    z) and that touches only the fixtures (``TOOL_CONTACT``: not the bar it holds by the weld,
    not the floor), and the site ``<robot>/ft`` at its origin, where MuJoCo's force and torque
    sensors measure what passes between the flange and the tool (sensors
    ``<robot>/ft_force``, ``<robot>/ft_torque``: the force the flange applies to the tool,
    in the site frame).  Without a sensor in the config the tool is there, unmeasured.
    """
    ft = robot.ft
    flange = spec.body(f"{robot.name}/{FLANGE_FRAME}")
    tool = flange.add_body(name=f"{robot.name}/tool")
    if ft.tool_mass_kg > 0.0:  # else a massless tool: its pad has no density either
        tool.mass = ft.tool_mass_kg
        tool.ipos = list(ft.tool_com_m)
        inertia = ft.tool_mass_kg * TOOL_RADIUS_M**2 / 2.0
        tool.inertia = [inertia, inertia, inertia]
        tool.explicitinertial = True
    tool.add_geom(
        name=f"{robot.name}/pad",
        type=mujoco.mjtGeom.mjGEOM_SPHERE,
        size=[TOOL_RADIUS_M, 0.0, 0.0],
        pos=[0.0, 0.0, ft.tool_tip_m - TOOL_RADIUS_M],
        contype=TOOL_CONTACT,
        conaffinity=TOOL_CONTACT,
        priority=1,  # its friction and softness, not the fixture's, rule its contacts
        friction=[PAD_FRICTION, 0.005, 0.0001],
        solref=list(PAD_SOLREF),
        solimp=list(PAD_SOLIMP),
        mass=0.0,
        density=0.0,
        rgba=[0.2, 0.2, 0.25, 1.0],
    )
    site = tool.add_site(name=f"{robot.name}/ft", size=[0.01, 0.01, 0.004], rgba=[0.1, 0.3, 0.9, 1])
    if ft.sensor is None:
        return
    for kind, suffix in (
        (mujoco.mjtSensor.mjSENS_FORCE, "force"),
        (mujoco.mjtSensor.mjSENS_TORQUE, "torque"),
    ):
        sensor = spec.add_sensor()
        sensor.name = f"{robot.name}/ft_{suffix}"
        sensor.type = kind
        sensor.objtype = mujoco.mjtObj.mjOBJ_SITE
        sensor.objname = site.name


def _add_motors(spec: mujoco.MjSpec, robot: str, rtype: RobotType) -> None:
    """One motor per joint: its amplifier's current loop as a first-order actuator.

    The activation is the motor current (A), filtered exactly at the amplifier's bandwidth
    (``filterexact``); the gear G·Kt turns it into joint torque.  ``actrange`` is compiled as
    the motor's peak current; the plant narrows it every cycle to the bus-voltage limits, or
    to [0, 0] while the amplifier is off.
    """
    d = rtype.drive
    for j in range(rtype.n_joints):
        act = spec.add_actuator()
        act.name = f"{robot}/motor{j + 1}"
        act.target = f"{robot}/j{j + 1}"
        act.trntype = mujoco.mjtTrn.mjTRN_JOINT
        act.dyntype = mujoco.mjtDyn.mjDYN_FILTEREXACT
        act.dynprm[0] = 1.0 / (2.0 * math.pi * d.amp_bandwidth_hz)
        act.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        act.gainprm[0] = 1.0
        act.biastype = mujoco.mjtBias.mjBIAS_NONE
        act.gear[0] = float(d.gear[j] * d.kt[j])
        act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        act.actlimited = mujoco.mjtLimited.mjLIMITED_TRUE
        act.actrange = [-float(d.max_current[j]), float(d.max_current[j])]


def _add_weld(spec: mujoco.MjSpec, robot: str, obj: str, timeconst: float) -> None:
    """An inactive weld of ``robot``'s tool to object ``obj``; the plant writes its relpose
    as it activates it (``World.activate_weld``)."""
    spec.add_equality(
        name=f"{robot}/grasp/{obj}",
        type=mujoco.mjtEq.mjEQ_WELD,
        objtype=mujoco.mjtObj.mjOBJ_BODY,
        name1=f"{robot}/tool",
        name2=obj,
        active=False,
        data=[0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0, 0.0],
        solref=[timeconst, 1.0],
    )


__all__ = ["FLANGE_FRAME", "World", "build_world", "load_pinocchio"]
