"""Cartesian moves of an arm with fewer than six joints (issue 52 item 2).

A 4-joint arm (a yaw, then three pitches) reaches a 4-dimensional set of poses.  A line from
where its measured joints put the tool (``read_pose`` after ``settle``, a few encoder counts
off the set-point) used to be refused: along it, the path's orientation, turned from the
set-point's towards the measured one, and its position keep a part no joint can reach, of
order 1e-9, against an inverse-kinematics tolerance of 1e-11 ("ikine: no solution: 0.000 mm
and 0.0000° left").  The inverse kinematics of an arm of fewer than 6 free joints is now a
least squares one that leaves out up to 1 mm and 0.1° no joint can reach, and says in
readable numbers what it leaves when that is more.
"""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np
import pytest

from kali_daemons.client import Kali
from kali_daemons.core.errors import KinematicsError
from kali_daemons.core.layout import RequestState
from kali_daemons.robots import robot_type
from kali_daemons.robots.numik import OFF_RAD
from kali_daemons.tg.profiles import MotionError

from .test_bring_your_own import PLANAR3_PY, PLANAR3_URDF

YAW = """  <link name="base_link">
    <visual name="pedestal">
      <origin xyz="0 0 0.2" rpy="0 0 0"/>
      <geometry><cylinder radius="0.06" length="0.4"/></geometry>
    </visual>
  </link>
  <joint name="j1" type="revolute">
    <parent link="base_link"/>
    <child link="link0"/>
    <origin xyz="0 0 0.45" rpy="0 0 0"/>
    <axis xyz="0 0 1"/>
    <limit lower="-2.6" upper="2.6" effort="30" velocity="1.5"/>
  </joint>
  <link name="link0">
    <inertial>
      <origin xyz="0 0 0" rpy="0 0 0"/>
      <mass value="1.0"/>
      <inertia ixx="0.002" ixy="0" ixz="0" iyy="0.002" iyz="0" izz="0.002"/>
    </inertial>
  </link>
"""


def yaw4_urdf() -> str:
    """planar3 on a yaw joint: j1 about z at the pedestal's top, then planar3's pitches."""
    text = PLANAR3_URDF.replace('<robot name="planar3">', '<robot name="yaw4">')
    for j in (3, 2, 1):
        text = text.replace(f'name="j{j}"', f'name="j{j + 1}"')
    start = text.index('  <link name="base_link">')
    end = text.index("</link>", start) + len("</link>\n")
    text = text[:start] + YAW + text[end:]
    return text.replace(
        '<parent link="base_link"/>\n    <child link="link1"/>\n    <origin xyz="0 0 0.45"',
        '<parent link="link0"/>\n    <child link="link1"/>\n    <origin xyz="0 0 0"',
    )


def yaw4_py() -> str:
    """planar3's profile module with a fourth joint in front: every per-joint list grows by
    one, and the gains are computed from the URDF at import (servo_gains)."""
    text = PLANAR3_PY.replace("planar3", "yaw4").replace("3-joint planar arm", "4-joint arm")
    grow = {
        "Q_MIN = read_only([": "Q_MIN = read_only([-2.6, ",
        "Q_MAX = read_only([": "Q_MAX = read_only([2.6, ",
        "Q_HOME = read_only([": "Q_HOME = read_only([0.3, ",
        "gear=read_only([": "gear=read_only([100.0, ",
        "counts_per_rev=read_only([": "counts_per_rev=read_only([1000, ",
        "kt=read_only([": "kt=read_only([0.05, ",
        "r_armature=read_only([": "r_armature=read_only([0.6, ",
        "max_current=read_only([": "max_current=read_only([6.0, ",
        "rotor_inertia=read_only([": "rotor_inertia=read_only([2.0e-5, ",
        "viscous=read_only([": "viscous=read_only([0.5, ",
        "coulomb_pos=read_only([": "coulomb_pos=read_only([0.8, ",
        "coulomb_neg=read_only([": "coulomb_neg=read_only([-0.8, ",
        "brake_torque=read_only([": "brake_torque=read_only([25.0, ",
        "WN = read_only([": "WN = read_only([40.0, ",
        "qd_max=read_only([": "qd_max=read_only([1.5, ",
        "qdd_max=read_only([": "qdd_max=read_only([3.0, ",
        "index_phases=read_only([": "index_phases=read_only([1.9, ",
    }
    for old, new in grow.items():
        assert old in text, old
        text = text.replace(old, new)
    text = text.replace("n_joints=3", "n_joints=4")
    # the gains from the URDF, as the module's comment says they were found
    text = re.sub(r"(?ms)^J_HOME = .*?^GRAVITY_MAX = read_only\(\[[^\]]*\]\)  # N.m\n", "", text)
    return text.replace(
        "HOLD = GRAVITY_MAX",
        "import pinocchio as pin\n"
        "_model = pin.buildModelFromUrdf(str(URDF))\n"
        "_model.armature = np.array(DRIVE.armature)\n"
        "_data = _model.createData()\n"
        "J_HOME = np.diag(pin.crba(_model, _data, np.array(Q_HOME)))\n"
        "GRAVITY_MAX = np.abs(pin.computeGeneralizedGravity(_model, _data, np.zeros(4))) + 0.5\n"
        "HOLD = GRAVITY_MAX",
    )


