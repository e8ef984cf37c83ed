"""Robot program: a straight line bent into a sine over the part by a sensor loop (issue 28).

    kalictl start && kalictl run scripts/example_sensor_path.py
    kalictl start -c config/force.yaml && kalictl -i force run scripts/example_sensor_path.py

The tool goes along a straight line over the table, as the position equation

    tool = line(t) · down · bend

``line`` the built-in TG function (a point going from A to B at a speed), ``down`` the tool
pointing down, and ``bend`` a shared transform that a periodic function of this program
(``kali.control``, every 10 ms on the wall clock, thesis 3.6.2) writes from sensor records
while the arm moves (thesis 2.7: on-line path modification integrated with sensor I/O):

- the measured joints (SIO's record, through the arm's kinematics) say how far along the line
  the tool is, which gives the sine's phase: the bend is laid over the part in space, not in
  time, so a slower arm draws the same sine;
- with a wrist force sensor (every PUMA of config/default.yaml has one), the tool first finds
  the table by a guarded move and the same function then moves it along its z to hold
  ``FORCE`` on the surface, an integral force law on the sensor's contact force: it follows
  the surface.  Where the arm may run robot-level servos (config/force.yaml), a soft Cartesian
  impedance along z (``SOFT``) makes the contact force far steadier than the joint PIDs'
  stiff grip on a 20 N/mm pad: a millimetre of error is 0.5 N, not 20.
"""

import math

import numpy as np

from kali_daemons.client import Kali, pose
from kali_daemons.core.errors import ServoError

DOWN = np.diag([1.0, -1.0, -1.0])  # the tool pointing straight down
START = (-0.15, -0.38, 0.42)  # 2 cm over the table, within the left arm's reach (m, world)
LENGTH = 0.10  # m along the world's x
SPEED = 0.02  # m/s
AMPLITUDE = 0.01  # m, across the line (world y)
WAVELENGTH = 0.05  # m along it
FORCE = 10.0  # N pressing on the surface, with a wrist sensor
FORCE_GAIN = 0.0004  # m/s of z per N of force error (joint PIDs on the pad: ~20 N/mm)
SOFT = {"kz": 500.0, "dz": 50.0, "fz": 0.0}  # N/m, N·s/m: the impedance servo's z, no push
SOFT_GAIN = 0.005  # m/s per N under it (0.5 N/mm): 2.5 % of the error a tick, slow against the
# pad's 10 Hz bounce under a soft servo (faster gains ring with it)

with Kali() as kali:
    kali.ready(["left"])
    left = kali.robot("left")
    left.feedforward("full")
    sensing = kali.inst.config.robots[left.index].ft.sheet is not None
    kin = left.type.kinematics
    if sensing:
        tip = kali.inst.config.robots[left.index].ft.tool_tip_m
        left.set_tool(pose([0.0, 0.0, tip]))  # the pad's tip
    left.move_joints(left.joints_at(pose(START, DOWN), "run"))
    start = pose(START, DOWN)
    if sensing:  # find the surface; the line then starts on it
        left.tare()
        touch = left.move_line(pose([START[0], START[1], 0.3], DOWN), speed=0.01, guard=3.0)
        if touch.contact is None:
            raise SystemExit("no table under the tool")
        start = left.read_pose()
    soft = sensing and kali.inst.config.robots[left.index].robot_servos
    gain = SOFT_GAIN if soft else FORCE_GAIN
    if soft:
        left.set_servo(SOFT, "impedance")
        left.select_servo("impedance")  # bumpless: it holds where the joint servos were
    a, b = start[:3, 3], start[:3, 3] + [LENGTH, 0.0, 0.0]
    bend = kali.shared_transform("bend", np.eye(4), lifetime=0.1)
    line = kali.tg_function("line", x0=a[0], y0=a[1], z0=a[2], x1=b[0], y1=b[1], z1=b[2],
                            speed=SPEED)  # fmt: skip
    offset = pose([0.0, 0.0, 0.0])  # the bend: across the line and, sensing, along the tool z
    span = kali.inst.config.joints.span(left.index)
    joints_q = kali.servo.level.joints["q"]
    flange, tool = np.empty((4, 4)), np.empty((4, 4))
    dt = 0.01
    log: list[tuple[float, float, float]] = []  # (along, across, normal force)

    def sense(tick: int) -> None:
        """Every 10 ms: the measured tool along the line → the sine; the contact force →
        the depth.  Writes ``bend``."""
        kin.fkine(joints_q[span], out=flange)
        np.matmul(left.base @ flange, left.tool, out=tool)
        along = float(tool[0, 3] - a[0])
        offset[1, 3] = -AMPLITUDE * math.sin(
            2.0 * math.pi * along / WAVELENGTH
        )  # tool y = −world y
        force = 0.0
        if sensing:
            force = -float(kali.ft["tool"][left.index][2])  # the surface pushes along tool −z
            offset[2, 3] += gain * (FORCE - force) * dt  # deeper while too light
        bend.set(offset)
        log.append((along, float(tool[1, 3] - a[1]), force))

    sensor = kali.control(sense, period_ms=10)
    path = left.track([line, pose([0.0, 0.0, 0.0], DOWN), bend], speed=0.1, accel=0.5,
                      duration=LENGTH / SPEED + 1.0)  # fmt: skip
    while not path.done:
        kali.pause()
    sensor.release("the line is done")
    if path.message:
        raise ServoError(f"the path ended early: {path.message}")
    rows = np.array(log)
    inside = rows[(rows[:, 0] > 0.01) & (rows[:, 0] < LENGTH - 0.01)]
    low, high = inside[:, 1].min() * 1000, inside[:, 1].max() * 1000
    print(f"line of {LENGTH * 100:g} cm bent into a sine of {AMPLITUDE * 1000:g} mm: measured "
          f"across it {low:.1f} .. {high:.1f} mm")  # fmt: skip
    if sensing:
        f = inside[:, 2]
        print(f"following the surface with {FORCE:g} N: normal force {f.mean():.1f} N mean, "
              f"{f.min():.1f} .. {f.max():.1f} N")  # fmt: skip
    left.move_line(left.read_pose() @ pose([0.0, 0.0, -0.03]), speed=0.05)  # lift off
    if soft:
        left.select_servo("joints")
