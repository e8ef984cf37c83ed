"""Servo plugins loaded while running (issue 55 item 6, ``kali_daemons/servo/loading.py``):
``kali.servo.load(path)`` and ``kalictl servo load FILE`` add a joint-level or robot-level
plugin to a running instance, every SV, checked first as a plugin the config names is (and
its step against the servo period, its load against the gap after a cycle); the program then
trials it in shadow and selects it bumplessly.  A file that does not load, whose step raises,
returns NaN or is too slow, is refused before it runs a real tick, naming why."""

from __future__ import annotations

import os
import re
import textwrap
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core.errors import ServoError
from kali_daemons.core.layout import ShadowState
from kali_daemons.examples import servo_plugin_example
from kali_daemons.wallclock import step_kali_clock
from tests.test_armservo import LEFT_ROBOT_SERVOS
from tests.test_bridge import bridged  # noqa: F401  (the fixture)
from tests.test_launcher import kalictl
from tests.test_shadow import moving_left

EXAMPLE = Path(servo_plugin_example.__file__).read_text()


def renamed(tmp_path: Path, name: str, text: str = EXAMPLE) -> Path:
    """The example plugin (a bandwidth PD, ``bwpd``) as a file of its own registering
    ``name``: the default cell has ``bwpd`` from its config already."""
    path = tmp_path / f"{name}.py"
    path.write_text(text.replace('NAME = "bwpd"', f'NAME = "{name}"'))
    return path


