"""Moving in contact (issue 27 item 4), end to end in lockstep with the Cartesian impedance
servo: a tool slid along the table holds a normal force set-point.  Forces are the plant's
truth, never read by the controller."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from kali_daemons.client import Kali, pose
from kali_daemons.layout import RequestState
from kali_daemons.wallclock import step_kali_clock
from tests.test_armservo import tool_point
from tests.test_guarded import ABOVE, DOWN, TABLE_Z, over_the_table
from tests.test_wrench import truth

PRESS_N = 15.0
STROKE_M = 0.10
SLIDE_SPEED = 0.02  # m/s
# The impedance servo while polishing (example_polish.py): soft along the tool's z (a mm of
# unevenness is 0.5 N); little damping there, the pad on the table damps (the default 300
# N·s/m turns the encoders' velocity quantum into a ±1.5 N rattle against the table); the
# force loop on the wrist sensor five times the default (as the joints break away their
# friction changes: with 1 the force starts the stroke at 19 N, with 5 at 17).
POLISH = {"kz": 500.0, "dz": 50.0, "fz": PRESS_N, "kf": 5.0}


def test_a_tool_slides_along_the_table_pressing_at_the_set_force(
    kali: Callable[..., str],
) -> None:
    """Found by a guarded move, the table is pressed at 15 N by the impedance servo's force
    set-point along the tool's z; slid 10 cm along it at 2 cm/s, the true normal force stays
    15 ± 3 N from the first millimetre to the last (the pad's sliding friction, 0.3, drags
    4.5 N along), the tool stays on the table, and lifted off it returns to the joint servos
    without a fault."""
    name = kali(lockstep=True, base="force.yaml")
    with Kali(name) as k:
        left = over_the_table(k)
        touch = left.move_line(pose([ABOVE[0], ABOVE[1], TABLE_Z - 0.1], DOWN), speed=0.01,
                               guard=5.0)  # fmt: skip
        assert touch.state == RequestState.CONTACT, touch.message
        left.set_servo(POLISH, "impedance")  # then taken over bumplessly, pressing
        left.select_servo("impedance")
        step_kali_clock(k.inst, 1500)
        pressed = -truth(k)["ft_wrench"][0][2]
        assert abs(pressed - PRESS_N) < 1.0, f"pressing {pressed:.1f} N at rest"
        start = tool_point(k, 0)[0]
        on = left.read_pose()
        stroke = left.move_line(pose(on[:3, 3] + [STROKE_M, 0.0, 0.0], DOWN),
                                speed=SLIDE_SPEED, wait=False)  # fmt: skip
        along, normal, height = [], [], []
        while not stroke.done:
            step_kali_clock(k.inst, 1)
            x = tool_point(k, 0)[0]
            along.append(x[0] - start[0])
            height.append(x[2])
            normal.append(-truth(k)["ft_wrench"][0][2])
        assert stroke.state == RequestState.DONE, stroke.message
        along_m, normal_n = np.array(along), np.array(normal)
        assert along_m[-1] > STROKE_M - 0.003, f"slid {along_m[-1] * 100:.1f} cm"
        sliding = (along_m > 0.001) & (along_m < along_m[-1] - 0.001)
        assert sliding.sum() > 0.8 * STROKE_M / SLIDE_SPEED * 1000  # ticks: most of them
        f = normal_n[sliding]
        assert np.all(np.abs(f - PRESS_N) <= 3.0), f"{f.min():.1f} .. {f.max():.1f} N"
        assert abs(f.mean() - PRESS_N) < 0.5, f"{f.mean():.2f} N mean"
        assert np.ptp(height) < 0.002  # on the (compliant pad on the) table all along
        left.set_servo({"fz": 0.0})
        left.move_line(pose(on[:3, 3] + [STROKE_M, 0.0, 0.03], DOWN), speed=0.05)
        left.select_servo("joints")
        step_kali_clock(k.inst, 100)
        assert truth(k)["ft_wrench"][0][2] == 0.0  # off the table
        assert k.inst.fault_text() is None
