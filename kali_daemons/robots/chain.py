"""A robot type's serial chain from its URDF, and the flange's forward kinematics on it,
without Pinocchio or MuJoCo: the servo I/O process needs the flange pose every tick (a wrist
force/torque sensor's reading in the world frame, the tool's gravity) and loads neither.

``chain_of`` reads the URDF once (``xml.etree``) into a ``Chain``: per moving joint the fixed
transform from the parent frame to the joint's frame and the joint's axis, fixed joints folded
into the next transform.  ``flange_pose`` is the numpy reference; inside the cycle the
compiled ``kali_chain_pose`` (``csrc/chain.c``, bound by ``kernels.chain_pose``) computes the
same product on the same arrays.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from ..core.errors import ModelError
from .cell import FLANGE_FRAME

if TYPE_CHECKING:
    from . import RobotType

FloatArray = npt.NDArray[np.float64]

MOVING = ("revolute", "continuous")  # a continuous joint is a revolute one without limits
FIXED = "fixed"


@dataclass(frozen=True)
class Chain:
    """A serial chain of ``n`` revolute joints, base link to flange.

    ``origins`` (n + 1, 4, 4), C-contiguous: ``origins[i]`` is the fixed transform from
    joint i's parent frame (the base for i = 0) to joint i's frame at zero angle, fixed joints
    met before it composed in; ``origins[n]`` the one from the last joint's frame to the
    flange (identity when the flange is that joint's child link).  ``axes`` (n, 3): each
    joint's unit axis in its own frame.  Both read-only: the kernel reads them in place.
    """

    n: int
    origins: FloatArray
    axes: FloatArray


def chain_of(rtype: RobotType) -> Chain:
    """The chain of ``rtype.urdf`` from its root link to ``FLANGE_FRAME``, checked to have
    ``rtype.n_joints`` moving joints named j1..jN in order; ``ModelError`` naming the file
    and the joint otherwise.  Read once per file and joint count (outside any cycle)."""
    return _chain(Path(rtype.urdf), rtype.n_joints, rtype.name)


def base_pose(xyz: tuple[float, float, float], yaw_deg: float) -> np.ndarray:
    """A robot's base in the world (4×4): at ``xyz``, turned ``yaw_deg`` about z."""
    c, s = math.cos(math.radians(yaw_deg)), math.sin(math.radians(yaw_deg))
    t = np.eye(4)
    t[:2, :2] = [[c, -s], [s, c]]
    t[:3, 3] = xyz
    return t


def flange_pose(chain: Chain, q: FloatArray, out: FloatArray | None = None) -> FloatArray:
    """The flange (4×4) in the robot's base frame at joint angles ``q`` (rad):
    Π_i origins[i] · Rot(axes[i], q[i]), then · origins[n].  Into ``out`` if given.

    The numpy reference of ``kali_chain_pose``; it allocates (outside the cycle)."""
    assert len(q) == chain.n, f"chain: {len(q)} joint angles for a chain of {chain.n} joints"
    pose = chain.origins[0].copy()
    turn = np.eye(4)
    for i in range(chain.n):
        if i:
            pose = pose @ chain.origins[i]
        turn[:3, :3] = _rotation(chain.axes[i], float(q[i]))
        pose = pose @ turn
    pose = pose @ chain.origins[chain.n]
    if out is None:
        return pose
    out[...] = pose
    return out


def _rotation(axis: FloatArray, angle: float) -> FloatArray:
    """The rotation (3×3) by ``angle`` about the unit ``axis`` (Rodrigues):
    cos·I + sin·[axis]× + (1 − cos)·axis·axisᵀ, entry for entry as ``csrc/chain.c`` has it."""
    x, y, z = (float(v) for v in axis)
    c, s = math.cos(angle), math.sin(angle)
    t = 1.0 - c
    return np.array(
        [
            [t * x * x + c, t * x * y - s * z, t * x * z + s * y],
            [t * x * y + s * z, t * y * y + c, t * y * z - s * x],
            [t * x * z - s * y, t * y * z + s * x, t * z * z + c],
        ]
    )


# --------------------------------------------------------------------------------------------
# Reading the URDF (outside any cycle)


@cache
def _chain(urdf: Path, n_joints: int, type_name: str) -> Chain:
    """``chain_of`` for one file, joint count and type name (the name is for messages)."""
    joints = _path_to_flange(urdf)
    origins: list[FloatArray] = []
    axes: list[FloatArray] = []
    names: list[str] = []
    pending = np.eye(4)  # fixed joints since the last moving one
    for joint in joints:
        name, kind = joint.get("name", "?"), joint.get("type", "?")
        placed = pending @ _origin(urdf, joint)
        if kind == FIXED:
            pending = placed
            continue
        if kind not in MOVING:
            raise ModelError(
                f"{urdf}: joint {name!r} on the chain to {FLANGE_FRAME!r} is {kind!r}: "
                f"the chain supports {', '.join(MOVING)} and {FIXED} joints"
            )
        names.append(name)
        origins.append(placed)
        axes.append(_axis(urdf, joint))
        pending = np.eye(4)
    origins.append(pending)
    expected = [f"j{k + 1}" for k in range(n_joints)]
    if names != expected:
        raise ModelError(
            f"{urdf}: the chain to {FLANGE_FRAME!r} has {len(names)} moving joints "
            f"({', '.join(names) or 'none'}); robot type {type_name!r} expects {n_joints}, "
            f"named j1..j{n_joints} from the base"
        )
    return Chain(n=n_joints, origins=_read_only(np.stack(origins)), axes=_read_only(axes))


def _path_to_flange(urdf: Path) -> list[ET.Element]:
    """The joints from the root link to ``FLANGE_FRAME``, base first: each link's one parent
    joint, from the flange up (links off this path are not the chain's)."""
    try:
        robot = ET.parse(urdf).getroot()
    except (OSError, ET.ParseError) as exc:
        raise ModelError(f"{urdf}: cannot read it as a URDF: {exc}") from None
    links = {link.get("name") for link in robot.iter("link")}
    if FLANGE_FRAME not in links:
        raise ModelError(
            f"{urdf}: no link {FLANGE_FRAME!r} (a robot type's chain ends at its flange link); "
            f"links: {', '.join(sorted(str(n) for n in links))}"
        )
    parent_joint: dict[str, ET.Element] = {}
    for joint in robot.findall("joint"):
        child = _link_of(urdf, joint, "child")
        if child in parent_joint:
            raise ModelError(
                f"{urdf}: link {child!r} is the child of joints "
                f"{parent_joint[child].get('name')!r} and {joint.get('name')!r}: not a tree"
            )
        parent_joint[child] = joint
    path: list[ET.Element] = []
    link = FLANGE_FRAME
    while link in parent_joint:
        joint = parent_joint[link]
        if len(path) > len(parent_joint):
            raise ModelError(f"{urdf}: joint {joint.get('name')!r} closes a loop: not a tree")
        path.append(joint)
        link = _link_of(urdf, joint, "parent")
    return path[::-1]


def _link_of(urdf: Path, joint: ET.Element, which: str) -> str:
    """The ``parent`` or ``child`` link a joint names."""
    tag = joint.find(which)
    name = None if tag is None else tag.get("link")
    if not name:
        raise ModelError(f"{urdf}: joint {joint.get('name')!r} names no {which} link")
    return name


def _numbers(urdf: Path, joint: ET.Element, tag: str, attr: str, default: str) -> FloatArray:
    """Three numbers of a joint's ``<tag attr="x y z">`` (``default`` when absent, as URDF
    has it)."""
    element = joint.find(tag)
    text = default if element is None else element.get(attr, default)
    try:
        values = np.array([float(v) for v in text.split()])
    except ValueError:
        values = np.zeros(0)
    if values.shape != (3,) or not np.isfinite(values).all():
        raise ModelError(
            f"{urdf}: joint {joint.get('name')!r}: <{tag} {attr}={text!r}> must be 3 numbers"
        )
    return values


def _origin(urdf: Path, joint: ET.Element) -> FloatArray:
    """A joint's ``<origin xyz rpy>`` as a 4×4: R = Rz(yaw)·Ry(pitch)·Rx(roll), URDF's."""
    xyz = _numbers(urdf, joint, "origin", "xyz", "0 0 0")
    roll, pitch, yaw = _numbers(urdf, joint, "origin", "rpy", "0 0 0")
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    t = np.eye(4)
    t[:3, :3] = [
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ]
    t[:3, 3] = xyz
    return t


def _axis(urdf: Path, joint: ET.Element) -> FloatArray:
    """A joint's ``<axis xyz>`` (URDF's default 1 0 0), normalised."""
    axis = _numbers(urdf, joint, "axis", "xyz", "1 0 0")
    norm = float(np.linalg.norm(axis))
    if norm < 1e-9:
        raise ModelError(f"{urdf}: joint {joint.get('name')!r}: axis {axis.tolist()} is zero")
    return axis / norm


def _read_only(values: object) -> FloatArray:
    arr = np.ascontiguousarray(values, dtype=np.float64)
    arr.setflags(write=False)
    return arr
