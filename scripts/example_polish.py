"""Robot program: the left arm's tool slides 10 cm along the table pressing down with 15 N,
as a polishing or wiping tool would.

    kalictl start -c config/force.yaml && kalictl -i force run scripts/example_polish.py

Moving in contact (issue 27): a guarded move finds the table, then the Cartesian impedance
servo (thesis 3.3.4; ``robot_servos: true`` in config/force.yaml) holds a force set-point
along the tool's z, closing the loop on the wrist sensor, while the trajectory generator
slides the tool along the surface.  The program prints the normal force its sensor measured.
"""

import numpy as np

from kali_daemons.client import Kali, pose

DOWN = np.diag([1.0, -1.0, -1.0])  # the tool pointing straight down
START = (-0.15, -0.38, 0.42)  # 2 cm over the table, within the left arm's reach (m, world)
STROKE = 0.10  # m along the world's x
FORCE = 15.0  # N, pressing along the tool's z (down)
# soft along z, little damping there (the pad on the table damps), pressing with FORCE, the
# force loop on the wrist sensor five times its default (the joints' friction as they start)
POLISH = {"kz": 500.0, "dz": 50.0, "fz": FORCE, "kf": 5.0}

with Kali() as kali:
    kali.ready(["left"])
    arm = kali.robot("left")
    tip = kali.inst.config.robots[arm.index].ft.tool_tip_m
    arm.set_tool(pose([0.0, 0.0, tip]))  # the pad's tip
    arm.move_joints(arm.joints_at(pose(START, DOWN), "run"))
    arm.tare()
    touch = arm.move_line(pose([START[0], START[1], 0.3], DOWN), speed=0.01, guard=5.0)
    if touch.contact is None:
        raise SystemExit("no table under the tool")
    # the servo's parameters outlive the program: keep what it had, to give back at the end
    # (another program on this cell gets the impedance servo as it knows it)
    found = arm.servo_params("impedance")
    arm.set_servo(POLISH, "impedance")
    arm.select_servo("impedance")  # bumpless, from the joint servos' torque: now pressing
    kali.sleep(1.5)
    on = arm.read_pose()
    end = pose(on[:3, 3] + [STROKE, 0.0, 0.0], DOWN)
    stroke = arm.move_line(end, speed=0.02, wait=False)
    along, normal = [], []
    while not stroke.done:
        along.append(arm.read_pose()[0, 3])
        normal.append(-arm.read_wrench("tool")[2])  # the table pushes back along the tool's -z
        kali.pause()
    stroke.wait()
    x = np.array(along)  # from its first millimetre to its last: breaking away, stopping aside
    f = np.array(normal)[(x > x[0] + 0.001) & (x < x[-1] - 0.001)]
    print(f"slid {STROKE * 100:g} cm pressing {FORCE:g} N: normal force {f.mean():.1f} N mean, "
          f"{f.min():.1f} .. {f.max():.1f} N")  # fmt: skip
    arm.set_servo({"fz": 0.0})
    arm.move_line(pose(end[:3, 3] + [0.0, 0.0, 0.03], DOWN), speed=0.05)  # lift off
    arm.set_servo({name: found[name] for name in POLISH})
    arm.select_servo("joints")
