"""Generate ``robots/ur5/ur5.urdf`` and ``robots/panda/panda.urdf`` from their robot types' facts.

    .venv/bin/python scripts/gen_robot_urdf.py                 # (re)write both
    .venv/bin/python scripts/gen_robot_urdf.py panda           # one of them
    .venv/bin/python scripts/gen_robot_urdf.py --check         # exit 1 if a file is stale

The conventions of ``scripts/gen_puma560_urdf.py``: revolute joints ``j1 .. jN`` about their
z axis, the last link ``flange`` on a fixed joint, inertials from the facts, joint limits
(position from the facts, effort and velocity from the drive: peak motor torque through the
gearbox, and the speed at which back-EMF eats the bus), cylinders for visual and collision
geometry (a housing around each joint axis and a bone from each joint to the next), and the
``<mujoco>`` extension that keeps MuJoCo from fusing the massless ``flange`` into link N and
from discarding the visuals.  Rotor inertia is not in the file (neither loader reads it).

- UR5, standard DH (``A_i = Rz(θ_i)·M_i``, ``M_i = Tz(d_i)·Tx(a_i)·Rx(α_i)``): as for the
  PUMA, URDF link ``i`` is DH frame ``i-1`` turned by θ_i, joint ``j<i>``'s origin is
  ``M_{i-1}``, the flange is ``M_6`` past link 6, and link i's inertial (given in DH frame i)
  sits at ``M_i`` composed with its centre of mass.
- Panda, modified DH (``T_i = Rx(α_{i-1})·Tx(a_{i-1})·Rz(θ_i)·Tz(d_i)``): URDF link ``i`` is
  DH frame ``i`` itself, joint ``j<i>``'s origin is ``Rx(α_{i-1})·Tx(a_{i-1})·Tz(d_i)``, the
  flange is ``Tz(0.107)`` past link 7, and the inertials are in the link frames already.

The output is deterministic (shortest round-trip float text, fixed order), so ``--check``
compares it byte for byte with the committed file.
"""

from __future__ import annotations

import argparse
import difflib
import math
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from kali_daemons.robots.panda import facts as panda
from kali_daemons.robots.ur5 import facts as ur5

Vec = tuple[float, float, float]
SNAP = 1e-12  # |x| below this is written as 0 (cos 90° · d and the like)


def _snap(v: Sequence[float] | np.ndarray) -> Vec:
    x, y, z = (0.0 if abs(float(c)) < SNAP else float(c) for c in v)
    return (x, y, z)


def _num(x: float) -> str:
    """Shortest text that reads back as the same double; no '-0'."""
    x = float(x)
    if x == 0.0:
        return "0"
    if x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def _vec(v: Sequence[float]) -> str:
    return " ".join(_num(x) for x in v)


def _origin(xyz: Sequence[float], rpy: Sequence[float]) -> str:
    return f'<origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>'


def _rx(alpha: float) -> np.ndarray:
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


@dataclass(frozen=True)
class Cylinder:
    """A cylinder in its link's frame: centre, orientation (rpy), radius and length."""

    name: str
    xyz: Vec
    rpy: Vec
    radius: float
    length: float
    material: str


@dataclass(frozen=True)
class Inertial:
    """Mass, centre of mass and inertia tensor (ixx, iyy, izz, ixy, ixz, iyz) in the frame
    given by ``rpy`` at the centre of mass."""

    mass: float
    xyz: Vec
    rpy: Vec
    inertia: tuple[float, float, float, float, float, float]


@dataclass
class Link:
    """One URDF link and the joint that moves it (its origin in the parent link's frame)."""

    name: str
    joint_xyz: Vec = (0.0, 0.0, 0.0)
    joint_rpy: Vec = (0.0, 0.0, 0.0)
    inertial: Inertial | None = None
    shapes: list[Cylinder] = field(default_factory=list)


@dataclass(frozen=True)
class Arm:
    """What the generator writes for one robot type."""

    name: str
    comment: str
    path: Path
    links: list[Link]  # base_link, link1 .. linkN (joint j<i> moves link i)
    flange_xyz: Vec
    flange_rpy: Vec
    q_min: np.ndarray
    q_max: np.ndarray
    effort: np.ndarray
    velocity: np.ndarray
    materials: dict[str, tuple[float, float, float, float]]


def _bone(name: str, to: Vec, radius: float, material: str) -> Cylinder | None:
    """A cylinder from the link's origin to point ``to`` (None if they coincide)."""
    length = math.sqrt(sum(c * c for c in to))
    if length < 1e-6:
        return None
    pitch = math.acos(max(-1.0, min(1.0, to[2] / length)))
    yaw = math.atan2(to[1], to[0]) if abs(pitch) > SNAP else 0.0
    centre = _snap([0.5 * c for c in to])
    return Cylinder(name, centre, _snap((0.0, pitch, yaw)), radius, length, material)


