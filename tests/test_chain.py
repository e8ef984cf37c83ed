"""The serial chain read from a robot type's URDF (``kali_daemons.robots.chain``): its flange pose
equals Pinocchio's on every shipped type and on an arm with unaligned axes and fixed joints
between the moving ones, the compiled ``kali_chain_pose`` equals the numpy reference, and a
URDF that is not a type's chain is refused naming the file."""

from __future__ import annotations

import dataclasses
from functools import cache
from pathlib import Path

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kali_daemons.core import kernels
from kali_daemons.core.errors import ModelError
from kali_daemons.robots import RobotType, known_types, robot_type
from kali_daemons.robots.cell import FLANGE_FRAME, load_pinocchio
from kali_daemons.robots.chain import Chain, chain_of, flange_pose

SETTINGS = settings(max_examples=60, deadline=None)
TOL = 1e-12
TYPES = known_types()


@cache
def pinocchio_of(urdf: Path) -> tuple[pin.Model, pin.Data, int]:
    """A Pinocchio model of ``urdf`` (a shipped type's through ``load_pinocchio``), its data
    and the flange's frame id."""
    shipped = {robot_type(name).urdf: robot_type(name) for name in TYPES}
    model = load_pinocchio(shipped[urdf]) if urdf in shipped else pin.buildModelFromUrdf(str(urdf))
    return model, model.createData(), model.getFrameId(FLANGE_FRAME)


def pinocchio_flange(urdf: Path, q: np.ndarray) -> np.ndarray:
    """Pinocchio's flange placement (4×4) at joint angles ``q`` (a continuous joint's
    configuration is its angle's cosine and sine there)."""
    model, data, flange = pinocchio_of(urdf)
    config = np.zeros(model.nq)
    for joint in model.joints[1:]:
        angle = q[joint.idx_v]
        if joint.nq == 2:
            config[joint.idx_q : joint.idx_q + 2] = np.cos(angle), np.sin(angle)
        else:
            config[joint.idx_q] = angle
    pin.forwardKinematics(model, data, config)
    pin.updateFramePlacements(model, data)
    return data.oMf[flange].homogeneous


@st.composite
def angles_of(draw: st.DrawFn, rtype: RobotType) -> np.ndarray:
    """Joint angles within ``rtype``'s limits, the limits themselves included."""
    return np.array(
        [
            draw(st.floats(float(lo), float(hi), allow_nan=False))
            for lo, hi in zip(rtype.q_min, rtype.q_max, strict=True)
        ]
    )


# --------------------------------------------------------------------------------------------
# The shipped types


@pytest.mark.parametrize("name", TYPES)
@SETTINGS
@given(data=st.data())
def test_flange_pose_equals_pinocchio_on_every_type(name: str, data: st.DataObject) -> None:
    rtype = robot_type(name)
    q = data.draw(angles_of(rtype))
    chain = chain_of(rtype)
    expected = pinocchio_flange(rtype.urdf, q)
    np.testing.assert_allclose(flange_pose(chain, q), expected, rtol=0, atol=TOL)


@pytest.mark.parametrize("name", TYPES)
@SETTINGS
@given(data=st.data())
def test_the_kernel_equals_flange_pose(name: str, data: st.DataObject) -> None:
    rtype = robot_type(name)
    chain = chain_of(rtype)
    q, out = np.zeros(chain.n), np.full((4, 4), np.nan)
    pose = kernels.chain_pose(chain, q, out)
    q[:] = data.draw(angles_of(rtype))  # the kernel reads q where it was bound
    assert pose() == 0
    np.testing.assert_allclose(out, flange_pose(chain, q), rtol=0, atol=TOL)
    assert out[3].tolist() == [0.0, 0.0, 0.0, 1.0]


