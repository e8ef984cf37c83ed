"""Bring your own arm (issue 25 item 7), written as a new user would: a URDF and one profile
module in a directory of their own, named in the config as ``model: planar3.py``, with no
edit to Kali.

The arm: three revolute joints in a vertical plane (the x-z plane of its base, every joint
turning about y), links of 0.3, 0.3 and 0.2 m from joint 1 to the flange, joint 1 on a
0.45 m pedestal.  The profile module declares its drive, limits, gains by ``servo_gains``
from the joint inertia and gravity torque Pinocchio gives for the URDF (written down, and
recomputed here), a calibration sheet, and the generic numerical kinematics
(``kali_daemons.robots.numik.NumericalKinematics``).
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core.errors import ConfigError, KinematicsError
from kali_daemons.core.layout import (
    CalibState,
    FaultCode,
    PowerState,
    RequestState,
)
from kali_daemons.hardware.mcgill.registers import CSR_NO_DISABLE
from kali_daemons.robots import robot_type
from kali_daemons.robots.numik import NEAREST
from kali_daemons.robots.profile import RobotType
from kali_daemons.runtime.config import load_config, parse_config
from kali_daemons.tg.profiles import MotionError
from kali_daemons.tools import launcher
from kali_daemons.wallclock import step_kali_clock

from ..conftest import boards_of, config_text, leftovers, unique_name
from ..test_launcher import kalictl
from . import numpy_data_allocations

# --------------------------------------------------------------------------------------------
# What the user writes

PLANAR3_URDF = """\
<?xml version="1.0"?>
<!-- A 3-joint planar arm: joints j1..j3 about y (the arm moves in the x-z plane), links
     0.3, 0.3 and 0.2 m, the last link 'flange'.  Boxes and cylinders only (the viewer
     draws those).  Inertias: solid boxes about their centres of mass. -->
<robot name="planar3">
  <link name="base_link">
    <visual name="pedestal">
      <origin xyz="0 0 0.2" rpy="0 0 0"/>
      <geometry><cylinder radius="0.06" length="0.4"/></geometry>
    </visual>
  </link>
  <joint name="j1" type="revolute">
    <parent link="base_link"/>
    <child link="link1"/>
    <origin xyz="0 0 0.45" rpy="0 0 0"/>
    <axis xyz="0 1 0"/>
    <limit lower="-2.6" upper="2.6" effort="30" velocity="1.5"/>
  </joint>
  <link name="link1">
    <inertial>
      <origin xyz="0.15 0 0" rpy="0 0 0"/>
      <mass value="2.0"/>
      <inertia ixx="0.0012" ixy="0" ixz="0" iyy="0.0156" iyz="0" izz="0.0156"/>
    </inertial>
    <visual name="link1">
      <origin xyz="0.15 0 0" rpy="0 0 0"/>
      <geometry><box size="0.3 0.06 0.06"/></geometry>
    </visual>
  </link>
  <joint name="j2" type="revolute">
    <parent link="link1"/>
    <child link="link2"/>
    <origin xyz="0.3 0 0" rpy="0 0 0"/>
    <axis xyz="0 1 0"/>
    <limit lower="-2.6" upper="2.6" effort="30" velocity="1.5"/>
  </joint>
  <link name="link2">
    <inertial>
      <origin xyz="0.15 0 0" rpy="0 0 0"/>
      <mass value="1.5"/>
      <inertia ixx="0.0009" ixy="0" ixz="0" iyy="0.0117" iyz="0" izz="0.0117"/>
    </inertial>
    <visual name="link2">
      <origin xyz="0.15 0 0" rpy="0 0 0"/>
      <geometry><box size="0.3 0.06 0.06"/></geometry>
    </visual>
  </link>
  <joint name="j3" type="revolute">
    <parent link="link2"/>
    <child link="link3"/>
    <origin xyz="0.3 0 0" rpy="0 0 0"/>
    <axis xyz="0 1 0"/>
    <limit lower="-2.0" upper="2.0" effort="4.5" velocity="2"/>
  </joint>
  <link name="link3">
    <inertial>
      <origin xyz="0.1 0 0" rpy="0 0 0"/>
      <mass value="0.6"/>
      <inertia ixx="0.00025" ixy="0" ixz="0" iyy="0.002125" iyz="0" izz="0.002125"/>
    </inertial>
    <visual name="link3">
      <origin xyz="0.1 0 0" rpy="0 0 0"/>
      <geometry><box size="0.2 0.05 0.05"/></geometry>
    </visual>
  </link>
  <joint name="flange_joint" type="fixed">
    <parent link="link3"/>
    <child link="flange"/>
    <origin xyz="0.2 0 0" rpy="0 1.5707963267948966 0"/>
  </joint>
  <link name="flange"/>