def _add_shapes(
    links: list[Link],
    flange_xyz: Vec,
    housing: Sequence[tuple[float, float]],
    bone_radius: Sequence[float],
    base_bone: float,
    colours: tuple[str, str],
) -> None:
    """A housing around each joint's axis, a bone from each joint to the next, a flange disc."""
    light, dark = colours
    nexts = [link.joint_xyz for link in links[1:]] + [flange_xyz]
    for i, link in enumerate(links):
        if i == 0:
            bone = _bone("column", nexts[0], base_bone, light)
            link.shapes.append(
                Cylinder("plate", (0.0, 0.0, 0.01), (0.0, 0.0, 0.0), 0.1, 0.02, dark)
            )
        else:
            r, length = housing[i - 1]
            link.shapes.append(
                Cylinder(f"housing{i}", (0.0, 0.0, 0.0), (0.0, 0.0, 0.0), r, length, dark)
            )
            bone = _bone(f"bone{i}", nexts[i], bone_radius[i - 1], light)
        if bone is not None:
            link.shapes.append(bone)
    links[-1].shapes.append(
        Cylinder("flange_disc", _snap(flange_xyz), (0.0, 0.0, 0.0), 0.0315, 0.01, dark)
    )


def ur5_arm() -> Arm:
    """The UR5 from ``kali_daemons.robots.ur5.facts`` (standard DH)."""
    n = ur5.NJOINTS
    links = [Link("base_link")]
    for i in range(n):
        link = Link(f"link{i + 1}")
        if i > 0:
            link.joint_xyz = _snap((ur5.A[i - 1], 0.0, ur5.D[i - 1]))
            link.joint_rpy = (float(ur5.ALPHA[i - 1]), 0.0, 0.0)
        t = np.array([ur5.A[i], 0.0, ur5.D[i]])
        alpha = float(ur5.ALPHA[i])
        ixx, iyy, izz = (float(v) for v in ur5.INERTIA[i])
        link.inertial = Inertial(
            float(ur5.MASS[i]),
            _snap(t + _rx(alpha) @ ur5.COM[i]),
            (alpha, 0.0, 0.0),
            (ixx, iyy, izz, 0.0, 0.0, 0.0),
        )
        links.append(link)
    flange_xyz = _snap((ur5.A[n - 1], 0.0, ur5.D[n - 1]))
    _add_shapes(
        links,
        flange_xyz,
        housing=[(0.06, 0.13)] * 3 + [(0.045, 0.1)] * 3,
        bone_radius=[0.06, 0.045, 0.04, 0.04, 0.04, 0.035],
        base_bone=0.06,
        colours=("ur_blue", "ur_grey"),
    )
    return Arm(
        name="ur5",
        comment="UR5, standard DH (UR's table), cylinder inertias:\n"
        "     kali_daemons/robots/ur5/facts.py",
        path=ur5.URDF_PATH,
        links=links,
        flange_xyz=flange_xyz,
        flange_rpy=(float(ur5.ALPHA[n - 1]), 0.0, 0.0),
        q_min=ur5.Q_MIN,
        q_max=ur5.Q_MAX,
        effort=ur5.PEAK_JOINT_TORQUE,
        velocity=ur5.MAX_JOINT_SPEED,
        materials={"ur_blue": (0.55, 0.7, 0.85, 1.0), "ur_grey": (0.3, 0.32, 0.35, 1.0)},
    )


def panda_arm() -> Arm:
    """The Panda from ``kali_daemons.robots.panda.facts`` (modified DH)."""
    links = [Link("base_link")]
    for i in range(panda.NJOINTS):
        alpha, a, d = float(panda.ALPHA[i]), float(panda.A[i]), float(panda.D[i])
        ixx, iyy, izz, ixy, ixz, iyz = (float(v) for v in panda.INERTIA[i])
        links.append(
            Link(
                f"link{i + 1}",
                joint_xyz=_snap((a, -d * math.sin(alpha), d * math.cos(alpha))),
                joint_rpy=(alpha, 0.0, 0.0),
                inertial=Inertial(
                    float(panda.MASS[i]),
                    _snap(panda.COM[i]),
                    (0.0, 0.0, 0.0),
                    (ixx, iyy, izz, ixy, ixz, iyz),
                ),
            )
        )
    flange_xyz = (0.0, 0.0, panda.D_FLANGE)
    _add_shapes(
        links,
        flange_xyz,
        housing=[(0.06, 0.12)] * 4 + [(0.05, 0.1)] * 3,
        bone_radius=[0.06, 0.06, 0.05, 0.05, 0.045, 0.045, 0.04],
        base_bone=0.07,
        colours=("panda_white", "panda_dark"),
    )
    return Arm(
        name="panda",
        comment="Franka Emika Panda, modified DH (Franka's table), Gaz et al. 2019 "
        "inertials:\n     kali_daemons/robots/panda/facts.py",
        path=panda.URDF_PATH,
        links=links,
        flange_xyz=flange_xyz,
        flange_rpy=(0.0, 0.0, 0.0),
        q_min=panda.Q_MIN,
        q_max=panda.Q_MAX,
        effort=panda.PEAK_JOINT_TORQUE,
        velocity=panda.MAX_JOINT_SPEED,
        materials={"panda_white": (0.92, 0.92, 0.9, 1.0), "panda_dark": (0.2, 0.2, 0.22, 1.0)},
    )


