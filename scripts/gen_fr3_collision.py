"""Write the FR3's collision shapes into ``robots/fr3/fr3.urdf``: one cylinder per link
around franky-sim's collision mesh of that link (the FR3 simulator's, from franka_description;
Apache-2.0, NOTICE beside the URDF), so the controller's collision model (``robots.collision``)
checks FR3 cells as it checks the others.

    .venv/bin/python scripts/gen_fr3_collision.py           # (re)write the <collision> elements
    .venv/bin/python scripts/gen_fr3_collision.py --check   # exit 1 if the file is stale

Each cylinder holds every vertex of its mesh: its axis the mesh's principal axis (the
vertices' largest spread) through the centre of their extent across it, its length their extent
along it, its radius the farthest vertex from the axis, rounded up to the millimetre.  The
meshes are read from franky-sim's MJCF (``assets/fr3.xml``, compiled by MuJoCo): its body
``fr3_link<i>`` is the URDF's link ``link<i>`` (``base_link`` for link 0), frame for frame.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path

import mujoco
import numpy as np

URDF = Path(__file__).resolve().parent.parent / "kali_daemons" / "robots" / "fr3" / "fr3.urdf"
MM = 1000.0


def franky_model() -> mujoco.MjModel:
    """franky-sim's FR3, compiled (its meshes beside the MJCF, in ``meshes/``)."""
    import franky_sim

    assets = Path(franky_sim.__file__).parent / "assets"
    spec = mujoco.MjSpec.from_file(str(assets / "fr3.xml"))
    spec.meshdir = str(assets / "meshes")
    return spec.compile()


def link_vertices(model: mujoco.MjModel, link: int) -> np.ndarray:
    """Link ``link``'s collision-mesh vertices in its body's frame (n × 3, m)."""
    g = model.geom(f"fr3_link{link}_collision")
    mesh = int(g.dataid[0])
    start, count = int(model.mesh_vertadr[mesh]), int(model.mesh_vertnum[mesh])
    local = model.mesh_vert[start : start + count]
    rotation = np.empty(9)
    mujoco.mju_quat2Mat(rotation, g.quat)
    return local @ rotation.reshape(3, 3).T + g.pos


def fit(points: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The smallest of the cylinders holding ``points`` along the link frame's axes and the
    points' principal axis: its centre, unit axis, length and radius (m)."""
    centred = points - points.mean(axis=0)
    principal = np.linalg.svd(centred, full_matrices=False)[2][0]
    fits = [around(points, axis) for axis in (*np.eye(3), principal)]
    return min(fits, key=lambda f: f[3] ** 2 * f[2])


def around(points: np.ndarray, axis: np.ndarray) -> tuple[np.ndarray, np.ndarray, float, float]:
    """The cylinder along ``axis`` holding ``points``: its axis through the middle of their
    extent across it (along two directions perpendicular to it)."""
    along = points @ axis
    across = points - np.outer(along, axis)
    u = np.cross(axis, [1.0, 0.0, 0.0] if abs(axis[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    v = np.cross(axis, u)
    a, b = across @ u, across @ v
    mid = u * (a.max() + a.min()) / 2.0 + v * (b.max() + b.min()) / 2.0
    centre = mid + axis * (along.max() + along.min()) / 2.0
    radius = float(np.linalg.norm(across - mid, axis=1).max())
    length = float(along.max() - along.min())
    # up to the next millimetre past a millimetre's margin: the written centre and turn are
    # rounded (to 0.1 mm, 0.1 mrad)
    length = math.ceil((length + 0.002) * MM) / MM
    return centre, axis, length, math.ceil((radius + 0.001) * MM) / MM


def rpy_of(axis: np.ndarray) -> tuple[float, float, float]:
    """Roll, pitch, yaw (URDF's fixed x, y, z) turning z onto ``axis``."""
    a = axis / np.linalg.norm(axis)
    pitch = math.atan2(math.hypot(a[0], a[1]), a[2])
    yaw = math.atan2(a[1], a[0])
    return 0.0, pitch, yaw


def collision_xml(link: int, model: mujoco.MjModel) -> str:
    centre, axis, length, radius = fit(link_vertices(model, link))
    rpy = rpy_of(axis)
    xyz = " ".join(f"{round(c, 4):g}" for c in centre)
    turn = " ".join(f"{round(r, 4):g}" for r in rpy)
    return (
        f'    <collision name="link{link}_collision">\n'
        f'      <origin xyz="{xyz}" rpy="{turn}"/>\n'
        f'      <geometry><cylinder radius="{radius:g}" length="{length:g}"/></geometry>\n'
        "    </collision>\n"
    )


def generate(text: str) -> str:
    """``text`` (the URDF) with each link's <collision> written after its <inertial>."""
    model = franky_model()
    text = re.sub(
        r"    <collision name=\"link\d_collision\">.*?</collision>\n", "", text, flags=re.S
    )
    for link in range(8):
        name = "base_link" if link == 0 else f"link{link}"
        m = re.search(rf'<link name="{name}">.*?</inertial>\n', text, flags=re.S)
        assert m, name
        text = text[: m.end()] + collision_xml(link, model) + text[m.end() :]
    return text


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="exit 1 if the file is stale")
    args = parser.parse_args(argv)
    old = URDF.read_text()
    new = generate(old)
    if args.check:
        if new != old:
            print(f"{URDF}: stale; run scripts/gen_fr3_collision.py", file=sys.stderr)
            return 1
        return 0
    URDF.write_text(new)
    return 0


if __name__ == "__main__":
    sys.exit(main())