</robot>
"""

PLANAR3_PY = '''\
"""planar3: a 3-joint planar arm (joints about y, links 0.3/0.3/0.2 m) on McGill-style
drives: 100:1 gears on joints 1-2, 50:1 on joint 3, 1000-count encoders."""

from pathlib import Path

import numpy as np

from kali_daemons.robots.numik import NumericalKinematics
from kali_daemons.robots.profile import Drive, RobotType, read_only, servo_gains

URDF = Path(__file__).with_name("planar3.urdf")
Q_MIN = read_only([-2.6, -2.6, -2.0])  # rad, as the URDF's limits
Q_MAX = read_only([2.6, 2.6, 2.0])
Q_HOME = read_only([-0.5, 1.0, 0.6])  # rad: the simulated arm starts here

DRIVE = Drive(
    gear=read_only([100.0, 100.0, 50.0]),  # motor angle = gear x joint angle
    counts_per_rev=read_only([1000, 1000, 1000], np.int64),  # per motor turn
    kt=read_only([0.05, 0.05, 0.03]),  # N.m/A: 30, 30 and 4.5 N.m at the joint at peak
    r_armature=read_only([0.6, 0.6, 1.2]),  # ohm
    max_current=read_only([6.0, 6.0, 3.0]),  # A, peak
    rotor_inertia=read_only([2.0e-5, 2.0e-5, 5.0e-6]),  # kg.m2, motor side
    viscous=read_only([0.5, 0.3, 0.05]),  # N.m.s/rad, joint side
    coulomb_pos=read_only([0.8, 0.6, 0.2]),  # N.m, joint side
    coulomb_neg=read_only([-0.8, -0.6, -0.2]),
    brake_torque=read_only([25.0, 25.0, 4.0]),  # N.m
    amp_gain_a_per_v=2.5,
    amp_bandwidth_hz=500.0,
    bus_voltage=48.0,
    dac_volts=10.0,
)

# Gains by the PUMA's rule (servo_gains).  From Pinocchio on planar3.urdf with the rotors
# (model.armature = DRIVE.armature): J_HOME = diag(crba(Q_HOME)), GRAVITY_MAX =
# |computeGeneralizedGravity(q = 0)| (the arm level and stretched out: the most on each joint).
J_HOME = read_only([0.7171, 0.3373, 0.02063])  # kg.m2
GRAVITY_MAX = read_only([13.68, 4.562, 0.5886])  # N.m
WN = read_only([40.0, 40.0, 60.0])  # rad/s; joint 3 at 40 held 1 count off, at 60 on it
HOLD = GRAVITY_MAX + np.maximum(DRIVE.coulomb_pos, -DRIVE.coulomb_neg)
PID, PD = servo_gains(J_HOME, WN, 0.7, DRIVE.viscous, HOLD)

ROBOT = RobotType(
    name="planar3",
    description="3-joint planar arm, 0.3/0.3/0.2 m, vertical plane (tests/robots)",
    urdf=URDF,
    n_joints=3,
    q_min=Q_MIN,
    q_max=Q_MAX,
    qd_max=read_only([1.5, 1.5, 2.0]),  # rad/s the trajectory generator plans with
    qdd_max=read_only([3.0, 3.0, 4.0]),  # rad/s2
    q_home=Q_HOME,
    drive=DRIVE,
    kinematics=NumericalKinematics(URDF, Q_MIN, Q_MAX, Q_HOME, name="planar3"),
    pid_defaults=PID,
    pd_defaults=PD,
    index_phases=read_only([0.7, 3.1, 5.2]),  # rad: each joint's index pulse, motor side
)
'''


def write_arm(where: Path, py: str = PLANAR3_PY, urdf: str = PLANAR3_URDF) -> Path:
    """The user's two files in ``where``; the module's path."""
    where.mkdir(parents=True, exist_ok=True)
    (where / "planar3.urdf").write_text(urdf)
    module = where / "planar3.py"
    module.write_text(py)
    return module


def pose_at(here: np.ndarray, shift: list[float]) -> np.ndarray:
    """``here`` moved by ``shift`` (m, world), its orientation kept."""
    there = here.copy()
    there[:3, 3] += shift
    return there


def write_config(where: Path, name: str, model: str = "planar3.py") -> Path:
    """The default config beside the arm: a PUMA on the left, ``model`` on the right."""
    text = config_text(name, {r"^(  - \{name: right, model: )puma560": rf"\g<1>{model}"})
    path = where / "kali.yaml"
    path.write_text(text)
    return path


def parse_beside(where: Path, model: str) -> None:
    """Parse a config in ``where`` whose right arm is ``model`` (a ConfigError if refused)."""
    text = config_text("byo", {r"^(  - \{name: right, model: )puma560": rf"\g<1>{model}"})
    parse_config(text, "kali.yaml", str(where))


@pytest.fixture
def planar3(tmp_path: Path) -> RobotType:
    """The user's arm, loaded through the config path a robot's model takes."""
    return robot_type(str(write_arm(tmp_path / "arm")))


# --------------------------------------------------------------------------------------------
# The type: loaded from the file, named absolute, the same object in every parse


def test_a_config_names_the_module_relative_to_itself(tmp_path: Path) -> None:
    module = write_arm(tmp_path)
    cfg = load_config(write_config(tmp_path, "byo"))
    right = cfg.robots[1]
    assert right.model == str(module) and right.type.name == "planar3"
    assert right.n_joints == 3 and cfg.joints.total == 9
    assert right.type is robot_type(str(module))  # loaded once per process
    assert right.index_phases == (0.7, 3.1, 5.2) and right.safe_rad == (0.15,) * 3
    # every process parses the arena's text with the same base_dir: the same config
    assert parse_config(cfg.text, cfg.source, cfg.base_dir) == cfg


def test_the_gains_follow_the_rule_on_the_urdf(planar3: RobotType) -> None:
    """The module's J_HOME and GRAVITY_MAX are what Pinocchio computes from the URDF."""
    import pinocchio as pin

    model = pin.buildModelFromUrdf(str(planar3.urdf))
    model.armature = np.array(planar3.drive.armature)
    data = model.createData()
    j_home = np.diag(pin.crba(model, data, np.array(planar3.q_home)))
    gravity = np.zeros(3)
    rng = np.random.default_rng(0)
    for q in rng.uniform(planar3.q_min, planar3.q_max, (2000, 3)):
        gravity = np.maximum(gravity, np.abs(pin.computeGeneralizedGravity(model, data, q)))
    kp = [g["kp"] for g in planar3.pid_defaults]
    resets = [g["integration_reset"] for g in planar3.pid_defaults]
    # servo_gains: ωn as written, raised where the load needs it to keep the 0.01 rad band
    band = [g["integration_band"] for g in planar3.pid_defaults]
    wn = np.maximum([40.0, 40.0, 60.0], np.sqrt(2.5 * np.array(resets) / (0.01 * j_home)))
    np.testing.assert_allclose(kp, j_home * wn**2, rtol=1e-3)
    assert band == [0.01] * 3
    assert (np.array(resets) >= gravity + planar3.drive.coulomb_pos).all(), (resets, gravity)
    assert (planar3.drive.peak_joint_torque > 2 * gravity).all()