ARMS = {"ur5": ur5_arm, "panda": panda_arm}


def _shape_xml(shape: Cylinder, tag: str) -> list[str]:
    suffix = "" if tag == "visual" else "_collision"  # MuJoCo wants unique geom names
    lines = [
        f'    <{tag} name="{shape.name}{suffix}">',
        f"      {_origin(shape.xyz, shape.rpy)}",
        f'      <geometry><cylinder radius="{_num(shape.radius)}" '
        f'length="{_num(shape.length)}"/></geometry>',
    ]
    if tag == "visual":
        lines.append(f'      <material name="{shape.material}"/>')
    lines.append(f"    </{tag}>")
    return lines


def _link_xml(link: Link) -> list[str]:
    lines = [f'  <link name="{link.name}">']
    if link.inertial is not None:
        m = link.inertial
        ixx, iyy, izz, ixy, ixz, iyz = m.inertia
        lines += [
            "    <inertial>",
            f"      {_origin(m.xyz, m.rpy)}",
            f'      <mass value="{_num(m.mass)}"/>',
            f'      <inertia ixx="{_num(ixx)}" ixy="{_num(ixy)}" ixz="{_num(ixz)}"'
            f' iyy="{_num(iyy)}" iyz="{_num(iyz)}" izz="{_num(izz)}"/>',
            "    </inertial>",
        ]
    for shape in link.shapes:
        lines += _shape_xml(shape, "visual")
    for shape in link.shapes:
        lines += _shape_xml(shape, "collision")
    lines.append("  </link>")
    return lines


def generate(arm: Arm) -> str:
    """The whole URDF text of ``arm``."""
    script = Path(__file__).name
    out = [
        '<?xml version="1.0"?>',
        f"<!-- {arm.comment}.",
        f"     GENERATED by scripts/{script} from the facts; do not edit.",
        f"     Joints j1..j{len(arm.links) - 1} turn about z; flange is the mounting flange.",
        "     Rotor inertia (armature) is not here: the loaders set it. -->",
        f'<robot name="{arm.name}">',
        "  <mujoco>",
        '    <compiler discardvisual="false" fusestatic="false"/>',
        "  </mujoco>",
    ]
    for name, rgba in arm.materials.items():
        out.append(f'  <material name="{name}"><color rgba="{_vec(rgba)}"/></material>')
    out += _link_xml(arm.links[0])
    for i, link in enumerate(arm.links[1:]):
        out += [
            f'  <joint name="j{i + 1}" type="revolute">',
            f'    <parent link="{arm.links[i].name}"/>',
            f'    <child link="{link.name}"/>',
            f"    {_origin(link.joint_xyz, link.joint_rpy)}",
            '    <axis xyz="0 0 1"/>',
            f'    <limit lower="{_num(arm.q_min[i])}" upper="{_num(arm.q_max[i])}"'
            f' effort="{_num(round(float(arm.effort[i]), 3))}"'
            f' velocity="{_num(round(float(arm.velocity[i]), 3))}"/>',
            "  </joint>",
        ]
        out += _link_xml(link)
    out += [
        '  <joint name="flange_joint" type="fixed">',
        f'    <parent link="{arm.links[-1].name}"/>',
        '    <child link="flange"/>',
        f"    {_origin(arm.flange_xyz, arm.flange_rpy)}",
        "  </joint>",
        '  <link name="flange"/>',
        "</robot>",
    ]
    return "\n".join(out) + "\n"


def _check(path: Path, text: str) -> bool:
    try:
        current = path.read_text(encoding="utf-8")
    except OSError as exc:
        print(f"{path}: cannot read: {exc.strerror}", file=sys.stderr)
        return False
    if current == text:
        print(f"{path}: up to date")
        return True
    diff = difflib.unified_diff(
        current.splitlines(keepends=True),
        text.splitlines(keepends=True),
        fromfile=f"{path} (committed)",
        tofile=f"{path} (generated)",
        n=1,
    )
    sys.stderr.writelines(list(diff)[:60])
    print(f"{path}: stale; run scripts/{Path(__file__).name}", file=sys.stderr)
    return False


def main(argv: list[str] | None = None) -> int:
    """Write the URDFs, or with ``--check`` report whether the committed ones are current."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("robots", nargs="*", help=f"any of {', '.join(ARMS)} (default: all)")
    parser.add_argument("--check", action="store_true", help="exit 1 if a file is stale")
    parser.add_argument(
        "--output-dir", type=Path, help="write there, not beside the facts"
    )
    args = parser.parse_args(argv)
    unknown = sorted(set(args.robots) - set(ARMS))
    if unknown:
        parser.error(f"no generator for {', '.join(unknown)} (known: {', '.join(ARMS)})")
    ok = True
    for name in args.robots or list(ARMS):
        arm = ARMS[name]()
        path = arm.path if args.output_dir is None else args.output_dir / arm.path.name
        text = generate(arm)
        if args.check:
            ok = _check(path, text) and ok
        else:
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path}")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
