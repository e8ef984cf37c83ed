"""Generate the PUMA's URDF (``robots/puma560/puma560.urdf``) from its facts
(``kali_daemons/robots/puma560/facts.py``).

    .venv/bin/python scripts/gen_puma560_urdf.py            # (re)write robots/puma560/puma560.urdf
    .venv/bin/python scripts/gen_puma560_urdf.py --check    # exit 1 if the file is stale

Standard DH to URDF.  A URDF joint moves its child by ``origin · Rz(q)`` while a DH link
transform is ``Rz(θ_i) · M_i`` with ``M_i = Tz(d_i)·Tx(a_i)·Rx(α_i)``, rotation first.  So
URDF link ``i`` is DH frame ``i-1`` turned by θ_i (its z is joint i's axis), joint ``j<i>``'s
origin is the previous link's constant part ``M_{i-1}`` (identity for j1), and DH frame ``i``
sits at ``M_i`` in URDF link ``i``.  The fixed joint to ``flange`` is ``M_6``, so the
``flange`` frame is DH frame 6, the toolbox's ``fkine``.  Each link's inertial (centre of mass
and principal inertia about it, given in DH frame i) is placed with ``M_i`` composed with the
COM offset; the values are the adjusted ones (``puma560.MASS``, ``puma560.INERTIA``).

Geometry is cylinders, boxes and spheres (URDF has no capsule) so that Pinocchio and MuJoCo
both load it; ``<visual>`` and ``<collision>`` carry the same shapes.  The ``<mujoco>``
extension keeps MuJoCo from discarding the coloured visuals and from fusing the massless
``flange`` link into ``link6``; urdfdom (Pinocchio) ignores it.  Rotor inertia is not in the
file: neither loader reads armature from URDF, ``kali_daemons.robots.model`` sets it on both.

The output is deterministic (shortest round-trip float text, fixed order), so ``--check``
can compare it byte for byte with the committed file.
"""

from __future__ import annotations

import argparse
import difflib
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from kali_daemons.robots import puma560

CREAM = (0.89, 0.86, 0.78, 1.0)
DARK = (0.22, 0.22, 0.25, 1.0)
STEEL = (0.62, 0.63, 0.67, 1.0)
MATERIALS = {"puma_cream": CREAM, "puma_dark": DARK, "puma_steel": STEEL}

# Rotations that turn a cylinder's own z axis onto the link frame's x or y axis.
ALONG_X = (0.0, math.pi / 2, 0.0)
ALONG_Y = (-math.pi / 2, 0.0, 0.0)
ALONG_Z = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class Shape:
    """One primitive, in its link's URDF frame: ``kind`` box (size), cylinder (r, length)."""

    name: str
    kind: str  # "box", "cylinder" or "sphere"
    dims: tuple[float, ...]
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    material: str


