"""Robot program: the first arm (the left PUMA in the default cell) follows a hand
controller, and stops when the device stops.

    kalictl start && kalictl run scripts/example_teleop.py

The device (``scripts/hand_controller.py``, started here as its own process) streams an
offset into the shared transform ``hand`` every 20 ms; the tool follows

    tool = start · hand

evaluated by the TG every tick within the tracking limits (issue 28: the teleoperation path).
When the device stops writing, the transform goes stale after its lifetime (0.1 s) and the TG
decelerates the arm to rest on its path: the motion ends STOPPED, saying so.
"""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from kali_daemons.client import Kali
from kali_daemons.core.errors import MotionError

DEVICE = Path(__file__).with_name("hand_controller.py")
DEVICE_S = 6.0

with Kali() as kali:
    name = kali.names[0]  # the cell's first arm
    kali.ready([name])
    left = kali.robot(name)
    left.feedforward("full")
    start = left.read_pose()
    device = subprocess.Popen([sys.executable, str(DEVICE), "--seconds", str(DEVICE_S)])
    try:
        hand = None
        deadline = time.monotonic() + 30.0
        while hand is None:  # the device holds its transform once it runs
            try:
                hand = kali.find_transform("hand")
            except MotionError:
                if device.poll() is not None or time.monotonic() > deadline:
                    raise
                kali.pause()
        follow = left.track([start, hand], speed=0.2, accel=1.0)
        farthest = 0.0
        while not follow.done:
            farthest = max(farthest, float(np.linalg.norm(left.read_pose()[:3, 3] - start[:3, 3])))
            kali.pause()
        print(f"followed the hand up to {farthest * 1000:.1f} mm from the start")
        print(f"the device stopped, and so did the arm: {follow.message}")
        print(f"rate-limited ticks: {follow.limited}")
    finally:  # in lockstep the device runs only while the clock steps: pause until it ends
        deadline = time.monotonic() + 30.0
        while device.poll() is None and time.monotonic() < deadline:
            kali.pause()
        if device.poll() is None:
            device.kill()
        device.wait()