def write_yaw4(where: Path) -> Path:
    where.mkdir(parents=True, exist_ok=True)
    (where / "yaw4.urdf").write_text(yaw4_urdf())
    module = where / "yaw4.py"
    module.write_text(yaw4_py())
    return module


def test_the_least_squares_solution_leaves_out_only_what_no_joint_reaches(
    tmp_path: Path,
) -> None:
    kin = robot_type(str(write_yaw4(tmp_path))).kinematics
    q0 = np.array([0.3, -0.5, 1.0, 0.6])
    pose = kin.fkine(q0)
    # a turn about the tool's own x axis: no joint of a yaw-and-pitches arm makes it
    for angle in (1e-6, 1e-4, 0.5 * OFF_RAD):
        off = pose.copy()
        c, s = math.cos(angle), math.sin(angle)
        off[:3, :3] = pose[:3, :3] @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
        q = kin.ikine(off, q_ref=q0 + 0.01)
        # the least squares solution: the joints move by no more than the tilt asks (the
        # yaw takes what of the tilt it can, along its own axis), the pose the nearest one
        assert np.abs(q - q0).max() <= angle, (angle, q - q0)
        got = kin.fkine(q)
        assert np.linalg.norm(got[:3, 3] - off[:3, 3]) < 1e-3
    c, s = math.cos(0.05), math.sin(0.05)  # 2.9°: far more than a measured pose's counts
    off[:3, :3] = pose[:3, :3] @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    with pytest.raises(KinematicsError) as info:
        kin.ikine(off, q_ref=q0)
    text = str(info.value)
    said = re.search(r"no solution: ([\d.e+-]+) mm and ([\d.e+-]+)° left", text)
    assert said and 0.1 < float(said.group(2)) < 2.9, text  # three figures, readable
    assert "a pose more than 1 mm or 0.1° off them" in text, text


def test_a_line_from_the_measured_pose_of_a_4_joint_arm_runs(
    kali: object, tmp_path: Path
) -> None:
    """The day-one experiment: settle, read_pose, 5 cm straight down; it runs and arrives.
    The measured joints after settle are within a few counts of the demand (here 0 or 1:
    this arm's joints hold well), so the start is also taken 4 counts off on every joint,
    as the researcher's arm was."""
    module = write_yaw4(tmp_path / "arm")
    name = kali(  # type: ignore[operator]
        lockstep=True,
        edits={r"^(  - \{name: right, model: )puma560": rf"\g<1>{module}"},
    )
    with Kali(name) as k:
        k.ready()
        arm = k.robot("right")
        arm.settle()
        counts = 4 * k.inst.cell.rad_per_count[arm.index]
        off = k.start_point(arm.index) + counts * np.array([1, -1, 1, -1])
        for start in (arm.read_pose(), arm.base @ k.flange_pose(off, arm.index) @ arm.tool):
            down = start.copy()
            down[2, 3] -= 0.05
            h = arm.move_line(down, speed=0.05, wait=False)
            h.wait(timeout=120)
            assert h.state == RequestState.DONE
            arm.settle()
            assert np.linalg.norm(arm.read_pose()[:3, 3] - down[:3, 3]) < 1e-3
            back = start.copy()
            arm.move_line(back, speed=0.05)
        with pytest.raises(MotionError, match=r"[\d.e-]+ mm and [\d.e-]+° left"):
            tilted = start.copy()
            c, s = math.cos(0.2), math.sin(0.2)
            tilted[:3, :3] = start[:3, :3] @ np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
            arm.move_line(tilted, speed=0.05)
