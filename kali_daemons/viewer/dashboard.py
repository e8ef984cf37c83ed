"""What the viewer draws (thesis 3.3.7, DESIGN 8): the dashboard's layout, the arms' shapes
and one frame of the arena's records, logged to a rerun recording.

``Dashboard`` is the viewer's cycle logic, apart from its process (``daemon.Viewer``): built
outside the cycle (it loads every arm type's shapes), ``frame`` once a viewer cycle.  Only a
viewer with somewhere to draw imports this module: rerun and the arms' shapes cost a start
that draws nowhere (a test's, a headless run's) about a third of a second.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import pinocchio as pin
import rerun as rr
import rerun.blueprint as rrb

from ..core import layout
from ..core.errors import DaemonError
from ..core.layout import ProcState
from ..hardware.camera import CameraRing
from ..robots import RobotType
from ..robots.cell import FLANGE_FRAME, base_transform, load_pinocchio
from ..robots.scene import SceneObject
from ..runtime.config import KaliConfig
from ..runtime.instance import decode, time_ms

TIMELINE = "kali_time"
PLOT_WINDOW_S = 10.0  # the time series show the last this many seconds
FLANGE_AXES_M = 0.12
JOINT_COLORS = np.array(  # one per joint an arm may have (layout.MAX_JOINTS)
    [
        [228, 26, 28],
        [255, 127, 0],
        [190, 170, 0],
        [77, 175, 74],
        [55, 126, 184],
        [152, 78, 163],
        [166, 86, 40],
        [247, 129, 191],
    ],
    dtype=np.uint8,
)
DEMAND_COLORS = (JOINT_COLORS // 2 + 128).astype(np.uint8)  # the same hue, paler
AXIS_COLORS = JOINT_COLORS[[0, 3, 4]]  # x y z, roll pitch yaw; fx fy fz
PALE_AXIS_COLORS = DEMAND_COLORS[[0, 3, 4]]  # tx ty tz: beside the force in one plot
# the contact arrow: 1 cm per newton, so the 150 N contact limit (FtConfig) is 1.5 m long
# and the sensor's noise after a tare (a few tenths of a newton) a few millimetres
CONTACT_M_PER_N = 0.01
CONTACT_COLOR = (230, 0, 180)  # magenta: apart from the arms', the series' and the cell's colours
CONTACT_RADIUS_M = 0.006


def joint_names(n_joints: int) -> list[str]:
    """The series names of an arm's joints: j1 .. jN, as its URDF names them."""
    return [f"j{j + 1}" for j in range(n_joints)]


def _rgba(color: np.ndarray) -> np.ndarray:
    """An RGBA colour in 0..1 (Pinocchio's) as 0..255 bytes (rerun's)."""
    return (np.clip(np.asarray(color), 0.0, 1.0) * 255).round().astype(np.uint8)


class Arm:
    """The visual shapes of an arm of type ``robot`` (its URDF's ``<visual>`` boxes and
    cylinders, through Pinocchio's visual geometry model), posed by forward kinematics.
    Built outside the cycle; ``place`` runs inside it, into preallocated ``poses``."""

    def __init__(self, robot: RobotType) -> None:
        self.model = load_pinocchio(robot)
        self.data = self.model.createData()
        urdf = robot.urdf
        self.geom = pin.buildGeomFromUrdf(self.model, str(urdf), pin.GeometryType.VISUAL)
        self.gdata = pin.GeometryData(self.geom)
        self.flange = self.model.getFrameId(FLANGE_FRAME)
        objects = list(self.geom.geometryObjects)
        kinds = [type(o.geometry).__name__ for o in objects]  # hpp-fcl's or coal's shapes
        self.boxes = [i for i, kind in enumerate(kinds) if kind == "Box"]
        self.cylinders = [i for i, kind in enumerate(kinds) if kind == "Cylinder"]
        if len(self.boxes) + len(self.cylinders) != len(objects):
            raise DaemonError(f"viewer: {urdf}: only box and cylinder visuals are drawn")
        self.half_sizes = np.array([objects[i].geometry.halfSide for i in self.boxes])
        self.radii = np.array([objects[i].geometry.radius for i in self.cylinders])
        self.lengths = np.array([2 * objects[i].geometry.halfLength for i in self.cylinders])
        self.box_colors = np.array([_rgba(objects[i].meshColor) for i in self.boxes])
        self.cylinder_colors = np.array([_rgba(objects[i].meshColor) for i in self.cylinders])
        self.poses = np.zeros((len(objects), 7))  # x y z, quaternion x y z w, in the base

    def place(self, q: np.ndarray) -> pin.SE3:
        """Pose every shape for joint angles ``q`` (``poses``); returns the flange in the base."""
        pin.forwardKinematics(self.model, self.data, q)
        pin.updateGeometryPlacements(self.model, self.data, self.geom, self.gdata)
        for g, placement in enumerate(self.gdata.oMg):
            self.poses[g] = pin.SE3ToXYZQUAT(placement)
        return pin.updateFramePlacement(self.model, self.data, self.flange)


