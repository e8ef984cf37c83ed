"""Shadow trials (issue 27 item 6, ``kali_daemons/servo/shadow.py``), end to end in lockstep on a
moving arm: a joint servo or a robot-level one in shadow is stepped every tick on exactly
the active servo's inputs (a private copy of its record, stepped here on the inputs each
tick left in the slot, gives its torque to the last bit), its torque is never applied, the
figures ``kalictl servo compare`` prints are the RMS and peak of (shadow − active) over the
ticks compared, and selecting the shadow afterwards goes on from its own state.  A shadow
that raises ends its trial and halts nothing; bad requests are refused naming why."""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core import layout
from kali_daemons.core.errors import ServoError
from kali_daemons.core.layout import RequestState, ShadowState
from kali_daemons.runtime import flightrec
from kali_daemons.servo import PD, struct_view
from kali_daemons.tools import top
from kali_daemons.tools.introspect import Introspector
from kali_daemons.wallclock import step_kali_clock
from tests.test_armservo import LEFT_ROBOT_SERVOS
from tests.test_introspect import render
from tests.test_launcher import kalictl

FAULTY = Path(__file__).parent / "system" / "faulty_servo.py"
WITH_FAULTY = {r"^plugins: \[(.*)\]$": rf"plugins: [\1, {FAULTY}]"}


def moving_left(k: Kali, degrees: list[float], speed: float = 0.3) -> object:
    """Ready the left arm and start a joint move by ``degrees``; its handle."""
    k.ready(["left"])
    step_kali_clock(k.inst, 200)
    left = k.robot("left")
    return left.move_joints(left.read_joints() + np.radians(degrees), speed=speed, wait=False)


def test_a_joint_servo_in_shadow_sees_the_active_inputs_and_is_never_applied(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True, edits=WITH_FAULTY)
    with Kali(name) as k:
        sv = k.servo
        i = sv.slot("left", 2)
        slot, joint = sv.level.slots[i : i + 1], sv.level.joints[i : i + 1]
        handle = moving_left(k, [10, -15, 10, 0, 0, 0])
        step_kali_clock(k.inst, 100)
        with pytest.raises(ServoError, match=r"'pid' is the joint's active servo"):
            sv.shadow("left", 2, "pid")
        with pytest.raises(ServoError, match=r"no algorithm 'nope'"):
            sv.shadow("left", 2, "nope")
        sv.shadow("left", 2, "pd", wait=False)
        step_kali_clock(k.inst, 1)  # the SV starts it (handed over from the PID) and steps it
        assert int(slot["shadow_state"][0]) == ShadowState.RUNNING
        mine = sv.get_servo("left", 2, "pd").copy()  # the clock stands: read at once
        rec = struct_view(mine)
        sq, peak = float(slot["shadow_sq"][0]), float(slot["shadow_peak"][0])
        for _ in range(150):
            step_kali_clock(k.inst, 1)
            demand, position = float(slot["demand"][0]), float(slot["position"][0])
            torque, _, _ = PD.step(rec, demand, position)
            assert float(slot["shadow_torque"][0]) == torque  # the same inputs, to the bit
            active = float(slot["torque"][0])
            assert float(joint["servo_torque"][0]) == active != torque  # never applied
            sq += (torque - active) ** 2
            peak = max(peak, abs(torque - active))
        assert int(slot["shadow_n"][0]) == 151
        assert math.isclose(float(slot["shadow_sq"][0]), sq, rel_tol=1e-12)
        assert float(slot["shadow_peak"][0]) == peak
        # the flight recorder has its torque tick by tick, NaN on the joints without a trial
        header = k.inst.arena.existing(layout.KEY_FLIGHT, layout.FLIGHT)
        rows = flightrec.read_ring(header, flightrec.attach_ring(k.inst.arena, header), True)
        assert rows["shadow_torque"][-1][i] == torque
        assert np.isnan(np.delete(rows["shadow_torque"][-1], i)).all()
        # kalictl status --json and top name the servos, and the one in shadow
        spy = Introspector(k.inst)
        try:
            servo = spy.snapshot()["robots"][0]["servo"]
            frame = render(top.frame(top.take(spy), top.take(spy), 0.1, 140), 140)
        finally:
            spy.close()
        assert servo["robot"] is None and servo["joints"] == ["pid"] * sv.level.map.counts[0]
        (trial,) = servo["trials"]
        assert (trial["joint"], trial["shadow"], trial["state"]) == (2, "pd", "RUNNING")
        assert trial["ticks"] == 151 and math.isclose(trial["rms_nm"], math.sqrt(sq / 151))
        assert re.search(r"left\s.*\spid \(shadow pd\)", frame), frame
        (row,) = [t for t in k.robot("left").trials() if t.joint == 2]
        assert (row.active, row.shadow, row.state, row.ticks) == (
            "pid",
            "pd",
            ShadowState.RUNNING,
            151,
        )
        assert math.isclose(row.rms, math.sqrt(sq / 151)) and row.peak == peak
        out = kalictl("-i", name, "servo", "compare", "left")
        assert out.returncode == 0, out.stderr
        assert f"{math.sqrt(sq / 151):9.4f}  {peak:9.4f}" in out.stdout, out.stdout
        assert "pid" in out.stdout and "running" in out.stdout

        # selected, it goes on from its own state: no hand-over from the PID's torque
        sv.select("left", 2, "pd", wait=False)
        step_kali_clock(k.inst, 1)
        torque, _, _ = PD.step(rec, float(slot["demand"][0]), float(slot["position"][0]))
        assert float(slot["torque"][0]) == torque and sv.active("left", 2) == "pd"
        assert int(slot["shadow_state"][0]) == ShadowState.SELECTED

        # a shadow that raises ends its trial; nothing halts, the arm runs on
        sv.set_params("left", 3, {"fail": 1.0}, "faulty")
        sv.shadow("left", 3, "faulty", wait=False)
        step_kali_clock(k.inst, 5)
        (row,) = [t for t in sv.trials("left") if t.joint == 3]
        assert row.state == ShadowState.RAISED and row.shadow == "faulty"
        step_kali_clock(k.inst, 4000)
        assert handle.state == RequestState.DONE, handle.message
        assert k.inst.fault_text() is None
        del slot, joint, header, rows


