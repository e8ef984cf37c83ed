"""Robot program: the left arm catches the bar riding the conveyor and picks it up on the move.

    kalictl start && kalictl run scripts/example_conveyor.py

The stand's top is a conveyor belt (the config's ``plant.conveyor_m_s``).  The program starts
it and, on the same tick, a ``conveyor`` TG function moving at the belt's velocity: the
bar's grasp site is then, as a position equation (thesis 3.2.3, RCCL),

    tool = conveyor(t) · site · approach

with ``site`` where the grasp was when the belt started (fixed) and ``approach`` a shared
transform the program lowers from 5 cm above the site onto it.  The TG evaluates the loop
every tick and the arm tracks it; the gripper closes on the moving bar, the arm stops on its
path, lifts the bar off the belt, stops the belt and sets the bar down.
"""

import numpy as np

from kali_daemons.client import Kali
from kali_daemons.robots.puma560 import kinematics

ABOVE = 0.05  # m: the approach starts this high above the grasp site
LIFT = 0.03  # m
DESCENT_S = 1.0
SETTLE_S = 1.0  # tracking the site before the gripper closes
MEASURE_S = 1.0


def shift(z: float) -> np.ndarray:
    t = np.eye(4)
    t[2, 3] = z
    return t


with Kali() as kali:
    kali.ready(["left"])
    left = kali.robot("left")
    left.feedforward("full")
    cfg = kali.inst.config
    vx, vy = cfg.plant.conveyor_m_s
    grasp = kali.scene.grasp_for("bar", cfg.robots[left.index])  # the flange on it, bar frame
    site = kali.scene.object("bar").pose @ grasp
    q = kinematics.ikine(np.linalg.inv(left.base) @ site @ shift(ABOVE), "run", left.read_joints())
    left.move_joints(q, speed=0.5, timeout=30)
    # the belt and its TG function start together; the tool follows conveyor(t) · site · approach
    approach = kali.shared_transform("approach", shift(ABOVE), lifetime=0)
    belt = kali.tg_function("conveyor", "belt", vx=vx, vy=vy)
    kali.run_conveyor(True)
    track = left.track([belt, site, approach], speed=0.1, accel=0.5)
    steps = 50
    for i in range(1, steps + 1):  # down onto the moving site
        approach.set(shift(ABOVE * (1 - i / steps)))
        kali.sleep(DESCENT_S / steps)
    kali.sleep(SETTLE_S)
    worst = 0.0  # the measured tool against where the site is now, as the belt has moved it
    for _ in range(25):
        t = (int(kali.inst.clock["tick"]) - int(kali.functions["start_tick"][belt.index])) * 1e-3
        now = site[:3, 3] + np.array([vx, vy, 0.0]) * t
        worst = max(worst, float(np.linalg.norm(left.read_pose()[:3, 3] - now)))
        kali.sleep(MEASURE_S / 25)
    left.grip(True)
    kali.sleep(0.1)
    left.stop()  # tracking ends (STOPPED): it decelerates on its path, the bar in the gripper
    while not track.done:
        kali.pause()
    down = left.base @ kinematics.fkine(kali.start_point(left.index))  # where it came to rest
    up = down.copy()
    up[2, 3] += LIFT
    left.move_line(up, speed=0.03)  # off the belt
    kali.run_conveyor(False)
    left.move_line(down, speed=0.03)
    left.grip(False)
    print(f"tracked the moving grasp site within {worst * 1000:.2f} mm (measured joints)")
    at = (left.read_pose() @ np.linalg.inv(grasp))[:3, 3]  # the bar's centre, from the grasp
    print(f"bar caught on the belt and set down at ({at[0]:.3f}, {at[1]:.3f}, {at[2]:.3f}) m")
