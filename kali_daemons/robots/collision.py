"""The cell's bodies as the controller knows them (issue 56 item 3's collision model): each
arm's collision shapes from its type's URDF (Pinocchio's ``GeometryModel``, coal's shapes:
the ones the plant's MuJoCo arms collide with) placed by its joint angles and base, and the
scene's objects (``scene.py``), where they were built.  ``distance(a, b)`` is the clearance
between two bodies: an arm, one of its links (``"left/link3"``) or an object.

Outside the cycle (coal's calls allocate).  A free object is taken where the scene builds it:
the controller does not track what the plant moves.

``CellClearance`` is the TG's check of a motion's poses (``ClearanceWalk``): an arm's links
against the other arms' and against the fixed objects its links touch (``arms_touch``; not its
base and first link, which stand on the world, nor its last link against what its tool may
touch, ``tools_touch``), as the plant's contacts are.  Free objects are the parts the arms
handle, not obstacles, but for one an arm holds (its load record names it): that goes with
the arm as its last link does, never checked against an arm holding it too.  Each pose's
distances are a lower bound found cheaply (each shape's bounding sphere; coal's exact distance
only for pairs the spheres bring near), and a walk along a path looks again only once the arms
may have moved by the margin the last look left (conservative advancement: the distance a
joint turn can move any point of an arm is bounded by the arm's reach beyond that joint).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import coal
import numpy as np
import pinocchio as pin

from ..core.errors import ConfigError
from .cell import FLANGE_FRAME, base_transform, coal_shape
from .scene import Clearance, Scene, SceneObject

if TYPE_CHECKING:
    from ..runtime.config import RobotConfig


class _Arm:
    """One arm's model and collision shapes, placed at its base; holding an object (``held``:
    the scene's object and the arm's grasp of it, the flange in its frame), that object's
    shape too, on the flange, named ``"<arm>/<object>"``."""

    def __init__(
        self, robot: RobotConfig, held: tuple[SceneObject, np.ndarray] | None = None
    ) -> None:
        urdf = str(robot.type.urdf)
        self.name = robot.name
        self.model = pin.buildModelFromUrdf(urdf)
        self.shapes = pin.buildGeomFromUrdf(self.model, urdf, pin.COLLISION)
        self.base = pin.SE3(base_transform(robot.base_xyz, robot.base_yaw_deg))
        self.links = [
            f"{robot.name}/{self.model.frames[g.parentFrame].name}"
            for g in self.shapes.geometryObjects
        ]
        self.holding = ""  # the object it holds, whose shape is its last row
        if held is not None:
            obj, grasp = held
            flange = self.model.frames[self.model.getFrameId(FLANGE_FRAME)]
            at = flange.placement * pin.SE3(np.linalg.inv(grasp))  # the object, joint frame
            self.shapes.addGeometryObject(
                pin.GeometryObject(obj.name, flange.parentJoint, at, coal_shape(obj))
            )
            self.links.append(f"{robot.name}/{obj.name}")
            self.holding = obj.name
        self.data, self.shape_data = self.model.createData(), self.shapes.createData()
        # each shape's bounding sphere in its joint's frame, and the joint (0: the base)
        objs = self.shapes.geometryObjects
        for g in objs:
            g.geometry.computeLocalAABB()
        self.joint_of = np.array([g.parentJoint for g in objs], dtype=np.intp)
        self.sphere_at = np.array(
            [g.placement.act(g.geometry.aabb_center) for g in objs], dtype=float
        ).reshape(-1, 3)
        self.radius = np.array([g.geometry.aabb_radius for g in objs], dtype=float)
        self._base = self.base.homogeneous
        self._sphere_col = self.sphere_at[:, :, None].copy()
        self._col = np.zeros_like(self._sphere_col)
        self.reach = self._reach()

    def _reach(self) -> np.ndarray:
        """Per joint (1..nq): the furthest any point of the links it turns lies from its axis
        (bounded by the distance from its origin along the chain), so a turn of ``dq`` moves
        no point of the arm more than ``reach[j] * |dq|``."""
        m = self.model
        extent = np.zeros(m.njoints)  # per joint: its shapes' furthest point from its origin
        for j, c, r in zip(self.joint_of, self.sphere_at, self.radius, strict=True):
            extent[j] = max(extent[j], float(np.linalg.norm(c)) + r)
        reach = np.zeros(m.njoints)
        for j in range(m.njoints - 1, 0, -1):  # a serial chain: joint j + 1's parent is j
            below = [k for k in range(j + 1, m.njoints) if m.parents[k] == j]
            reach[j] = max(
                [extent[j]]
                + [
                    float(np.linalg.norm(m.jointPlacements[k].translation)) + reach[k]
                    for k in below
                ]
            )
        return reach[1:]

    def spheres(self, q: np.ndarray, out: np.ndarray) -> None:
        """Place the shapes at ``q`` (for ``placement``) and write their spheres' world
        centres into ``out`` (one row a shape)."""
        pin.updateGeometryPlacements(self.model, self.data, self.shapes, self.shape_data, q)
        joints = self._base @ np.array([m.homogeneous for m in self.data.oMi])
        at = joints[self.joint_of]
        np.matmul(at[:, :3, :3], self._sphere_col, out=self._col)
        np.add(self._col[..., 0], at[:, :3, 3], out=out)

    def placement(self, i: int) -> coal.Transform3s:
        """Shape ``i``'s world placement where ``spheres`` last put the arm."""
        world = self.base * self.shape_data.oMg[i]
        return coal.Transform3s(world.rotation, world.translation)

    def placed(self, q: np.ndarray) -> list[tuple[str, object, coal.Transform3s]]:
        """Each shape's link, geometry and world placement at joint angles ``q``."""
        pin.updateGeometryPlacements(self.model, self.data, self.shapes, self.shape_data, q)
        shapes = self.shapes.geometryObjects
        return [(link, shapes[i].geometry, self.placement(i)) for i, link in enumerate(self.links)]


