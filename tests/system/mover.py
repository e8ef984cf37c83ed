"""The robot program of the fault-injection matrix: both arms moving until the system halts.

    python -m tests.system.mover INSTANCE

It powers both arms, turns full feed-forward on, prints ``moving``, then swings every joint
of both arms back and forth with joint moves (no calibration needed), waiting on each.  When
a wait is woken by a halt it prints ``woken <CLOCK_REALTIME ns> <the error>`` and exits 3;
any other failure exits 1 with the traceback.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from kali_daemons.client import Kali
from kali_daemons.client.common import MotionFailedError
from kali_daemons.core.layout import PowerState
from kali_daemons.runtime.instance import decode

SWING = np.radians([10.0, -8.0, 8.0, 20.0, 15.0, 20.0])  # about each arm's start
# the first joints of arms facing each other turn opposite ways: both wrists to the same side
# (the same way, they cross at the middle and meet: the plant's arms collide); 10° apiece: each
# arm's move is checked against the other standing at its start (the TG's clearance check),
# where 20° would bring the wrists within 10 mm of each other
FACING = np.array([-1.0, 1.0, 1.0, 1.0, 1.0, 1.0])
SPEED = 0.3  # of the joint speed and acceleration limits: a swing takes about a second


def main(instance: str) -> int:
    with Kali(instance) as kali:
        for name in kali.names:
            kali.servo.power(name, True)
        deadline = time.monotonic() + 10.0
        while any(kali.servo.power_state(n) != PowerState.ON for n in kali.names):
            if time.monotonic() > deadline or kali.inst.fault["active"]:
                robots = kali.servo.level.robots
                states = {
                    n: f"{kali.servo.power_state(n).name} ({decode(bytes(robots['message'][k]))})"
                    for k, n in enumerate(kali.names)
                }  # with what SIO said of it
                clock = kali.inst.clock
                print(
                    f"power failed: fault {kali.inst.fault_text()}; power {states}; clock "
                    f"mode {int(clock['mode'])} at tick {int(clock['tick'])}",
                    flush=True,
                )
                return 1
            time.sleep(0.01)
        arms = [kali.robot(n) for n in kali.names]
        for arm in arms:
            arm.feedforward("full")
        start = [arm.read_joints() for arm in arms]
        swings = [SWING if k % 2 == 0 else SWING * FACING for k in range(len(arms))]
        print("moving", flush=True)
        sign = 1.0
        while True:
            handles = [
                arm.move_joints(q + sign * swing, speed=SPEED, wait=False)
                for arm, q, swing in zip(arms, start, swings, strict=True)
            ]
            try:
                for h in handles:
                    h.wait(timeout=60.0)
            except MotionFailedError as exc:
                print(f"woken {time.time_ns()} {exc}", flush=True)
                return 3
            sign = -sign


if __name__ == "__main__":
    sys.exit(main(sys.argv[1]))
