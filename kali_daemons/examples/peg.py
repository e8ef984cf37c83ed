"""The peg-in-hole experiment's world (issue 56 item 5; thesis 2.1's insertion by sight and
feel): the table, a plate with a square hole 0.5 mm wider than the peg on every side placed
where a seed says, the peg standing on the table in the left arm's reach, and a camera looking
straight down on them.  ``scene(seed)`` is its scene file; ``config/scenes/peg.yaml`` is seed
0's (``python -m kali_daemons.examples.peg 0 > kali_daemons/config/scenes/peg.yaml``), and
``scripts/example_peg.py`` is the program that finds the hole and puts the peg in it.
"""

from __future__ import annotations

import math
import sys

import numpy as np

PEG_RADIUS_M = 0.01
PEG_LENGTH_M = 0.08
CLEARANCE_M = 0.0005  # between the peg and each side of the hole
HOLE_M = 2.0 * (PEG_RADIUS_M + CLEARANCE_M)  # the square hole's side
PLATE_M = 0.10  # the plate's side
PLATE_THICK_M = 0.02
TABLE_TOP_M = 0.40
PEG_AT = (-0.21, -0.30)  # where the peg stands (x, y; m, world)
# where a seed may put the plate's centre (m) and how it may be turned (degrees)
PLATE_X, PLATE_Y, PLATE_YAW = (-0.10, 0.02), (-0.44, -0.38), (0.0, 90.0)
PLATE_COLOR = (0.8, 0.15, 0.1)
CAMERA_AT = (-0.06, -0.40, 1.0)  # straight above the plate's range


def plate_pose(seed: int) -> tuple[float, float, float]:
    """Where seed ``seed`` puts the plate: its centre x, y (m) and yaw (degrees)."""
    rng = np.random.default_rng(seed)
    x, y, yaw = (float(rng.uniform(*r)) for r in (PLATE_X, PLATE_Y, PLATE_YAW))
    return round(x, 4), round(y, 4), round(yaw, 2)


def scene(seed: int) -> str:
    """The scene file's text with the plate where ``seed`` puts it: four fixed boxes around
    the hole."""
    x, y, yaw = plate_pose(seed)
    c, s = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))
    side, rim = (PLATE_M - HOLE_M) / 2.0, (PLATE_M + HOLE_M) / 4.0  # a rim's width, centre
    z = TABLE_TOP_M + PLATE_THICK_M / 2.0
    rims = [  # in the plate's frame: centre, size
        ((0.0, rim), (PLATE_M, side)),
        ((0.0, -rim), (PLATE_M, side)),
        ((rim, 0.0), (side, HOLE_M)),
        ((-rim, 0.0), (side, HOLE_M)),
    ]
    color = ", ".join(f"{v:g}" for v in PLATE_COLOR)
    lines = [
        f"# Kali scene file: the peg-in-hole experiment, seed {seed} (kali_daemons/examples/peg.py",
        "# wrote it; the format: default.yaml).  The plate's pose is the program's to find.",
        "version: 1",
        "objects:",
        "  - {name: table, shape: box, size: [0.5, 0.24, 0.40], at: [0.0, -0.38, 0.2], "
        "fixed: true, arms_touch: false, color: [0.62, 0.6, 0.55]}",
    ]
    for i, ((u, v), (a, b)) in enumerate(rims):
        at = (x + c * u - s * v, y + s * u + c * v, z)
        lines.append(
            f"  - {{name: plate_{i}, shape: box, size: [{a!r}, {b!r}, {PLATE_THICK_M!r}], "
            f"at: [{at[0]!r}, {at[1]!r}, {at[2]!r}], rpy_deg: [0, 0, {yaw!r}], "
            f"fixed: true, color: [{color}]}}"
        )
    top = PEG_LENGTH_M / 2.0 + 0.045  # the flange 4.5 cm over the peg's top, tool down
    lines += [
        f"  - name: peg\n    shape: cylinder\n    size: [{PEG_RADIUS_M:g}, {PEG_LENGTH_M:g}]\n"
        f"    at: [{PEG_AT[0]:g}, {PEG_AT[1]:g}, {TABLE_TOP_M + PEG_LENGTH_M / 2.0:g}]\n"
        "    mass: 0.1\n    color: [0.2, 0.4, 0.8]\n"
        f"    grasps:\n      - {{name: top, at: [0.0, 0.0, {top:g}], rpy_deg: [180, 0, 0]}}",
        "cameras:",
        f"  - {{name: above, at: [{CAMERA_AT[0]:g}, {CAMERA_AT[1]:g}, {CAMERA_AT[2]:g}], "
        f"look_at: [{CAMERA_AT[0]:g}, {CAMERA_AT[1]:g}, {TABLE_TOP_M:g}], fovy_deg: 45, "
        "width: 640, height: 480, rate_hz: 2}",
    ]
    return "\n".join(lines) + "\n"


if __name__ == "__main__":  # python -m kali_daemons.examples.peg SEED: the scene on stdout
    sys.stdout.write(scene(int(sys.argv[1]) if len(sys.argv) > 1 else 0))