def test_a_servo_loaded_while_the_arm_moves_is_tried_in_shadow_then_selected_bumplessly(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    name = kali(lockstep=True)
    with Kali(name) as k:
        sv = k.servo
        handle = moving_left(k, [10, -15, 10, 0, 0, 0])
        step_kali_clock(k.inst, 50)
        assert sv.load(renamed(tmp_path, "live_pd")) == ["live_pd"]
        assert [(e.servos, e.verdict) for e in sv.loaded()] == [(["live_pd"], "")]
        left = k.robot("left")
        left.shadow_servo("live_pd", joint=2)
        step_kali_clock(k.inst, 100)
        (trial,) = [t for t in left.trials() if t.state == ShadowState.RUNNING]
        assert trial.shadow == "live_pd" and trial.ticks >= 99
        # joint 3 is handed over from its PID (joint 2 goes on from its trial's own state)
        torque = sv.level.slots["torque"][sv.slot("left", 3) : sv.slot("left", 3) + 1]
        earlier = float(torque[0])
        step_kali_clock(k.inst, 1)
        before = float(torque[0])
        left.select_joint_servos("live_pd", {"bandwidth_hz": 4.0, "inertia": 4.4})  # a tick
        assert [sv.active("left", j) for j in range(1, 7)] == ["live_pd"] * 6
        # no jump: the switch tick's change is of the moving arm's tick-to-tick size
        assert abs(float(torque[0]) - before) < max(3 * abs(before - earlier), 0.5)
        handle.wait(timeout=30.0)
        assert handle.state.name == "DONE"
        # a second program attaching later sees it by name, as a configured plugin's
        with Kali(name) as other:
            assert other.servo.active("left", 2) == "live_pd"
            assert other.servo.get_params("left", 2)["bandwidth_hz"] == 4.0


SPIN = "t = time.{clock}() + {s}\nwhile time.{clock}() < t:\n    pass\n"
TAB = " " * 4
STEP_BODY = TAB + "error = demand - position\n"
BAD_FILES = {  # what is changed in the example plugin (named 'bad'), and the refusal
    "syntax": (("def step(", "def step(:"), r"syntax error at line \d+"),
    "import-raises": (
        ("NAME = ", "raise RuntimeError('no')\nNAME = "),
        r"import failed: RuntimeError: no",
    ),
    "step-raises": (
        (STEP_BODY, STEP_BODY + "    1 / 0\n"),
        r"step\(data, 0.01, 0.0\) at its defaults raised ZeroDivisionError",
    ),
    "nan": (
        ("return data.kp * error - data.kv * v + bias, error", "return math.nan, error"),
        r"at its defaults returned \(nan",
    ),
    "slow-step": (
        (STEP_BODY, STEP_BODY + textwrap.indent(SPIN.format(clock="perf_counter", s=2e-3), TAB)),
        r"servo 'bad' takes \d+ µs a step, the servo period is 1000 µs",
    ),
    "slow-load": (
        ("NAME = ", SPIN.format(clock="thread_time", s=0.02) + "NAME = "),
        r"loading it takes \d+ µs, more than the 500 µs an SV may spend",
    ),
    "taken-name": (('NAME = "bad"', 'NAME = "pid"'), r"algorithm name 'pid' is already registered"),
    "nothing": (
        ("    registry.register(", "    return\n    registry.register("),
        r"registered no algorithm",
    ),
}


@pytest.mark.parametrize(("edit", "why"), BAD_FILES.values(), ids=BAD_FILES.keys())
def test_a_plugin_that_would_fail_is_refused_before_it_runs_a_tick(
    kali: Callable[..., str], tmp_path: Path, edit: tuple[str, str], why: str
) -> None:
    name = kali(lockstep=True)
    text = EXAMPLE.replace('NAME = "bwpd"', 'NAME = "bad"').replace(
        "import math\n", "import math\nimport time\n", 1
    )
    old, new = edit
    assert old in text
    path = tmp_path / "bad.py"
    path.write_text(text.replace(old, new, 1))
    with Kali(name) as k:
        tick = int(k.inst.clock["tick"])
        names = list(k.servo.level.registry.names())
        with pytest.raises(ServoError, match=why) as refused:
            k.servo.load(path)
        assert str(refused.value).startswith(f"servo: load '{path}': ")  # names the file
        assert int(k.inst.clock["tick"]) == tick  # refused before a tick ran
        assert k.servo.loaded() == [] and k.servo.level.registry.names() == names
        # and the instance loads a good file afterwards
        assert k.servo.load(renamed(tmp_path, "good_pd")) == ["good_pd"]


def test_kalictl_servo_load_offers_a_file_the_svs_take_at_their_next_tick(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    name = kali(lockstep=True)
    path = renamed(tmp_path, "cli_pd")
    out = kalictl("-i", name, "servo", "load", str(path))
    assert out.returncode == 0, out.stderr
    assert "offered cli_pd; the SVs take it at their next tick (kalictl clock step 1)" in out.stdout
    listed = kalictl("-i", name, "servo", "list").stdout
    assert re.search(r"cli_pd\.py: cli_pd being loaded", listed), listed
    kalictl("-i", name, "clock", "step", "1")
    listed = kalictl("-i", name, "servo", "list").stdout
    assert re.search(r"cli_pd\.py: cli_pd loaded", listed), listed
    assert re.search(r"^cli_pd\s+joint\s+bandwidth_hz, inertia", listed, re.M), listed
    with Kali(name) as k:
        k.ready(["left"])
        step_kali_clock(k.inst, 200)
        out = kalictl("-i", name, "servo", "select", "left", "2", "cli_pd")
        assert out.returncode == 0, out.stderr
        step_kali_clock(k.inst, 1)
        assert k.servo.active("left", 2) == "cli_pd"
        assert np.isfinite(float(k.servo.level.slots["torque"][k.servo.slot("left", 2)]))


def load_trial_select(k: Kali, path: Path) -> list[object]:
    """Load ``path``'s ``live_pd``, try it in shadow on the left arm's joint 2 while the
    arm holds, then select it on every joint: what a program sees on the way."""
    k.ready(["left"])
    k.sleep(0.2)
    names = k.servo.load(path)
    left = k.robot("left")
    left.shadow_servo("live_pd", joint=2)
    k.sleep(0.1)
    trials = [(t.shadow, t.ticks, t.rms) for t in left.trials() if t.state == ShadowState.RUNNING]
    left.select_joint_servos("live_pd", {"bandwidth_hz": 4.0, "inertia": 4.4})
    k.sleep(0.1)
    state = left.read_state()
    listed = [(e.file, e.servos, e.verdict) for e in k.servo.loaded()]
    return [names, trials, state.servos, state.q.tolist(), state.servo_torque.tolist(), listed]


def test_a_remote_program_loads_a_servo_as_a_local_one(
    kali: Callable[..., str],
    bridged: Callable[..., tuple[str, str]],  # noqa: F811
    tmp_path: Path,
) -> None:
    """Through the bridge (``Kali.connect``), unchanged: the plugin file is read on the
    program's machine and loaded on the controller's; what the program sees, tick for tick,
    equals the same program's run locally."""
    path = renamed(tmp_path, "live_pd")
    with Kali(kali(lockstep=True)) as local:
        here = load_trial_select(local, path)
    name, endpoint = bridged()
    with Kali.connect(endpoint, name) as remote:
        there = load_trial_select(remote, path)
    assert here[0] == ["live_pd"] and here[2] == ("live_pd",) * 6
    assert there == here


ARM_PD = Path(__file__).parent / "system" / "arm_pd_servo.py"


def test_a_robot_level_servo_loaded_while_running_runs_the_arm(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True, edits=LEFT_ROBOT_SERVOS)
    with Kali(name) as k:
        k.ready(["left"])
        step_kali_clock(k.inst, 200)
        assert k.servo.load(ARM_PD) == ["arm_pd"]
        left = k.robot("left")
        sent = k.servo.level.joints["torque"][k.servo.level.map.span(0)]
        before = sent.copy()
        left.select_servo("arm_pd")
        step_kali_clock(k.inst, 1)
        assert k.servo.arm_active("left") == "arm_pd"
        assert left.servo_params() == {"kp": 2000.0, "kv": 100.0}
        np.testing.assert_allclose(sent, before, atol=0.5)  # handed over, no jump
        q = left.read_joints()
        handle = left.move_joints(q + np.radians([5, -5, 5, 0, 0, 0]), speed=0.3, wait=False)
        handle.wait(timeout=30.0)
        assert handle.state.name == "DONE" and left.read_state().servos == ("arm_pd",) * 6
        assert k.inst.fault_text() is None


AWARE = Path(__file__).parent / "system" / "aware_servo.py"


def test_a_loaded_servo_learns_its_joint_and_steps_on_the_demands_velocity(
    kali: Callable[..., str],
) -> None:
    """``joint_aware``: ``init`` gets each joint's ``JointInfo`` (its robot type's limits and
    drive); ``velocity_aware``: ``step`` gets the demand's velocity SIO fed the slot."""
    name = kali(lockstep=True)
    with Kali(name) as k:
        sv = k.servo
        assert sv.load(AWARE) == ["aware_pd"]
        rtype = k.robot("right").type
        for robot in ("left", "right"):
            for j in range(1, 7):
                rec = sv.get_servo(robot, j, "aware_pd")
                drive = rtype.drive
                limit = drive.kt[j - 1] * drive.max_current[j - 1] * abs(drive.gear[j - 1])
                assert int(rec["joint"]) == j and float(rec["q_max"]) == rtype.q_max[j - 1]
                assert float(rec["limit"]) == pytest.approx(limit)
        handle = moving_left(k, [10, -15, 10, 0, 0, 0])
        step_kali_clock(k.inst, 300)  # under way
        k.robot("left").select_joint_servos("aware_pd")
        i = sv.slot("left", 2)
        seen = []
        for _ in range(50):
            step_kali_clock(k.inst, 1)
            rec = sv.get_servo("left", 2, "aware_pd")
            seen.append(float(rec["last_velocity_demand"]))
            assert seen[-1] == float(sv.level.slots["demand_vel"][i])
        assert max(abs(v) for v in seen) > 0.01  # the arm is moving: a real velocity
        handle.wait(timeout=30.0)
        assert handle.state.name == "DONE" and k.inst.fault_text() is None


def test_a_file_an_sv_cannot_take_is_refused_and_holds_its_place(
    kali: Callable[..., str], tmp_path: Path
) -> None:
    """A file that loads in the client but not in the SVs (here: its top level raises in any
    other process) is refused naming the SV and why; its servos can be neither selected nor
    tried, and a file loaded after it gets the next places in every process."""
    name = kali(lockstep=True)
    fussy = EXAMPLE.replace(
        'NAME = "bwpd"',
        f'if __import__("os").getpid() != {os.getpid()}:\n'
        '    raise RuntimeError("only in the loading process")\nNAME = "fussy"',
    )
    path = tmp_path / "fussy.py"
    path.write_text(fussy)
    with Kali(name) as k:
        k.ready(["left"])
        step_kali_clock(k.inst, 200)
        with pytest.raises(ServoError, match=r"offered, but sv\.\d: .*only in the loading process"):
            k.servo.load(path)
        (entry,) = k.servo.loaded()
        assert entry.servos == ["fussy"] and "only in the loading process" in str(entry.verdict)
        with pytest.raises(ServoError, match=r"servo 'fussy' is not loaded here"):
            k.robot("left").select_joint_servos("fussy")
        assert k.servo.active("left", 1) == "pid"
        assert k.servo.load(renamed(tmp_path, "after_pd")) == ["after_pd"]
        k.robot("left").select_joint_servos("after_pd")
        assert k.servo.active("left", 1) == "after_pd"
        with Kali(name) as other:  # a reader taking both: the failed one held, the next after
            assert other.servo.active("left", 1) == "after_pd"
        assert k.inst.fault_text() is None
