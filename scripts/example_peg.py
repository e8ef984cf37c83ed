"""Robot program: the left arm puts a peg in the hole of a plate it finds with the camera, by
sight and feel (thesis 2.1).

    kalictl start -c config/peg.yaml && kalictl -i peg run scripts/example_peg.py
    kalictl -i peg run scripts/example_peg.py -- --aside 2   # aim 2 mm off: watch it search
    kalictl -i peg run scripts/example_peg.py -- --leave     # and leave the peg in the hole

The plate lies somewhere on the table, turned some way (config/scenes/peg.yaml, one of the
worlds kali_daemons/examples/peg.py writes); the program knows its colour and the peg, not
where the plate is.  It finds the hole in the camera looking down on the table (numpy only:
the plate's colour, and the depth where the hole shows the table 2 cm below the plate's top),
picks the peg up, carries it over the hole, comes down with a guard until the peg is just
above the plate, and then inserts it under the Cartesian impedance servo, compliant across and
pressing down: if the peg lands on the plate's top rather than in the hole it searches in a
spiral until it drops in.  The hole is 0.5 mm wider than the peg on every side.  Then it draws
the peg out and stands it back where it was (``--leave``: leaves it in), the arm back where it
started, out of the camera's view.
"""

from __future__ import annotations

import argparse

import numpy as np

from kali_daemons.client import Kali, pose
from kali_daemons.examples.peg import PEG_LENGTH_M, PLATE_THICK_M
from kali_daemons.hardware.camera import Frame

RED_SHARE = 0.42  # a plate pixel's red of its red, green and blue (lit, the table's is 0.35)
HOVER_M = 0.01  # the peg's end this far over the plate before it goes in
INSERT_M = 0.015  # how deep the peg goes
PRESS_N = 4.0  # pressing down while it goes in (N, along the tool's z)
# compliant across (the hole's sides guide it), stiff enough along z to follow the demand
INSERTING = {"kx": 300.0, "ky": 300.0, "kz": 1000.0, "dx": 60.0, "dy": 60.0, "fz": PRESS_N}
SPIRAL_PITCH_M = 0.0006  # the search spiral's step out a turn: under the 1 mm of play
SPIRAL_M = 0.004  # how far out it searches
SPIRAL_STEP_M = 0.0005  # between the spiral's points
DROPPED_M = 0.004  # the peg's end this far under the plate's top: it is in the hole


def find_hole(frame: Frame) -> tuple[np.ndarray, float]:
    """The hole's centre (x, y, m, world) and the plate's top (z, m) in ``frame``: the plate's
    pixels by colour, the hole those inside the plate that are not the plate's and lie deeper
    than its top (the table shows through)."""
    rgb = frame.image.astype(float)
    red = rgb[..., 0] / (rgb.sum(axis=2) + 1e-9)  # the plate is the red thing in the cell
    plate = red > RED_SHARE
    if plate.sum() < 100:
        raise SystemExit("no plate in the camera's view (is an arm between it and the table?)")
    top = float(np.median(frame.depth[plate]))
    # inside the plate: plate pixels on both sides along its row and along its column
    inside = np.ones_like(plate)
    for axis in (0, 1):
        before = np.cumsum(plate, axis=axis) > 0
        after = np.flip(np.cumsum(np.flip(plate, axis), axis=axis), axis) > 0
        inside &= before & after
    hole = inside & ~plate & (frame.depth > top + PLATE_THICK_M / 2.0)
    if hole.sum() < 10:
        raise SystemExit("no hole in the plate")
    v, u = np.nonzero(hole)
    uv = np.array([u.mean() + 0.5, v.mean() + 0.5, 1.0])
    in_camera = np.linalg.solve(frame.K, uv) * top  # the hole's centre at the plate's top
    world = frame.pose @ np.append(in_camera, 1.0)
    return world[:2], float(world[2])


parser = argparse.ArgumentParser(description="the peg in the hole, by sight and feel")
parser.add_argument(
    "--aside",
    type=float,
    default=0.0,
    help="aim this far (mm, along x) off the hole seen, as a worse camera would: the search "
    "then finds the hole",
)
parser.add_argument(
    "--leave", action="store_true", help="leave the peg in the hole (else it is put back)"
)
args = parser.parse_args()