@dataclass(frozen=True)
class RobotPaths:
    """The entity paths of one robot."""

    base: str
    boxes: str
    cylinders: str
    flange: str
    q: str
    demand: str
    error: str
    torque: str
    ff_torque: str
    current: str
    flange_position: str
    flange_rpy: str
    wrench_force: str
    wrench_torque: str
    contact: str
    events: str

    @classmethod
    def of(cls, robot: str) -> RobotPaths:
        """Paths of robot ``robot``."""
        r = f"robots/{robot}"
        base = f"world/{robot}"
        return cls(
            base=base,
            boxes=f"{base}/links/boxes",
            cylinders=f"{base}/links/cylinders",
            flange=f"{base}/flange",
            q=f"{r}/q",
            demand=f"{r}/demand",
            error=f"{r}/error",
            torque=f"{r}/torque",
            ff_torque=f"{r}/ff_torque",
            current=f"{r}/current",
            flange_position=f"{r}/flange/position",
            flange_rpy=f"{r}/flange/rpy",
            wrench_force=f"{r}/wrench/force",
            wrench_torque=f"{r}/wrench/torque",
            contact=f"{base}/contact",
            events=f"events/{robot}",
        )


def has_sensor(cfg: KaliConfig) -> list[bool]:
    """Per robot (config order): whether it has a wrist force/torque sensor (as SIO's
    ``sensors_of``)."""
    return [r.ft.sheet is not None for r in cfg.robots]


def blueprint(robots: list[str], sensed: list[bool] | None = None) -> rrb.Blueprint:
    """The dashboard's layout: arms in 3D above the event log; per robot and quantity a time
    series of the last ``PLOT_WINDOW_S`` seconds (the contact wrench only for the robots
    ``sensed`` says have a wrist sensor: a last row of the grid); process timing and flanges
    below."""
    window = rrb.VisibleTimeRange(
        TIMELINE,
        start=rrb.TimeRangeBoundary.cursor_relative(seconds=-PLOT_WINDOW_S),
        end=rrb.TimeRangeBoundary.cursor_relative(),
    )

    def series(name: str, *contents: str) -> rrb.TimeSeriesView:
        return rrb.TimeSeriesView(
            name=name,
            origin="/",
            contents=list(contents),
            time_ranges=window,
            plot_legend=rrb.PlotLegend(visible=False),
        )

    paths = [RobotPaths.of(r) for r in robots]
    plots = []
    for title, fields in (
        ("angle, demand (deg)", ("q", "demand")),
        ("tracking error (deg)", ("error",)),
        ("torque, feed-forward (N·m)", ("torque", "ff_torque")),
        ("motor current (A)", ("current",)),
    ):
        for r, p in zip(robots, paths, strict=True):
            plots.append(series(f"{r}: {title}", *(getattr(p, f) for f in fields)))
    for r, p, s in zip(robots, paths, sensed or [False] * len(robots), strict=True):
        if s:
            plots.append(
                series(f"{r}: contact force, torque (N, N·m)", p.wrench_force, p.wrench_torque)
            )
    bottom = rrb.Horizontal(
        series("execution time (µs)", "timing/exec_us"),
        series("wake-up lateness, SIO sensor→DAC (µs)", "timing/late_us", "timing/sio_latency_us"),
        rrb.Tabs(
            series("flange position (m)", *(p.flange_position for p in paths)),
            series("flange roll, pitch, yaw (deg)", *(p.flange_rpy for p in paths)),
            series("missed deadlines", "timing/misses"),
        ),
    )
    arms = rrb.Spatial3DView(
        name="arms",
        origin="world",
        eye_controls=rrb.EyeControls3D(
            position=(0.3, -1.9, 1.35), look_target=(0.0, 0.0, 0.55), eye_up=(0.0, 0.0, 1.0)
        ),
    )
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(arms, rrb.TextLogView(name="events", origin="events"), row_shares=[3, 1]),
            rrb.Vertical(rrb.Grid(*plots, grid_columns=len(robots)), bottom, row_shares=[3, 1]),
            column_shares=[2, 3],
        ),
        rrb.TimePanel(timeline=TIMELINE, state="collapsed"),
        collapse_panels=True,
    )