class CellGeometry:
    """The arms of ``robots`` and the objects of ``scene`` as collision shapes."""

    def __init__(
        self,
        robots: Sequence[RobotConfig],
        scene: Scene,
        held: Mapping[int, tuple[str, np.ndarray]] | None = None,
    ) -> None:
        """``held``: per robot index holding an object, its name and the arm's grasp of it
        (the flange in the object's frame): the object's shape goes with the arm."""
        held = held or {}
        self.arms = [
            _Arm(r, (scene.object(held[k][0]), held[k][1]) if k in held else None)
            for k, r in enumerate(robots)
        ]
        self.objects = {
            o.name: (coal_shape(o), coal.Transform3s(o.pose[:3, :3], o.pose[:3, 3]))
            for o in scene.objects
        }
        self.scene = scene

    def _shapes(
        self, body: str, qs: Sequence[np.ndarray]
    ) -> list[tuple[str, object, coal.Transform3s]]:
        """The shapes of ``body`` (an arm, ``arm/link``, or a scene object) placed at ``qs``."""
        if body in self.objects:
            shape, at = self.objects[body]
            return [(body, shape, at)]
        arm, _, link = body.partition("/")
        for k, a in enumerate(self.arms):
            if a.name == arm:
                shapes = a.placed(np.asarray(qs[k], dtype=float))
                chosen = [s for s in shapes if not link or s[0] == body]
                if chosen:
                    return chosen
                links = sorted({s[0] for s in shapes})
                raise ConfigError(f"distance: robot '{arm}' has no link {link!r}; {links}")
        known = [a.name for a in self.arms] + list(self.objects)
        raise ConfigError(f"distance: no body {body!r}: the arms and the scene's objects {known}")

    def distance(self, a: str, b: str, qs: Sequence[np.ndarray]) -> Clearance:
        """The clearance between bodies ``a`` and ``b`` with the arms at ``qs`` (per robot,
        config order): the nearest pair of their shapes."""
        if a.partition("/")[0] == b.partition("/")[0]:
            raise ConfigError(f"distance: {a!r} and {b!r} are one body")
        request, best = coal.DistanceRequest(), None
        for name_a, shape_a, at_a in self._shapes(a, qs):
            for name_b, shape_b, at_b in self._shapes(b, qs):
                result = coal.DistanceResult()
                d = coal.distance(shape_a, at_a, shape_b, at_b, request, result)
                if best is None or d < best.distance:
                    best = Clearance(
                        float(d),
                        name_a,
                        name_b,
                        np.array(result.getNearestPoint1()),
                        np.array(result.getNearestPoint2()),
                    )
        assert best is not None  # every body has a shape
        return best


