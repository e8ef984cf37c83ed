"""Robot program: tune joint 2's PID gain on line while the arm moves.

    kalictl start && kalictl run scripts/example_tune_pid.py

The left arm's shoulder (joint 2) swings ±10° again and again through the trajectory
generator; before each swing the program sets a new proportional gain ``kp`` through the
servo interface (thesis 3.4, bumpless) and measures the tracking error during the swing.
Too soft lags, too stiff rings: the table shows where this joint's gain is best.
"""

import math

import numpy as np

from kali_daemons.client import Kali

ROBOT, JOINT = "left", 1  # joint index 1 = joint 2, the shoulder
SWING = math.radians(10)

with Kali() as kali:
    kali.ready([ROBOT])
    arm = kali.robot(ROBOT)
    servo = kali.servo
    q0 = arm.read_joints()
    kp0 = servo.get_params(ROBOT, JOINT)["kp"]
    robots = servo.level.robots
    print(f"{ROBOT} joint {JOINT + 1}: {servo.active(ROBOT, JOINT)}, kp {kp0:g} at start")
    print("    kp   rms error (mrad)   max error (mrad)")
    for i, scale in enumerate((0.5, 1.0, 2.0)):
        servo.set_params(ROBOT, JOINT, {"kp": kp0 * scale})  # on line, while holding
        target = q0.copy()
        target[JOINT] += SWING if i % 2 == 0 else -SWING
        swing = arm.move_joints(target, speed=0.5, wait=False)
        errors = []
        while not swing.done:
            kali.pause()
            errors.append(float(robots["q"][arm.index][JOINT] - robots["demand"][arm.index][JOINT]))
        swing.wait(0)
        e = np.array(errors) * 1000
        print(f"{kp0 * scale:6g}   {np.sqrt(np.mean(e**2)):17.3f}   {np.abs(e).max():16.3f}")
    servo.set_params(ROBOT, JOINT, {"kp": kp0})
    arm.move_joints(q0)
    print(f"kp back to {servo.get_params(ROBOT, JOINT)['kp']:g}; the arm is where it started")
    del robots