def test_a_robot_level_servo_in_shadow_then_selected_while_moving(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True, edits=LEFT_ROBOT_SERVOS)
    with Kali(name) as k:
        sv, left = k.servo, k.robot("left")
        span = sv.level.map.span(0)
        slots, joints = sv.level.slots[span], sv.level.joints[span]
        sv.feedforward("left", "full")
        handle = moving_left(k, [15, -20, 15, 0, 10, 0], speed=0.2)
        step_kali_clock(k.inst, 100)
        out = kalictl("-i", name, "servo", "shadow", "left", "computed_torque")
        assert out.returncode == 0, out.stderr
        step_kali_clock(k.inst, 1)
        out = kalictl("-i", name, "servo", "list")
        assert "in shadow: computed_torque (robot-level)" in out.stdout, out.stdout
        step_kali_clock(k.inst, 399)
        assert (joints["servo_torque"] == slots["torque"]).all()  # never applied
        rows = left.trials()
        assert [t.joint for t in rows] == list(range(1, span.stop - span.start + 1))
        assert {(t.level, t.active, t.shadow, t.state, t.ticks) for t in rows} == {
            ("robot", "pid", "computed_torque", ShadowState.RUNNING, 400)
        }
        # the figures hold together: the last tick's difference, as the motors would get
        # the torques (the PIDs' with SIO's feed-forward), is within the peak, RMS below it
        last = np.abs(slots["shadow_torque"] - slots["torque"] - slots["ff"])
        assert all(last[t.joint - 1] <= t.peak and 0.0 < t.rms <= t.peak for t in rows)
        with pytest.raises(ServoError, match=r"runs robot-level servo 'computed_torque' in shadow"):
            sv.shadow("left", 2, "pd")
        with pytest.raises(ServoError, match=r"'pid' is a joint servo"):
            sv.shadow_arm("left", "pid")

        # selected while the arm moves: it goes on from its own output, which changes from
        # tick to tick as the arm accelerates; its step as the active servo is one of those
        own = []
        for _ in range(20):
            step_kali_clock(k.inst, 1)
            own.append(slots["shadow_torque"].copy())
        left.select_servo("computed_torque")  # steps the lockstep clock to its tick
        assert sv.arm_active("left") == "computed_torque"
        assert {t.state for t in left.trials()} == {ShadowState.SELECTED}
        steps = np.abs(np.diff(own, axis=0)).max(axis=0)
        jump = np.abs(slots["torque"] - own[-1])
        assert (jump <= 1.5 * steps + 1e-3).all(), (jump, steps)
        step_kali_clock(k.inst, 5000)
        assert handle.state == RequestState.DONE, handle.message
        assert k.inst.fault_text() is None
        left.shadow_servo(None)  # no trial runs: nothing to end, nothing refused
        # a joint's mailbox under a robot-level servo is carried out (it used to stay pending
        # until the client gave up): here a joint servo chosen for when the joints take over
        sv.select("left", 2, "pd", wait=False)
        step_kali_clock(k.inst, 2)
        assert sv.active("left", 2) == "pd" and sv.arm_active("left") == "computed_torque"
        del slots, joints