@pytest.mark.parametrize("name", TYPES)
def test_a_types_chain_is_its_joints_and_read_once(name: str) -> None:
    rtype = robot_type(name)
    chain = chain_of(rtype)
    assert chain is chain_of(rtype)
    n = rtype.n_joints
    assert chain.n == n
    assert chain.origins.shape == (n + 1, 4, 4) and chain.axes.shape == (n, 3)
    assert chain.origins.flags.c_contiguous and not chain.origins.flags.writeable
    np.testing.assert_allclose(np.linalg.norm(chain.axes, axis=1), 1.0, rtol=0, atol=1e-15)
    assert (chain.origins[:, 3] == [0.0, 0.0, 0.0, 1.0]).all()


def test_flange_pose_writes_into_out() -> None:
    chain = chain_of(robot_type("puma560"))
    q = robot_type("puma560").q_home
    out = np.zeros((4, 4))
    assert flange_pose(chain, q, out) is out
    np.testing.assert_array_equal(out, flange_pose(chain, q))


# --------------------------------------------------------------------------------------------
# An arm of our own: what the shipped URDFs do not have


def joint(name: str, kind: str, parent: str, child: str, xyz: str, rpy: str, axis: str) -> str:
    limit = '<limit lower="-3" upper="3" effort="1" velocity="1"/>' if kind != "fixed" else ""
    axis_tag = f'<axis xyz="{axis}"/>' if axis else ""
    return (
        f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
        f'<origin xyz="{xyz}" rpy="{rpy}"/>{axis_tag}{limit}</joint>'
    )


def urdf_text(joints: list[tuple[str, str, str, str, str, str, str]]) -> str:
    """A URDF of bare links (a point mass each, so Pinocchio keeps them) joined by
    ``joints``: (name, type, parent, child, xyz, rpy, axis)."""
    links = {j[2] for j in joints} | {j[3] for j in joints}
    inertial = (
        '<inertial><mass value="1"/>'
        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial>'
    )
    body = "".join(f'<link name="{link}">{inertial}</link>' for link in sorted(links))
    body += "".join(joint(*j) for j in joints)
    return f'<?xml version="1.0"?><robot name="odd">{body}</robot>'


# Six moving joints as a UR5 type has: fixed joints before j1, between j3 and j4 and after
# j6; axes off the frame's axes, one given unnormalised, one left to URDF's default (x);
# a continuous joint; a branch (a camera) off the chain, which is not the chain's.
ODD_ARM = [
    ("mount", "fixed", "base_link", "plate", "0.1 -0.2 0.05", "0.1 0.2 0.3", ""),
    ("j1", "revolute", "plate", "l1", "0 0 0.3", "0 0 0.5", "0 0 1"),
    ("j2", "continuous", "l1", "l2", "0.05 0 0.1", "1.5707963267948966 0 0", "0.6 0 0.8"),
    ("j3", "revolute", "l2", "l3", "0.4 0 0", "0 0 0", "1 2 2"),
    ("spacer", "fixed", "l3", "s3", "0.1 0.02 0", "-0.3 0.4 0.1", ""),
    ("j4", "revolute", "s3", "l4", "0.3 0 0", "0 -1.2 0", "0 1 0"),
    ("j5", "revolute", "l4", "l5", "0 0 0.1", "0.7 0 0", ""),
    ("j6", "revolute", "l5", "l6", "0 0 0.08", "0 0 0", "0 0.28 0.96"),
    ("tool", "fixed", "l6", FLANGE_FRAME, "0 0 0.05", "0 0.5 1.0", ""),
    ("camera_mount", "fixed", "l3", "camera", "0 0.1 0", "0 0 0", ""),
]


def odd_type(tmp_path: Path, joints: list, name: str = "odd.urdf") -> RobotType:
    """The UR5 type with its URDF replaced by one of ``joints``."""
    path = tmp_path / name
    path.write_text(urdf_text(joints))
    return dataclasses.replace(robot_type("ur5"), urdf=path)


