"""Robot program: tune joint 2's PID gain on line while the arm moves.

    kalictl start && kalictl run scripts/example_tune_pid.py

The first arm's shoulder (joint 2; the left PUMA in the default cell) swings 10° out and
back, once per gain; before each swing
the program sets a new proportional gain ``kp`` through the servo interface (thesis 3.4,
bumpless) and measures the joint's tracking error during the swing.  Every gain sees the
same motion, so the table compares the gains alone: too soft lags, too stiff rings.  The
arm's feed-forward is off meanwhile (it would take most of the error the gain is judged by)
and back as it was after.

The servo interface numbers joints 1..6 as the thesis and the PUMA do; joint vectors such as
``read_joints()`` are indexed from 0, so joint 2 is index 1 there.
"""

import math
import sys

import numpy as np

from kali_daemons.client import Kali

JOINT = 2  # the shoulder; index JOINT - 1 in joint vectors
SWING = math.radians(10)
SPEED = 0.2  # of the arm's planned speed: slow enough that the softest gain lags safely

with Kali() as kali:
    ROBOT = kali.names[0]  # the cell's first arm
    kali.ready([ROBOT])
    arm = kali.robot(ROBOT)
    servo = kali.servo
    j = JOINT - 1
    algorithm, params = servo.active(ROBOT, JOINT), servo.get_params(ROBOT, JOINT)
    if "kp" not in params:
        sys.exit(
            f"{ROBOT} joint {JOINT} runs '{algorithm}', which has no kp to tune: "
            f"kalictl servo select {ROBOT} {JOINT} pid"
        )
    kp0 = params["kp"]
    ff = servo.feedforward_state(ROBOT)[0].name.lower()  # as the config starts it: full
    arm.feedforward("off")  # the PID alone
    kali.sleep(0.5)  # faded out (feedforward.ramp_ms)
    q0 = arm.read_joints()
    out = q0.copy()
    out[j] += SWING
    q, demand = servo.level.arm("q", arm.index), servo.level.arm("demand", arm.index)
    print(f"{ROBOT} joint {JOINT}: {algorithm}, kp {kp0:g} at start")
    print("    kp   rms error (mrad)   max error (mrad)")
    for scale in (0.5, 1.0, 2.0):
        servo.set_params(ROBOT, JOINT, {"kp": kp0 * scale})  # on line, while holding
        errors = []
        for target in (out, q0):  # out and back: the same swing for every gain
            swing = arm.move_joints(target, speed=SPEED, wait=False)
            while not swing.done:
                kali.pause()
                errors.append(float(q[j] - demand[j]))
            swing.wait(0)
        e = np.array(errors) * 1000
        print(f"{kp0 * scale:6g}   {np.sqrt(np.mean(e**2)):17.3f}   {np.abs(e).max():16.3f}")
    servo.set_params(ROBOT, JOINT, {"kp": kp0})
    arm.move_joints(q0)
    arm.feedforward(ff)
    print(f"kp back to {servo.get_params(ROBOT, JOINT)['kp']:g}; the arm is where it started")
    del q, demand