def open_recording(inst: Any, grpc: list[str], files: list[str]) -> rr.RecordingStream:
    """Instance ``inst``'s dashboard recording, streaming to the gRPC URLs ``grpc`` and
    writing the ``.rrd`` files ``files``, with the dashboard's layout (``blueprint``)."""
    cfg = inst.config
    recording_id = f"{inst.name}-{int(inst.arena.header['created_ns'])}"
    rec = rr.RecordingStream("kali", recording_id=recording_id)
    sinks: list[rr.GrpcSink | rr.FileSink] = [rr.GrpcSink(url) for url in grpc]
    sinks += [rr.FileSink(f) for f in files]
    rec.set_sinks(
        *sinks, default_blueprint=blueprint([r.name for r in cfg.robots], has_sensor(cfg))
    )
    rec.send_recording_name(f"Kali '{inst.name}'")
    return rec


class Dashboard:
    """The dashboard of one instance ``inst`` (its config, arena, clock, process table and
    fault record), drawn into ``rec``: ``log_static`` once, then ``frame`` each cycle (it
    allocates: the viewer is not a real-time process)."""

    def __init__(self, inst: Any, rec: rr.RecordingStream) -> None:
        self.inst = inst
        self.rec = rec
        self.load(inst.config)
        self.attach()

    def load(self, cfg: KaliConfig) -> None:
        """Each robot's entity paths, base and arm shapes (one ``Arm`` per robot type), and
        where its joints sit in the per-joint records (outside the cycle)."""
        self.names = [r.name for r in cfg.robots]
        self.paths = [RobotPaths.of(r) for r in self.names]
        self.bases = [pin.SE3(base_transform(r.base_xyz, r.base_yaw_deg)) for r in cfg.robots]
        shapes: dict[str, Arm] = {}  # one per robot type
        for r in cfg.robots:
            shapes.setdefault(r.model, Arm(r.type))
        self.arms = [shapes[r.model] for r in cfg.robots]
        for r, arm in zip(cfg.robots, self.arms, strict=True):
            arm.place(r.type.q_home.copy())  # the first use of Pinocchio faults pages in
        self.joint_map = cfg.joints
        self.spans = [self.joint_map.span(k) for k in range(len(self.names))]
        self.sensed = has_sensor(cfg)
        # the tool point, where SIO gives the contact wrench: tool_tip_m out along the flange's z
        self.tips = [np.array([0.0, 0.0, r.ft.tool_tip_m]) for r in cfg.robots]
        self.free = [o.name for o in cfg.scene.free]  # the objects whose truth it draws
        self.base_rot_t = [b.rotation.T.copy() for b in self.bases]  # world axes → base axes
        self.cameras = cfg.scene.cameras

    def attach(self) -> None:
        """SIO's, the plant's and the instance's records, once they are laid out."""
        inst = self.inst
        arena = inst.arena
        n = len(self.names)
        self.robots = arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, n)
        self.joints = arena.existing(layout.KEY_JOINTS, layout.JOINT_STATE, self.joint_map.total)
        self.ctrl = arena.existing(layout.KEY_SERVO_CTRL, layout.SERVO_CTRL)
        self.objects = arena.existing(
            layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, len(self.free)
        )["pose"]
        # the wrist sensors (kalictl start lays a record out for every robot, sensor or not)
        self.ft = (
            arena.existing(layout.KEY_FT, layout.FT_STATE, n)
            if any(self.sensed) and arena.lookup(layout.KEY_FT) is not None
            else None
        )
        self._ft = np.zeros(n, dtype=layout.FT_STATE)  # each frame's snapshot of it
        self.clock, self.procs, self.fault = inst.clock, inst.procs, inst.fault
        self._proc_names: list[str] = []  # every process seen, in order: the timing series
        self._proc_slot = np.zeros(0, dtype=np.int64)  # its slot now, -1 when it has left
        self._proc_state = np.zeros(0, dtype=np.int64)
        self._gen = -1
        self._fault_count = 0
        self._fault_active = False
        self._messages = np.zeros(n, dtype=self.robots["message"].dtype)
        self.camera_rings = [CameraRing(arena, self.cameras, i) for i in range(len(self.cameras))]
        self._camera_shown = [0] * len(self.cameras)  # the stamp of each one's frame drawn

    def log_static(self) -> None:
        """What never changes: the cell, the arms' shape sizes, series names and colours."""
        rec = self.rec
        rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for obj in self.inst.config.scene.objects:  # a free one's pose each frame
            if obj.fixed:
                w, x, y, z = obj.quat
                placed = rr.Transform3D(translation=obj.xyz, quaternion=(x, y, z, w))  # type: ignore[arg-type]
                rec.log(f"world/{obj.name}", _shape(obj), placed, static=True)
            else:
                rec.log(f"world/{obj.name}", _shape(obj), static=True)
        for p, base, arm, n, sensed in zip(
            self.paths, self.bases, self.arms, self.joint_map.counts, self.sensed, strict=True
        ):
            rec.log(
                p.base,
                rr.Transform3D(translation=base.translation, mat3x3=base.rotation),
                static=True,
            )
            rec.log(
                p.boxes,
                rr.Boxes3D(half_sizes=arm.half_sizes, colors=arm.box_colors, fill_mode="solid"),
                static=True,
            )
            rec.log(
                p.cylinders,
                rr.Cylinders3D(
                    lengths=arm.lengths,
                    radii=arm.radii,
                    colors=arm.cylinder_colors,
                    fill_mode="solid",
                ),
                static=True,
            )
            rec.log(p.flange, rr.TransformAxes3D(FLANGE_AXES_M), static=True)
            joints, hues, paler = joint_names(n), JOINT_COLORS[:n], DEMAND_COLORS[:n]
            for path, names, colors in (
                (p.q, joints, hues),
                (p.demand, [f"{j} demand" for j in joints], paler),
                (p.error, joints, hues),
                (p.torque, joints, hues),
                (p.ff_torque, [f"{j} ff" for j in joints], paler),
                (p.current, joints, hues),
                (p.flange_position, ["x", "y", "z"], AXIS_COLORS),
                (p.flange_rpy, ["roll", "pitch", "yaw"], AXIS_COLORS),
            ):
                rec.log(path, rr.SeriesLines(names=names, colors=colors), static=True)
            if sensed:
                for path, names, colors in (
                    (p.wrench_force, ["fx", "fy", "fz"], AXIS_COLORS),
                    (p.wrench_torque, ["tx", "ty", "tz"], PALE_AXIS_COLORS),
                ):
                    rec.log(path, rr.SeriesLines(names=names, colors=colors), static=True)
                rec.log(
                    p.contact,
                    rr.Arrows3D.from_fields(colors=[CONTACT_COLOR], radii=[CONTACT_RADIUS_M]),
                    static=True,
                )
        rec.log("timing/sio_latency_us", rr.SeriesLines(names=["SIO sensor→DAC"]), static=True)
        for cam in self.cameras:  # each camera where it stands, its images under it
            path = f"world/cameras/{cam.name}"
            pose = cam.pose
            rec.log(path, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]), static=True)
            rec.log(
                path,
                rr.Pinhole(
                    image_from_camera=cam.K,
                    resolution=[cam.width, cam.height],
                    camera_xyz=rr.ViewCoordinates.RDF,  # x right, y down, z along the view
                ),
                static=True,
            )

    def frame(self) -> None:
        rec = self.rec
        rec.set_time(TIMELINE, duration=time_ms(self.clock) / 1000.0)
        robots, joints = self.robots, self.joints
        q = joints["q"].copy()  # Type 4: a snapshot, consistent enough for a picture
        q_deg = np.degrees(q)
        demand_deg = np.degrees(joints["demand"])
        error_deg = demand_deg - q_deg
        torque, ff, current = joints["torque"], joints["ff_torque"], joints["current"]
        ft = self._ft
        if self.ft is not None:
            ft[:] = self.ft  # Type 4, like the joints; never a sensor's reading when absent
        for k, p in enumerate(self.paths):
            arm = self.arms[k]
            if not robots["pots_read"][k]:
                continue  # SIO has no angles for this arm yet
            span = self.spans[k]  # the arm's joints in the flat per-joint arrays
            rec.log(p.q, rr.Scalars(q_deg[span]))
            rec.log(p.demand, rr.Scalars(demand_deg[span]))
            rec.log(p.error, rr.Scalars(error_deg[span]))
            rec.log(p.torque, rr.Scalars(torque[span]))
            rec.log(p.ff_torque, rr.Scalars(ff[span]))
            rec.log(p.current, rr.Scalars(current[span]))
            flange = arm.place(q[span])
            poses = arm.poses
            rec.log(
                p.boxes,
                rr.Boxes3D.from_fields(
                    centers=poses[arm.boxes, :3], quaternions=poses[arm.boxes, 3:]
                ),
            )
            rec.log(
                p.cylinders,
                rr.Cylinders3D.from_fields(
                    centers=poses[arm.cylinders, :3], quaternions=poses[arm.cylinders, 3:]
                ),
            )
            rec.log(
                p.flange, rr.Transform3D(translation=flange.translation, mat3x3=flange.rotation)
            )
            world = self.bases[k] * flange
            rec.log(p.flange_position, rr.Scalars(world.translation))
            rec.log(p.flange_rpy, rr.Scalars(np.degrees(pin.rpy.matrixToRpy(world.rotation))))
            if self.sensed[k] and ft[k]["present"]:
                tool = ft[k]["tool"]  # about the tool point, tool axes
                rec.log(p.wrench_force, rr.Scalars(tool[:3]))
                rec.log(p.wrench_torque, rr.Scalars(tool[3:]))
                # p.contact sits under the base's transform: the tool point and the world-axes
                # force are given in the base's coordinates
                force = self.base_rot_t[k] @ ft[k]["world"][:3]
                rec.log(
                    p.contact,
                    rr.Arrows3D.from_fields(
                        origins=[flange.act(self.tips[k])], vectors=[force * CONTACT_M_PER_N]
                    ),
                )
        for name, pose in zip(self.free, self.objects, strict=True):
            if pose[3:] @ pose[3:] > 0.5:  # a unit quaternion once the plant has written it
                w, x, y, z = pose[3:]
                # rerun types QuaternionLike as its Quaternion only; it takes (x, y, z, w)
                placed = rr.Transform3D(translation=pose[:3], quaternion=(x, y, z, w))  # type: ignore[arg-type]
                rec.log(f"world/{name}", placed)
        self._camera_frames()
        self._timing()
        self._events()

    def _camera_frames(self) -> None:
        """Each camera's latest frame, colour and depth, once."""
        for i, ring in enumerate(self.camera_rings):
            if ring.stamp() == self._camera_shown[i]:  # no new frame: no copy of the last
                continue
            shot = ring.read()
            if shot is None or shot.stamp_ns == self._camera_shown[i]:
                continue
            self._camera_shown[i] = shot.stamp_ns
            path = f"world/cameras/{ring.name}"
            self.rec.log(f"{path}/image", rr.Image(shot.image))
            self.rec.log(f"{path}/depth", rr.DepthImage(shot.depth, meter=1.0))

    def _timing(self) -> None:
        """Per process: last execution time and lateness (µs), missed deadlines; SIO's
        sensor-to-DAC latency."""
        rec = self.rec
        gen = int(self.clock["registry_gen"])
        if gen != self._gen:
            self._gen = gen
            self._rescan()
        slots = self._proc_slot
        here = slots >= 0
        at = np.where(here, slots, 0)
        p = self.procs
        rec.log("timing/exec_us", rr.Scalars(np.where(here, p["exec_last_ns"][at] / 1e3, np.nan)))
        rec.log("timing/late_us", rr.Scalars(np.where(here, p["late_last_ns"][at] / 1e3, np.nan)))
        rec.log("timing/misses", rr.Scalars(np.where(here, p["misses"][at], np.nan)))
        rec.log("timing/sio_latency_us", rr.Scalars(self.ctrl["latency_last_ns"] / 1e3))
        state = np.where(here, p["state"][at], ProcState.FREE)
        if not np.array_equal(state, self._proc_state):
            for i in np.flatnonzero(state != self._proc_state):
                self._process_event(i, int(self._proc_state[i]), int(state[i]))
            self._proc_state = state

    def _rescan(self) -> None:
        """The process table changed: map every process's name to its slot (new names get new
        series; a process that left keeps its series, empty from then on)."""
        p = self.procs
        slots = np.full(len(self._proc_names), -1, dtype=np.int64)
        grown = False
        for i in range(layout.MAX_PROCESSES):
            if p[i]["state"] == ProcState.FREE:
                continue
            name = decode(p[i]["name"])
            if name not in self._proc_names:
                self._proc_names.append(name)
                slots = np.append(slots, -1)
                self._proc_state = np.append(self._proc_state, ProcState.FREE)
                grown = True
            slots[self._proc_names.index(name)] = i
        self._proc_slot = slots
        if grown:
            names = self._proc_names
            for path in ("timing/exec_us", "timing/late_us", "timing/misses"):
                self.rec.log(path, rr.SeriesLines(names=names), static=True)

    def _process_event(self, i: int | np.integer, was: int, now: int) -> None:
        name = self._proc_names[i]
        if now == ProcState.FREE:
            text, level = f"process '{name}' left", rr.TextLogLevel.INFO
        else:
            state = ProcState(now).name
            text = f"process '{name}': {state}"
            if was != ProcState.FREE:
                text += f" (was {ProcState(was).name})"
            level = rr.TextLogLevel.ERROR if now == ProcState.ERROR else rr.TextLogLevel.INFO
        self.rec.log("events/processes", rr.TextLog(text, level=level))

    def _events(self) -> None:
        """Faults and their clearing; the robots' power and calibration messages."""
        rec = self.rec
        f = self.fault
        count, active = int(f["count"]), bool(f["active"])
        new = count != self._fault_count
        if new:
            text = self.inst.fault_text(last=True) or "fault"
            more = count - self._fault_count - 1
            if more > 0:
                text += f" (and {more} more fault{'s' if more > 1 else ''} while halted)"
            rec.log("events/faults", rr.TextLog(text, level=rr.TextLogLevel.ERROR))
            self._fault_count = count
        if (new or self._fault_active) and not active:  # also one raised and cleared between
            rec.log("events/faults", rr.TextLog("fault cleared", level=rr.TextLogLevel.INFO))
        self._fault_active = active
        messages = self.robots["message"]
        if not np.array_equal(messages, self._messages):
            for k in np.flatnonzero(messages != self._messages):
                text = f"{self.names[k]}: {decode(messages[k])}"
                rec.log(self.paths[k].events, rr.TextLog(text, level=rr.TextLogLevel.INFO))
            self._messages[:] = messages


def _shape(obj: SceneObject) -> Any:
    """A scene object's shape as rerun draws it, about its own frame."""
    colour = [round(255 * c) for c in obj.color]
    size = obj.size
    if obj.shape == "box":
        half = [v / 2 for v in size]
        return rr.Boxes3D(half_sizes=[half], colors=[colour], fill_mode="solid")
    if obj.shape == "sphere":
        return rr.Ellipsoids3D(half_sizes=[[size[0]] * 3], colors=[colour], fill_mode="solid")
    if obj.shape == "cylinder":  # rerun's run along z from its centre: as the scene's
        return rr.Cylinders3D(
            lengths=[size[1]], radii=[size[0]], centers=[[0.0, 0.0, 0.0]], colors=[colour]
        )
    # a capsule: rerun's starts at its frame and runs its length along +z
    return rr.Capsules3D(
        lengths=[size[1]], radii=[size[0]], translations=[[0.0, 0.0, -size[1] / 2]], colors=[colour]
    )