@SETTINGS
@given(q=st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6).map(np.array))
def test_unaligned_axes_and_fixed_joints_equal_pinocchio(
    tmp_path_factory: pytest.TempPathFactory, q: np.ndarray
) -> None:
    rtype = odd_type(tmp_path_factory.getbasetemp(), ODD_ARM)
    chain = chain_of(rtype)
    expected = pinocchio_flange(rtype.urdf, q)
    np.testing.assert_allclose(flange_pose(chain, q), expected, rtol=0, atol=TOL)
    out = np.zeros((4, 4))
    kernels.chain_pose(chain, q, out)()
    np.testing.assert_allclose(out, expected, rtol=0, atol=TOL)


def test_fixed_joints_fold_into_the_next_origin(tmp_path: Path) -> None:
    chain = chain_of(odd_type(tmp_path, ODD_ARM))
    assert chain.n == 6
    np.testing.assert_allclose(chain.axes[1], [0.6, 0.0, 0.8], rtol=0, atol=1e-15)
    np.testing.assert_allclose(chain.axes[2], [1 / 3, 2 / 3, 2 / 3], rtol=0, atol=1e-15)
    assert chain.axes[4].tolist() == [1.0, 0.0, 0.0]  # URDF's default axis
    assert not np.allclose(chain.origins[0][:3, 3], [0, 0, 0.3])  # the mount is in it
    assert not np.allclose(chain.origins[6], np.eye(4))  # the tool is the last one


# --------------------------------------------------------------------------------------------
# URDFs that are not a type's chain


def test_a_wrong_joint_count_is_refused_naming_the_file(tmp_path: Path) -> None:
    three = [*ODD_ARM[:4], ("tool", "fixed", "l3", FLANGE_FRAME, "0 0 0.1", "0 0 0", "")]
    rtype = odd_type(tmp_path, three, "three.urdf")
    with pytest.raises(ModelError, match=r"three\.urdf.*3 moving joints.*'ur5' expects 6"):
        chain_of(rtype)


def test_a_urdf_without_a_flange_is_refused_naming_the_file(tmp_path: Path) -> None:
    no_flange = [(*j[:3], "tool0", *j[4:]) if j[3] == FLANGE_FRAME else j for j in ODD_ARM]
    rtype = odd_type(tmp_path, no_flange, "no_flange.urdf")
    with pytest.raises(ModelError, match=r"^model: .*no_flange\.urdf: no link 'flange'"):
        chain_of(rtype)


def test_joints_out_of_order_are_refused(tmp_path: Path) -> None:
    swapped = [(("j5" if j[0] == "j4" else "j4"), *j[1:]) if j[0] in ("j4", "j5") else j
               for j in ODD_ARM]  # fmt: skip
    rtype = odd_type(tmp_path, swapped, "swapped.urdf")
    with pytest.raises(ModelError, match=r"swapped\.urdf.*\(j1, j2, j3, j5, j4, j6\)"):
        chain_of(rtype)


def test_a_prismatic_joint_is_refused_naming_it(tmp_path: Path) -> None:
    sliding = [(j[0], "prismatic", *j[2:]) if j[0] == "j3" else j for j in ODD_ARM]
    rtype = odd_type(tmp_path, sliding, "sliding.urdf")
    with pytest.raises(ModelError, match=r"sliding\.urdf: joint 'j3' .* is 'prismatic'"):
        chain_of(rtype)


def test_a_file_that_is_not_xml_is_refused(tmp_path: Path) -> None:
    rtype = odd_type(tmp_path, ODD_ARM, "broken.urdf")
    rtype.urdf.write_text("<robot><link name='flange'>")
    with pytest.raises(ModelError, match=r"broken\.urdf: cannot read it as a URDF"):
        chain_of(rtype)


def test_the_bound_kernel_refuses_arrays_it_cannot_read() -> None:
    chain: Chain = chain_of(robot_type("ur5"))
    with pytest.raises(AssertionError, match="q must be float64"):
        kernels.chain_pose(chain, np.zeros(12)[::2], np.zeros((4, 4)))