NEAR_M = 0.08  # pairs whose spheres come within the clearance and this get coal's distance
STEP_M = 0.001  # a joint move's walk steps at least this far (its poses checked this finely)
AWAY_TOL_M = 1e-4  # arms within the clearance "move away" unless this much nearer (rounding)


class CellClearance:
    """Which pairs of the cell's bodies a motion must keep ``clearance`` apart, and the least
    distance among them at given joint angles (see the module's docstring)."""

    def __init__(self, geometry: CellGeometry) -> None:
        self.geometry = geometry
        self.clearance = geometry.scene.clearance_m
        arms = geometry.arms
        self.first = np.cumsum([0] + [len(a.radius) for a in arms])  # each arm's first row
        fixed = [o for o in geometry.scene.objects if o.fixed and o.arms_touch]
        n = int(self.first[-1])
        self.names = [link for a in arms for link in a.links] + [o.name for o in fixed]
        self.centres = np.zeros((n + len(fixed), 3))
        self.radius = np.concatenate([a.radius for a in arms] + [np.zeros(len(fixed))])
        self._objects = []
        for k, o in enumerate(fixed):
            shape, at = geometry.objects[o.name]
            assert isinstance(shape, coal.CollisionGeometry)
            shape.computeLocalAABB()
            self.centres[n + k] = at.transform(shape.aabb_center)
            self.radius[n + k] = shape.aabb_radius
            self._objects.append((o, shape, at))
        pairs: list[tuple[int, int]] = []
        for a, arm in enumerate(arms):
            rows = range(int(self.first[a]), int(self.first[a + 1]))
            for b in range(a + 1, len(arms)):
                pairs += [
                    (i, j)
                    for i in rows
                    for j in range(self.first[b], self.first[b + 1])
                    if not self._shared(i, j)
                ]
            last = int(arm.joint_of.max(initial=0))
            for i in rows:
                joint = int(arm.joint_of[i - self.first[a]])
                for k, o in enumerate(fixed):
                    if joint >= 2 and not (joint == last and o.tools_touch):
                        pairs.append((i, n + k))
        self.pair_a = np.array([p[0] for p in pairs], dtype=np.intp)
        self.pair_b = np.array([p[1] for p in pairs], dtype=np.intp)
        self._radii = self.radius[self.pair_a] + self.radius[self.pair_b]
        self._request, self._result = coal.DistanceRequest(), coal.DistanceResult()
        self._arm_of = np.searchsorted(self.first, np.arange(n), side="right") - 1

    def _shared(self, i: int, j: int) -> bool:
        """Whether rows ``i`` and ``j`` (of two arms) are an object and an arm holding it: the
        object is part of each holder's tool (two arms carrying one bar)."""
        arms, first = self.geometry.arms, self.first
        a, b = (int(np.searchsorted(first, r, side="right")) - 1 for r in (i, j))
        held_i = arms[a].holding and i == first[a + 1] - 1
        held_j = arms[b].holding and j == first[b + 1] - 1
        return bool(
            (held_i and arms[b].holding == arms[a].holding)
            or (held_j and arms[a].holding == arms[b].holding)
        )

    def geometry_of(self, row: int) -> object:
        """Row ``row``'s coal geometry: an arm's shape, or a fixed object's."""
        n = int(self.first[-1])
        if row >= n:
            return self._objects[row - n][1]
        a = int(self._arm_of[row])
        return self.geometry.arms[a].shapes.geometryObjects[row - int(self.first[a])].geometry

    def placement(self, row: int) -> coal.Transform3s:
        """Row ``row``'s world placement: a fixed object's, or an arm's shape where the arm's
        ``spheres`` last put it."""
        n = int(self.first[-1])
        if row >= n:
            return self._objects[row - n][2]
        a = int(self._arm_of[row])
        return self.geometry.arms[a].placement(row - int(self.first[a]))

    def rows_of(self, arm: int) -> slice:
        """The rows of arm ``arm``'s shapes."""
        return slice(int(self.first[arm]), int(self.first[arm + 1]))

    def gap(self, qs: Sequence[np.ndarray]) -> tuple[float, Clearance | None]:
        """With the arms at ``qs`` (per robot, config order): a lower bound of the least
        distance between the pairs, and the nearest pair if its distance was computed (it
        is, within the clearance and ``NEAR_M``)."""
        for a, arm in enumerate(self.geometry.arms):
            arm.spheres(np.asarray(qs[a], dtype=float), self.centres[self.rows_of(a)])
        return self.least(self.centres, self.pair_a, self.pair_b, self._radii, {})

    def least(
        self,
        centres: np.ndarray,
        pair_a: np.ndarray,
        pair_b: np.ndarray,
        radii: np.ndarray,
        at: dict[int, coal.Transform3s],
    ) -> tuple[float, Clearance | None]:
        """The least distance of pairs ``pair_a``-``pair_b`` (rows; their spheres' summed
        ``radii``) with the shapes' spheres at ``centres`` and placements ``at`` (rows not
        in it: ``placement``, kept there): a lower bound, exact where the nearest pair's
        distance was computed (then that pair too).  Pairs are measured by coal nearest
        sphere gap first, only within the clearance and ``NEAR_M``, and no further once a
        measured distance is below every sphere gap left."""
        if not len(pair_a):
            return math.inf, None
        apart = centres[pair_a] - centres[pair_b]
        gaps = np.sqrt(np.einsum("ij,ij->i", apart, apart)) - radii
        near = np.flatnonzero(gaps < self.clearance + NEAR_M)
        least = float(np.delete(gaps, near).min(initial=math.inf))
        best, points = -1, (np.zeros(3), np.zeros(3))
        for p in near[np.argsort(gaps[near])]:
            if gaps[p] >= least:  # no pair left can be nearer
                break
            i, j = int(pair_a[p]), int(pair_b[p])
            if i not in at:
                at[i] = self.placement(i)
            if j not in at:
                at[j] = self.placement(j)
            at_i, at_j = at[i], at[j]
            self._result.clear()  # a result keeps the least distance it has seen
            d = coal.distance(
                self.geometry_of(i), at_i, self.geometry_of(j), at_j, self._request, self._result
            )
            if d < least:
                least, best = d, p
                points = (
                    np.array(self._result.getNearestPoint1()),
                    np.array(self._result.getNearestPoint2()),
                )
        if best < 0:
            return least, None
        i, j = int(pair_a[best]), int(pair_b[best])
        return least, Clearance(least, self.names[i], self.names[j], *points)

    def walk(self, robots: Sequence[int], qs: Sequence[np.ndarray]) -> ClearanceWalk:
        """A walk along a motion of ``robots`` (cell indices), every arm starting at ``qs``
        (per robot, config order: the others stay there)."""
        return ClearanceWalk(self, robots, qs)