def test_kalictl_types_checks_the_file(tmp_path: Path) -> None:
    module = write_arm(tmp_path)
    r = kalictl("types", str(module))
    assert r.returncode == 0, r.stderr
    assert "puma560      6 joints" in r.stdout
    assert f"{module} 3 joints  3-joint planar arm" in r.stdout and "(ROBOT 'planar3')" in r.stdout
    r = kalictl("types", str(tmp_path / "nothere.py"))
    assert r.returncode == 1 and f"robot type file {tmp_path}/nothere.py: no such file" in r.stderr


# --------------------------------------------------------------------------------------------
# Refusals at config parse: the file, the field, the value and the rule

_URDF_AT = 'URDF = Path(__file__).with_name("planar3.urdf")'


@pytest.mark.parametrize(
    ("module", "urdf", "says"),
    [
        ("1 / 0\n" + PLANAR3_PY, None, r"importing it raised ZeroDivisionError \(line 1\): "),
        (PLANAR3_PY.replace("ROBOT = ", "ARM = "), None, r"defines no ROBOT; the module must"),
        (PLANAR3_PY + "ROBOT = 'planar3'\n", None, r"ROBOT is str 'planar3', not a RobotType"),
        (
            PLANAR3_PY.replace("n_joints=3", "n_joints=9"),
            None,
            r"\(line \d+\): robot type 'planar3': n_joints = 9: must be 1 \.\. 8",
        ),
        (
            PLANAR3_PY.replace("read_only([1.5, 1.5, 2.0])", "read_only([1.5, 1.5])"),
            None,
            r"robot type 'planar3': qd_max = .*: must be 3 finite numbers, one per joint",
        ),
        (
            PLANAR3_PY.replace(_URDF_AT, _URDF_AT.replace("planar3.urdf", "nope.urdf")),
            None,
            r"robot type 'planar3': urdf = '.*/nope\.urdf': no such file",
        ),
        (
            None,
            PLANAR3_URDF.replace("</robot>", ""),
            r"ROBOT\.urdf .*/planar3\.urdf: Pinocchio cannot load it: .*not contain a valid URDF",
        ),
        (
            None,
            PLANAR3_URDF.replace('"j2"', '"elbow"'),
            r"moving joints \['j1', 'elbow', 'j3'\] \(Pinocchio\): must be exactly \['j1', 'j2', "
            r"'j3'\], one per joint of ROBOT\.n_joints = 3",
        ),
        (
            None,
            PLANAR3_URDF.replace('"flange"', '"tool0"'),
            r"no link 'flange': the arm's last link must be named so",
        ),
        (
            None,
            re.sub(
                r'(<link name="link3">)\s*<inertial>.*?</inertial>',
                r"\1",
                PLANAR3_URDF,
                count=1,
                flags=re.S,
            ),
            r"MuJoCo cannot load it: .*mass and inertia of moving bodies .*'link3'",
        ),
        (
            PLANAR3_PY.replace(
                "NumericalKinematics(URDF,", 'NumericalKinematics(URDF.with_name("other.urdf"),'
            ),
            None,
            r"ROBOT\.kinematics\.fkine\(q_home\) puts the flange at \(0\.6399, 0\.0000, "
            r"0\.2272\) m, the URDF at \(0\.6173, 0\.0000, 0\.2718\) m \(50\.\d+ mm apart",
        ),
    ],
    ids=[
        "raises",
        "no-robot",
        "not-a-robot-type",
        "nine-joints",
        "short-list",
        "no-urdf",
        "urdf-not-xml",
        "joint-names",
        "no-flange",
        "mujoco-refuses",
        "kinematics-of-another-arm",
    ],
)
def test_a_bad_arm_is_refused_at_parse_naming_file_field_value_and_rule(
    tmp_path: Path, module: str | None, urdf: str | None, says: str
) -> None:
    path = write_arm(tmp_path, module or PLANAR3_PY, urdf or PLANAR3_URDF)
    # a link 0.05 m longer: the same joints, the flange elsewhere
    (tmp_path / "other.urdf").write_text(
        PLANAR3_URDF.replace('"0.2 0 0" rpy="0 1.57', '"0.25 0 0" rpy="0 1.57')
    )
    with pytest.raises(ConfigError) as refused:
        parse_beside(tmp_path, "planar3.py")
    text = str(refused.value)
    assert text.startswith(
        f"config: kali.yaml: robots[1].model = 'planar3.py': robot type file {path}"
    ), text
    assert re.search(says, text), text


