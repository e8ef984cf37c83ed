"""Robot program: both arms pick up the bar, carry it squeezing it with a regulated 20 N and
put it back.

    kalictl start -c config/force.yaml && kalictl -i force run scripts/example_squeeze.py

The carry of example_carry.py, with the squeeze along the line between the two grasps
regulated from both wrist sensors (``MotionSystem.set_internal_force``, issue 27): each arm
runs the Cartesian impedance servo (``robot_servos: true`` in config/force.yaml) and pushes
towards the other by the set squeeze plus equal and opposite corrections of the squeeze both
sensors measure.  On their position servos alone the two arms squeeze the bar with whatever
their servo errors make, 19-66 N.  The program prints the squeeze its sensors measured.
"""

import numpy as np

from kali_daemons.client import Kali
from kali_daemons.robots.puma560 import kinematics

LIFT = 0.08  # m
SHIFT = 0.06  # m, sideways while lifted
SQUEEZE = 20.0  # N
SET_DOWN = 0.005  # m/s over the last centimetre onto the stand: gently, the squeeze held


def squeeze(arms: list) -> float:
    """The squeeze both wrist sensors measure: each pushed back along the line to the other."""
    a, b = (arm.read_pose()[:3, 3] for arm in arms)
    line = (b - a) / np.linalg.norm(b - a)
    return 0.5 * float(arms[1].read_wrench()[:3] @ line - arms[0].read_wrench()[:3] @ line)


with Kali() as kali:
    kali.ready(["left", "right"])
    arms = [kali.robot(name) for name in ("left", "right")]
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
    for arm in arms:  # still, touching nothing: zero the sensors
        arm.tare()
    # 2. straight down onto the sites, grip, squeeze
    moves = [
        arm.move_line(site, speed=0.05, wait=False) for arm, site in zip(arms, sites, strict=True)
    ]
    for m in moves:
        m.wait(timeout=30)
    for arm in arms:  # there, not on the way (DONE: the last set-point is demanded)
        arm.settle()
    for arm in arms:
        arm.grip(True)
    bar = kali.motion_system(["left", "right"], grasps)  # the bar's load left undeclared: see
    # docs/guide/scenes.md (the impedance squeeze with a declared load is not yet tuned)
    bar.set_internal_force(SQUEEZE)  # both arms onto the impedance servo, bumplessly
    kali.sleep(1.5)
    # 3. up, across, back, down: the squeeze measured all along
    here = bar.read_pose()
    up, over, near = here.copy(), here.copy(), here.copy()
    up[2, 3] += LIFT
    over[2, 3] += LIFT
    over[1, 3] += SHIFT
    near[2, 3] += 0.01
    seen = []
    carry = bar.move_path([up, over, up, near], speed=0.08, transition_s=0.2, wait=False)
    while not carry.done:
        seen.append(squeeze(arms))
        kali.pause()
    carry.wait()
    down = bar.move_line(here, speed=SET_DOWN, wait=False)
    while not down.done:
        seen.append(squeeze(arms))
        kali.pause()
    down.wait()
    s = np.array(seen)
    print(f"carried the bar squeezing {SQUEEZE:g} N: squeeze {s.mean():.1f} N mean, "
          f"{s.min():.1f} .. {s.max():.1f} N (wrist sensors)")  # fmt: skip
    bar.set_internal_force(0.0)
    for arm in arms:
        arm.grip(False)
        arm.select_servo("joints")
    at = bar.read_pose()[:3, 3]
    print(f"bar put back at ({at[0]:.3f}, {at[1]:.3f}, {at[2]:.3f}) m")