class ClearanceWalk:
    """The clearance along one motion's poses, taken in order: ``hit`` at each pose of the
    motion's arms says the pair within the clearance, or None, looking again only once the
    arms may have moved by the margin the last look left.  Only the pairs with a shape of
    the motion's arms are looked at; the other arms' shapes are placed once, here.

    ``refused`` is the check's rule: arms that start within the clearance (a held part resting
    on a fixture its tool may not touch) may move away, never nearer than they have come out
    to (MoveIt Servo's rule); once out, the clearance holds again."""

    def __init__(
        self, cell: CellClearance, robots: Sequence[int], qs: Sequence[np.ndarray]
    ) -> None:
        self.cell = cell
        self.robots = list(robots)
        self.qs = [np.array(q, dtype=float) for q in qs]
        self._reach = [cell.geometry.arms[k].reach for k in self.robots]
        self._prev = [self.qs[k].copy() for k in self.robots]
        self._step = [p.copy() for p in self._prev]
        self._slack = -1.0  # m the arms may move before the next look (< 0: look now)
        self.nearest: Clearance | None = None  # the last look's nearest pair, if measured
        self.looks = 0  # how many times the distances were computed
        self.centres = cell.centres.copy()
        self._standing: dict[int, coal.Transform3s] = {}  # the other arms' shapes, placed
        for a, arm in enumerate(cell.geometry.arms):
            if a not in self.robots:
                arm.spheres(self.qs[a], self.centres[cell.rows_of(a)])
                rows = cell.rows_of(a)
                self._standing.update({r: cell.placement(r) for r in range(rows.start, rows.stop)})
        moving = np.zeros(len(self.centres), dtype=bool)
        for k in self.robots:
            moving[cell.rows_of(k)] = True
        mine = moving[cell.pair_a] | moving[cell.pair_b]
        self._pairs = (cell.pair_a[mine], cell.pair_b[mine], cell._radii[mine])
        near = self.hit([self.qs[k] for k in self.robots])  # where the motion starts
        # the least distance the arms have come out to while within the clearance (inf: out)
        self.inside = math.inf if near is None else near.distance

    def hit(self, rows: Sequence[np.ndarray], fresh: float = 0.0) -> Clearance | None:
        """The motion's arms at ``rows`` (one per robot of the motion, in its order), the
        pose after the last one given: the pair within the clearance, or None.  It looks
        again once the margin left is no more than ``fresh`` (m; 0: once it is used up)."""
        moved = 0.0
        for i, q in enumerate(rows):  # in a tracking motion's cycle: into scratch
            step = self._step[i]
            np.subtract(q, self._prev[i], out=step)
            np.abs(step, out=step)
            moved += float(np.dot(step, self._reach[i]))
            self._prev[i][:] = q
        self._slack -= moved
        if self._slack > fresh:
            return None
        cell = self.cell
        for i, k in enumerate(self.robots):
            self.qs[k][:] = rows[i]
            cell.geometry.arms[k].spheres(self.qs[k], self.centres[cell.rows_of(k)])
        self.looks += 1
        least, self.nearest = cell.least(self.centres, *self._pairs, dict(self._standing))
        self._slack = least - cell.clearance
        return self.nearest if least < cell.clearance else None

    def refused(self, rows: Sequence[np.ndarray], fresh: float = 0.0) -> Clearance | None:
        """As ``hit``, under the rule for arms within the clearance (the class's docstring):
        the pair that refuses the pose ``rows``, or None."""
        near = self.hit(rows, fresh)
        if near is None:
            self.inside = math.inf
            return None
        if near.distance < self.inside - AWAY_TOL_M:
            return near
        self.inside = max(self.inside, near.distance)
        return None

    def rate(self, delta: Sequence[np.ndarray]) -> float:
        """How far (m) any point of the motion's arms may move per unit of a straight joint
        move by ``delta`` (one row per robot of the motion)."""
        return sum(float(np.abs(d) @ r) for d, r in zip(delta, self._reach, strict=True))

    @property
    def slack(self) -> float:
        """How far the arms may move from the last pose before the clearance could be
        reached (m)."""
        return self._slack