def test_a_missing_module_is_refused_naming_where_relative_paths_start(tmp_path: Path) -> None:
    with pytest.raises(
        ConfigError,
        match=rf"robots\[1\]\.model = 'arms/planar3\.py': robot type file {tmp_path}/arms/"
        rf"planar3\.py: no such file \(a relative path is taken from the config file's "
        rf"directory, {tmp_path}\)",
    ):
        parse_beside(tmp_path, "arms/planar3.py")
    with pytest.raises(
        ConfigError,
        match=r"robots\[1\]\.model = 'kuka': must be one of: fr3, panda, puma560, ur5, "
        r"or a \.py file defining ROBOT",
    ):
        parse_beside(tmp_path, "kuka")


def test_kalictl_start_refuses_a_bad_arm_and_leaves_nothing(tmp_path: Path) -> None:
    write_arm(tmp_path, PLANAR3_PY.replace("ROBOT = ", "ARM = "))
    name = unique_name()
    r = kalictl("start", "-c", str(write_config(tmp_path, name)), "--lockstep")
    assert r.returncode == 1
    assert (
        f"robots[1].model = 'planar3.py': robot type file {tmp_path}/planar3.py: defines no ROBOT"
        in r.stderr
    )
    assert leftovers(name) == ([], [])


# --------------------------------------------------------------------------------------------
# The generic numerical kinematics on a planar arm


