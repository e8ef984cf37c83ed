"""The simulator's truth, public (``kali.sim.truth(robot)``): what the plant knows of an arm
and the world, which the controller never reads (it sees encoders, currents and the wrist
sensor through the boards).  For judging a controller on what really happened: the true
joints, the tool point, the contact and grasp forces, the held object.  Simulation only: an
instance without a simulated plant has no truth, and says so.

Each value is the plant's latest; in lockstep (the clock stopped between steps) they are all
of one plant cycle, in real time each record is as the plant last wrote it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ..core import layout
from ..core.errors import ServoError
from ..robots.cell import base_transform
from ..robots.scene import quaternion_pose

if TYPE_CHECKING:
    from .motion import Kali

ARRAYS = (
    "q", "qd", "current", "torque", "flange", "tool_point", "contact_wrench", "grasp_wrench",
    "push",
)  # fmt: skip


@dataclass(frozen=True, eq=False)
class Truth:
    """One arm and the world as the simulator has them (never measured by Kali).

    ``sim_time_s`` and ``plant_ticks``: the plant's simulated time and cycles.  The arm's
    true joint angles ``q`` (rad) and velocities ``qd`` (rad/s), motor ``current`` (A) and
    motor ``torque`` at the joints (N·m); its ``flange`` pose (4×4, world) and ``tool_point``
    (m, world: the pad's tip, ``ft.tool_tip_m`` along the flange's z); ``contact_wrench``:
    what an ideal wrist sensor reads, the wrench the tool exerts on it (sensor frame, N, N·m);
    ``grasp_wrench``: the grasp's force and torque on the object (world), while ``grasped``;
    ``push``: a ``kalictl push`` on the tool now (N, world); ``amps_on``, ``brakes_engaged``,
    ``watchdog_tripped``, ``estop``: the board as it is; ``held``: the object the arm holds
    (its name in the scene), None; ``objects``: every free object's pose (4×4, world) by name;
    ``internal_force``: the squeeze along the line between the first two grasps of one object
    (N, + squeezing)."""

    robot: str
    sim_time_s: float
    plant_ticks: int
    q: np.ndarray
    qd: np.ndarray
    current: np.ndarray
    torque: np.ndarray
    flange: np.ndarray
    tool_point: np.ndarray
    contact_wrench: np.ndarray
    grasp_wrench: np.ndarray
    grasped: bool
    push: np.ndarray
    amps_on: bool
    brakes_engaged: bool
    watchdog_tripped: bool
    estop: bool
    held: str | None
    objects: dict[str, np.ndarray]
    internal_force: float

    def __post_init__(self) -> None:
        """Arrays as float arrays, however they came (a remote copy crosses as lists)."""
        for name in ARRAYS:
            object.__setattr__(self, name, np.asarray(getattr(self, name), dtype=np.float64))
        poses = {k: np.asarray(v, dtype=np.float64) for k, v in self.objects.items()}
        object.__setattr__(self, "objects", poses)

    def same(self, other: Truth) -> bool:
        """Whether ``other`` holds the same values (arrays compared exactly)."""
        for name in self.__dataclass_fields__:
            a, b = getattr(self, name), getattr(other, name)
            if name in ARRAYS:
                if not np.array_equal(a, b):
                    return False
            elif name == "objects":
                if a.keys() != b.keys() or not all(np.array_equal(a[k], b[k]) for k in a):
                    return False
            elif a != b:
                return False
        return True


class SimTruth:
    """``kali.sim``: the simulator's truth of a program's instance (``truth``)."""

    def __init__(self, kali: Kali) -> None:
        self._kali = kali
        inst = kali.inst
        cfg = inst.config
        self.simulated = cfg.simulated
        if self.simulated:
            arena, n = inst.arena, len(cfg.robots)
            self._arms = arena.existing(layout.KEY_TRUTHS, layout.ARM_TRUTH, n)
            self._joints = arena.existing(
                layout.KEY_JOINT_TRUTHS, layout.JOINT_TRUTH, cfg.joints.total
            )
            self._world = arena.existing(layout.KEY_WORLD_TRUTH, layout.WORLD_TRUTH, 1)
            self._names = tuple(o.name for o in cfg.scene.free)
            self._objects = arena.existing(
                layout.KEY_OBJECT_TRUTHS, layout.OBJECT_TRUTH, len(self._names)
            )

    def truth(self, robot: str | int) -> Truth:
        """Robot ``robot``'s truth and the world's, now; ServoError on an instance without a
        simulated plant (real hardware has no truth)."""
        kali = self._kali
        k = kali.servo.robot_index(robot)
        name = kali.names[k]
        if not self.simulated:
            raise ServoError(
                f"sim.truth: robot '{name}': instance '{kali.inst.name}' has no simulated "
                "plant: real hardware has no truth, only what the controller measures"
            )
        cfg = kali.inst.config
        arm, world, objects = self._arms[k].copy(), self._world[0].copy(), self._objects.copy()
        joints = self._joints[cfg.joints.span(k)].copy()
        robot_cfg = cfg.robots[k]
        q = joints["q"]
        flange = base_transform(robot_cfg.base_xyz, robot_cfg.base_yaw_deg) @ kali.flange_pose(q, k)
        return Truth(
            robot=name,
            sim_time_s=int(world["sim_time_ns"]) / 1e9,
            plant_ticks=int(world["ticks"]),
            q=q,
            qd=joints["qd"],
            current=joints["current"],
            torque=joints["torque"],
            flange=flange,
            tool_point=flange[:3, 3] + flange[:3, 2] * robot_cfg.ft.tool_tip_m,
            contact_wrench=arm["ft_wrench"],
            grasp_wrench=arm["grasp_wrench"],
            grasped=bool(arm["grasped"]),
            push=arm["push"],
            amps_on=bool(arm["amps_on"]),
            brakes_engaged=bool(arm["brakes_engaged"]),
            watchdog_tripped=bool(arm["watchdog_tripped"]),
            estop=bool(arm["estop"]),
            held=None if arm["held"] < 0 else self._names[int(arm["held"])],
            objects={
                n: quaternion_pose(p[:3], p[3:])
                for n, p in zip(self._names, objects["pose"], strict=True)
            },
            internal_force=float(world["internal_force"]),
        )
