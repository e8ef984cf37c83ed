"""Robot program: both arms pick up the bar from the stand, carry it and put it back.

    kalictl start && kalictl run scripts/example_carry.py

The two arms are one motion system: the program moves the bar, and each arm's T6 follows
as B⁻¹ · bar · grasp (DESIGN 5).  The bar and its grasps (where each flange holds it, in
the bar's frame) are the scene's (``kali.scene``, config/scenes/default.yaml).
"""

import numpy as np

from kali_daemons.client import Kali
from kali_daemons.robots.puma560 import kinematics

LIFT = 0.08  # m
SHIFT = 0.06  # m, sideways while lifted

with Kali() as kali:
    kali.ready(["left", "right"])
    arms = [kali.robot(name) for name in ("left", "right")]
    for arm in arms:  # the dynamics process's torques: the arms follow closer, squeeze less
        arm.feedforward("full")
    on_stand = kali.scene.object("bar").pose  # where the scene puts it
    grasps = [kali.scene.grasp_for("bar", kali.inst.config.robots[a.index]) for a in arms]
    sites = [on_stand @ g for g in grasps]  # where each flange must be to grip
    # 1. each arm to 5 cm above its grasp site, in its grasping configuration ('run')
    moves = []
    for arm, site in zip(arms, sites, strict=True):
        above = site.copy()
        above[2, 3] += 0.05
        q = kinematics.ikine(np.linalg.inv(arm.base) @ above, "run", q_ref=arm.read_joints())
        moves.append(arm.move_joints(q, speed=0.5, wait=False))
    for m in moves:
        m.wait(timeout=30)
    # 2. straight down onto the sites, then close both grippers
    moves = [
        arm.move_line(site, speed=0.05, wait=False) for arm, site in zip(arms, sites, strict=True)
    ]
    for m in moves:
        m.wait(timeout=30)
    for arm in arms:  # there, not on the way (DONE: the last set-point is demanded)
        arm.settle()
    for arm in arms:
        arm.grip(True)
    # 3. the bar as one motion system: up, across, back, down
    bar = kali.motion_system(["left", "right"], holding="bar")
    here = bar.read_pose()
    up, over = here.copy(), here.copy()
    up[2, 3] += LIFT
    over[2, 3] += LIFT
    over[1, 3] += SHIFT
    bar.move_path([up, over, up, here], speed=0.08, transition_s=0.2)
    for arm in arms:
        arm.grip(False)
    at = bar.read_pose()[:3, 3]
    print(f"bar carried and put back at ({at[0]:.3f}, {at[1]:.3f}, {at[2]:.3f}) m")
