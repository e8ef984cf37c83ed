"""Robot program: the left arm's tool descends onto the table until it touches, and says how
high the table is.

    kalictl start && kalictl run scripts/example_guarded.py

A guarded move (issue 27): a straight line down at 10 mm/s that SIO stops, in the servo tick
the wrist sensor's contact force reaches 5 N, holding the arm where it touched. The sensor is
tared first, with the arm still and touching nothing.
"""

import numpy as np

from kali_daemons.client import Kali, pose

DOWN = np.diag([1.0, -1.0, -1.0])  # the tool pointing straight down
ABOVE = (-0.15, -0.38, 0.46)  # over the table, within the left arm's reach (m, world)

with Kali() as kali:
    kali.ready(["left"])
    arm = kali.robot("left")
    tip = kali.inst.config.robots[arm.index].ft.tool_tip_m
    arm.set_tool(pose([0.0, 0.0, tip]))  # the pad's tip: where the contact is
    arm.move_joints(arm.joints_at(pose(ABOVE, DOWN), "run"))  # a wrist that can point down
    arm.tare()
    floor = pose([ABOVE[0], ABOVE[1], 0.0], DOWN)  # 46 cm further down: it never gets there
    touch = arm.move_line(floor, speed=0.01, guard=5.0)
    if touch.contact is None:
        print("no contact: the tool reached the floor pose")
    else:
        x, y, z = touch.contact.position
        print(f"contact at ({x:.3f}, {y:.3f}, {z:.3f}) m: the table is {z * 100:.1f} cm high")
        print(f"the tool felt {touch.contact.force:.1f} N there (guard 5 N)")
    arm.move_line(pose(ABOVE, DOWN), speed=0.05)  # and up again