def _geometry() -> dict[str, list[Shape]]:
    """A recognisable PUMA in each URDF link's frame (see the module docstring for frames).

    The numbers follow the DH lengths: the shoulder axis at d1, the upper arm beside it along
    a2 at the side its centre of mass says (z2 ≈ 0.23), the forearm at the d3 = 0.15 offset
    running d4 to the wrist centre, a small wrist and a flange disc beyond it.
    """
    d1, a2, d3, a3, d4 = puma560.D[0], puma560.A[1], puma560.D[2], puma560.A[2], puma560.D[3]
    arm_z = 0.23  # the upper arm's plane along the shoulder axis (its COM is at 0.2275)
    return {
        "base_link": [
            Shape("plate", "box", (0.36, 0.36, 0.03), (0.0, 0.0, 0.015), ALONG_Z, "puma_dark"),
            Shape("pedestal", "cylinder", (0.1, 0.5), (0.0, 0.0, 0.28), ALONG_Z, "puma_cream"),
        ],
        "link1": [
            Shape("trunk", "cylinder", (0.09, 0.12), (0.0, 0.0, 0.59), ALONG_Z, "puma_dark"),
            # the joint-2 axis is -y here (Rx(+90°) turns z1 onto -y)
            Shape("shoulder", "cylinder", (0.1, 0.2), (0.0, 0.0, d1), ALONG_Y, "puma_cream"),
        ],
        "link2": [
            Shape("hub", "cylinder", (0.085, 0.1), (0.0, 0.0, 0.15), ALONG_Z, "puma_cream"),
            Shape(
                "upper_arm",
                "box",
                (a2 + 0.16, 0.14, 0.07),
                (a2 / 2, 0.0, arm_z),
                ALONG_Z,
                "puma_cream",
            ),
        ],
        "link3": [
            Shape("elbow", "cylinder", (0.065, 0.1), (0.0, 0.0, d3), ALONG_Z, "puma_dark"),
            # the forearm runs along +y here (Rx(-90°) turns z3 onto +y), d3 off the arm
            Shape("forearm", "cylinder", (0.05, 0.31), (a3, 0.095, d3), ALONG_Y, "puma_cream"),
        ],
        "link4": [
            Shape("wrist_roll", "cylinder", (0.042, 0.14), (0.0, 0.0, 0.32), ALONG_Z, "puma_cream"),
            Shape("fork", "box", (0.05, 0.1, 0.04), (0.0, 0.0, d4 - 0.05), ALONG_Z, "puma_dark"),
        ],
        "link5": [
            Shape("wrist", "cylinder", (0.04, 0.09), (0.0, 0.0, 0.0), ALONG_Z, "puma_dark"),
        ],
        "link6": [
            Shape("stalk", "cylinder", (0.02, 0.03), (0.0, 0.0, 0.025), ALONG_Z, "puma_steel"),
            Shape("flange", "cylinder", (0.032, 0.01), (0.0, 0.0, 0.04), ALONG_Z, "puma_steel"),
        ],
    }


def _num(x: float) -> str:
    """Shortest text that reads back as the same double; no '-0'."""
    x = float(x)
    if x == 0.0:
        return "0"
    if x == int(x) and abs(x) < 1e15:
        return str(int(x))
    return repr(x)


def _vec(v: tuple[float, ...] | np.ndarray) -> str:
    return " ".join(_num(x) for x in v)


def _dh_constant(i: int) -> tuple[np.ndarray, float]:
    """``M_i = Tz(d)·Tx(a)·Rx(α)`` of joint index ``i`` (0-based) as (translation, α)."""
    return np.array([puma560.A[i], 0.0, puma560.D[i]]), float(puma560.ALPHA[i])


def _rx(alpha: float) -> np.ndarray:
    c, s = math.cos(alpha), math.sin(alpha)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def _origin(xyz: tuple[float, ...] | np.ndarray, rpy: tuple[float, ...]) -> str:
    return f'<origin xyz="{_vec(xyz)}" rpy="{_vec(rpy)}"/>'


def _shape_xml(shape: Shape, tag: str) -> list[str]:
    if shape.kind == "box":
        geom = f'<box size="{_vec(shape.dims)}"/>'
    elif shape.kind == "cylinder":
        geom = f'<cylinder radius="{_num(shape.dims[0])}" length="{_num(shape.dims[1])}"/>'
    else:
        geom = f'<sphere radius="{_num(shape.dims[0])}"/>'
    suffix = "" if tag == "visual" else "_collision"  # MuJoCo wants unique geom names
    lines = [
        f'    <{tag} name="{shape.name}{suffix}">',
        f"      {_origin(shape.xyz, shape.rpy)}",
        f"      <geometry>{geom}</geometry>",
    ]
    if tag == "visual":
        lines.append(f'      <material name="{shape.material}"/>')
    lines.append(f"    </{tag}>")
    return lines


