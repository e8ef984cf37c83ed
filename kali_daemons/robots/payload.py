"""What an arm holds beyond its configured tool (libfranka's ``setLoad``): a program declares
it (``robot.set_load``, a gripper closing on a scene object, a motion system holding one), the
dynamics process's feed-forward and the robot-level servos' model carry it.

``LOAD`` is a Type 4 record per robot (``core.layout``): its one writer at a time (the program
that moves the arm) makes ``seq`` odd, writes, makes it even; a reader takes a copy between
two equal even values and applies it to its Pinocchio model as a body on the flange, beside
the arm's last link and its tool.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ..core import atomic
from ..core.errors import ServoError
from .cell import FLANGE_FRAME

if TYPE_CHECKING:
    import pinocchio as pin

MAX_LOAD_KG = 50.0  # above this a load is a units mistake, not a part
MAX_LOAD_COM_M = 2.0  # its centre of mass this far from the flange at most


def write_load(
    record: np.ndarray,
    mass: float,
    com: np.ndarray,
    inertia: np.ndarray,
    what: str,
    held: int = 0,
) -> None:
    """Write one robot's load record (0-d view) whole, after checking it: ``mass`` (kg),
    ``com`` its centre of mass in the flange frame (m), ``inertia`` about it in flange axes
    (kg·m²; symmetric, positive semi-definite), ``held`` the scene object it is (its index in
    the scene's objects + 1, 0 for none; the TG's collision model then carries its shape).
    ServoError naming ``what`` for a bad value."""
    com = np.asarray(com, dtype=np.float64)
    inertia = np.asarray(inertia, dtype=np.float64)
    if not (np.isfinite(mass) and 0.0 <= mass <= MAX_LOAD_KG):
        raise ServoError(f"{what}: mass = {mass!r}: within 0..{MAX_LOAD_KG:g} kg")
    if com.shape != (3,) or not np.all(np.isfinite(com)) or np.linalg.norm(com) > MAX_LOAD_COM_M:
        raise ServoError(
            f"{what}: com = {com.tolist()}: 3 numbers, within {MAX_LOAD_COM_M:g} m of the flange"
        )
    if (
        inertia.shape != (3, 3)
        or not np.all(np.isfinite(inertia))
        or not np.allclose(inertia, inertia.T, atol=1e-12)
        or np.linalg.eigvalsh(inertia).min() < -1e-12
    ):
        raise ServoError(
            f"{what}: inertia = {inertia.tolist()}: a symmetric positive semi-definite 3 x 3 "
            "(kg·m², about the centre of mass, flange axes)"
        )
    addr = record["seq"].ctypes.data
    seq = atomic.load32(addr)
    atomic.store32(addr, (seq + 1) | 1)
    record["held"] = held
    record["mass"] = mass
    record["com"] = com
    record["inertia"] = inertia
    atomic.store32(addr, ((seq + 1) | 1) + 1)


class HeldLoad:
    """The load a Pinocchio arm model carries: a body on its flange's parent joint, added to
    what the joint's body was when bound (the last link and the tool).  ``follow(record)``
    applies the record's load when it changed (one 32-bit load when it did not: in the
    cycle; a change builds two small Pinocchio objects, which a program's grip makes rare)."""

    def __init__(self, model: pin.Model) -> None:
        import pinocchio as pin  # here: a program that only writes loads does not load it

        self.model = model
        flange = model.frames[model.getFrameId(FLANGE_FRAME)]
        self.joint = flange.parentJoint
        self.placement = flange.placement
        self.bare = pin.Inertia(model.inertias[self.joint])  # the joint's body without a load
        self.seq = 0  # the record's sequence count last applied (0: never written)

    def set(self, mass: float, com: np.ndarray, inertia: np.ndarray) -> None:
        """Carry ``mass`` at ``com`` (flange frame) with ``inertia`` about it (flange axes)."""
        import pinocchio as pin  # as in __init__

        load = pin.Inertia(float(mass), np.asarray(com, dtype=float), np.asarray(inertia))
        self.model.inertias[self.joint] = self.bare + self.placement.act(load)

    def follow(self, record: np.ndarray) -> bool:
        """Apply ``record``'s load if its sequence count moved on and a whole copy is taken
        (a writer mid-write: next time); whether it applied one."""
        addr = record["seq"].ctypes.data
        s0 = atomic.load32(addr)
        if s0 == self.seq or s0 & 1:
            return False
        mass, com, inertia = float(record["mass"]), record["com"].copy(), record["inertia"].copy()
        if atomic.load32(addr) != s0:
            return False
        self.set(mass, com, inertia)
        self.seq = s0
        return True
