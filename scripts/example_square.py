"""Robot program: the first arm's tool draws a 10 cm square in a vertical plane (the left
PUMA in the default cell; any cell's first arm: kalictl start -c config/fr3.yaml for an FR3).

    kalictl start && kalictl run scripts/example_square.py

Straight lines at 0.1 m/s, blended over 0.1 s at each corner (thesis 2.2.1); the whole path
is checked for reach, joint limits and singularities before the arm moves.
"""

import numpy as np

from kali_daemons.client import Kali, pose

SIDE = 0.10  # m

with Kali() as kali:  # the instance `kalictl run` names ($KALI_INSTANCE), else "default"
    name = kali.names[0]  # the cell's first arm
    kali.ready([name])  # power on and calibrate, if not done yet
    arm = kali.robot(name)
    start = arm.read_pose()  # the tool in the world frame, 4×4
    corners = [
        pose(start[:3, 3] + np.array(step), start)  # same orientation, moved
        for step in ([0, SIDE, 0], [0, SIDE, SIDE], [0, 0, SIDE], [0, 0, 0])
    ]
    arm.move_path(corners, speed=0.1, transition_s=0.1)  # blocks until done
    off = np.linalg.norm(arm.read_pose()[:3, 3] - start[:3, 3])
    print(f"square of {SIDE * 100:g} cm done; the tool is {off * 1000:.2f} mm from its start")