def _link_xml(name: str, index: int | None, shapes: list[Shape]) -> list[str]:
    """A ``<link>``; ``index`` (0-based joint index) gives it the inertial of that DH link."""
    lines = [f'  <link name="{name}">']
    if index is not None:
        t, alpha = _dh_constant(index)
        com = t + _rx(alpha) @ puma560.COM[index]  # COM in this URDF link frame
        ixx, iyy, izz = puma560.INERTIA[index]
        lines += [
            "    <inertial>",
            f"      {_origin(com, (alpha, 0.0, 0.0))}",
            f'      <mass value="{_num(puma560.MASS[index])}"/>',
            f'      <inertia ixx="{_num(ixx)}" ixy="0" ixz="0" iyy="{_num(iyy)}" iyz="0"'
            f' izz="{_num(izz)}"/>',
            "    </inertial>",
        ]
    for shape in shapes:
        lines += _shape_xml(shape, "visual")
    for shape in shapes:
        lines += _shape_xml(shape, "collision")
    lines.append("  </link>")
    return lines


def generate() -> str:
    """The whole URDF text."""
    geometry = _geometry()
    out = [
        '<?xml version="1.0"?>',
        "<!-- PUMA 560, standard DH with pedestal (d1 = 0.6718 m), inertias as adjusted in its",
        "     facts (robots/puma560/facts.py).  GENERATED by scripts/gen_puma560_urdf.py; do not",
        "     edit.",
        "     URDF link i is DH frame i-1 turned by joint i; flange is DH frame 6.  Rotor",
        "     inertia (armature) is not here: robots/model.py sets it on both loaders. -->",
        '<robot name="puma560">',
        "  <mujoco>",
        '    <compiler discardvisual="false" fusestatic="false"/>',
        "  </mujoco>",
    ]
    for name, rgba in MATERIALS.items():
        out.append(f'  <material name="{name}"><color rgba="{_vec(rgba)}"/></material>')
    out += _link_xml("base_link", None, geometry["base_link"])
    parent = "base_link"
    for i in range(puma560.NJOINTS):
        link = f"link{i + 1}"
        if i == 0:
            xyz, rpy = np.zeros(3), (0.0, 0.0, 0.0)
        else:
            t, alpha = _dh_constant(i - 1)
            xyz, rpy = t, (alpha, 0.0, 0.0)
        out += [
            f'  <joint name="j{i + 1}" type="revolute">',
            f'    <parent link="{parent}"/>',
            f'    <child link="{link}"/>',
            f"    {_origin(xyz, rpy)}",
            '    <axis xyz="0 0 1"/>',
            f'    <limit lower="{_num(puma560.Q_MIN[i])}" upper="{_num(puma560.Q_MAX[i])}"'
            f' effort="{_num(round(puma560.PEAK_JOINT_TORQUE[i], 3))}"'
            f' velocity="{_num(round(puma560.MAX_JOINT_SPEED[i], 3))}"/>',
            "  </joint>",
        ]
        out += _link_xml(link, i, geometry[link])
        parent = link
    t, alpha = _dh_constant(puma560.NJOINTS - 1)
    out += [
        '  <joint name="flange_joint" type="fixed">',
        '    <parent link="link6"/>',
        '    <child link="flange"/>',
        f"    {_origin(t, (alpha, 0.0, 0.0))}",
        "  </joint>",
        '  <link name="flange"/>',
        "</robot>",
    ]
    return "\n".join(out) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Write the URDF, or with ``--check`` report whether the committed one is current."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the file is stale")
    parser.add_argument("--output", type=Path, default=puma560.URDF_PATH, help="the URDF to write")
    args = parser.parse_args(argv)
    text = generate()
    if args.check:
        try:
            current = args.output.read_text(encoding="utf-8")
        except OSError as exc:
            print(f"{args.output}: cannot read: {exc.strerror}", file=sys.stderr)
            return 1
        if current == text:
            print(f"{args.output}: up to date")
            return 0
        diff = difflib.unified_diff(
            current.splitlines(keepends=True),
            text.splitlines(keepends=True),
            fromfile=f"{args.output} (committed)",
            tofile=f"{args.output} (generated)",
            n=1,
        )
        sys.stderr.writelines(list(diff)[:60])
        print(f"{args.output}: stale; run scripts/gen_puma560_urdf.py", file=sys.stderr)
        return 1
    args.output.write_text(text, encoding="utf-8")
    print(f"wrote {args.output}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
