"""Guarded moves (issue 27 item 4), end to end in lockstep: a tool lowered onto the table
stops at contact, held where it touched, with the contact reported; a move that touches
nothing arrives; a guard the cell cannot honour is refused before anything moves."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.client import Kali, Robot, pose
from kali_daemons.core.errors import MotionError
from kali_daemons.core.layout import MotionKind, RequestState
from kali_daemons.wallclock import step_kali_clock
from tests.test_armservo import tool_point
from tests.test_wrench import truth

DOWN = np.diag([1.0, -1.0, -1.0])  # the tool's z straight down
TABLE_Z = 0.40  # the table's top (config/scenes/default.yaml)
ABOVE = (-0.15, -0.38, 0.41)  # 1 cm over the table, in the left arm's reach
GUARD_N = 10.0
SPEED = 0.01  # m/s
# the force goes on rising while the arm stops, more the faster it came: with the joint PIDs
# and the felt pad, 0.8 N at 10 mm/s, 1.6 N at 20, 7.9 N at 50 (docs/guide/force.md, Guarded moves)
OVERSHOOT_N = 0.2 * SPEED * 1000


def over_the_table(k: Kali) -> Robot:
    """The left arm, ready, its tool point (the pad's tip) 1 cm above the table pointing
    down, its sensor tared."""
    k.ready(["left"])
    left = k.robot("left")
    left.set_tool(pose([0.0, 0.0, k.inst.config.robots[0].ft.tool_tip_m]))
    left.move_joints(left.joints_at(pose(ABOVE, DOWN), "run"))
    step_kali_clock(k.inst, 300)
    left.tare()
    return left


def test_a_guarded_move_stops_at_first_contact_and_says_where(kali: Callable[..., str]) -> None:
    """Lowered at 10 mm/s towards a point 3 cm inside the table with a 10 N guard: the motion
    ends CONTACT; the tool rests within 2 mm of where it first touched (plant truth), the
    reported contact point is there too, and the force never passed the guard plus the
    stated overshoot.  The next move starts from the hold, without a jump."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        left = over_the_table(k)
        handle = left.move_line(
            pose([ABOVE[0], ABOVE[1], TABLE_Z - 0.03], DOWN), speed=SPEED, guard=GUARD_N, wait=False
        )
        touched, peak = None, 0.0
        for _ in range(3000):
            step_kali_clock(k.inst, 1)
            force = float(np.linalg.norm(truth(k)["ft_wrench"][0][:3]))
            peak = max(peak, force)
            if touched is None and force > 0.5:
                touched = tool_point(k, 0)[0]
            if handle.done:
                break
        step_kali_clock(k.inst, 500)
        assert handle.state == RequestState.CONTACT, handle.message
        handle.wait()  # a guarded move that touched is a success
        assert touched is not None
        rest = tool_point(k, 0)[0]
        assert np.linalg.norm(rest - touched) < 0.002, (rest, touched)
        contact = handle.contact
        assert contact is not None and contact.robot == "left"
        assert GUARD_N <= contact.force < GUARD_N + OVERSHOOT_N
        assert np.linalg.norm(contact.position - touched) < 0.002, (contact.position, touched)
        assert abs(contact.position[2] - TABLE_Z) < 0.002
        assert "contact: robot 'left' felt" in handle.message
        assert peak < GUARD_N + OVERSHOOT_N, f"peak {peak:.1f} N"
        assert k.inst.fault_text() is None
        # away again, from the hold: a guarded move that does not touch arrives
        up = left.move_line(pose(ABOVE, DOWN), speed=0.05, guard=GUARD_N)
        assert up.state == RequestState.DONE and up.contact is None
        assert np.linalg.norm(tool_point(k, 0)[0] - ABOVE) < 0.002


def test_a_guard_the_cell_cannot_honour_is_refused(kali: Callable[..., str]) -> None:
    """A guard on an arm without a wrist sensor, at or past the contact limit (which would
    halt first), or not a finite force >= 0: refused by the client and, put in the queue
    past it, by the TG; nothing moves."""
    name = kali(lockstep=True, edits={r"^(  - \{name: right.*)\}$": r"\1, ft: {sensor: none}}"})
    with Kali(name) as k:
        k.ready(["left", "right"])
        left, right = k.robot("left"), k.robot("right")
        q = left.read_joints()
        with pytest.raises(MotionError, match="robot 'right' has no wrist force/torque sensor"):
            right.move_joints(right.read_joints(), guard=5.0)
        with pytest.raises(MotionError, match="not below its contact limit 150 N"):
            left.move_joints(q, guard=150.0)
        with pytest.raises(MotionError, match="guard nan N"):
            left.move_joints(q, guard=float("nan"))
        with pytest.raises(MotionError, match="guard -1"):
            left.move_line(left.read_pose(), guard=-1.0)
        with pytest.raises(MotionError, match="must be a force"):
            left.move_joints(q, guard="hard")  # type: ignore[arg-type]
        # past the client's checks, straight into the queue: the TG refuses it the same way
        forged = k._request(
            MotionKind.JOINTS, [1], joints=[right.read_joints()], speed_scale=0.5, guard_n=5.0
        )
        while not forged.done:
            step_kali_clock(k.inst, 1)
        assert forged.state == RequestState.REFUSED
        assert "robot 'right' has no wrist force/torque sensor" in forged.message