with Kali() as kali:
    kali.ready(["left"])
    arm = kali.robot("left")
    start = arm.read_joints()
    camera = kali.camera("above")
    here = int(kali.inst.clock["tick"])
    centre, plate_top = find_hole(camera.read(since_tick=here))
    print(f"hole seen at ({centre[0]:.4f}, {centre[1]:.4f}) m, the plate's top {plate_top:.4f} m")
    centre = centre + np.array([args.aside / 1000.0, 0.0])

    # pick the peg up where it stands (the program's own part: it knows where)
    scene, me = kali.scene, kali.inst.config.robots[arm.index]
    grasp = scene.grasp_for("peg", me)  # the flange in the peg's frame
    site = scene.object("peg").pose @ grasp
    above = site @ pose([0.0, 0.0, -0.05])  # 5 cm up along the flange's -z (tool down)
    arm.move_joints(arm.joints_at(above, "run"), speed=0.5)
    arm.move_line(site, speed=0.05)
    kali.sleep(0.3)
    arm.grip(True, holding="peg")
    arm.move_line(above, speed=0.05)

    # over the hole, the peg's end HOVER_M over the plate
    def flange_over(depth: float) -> np.ndarray:
        """The flange when the peg's end is ``depth`` under the plate's top at the hole."""
        peg = pose([centre[0], centre[1], plate_top - depth + PEG_LENGTH_M / 2.0])
        return peg @ grasp

    arm.move_line(flange_over(-0.03), speed=0.1)
    arm.tare()  # the peg hanging still, touching nothing
    touch = arm.move_line(flange_over(-HOVER_M), speed=0.01, guard=3.0)
    if touch.contact is not None:
        raise SystemExit(f"touched something {HOVER_M * 1000:g} mm over the plate: {touch.contact}")

    # in, compliant: the impedance servo presses down; a line down INSERT_M
    found = arm.servo_params("impedance")
    arm.set_servo(INSERTING, "impedance")
    arm.select_servo("impedance")
    kali.sleep(0.3)

    def end_depth() -> float:
        """How far the peg's end is under the plate's top, by the flange's pose."""
        peg = arm.read_pose() @ np.linalg.inv(grasp)
        return plate_top - (peg[2, 3] - PEG_LENGTH_M / 2.0)

    def down_here() -> None:
        """A line straight down from where the peg is to INSERT_M deep."""
        target = arm.read_pose()
        target[2, 3] = flange_over(INSERT_M)[2, 3]
        arm.move_line(target, speed=0.005, timeout=30)
        kali.sleep(0.5)

    down_here()
    searched = 0.0
    if end_depth() < DROPPED_M:  # on the plate's top: search in a spiral, pressing down
        on = arm.read_pose()
        # an Archimedean spiral r = b·θ, its points SPIRAL_STEP_M apart along it (the length
        # out to θ is about b·θ²/2)
        b = SPIRAL_PITCH_M / (2.0 * np.pi)
        along = np.arange(SPIRAL_STEP_M, SPIRAL_M**2 / (2.0 * b), SPIRAL_STEP_M)
        theta = np.sqrt(2.0 * along / b)
        ring = [
            pose(on[:3, 3] + [b * a * np.cos(a), b * a * np.sin(a), 0.0], on[:3, :3]) for a in theta
        ]
        search = arm.move_path(ring, speed=0.004, transition_s=0.05, wait=False)
        while not search.done and end_depth() < DROPPED_M:
            kali.pause()
        if not search.done:
            search.cancel()  # it dropped in: stop there
            while not search.done:
                kali.pause()
        searched = float(np.linalg.norm(arm.read_pose()[:2, 3] - on[:2, 3]))
        if end_depth() < DROPPED_M:
            arm.set_servo({"fz": 0.0})
            arm.select_servo("joints")
            raise SystemExit(f"no hole within {SPIRAL_M * 1000:g} mm of where the camera saw it")
        down_here()
    depth = end_depth()
    print(f"peg {depth * 1000:.1f} mm into the hole (searched {searched * 1000:.1f} mm aside)")

    arm.set_servo({"fz": 0.0})
    arm.select_servo("joints")
    arm.set_servo({name: found[name] for name in INSERTING}, "impedance")  # as it was
    if args.leave:
        arm.grip(False)
        arm.move_line(arm.read_pose() @ pose([0.0, 0.0, -0.05]), speed=0.05)  # up, peg left in
    else:  # drawn out and stood back where it was, so the program runs again
        out = arm.read_pose()
        out[2, 3] = flange_over(-0.03)[2, 3]
        arm.move_line(out, speed=0.02)
        arm.move_line(above, speed=0.1)
        arm.move_line(site, speed=0.05)
        arm.grip(False)
        arm.move_line(above, speed=0.05)
    arm.move_joints(start, speed=0.5)  # out of the camera's view
