"""The cell's bodies as the controller knows them (issue 56 item 3's collision model): each
arm's collision shapes from its type's URDF (Pinocchio's ``GeometryModel``, coal's shapes:
the ones the plant's MuJoCo arms collide with) placed by its joint angles and base, and the
scene's objects (``scene.py``), where they were built.  ``distance(a, b)`` is the clearance
between two bodies: an arm, one of its links (``"left/link3"``) or an object.

Outside the cycle (coal's calls allocate).  A free object is taken where the scene builds it:
the controller does not track what the plant moves.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import coal
import numpy as np
import pinocchio as pin

from ..core.errors import ConfigError
from .cell import base_transform, coal_shape
from .scene import Clearance, Scene

if TYPE_CHECKING:
    from ..runtime.config import RobotConfig


class _Arm:
    """One arm's model and collision shapes, placed at its base."""

    def __init__(self, robot: RobotConfig) -> None:
        urdf = str(robot.type.urdf)
        self.name = robot.name
        self.model = pin.buildModelFromUrdf(urdf)
        self.shapes = pin.buildGeomFromUrdf(self.model, urdf, pin.COLLISION)
        self.data, self.shape_data = self.model.createData(), self.shapes.createData()
        self.base = pin.SE3(base_transform(robot.base_xyz, robot.base_yaw_deg))
        self.links = [
            f"{robot.name}/{self.model.frames[g.parentFrame].name}"
            for g in self.shapes.geometryObjects
        ]

    def placed(self, q: np.ndarray) -> list[tuple[str, object, coal.Transform3s]]:
        """Each shape's link, geometry and world placement at joint angles ``q``."""
        pin.updateGeometryPlacements(self.model, self.data, self.shapes, self.shape_data, q)
        out = []
        for link, g, at in zip(
            self.links, self.shapes.geometryObjects, self.shape_data.oMg, strict=True
        ):
            world = self.base * at
            out.append((link, g.geometry, coal.Transform3s(world.rotation, world.translation)))
        return out


class CellGeometry:
    """The arms of ``robots`` and the objects of ``scene`` as collision shapes."""

    def __init__(self, robots: Sequence[RobotConfig], scene: Scene) -> None:
        self.arms = [_Arm(r) for r in robots]
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