def test_ikine_finds_in_plane_poses_from_near(planar3: RobotType) -> None:
    """From the previous set-point's neighbourhood: to 1e-9 in a few iterations."""
    k = planar3.kinematics
    rng = np.random.default_rng(1)
    out = np.empty(3)
    iterations = []
    for q in rng.uniform(planar3.q_min, planar3.q_max, (300, 3)):
        t6 = k.fkine(q)
        assert abs(t6[1, 3]) < 1e-15  # in the x-z plane
        q_ref = np.clip(q + rng.normal(0.0, 0.01, 3), planar3.q_min, planar3.q_max)
        got = k.ikine(t6, NEAREST, q_ref=q_ref, out=out)
        assert got is out
        np.testing.assert_allclose(k.fkine(got), t6, rtol=0, atol=1e-9)
        iterations.append(k.solver.iterations)
    assert np.percentile(iterations, 95) <= 4, np.bincount(iterations)
    assert k.config_of(planar3.q_home) is NEAREST and k.configs == (NEAREST,)
    assert k.parse_config("NEAREST") is NEAREST
    with pytest.raises(KinematicsError, match="planar3: configuration 'lun': the planar3 has one"):
        k.parse_config("lun")


def test_ikine_refuses_a_pose_off_the_plane_naming_the_residual(planar3: RobotType) -> None:
    k = planar3.kinematics
    here = k.fkine(planar3.q_home)
    off = here.copy()
    off[1, 3] = 0.01  # 1 cm out of the plane
    with pytest.raises(
        KinematicsError,
        match=r"planar3 ikine: no solution: 10 mm and 0° left after \d iterations, "
        r"which no joint's motion reduces \(with 3 free joints the flange moves in only 3 of a "
        r"pose's 6 directions",
    ):
        k.ikine(off, NEAREST, q_ref=planar3.q_home)
    assert k.solver.iterations <= 3  # no 60 iterations spent on it
    tilted = here.copy()
    tilted[:3, :3] = here[:3, :3] @ np.array(  # turned 2° about the flange's z
        [[math.cos(0.035), -math.sin(0.035), 0], [math.sin(0.035), math.cos(0.035), 0], [0, 0, 1]]
    )
    tilted[0, 3] += 0.02  # and 2 cm along x, which alone is reachable
    with pytest.raises(KinematicsError, match=r"mm and 2\.0\d° left after \d+ iterations"):
        k.ikine(tilted, NEAREST, q_ref=planar3.q_home)
    far = here.copy()
    far[0, 3] = 1.0
    with pytest.raises(KinematicsError, match=r"out of reach: the flange at \(1\.0000, "):
        k.ikine(far, NEAREST, q_ref=planar3.q_home)


def test_singular_names_the_planar_jacobian(planar3: RobotType) -> None:
    k = planar3.kinematics
    assert k.singular(planar3.q_home) is None
    why = k.singular(np.array([0.3, 0.0, 0.0]))  # stretched out: the elbow singularity
    assert why is not None and re.match(
        r"0\.0000 from a singularity: the 6×3 Jacobian's smallest singular value is below 0\.02",
        why,
    ), why


def test_the_cycle_functions_allocate_no_numpy_data(planar3: RobotType) -> None:
    k = planar3.kinematics
    q = planar3.q_home.copy()
    t6, out = np.empty((4, 4)), np.empty(3)
    k.fkine(q, t6)
    q_ref = q + 0.01
    assert numpy_data_allocations(lambda: k.fkine(q, t6)) == 0
    assert numpy_data_allocations(lambda: k.ikine(t6, NEAREST, q_ref, out)) == 0
    assert numpy_data_allocations(lambda: k.singular(q)) == 0


# --------------------------------------------------------------------------------------------
# End to end: the planar arm beside a PUMA, started from the command line in lockstep


@pytest.fixture
def started(tmp_path: Path) -> Iterator[str]:
    """``kalictl start -c kali.yaml --lockstep`` in the user's directory; the instance name.
    Stopped afterwards, leaving no process and no /dev/shm object."""
    write_arm(tmp_path)
    name = unique_name()
    env = {"KALI_LOG_DIR": str(tmp_path / "logs")}
    try:
        r = kalictl("start", "-c", str(write_config(tmp_path, name)), "--lockstep", env=env)
        assert r.returncode == 0, r.stderr
        yield name
    finally:
        launcher.stop(name)
        assert leftovers(name) == ([], []), f"instance {name} left something behind"


def step_until(k: Kali, done: object, ticks: int, what: str) -> None:
    """Step the clock 10 ticks at a time until ``done()`` (at most ``ticks``)."""
    for _ in range(ticks // 10):
        if done():  # type: ignore[operator]
            return
        step_kali_clock(k.inst, 10)
    assert done(), f"not within {ticks} ticks: {what}"  # type: ignore[operator]


def test_the_planar_arm_powers_calibrates_holds_moves_and_halts_on_its_range(
    started: str,
) -> None:
    with Kali(started) as k:
        right = k.robot("right")
        rtype = k.inst.config.robots[1].type
        count = rtype.drive.rad_per_count
        joints = k.servo.level.joints
        arm = k.inst.config.joints.span(1)
        step_kali_clock(k.inst, 30)
        for robot in k.names:
            k.servo.power(robot, True)
        step_kali_clock(k.inst, 100)
        assert [k.servo.power_state(r) for r in k.names] == [PowerState.ON] * 2
        assert right.read_joints().shape == (3,)

        k.servo.calibrate("right")
        step_until(
            k,
            lambda: k.servo.calibration("right")[0] in (CalibState.DONE, CalibState.FAILED),
            10_000,
            "calibration over",
        )
        assert k.servo.calibrated("right"), k.servo.calibration("right")

        step_kali_clock(k.inst, 3000)  # the integral takes up the gravity load
        worst = np.zeros(3)
        for _ in range(20):  # at rest, over 200 ms
            step_kali_clock(k.inst, 10)
            error = (joints["demand"][arm] - joints["q"][arm]) / count
            worst = np.maximum(worst, np.abs(error))
        assert (worst <= 1.0).all(), f"hold error (counts) {worst}"

        target = right.read_joints() + np.radians([15.0, -20.0, 25.0])
        h = right.move_joints(target, speed=0.5, wait=False)
        step_until(k, lambda: h.done, 5000, "move_joints over")
        assert h.state == RequestState.DONE, h.message
        step_kali_clock(k.inst, 1000)
        assert np.abs(right.read_joints() - target).max() < math.radians(0.05)

        here = right.read_pose()  # in the world; the arm's plane is the world's x-z plane
        h = right.move_line(pose_at(here, [0.03, 0.0, 0.03]), speed=0.05, wait=False)
        step_until(k, lambda: h.done, 5000, "move_line over")
        assert h.state == RequestState.DONE, h.message
        step_kali_clock(k.inst, 1000)
        np.testing.assert_allclose(right.read_pose(), pose_at(here, [0.03, 0.0, 0.03]), atol=3e-4)

        # every process took the arm: the non-serious dynamics and viewer are still there
        rows = launcher.describe(k.inst)
        assert {r["name"] for r in rows if r["state"] == "ACTIVE" and r["alive"]} == {
            p.name for p in k.inst.config.processes
        }

        with pytest.raises(MotionError, match=r"joint 3: target 120\.00° outside its range"):
            right.move_joints(np.append(target[:2], math.radians(120.0)), wait=False)

        # pushed past joint 3's +2.0 rad limit through its set-point FIFO: SIO halts
        fifo = k.servo.level.fifo(1)
        start = joints["demand"][arm].copy()
        for m in range(1, 151):
            fifo.push(start + np.array([0.0, 0.0, (2.05 - start[2]) * m / 150]))
        step_until(k, lambda: bool(k.inst.fault["active"]), 3000, "a fault")
        info = k.inst.read_fault()
        text = k.inst.fault_text() or ""
        assert FaultCode[info.code] == FaultCode.RANGE and info.process == "sio", text
        assert re.search(r"robot 'right' joint 3 at 114\.\d\d° is beyond its limit 114\.59°", text)
        boards = boards_of(k.inst)
        assert not int(boards["csr"][1]) & CSR_NO_DISABLE  # amplifiers commanded off
        del joints, fifo, boards
