"""Tests for the closed-form PUMA 560 kinematics (kali_daemons.robots.puma560.kinematics).

Oracles: robotics-toolbox-python's ``Puma560`` (``fkine`` from the DH table, ``ikine_a`` after
Paul & Zhang) with its d1 set to ours, and Pinocchio's ``flange`` frame from the URDF.  The
configuration flags are checked against their geometric definitions computed from the
toolbox's link transforms, and on poses whose flags can be seen by eye.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pinocchio as pin
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from kali_daemons.core.errors import KaliError
from kali_daemons.robots import puma560
from kali_daemons.robots.model import FLANGE_FRAME, load_pinocchio
from kali_daemons.robots.puma560.kinematics import (
    CONFIGS,
    REACH_MAX,
    REACH_MIN,
    STRETCH_Q3,
    Config,
    KinematicsError,
    config_of,
    fkine,
    ikine,
    singularities,
    wrist_centre,
)

N_POSES = 200
N_TOOLBOX_POSES = 200  # × 8 configurations; ikine_a takes ~0.3 ms a call
FK_TOL = 1e-12  # m and rotation entries; measured 7e-16 against both oracles
IK_TOL = 1e-9  # m and rotation entries, fkine(ikine(T)) against T
Q_TOL = 1e-8  # rad, two solutions of the same configuration
A2, A3, D3, D4 = puma560.A[1], puma560.A[2], puma560.D[2], puma560.D[3]
LIMIT_MSG = "out of joint limits"


# --------------------------------------------------------------------------------------------
# Fixtures and helpers


@pytest.fixture(scope="module")
def rtb_raw() -> Any:
    """robotics-toolbox-python's Puma560 exactly as shipped (d1 = 26.45 in = 0.67183 m)."""
    rtb = pytest.importorskip("roboticstoolbox", reason="the oracle; pip install '.[test]'")
    return rtb.models.DH.Puma560()


@pytest.fixture(scope="module")
def rtb_puma() -> Any:
    """The toolbox model with our d1 = 0.6718 m, so both describe the same arm.

    Its ``ikine_a`` subtracts its own ``links[0].d`` from the target's z, so it solves the
    same problem as ours; its base and tool stay identity.
    """
    rtb = pytest.importorskip("roboticstoolbox", reason="the oracle; pip install '.[test]'")
    robot = rtb.models.DH.Puma560()
    robot.links[0].d = float(puma560.D[0])
    return robot


@pytest.fixture(scope="module")
def pin_model() -> pin.Model:
    return load_pinocchio(puma560.ROBOT)


def random_q(n: int, seed: int = 5601) -> np.ndarray:
    """``n`` seeded joint vectors, uniform within the joint limits."""
    return np.random.default_rng(seed).uniform(puma560.Q_MIN, puma560.Q_MAX, size=(n, 6))


def wrap(q: np.ndarray) -> np.ndarray:
    """Angles into [-π, π), to compare joint vectors modulo 2π."""
    return (np.asarray(q) + math.pi) % (2 * math.pi) - math.pi


def within_limits(q: np.ndarray) -> bool:
    return bool(np.all(q >= puma560.Q_MIN) and np.all(q <= puma560.Q_MAX))


def has_equivalent_within_limits(q: np.ndarray) -> bool:
    """Whether every joint of ``q`` has a 2π-equivalent within its limits."""
    for v, lo, hi in zip(q, puma560.Q_MIN, puma560.Q_MAX, strict=True):
        k = math.ceil((lo - v) / (2 * math.pi) - 1e-12)
        if v + 2 * math.pi * k > hi + 1e-12:
            return False
    return True


def assert_reaches(q: np.ndarray, t: np.ndarray, config: Config) -> None:
    """``q`` is within the limits, reaches ``t`` and is in ``config``."""
    assert within_limits(q), np.degrees(q)
    np.testing.assert_allclose(fkine(q), t, rtol=0, atol=IK_TOL)
    assert config_of(q) == config, (str(config_of(q)), str(config))


def geometric_flags(robot: Any, q: np.ndarray) -> tuple[bool, bool, bool, float, float]:
    """The three flags by their definitions, from the toolbox's link frames (not our code).

    Returns (right, up, flip, ρ, height of the elbow above the line shoulder-wrist).
    """
    frames = [robot.A([0, i], q).A for i in range(robot.n)]  # DH frames 1..n in the base
    s = frames[0][:3, 3]  # shoulder, on joint 2's axis
    z0, z1 = np.array([0.0, 0.0, 1.0]), frames[0][:3, 2]
    x1 = np.cross(z0, z1)  # horizontal, in the arm plane
    e_pt = frames[1][:3, 3]  # elbow, on joint 3's axis
    w = frames[5][:3, 3]  # wrist centre = flange
    rho = float((w - s) @ x1)
    # in the arm plane: horizontal coordinate along x1, vertical along z0
    eh, ez = (e_pt - s) @ x1, (e_pt - s) @ z0
    wh, wz = (w - s) @ x1, (w - s) @ z0
    above = ez - wz * eh / wh  # the elbow's height above the line S-W at the elbow
    z3, z4, z5 = frames[2][:3, 2], frames[3][:3, 2], frames[4][:3, 2]
    flip = float(np.cross(z3, z5) @ z4) > 0.0
    return rho >= 0.0, above > 0.0, flip, rho, float(above)


# --------------------------------------------------------------------------------------------
# Forward kinematics


def test_fkine_matches_toolbox_and_pinocchio(rtb_puma: Any, pin_model: pin.Model) -> None:
    """T6 == the toolbox's fkine (same d1) == Pinocchio's flange frame (DH frame 6)."""
    data = pin_model.createData()
    fid = pin_model.getFrameId(FLANGE_FRAME)
    poses = [puma560.QZ, puma560.QR, puma560.QS, puma560.QN, *random_q(N_POSES)]
    for q in poses:
        t = fkine(q)
        assert t.shape == (4, 4) and t.dtype == np.float64
        np.testing.assert_allclose(t, rtb_puma.fkine(q).A, rtol=0, atol=FK_TOL)
        pin.framesForwardKinematics(pin_model, data, q)
        np.testing.assert_allclose(t, data.oMf[fid].homogeneous, rtol=0, atol=FK_TOL)


def test_toolbox_as_shipped_differs_by_the_pedestal_only(rtb_raw: Any) -> None:
    """The shipped toolbox has d1 = 0.67183 m: a pure shift along z0 (Tz(d1) commutes with
    Rz(θ1)), so its fkine is ours moved down by our d1 minus its own."""
    dz = float(puma560.D[0]) - rtb_raw.links[0].d
    assert abs(dz) < 5e-5
    for q in random_q(20, seed=7):
        expected = rtb_raw.fkine(q).A
        expected[2, 3] += dz
        np.testing.assert_allclose(fkine(q), expected, rtol=0, atol=FK_TOL)


def test_fkine_writes_into_out_and_takes_sequences() -> None:
    out = np.full((4, 4), np.nan)
    q = random_q(1, seed=3)[0]
    assert fkine(q, out) is out
    np.testing.assert_array_equal(out, fkine(q))
    np.testing.assert_array_equal(fkine(list(q)), fkine(q))
    np.testing.assert_allclose(fkine(puma560.QN)[:3, 3], puma560.FLANGE_QN, atol=1e-3)


def test_wrist_centre_is_the_flange_origin(rtb_puma: Any) -> None:
    """d5 = d6 = 0: DH frames 4, 5 and 6 share the wrist centre as origin."""
    for q in random_q(20, seed=11):
        t = fkine(q)
        w = wrist_centre(t)
        np.testing.assert_allclose(w, rtb_puma.A([0, 3], q).A[:3, 3], rtol=0, atol=FK_TOL)
        w[0] += 1.0  # a copy, not a view
        assert t[0, 3] != w[0]


# --------------------------------------------------------------------------------------------
# Configurations


def test_config_strings() -> None:
    assert len(set(CONFIGS)) == 8
    assert sorted(str(c) for c in CONFIGS) == sorted(
        a + b + c for a in "lr" for b in "ud" for c in "nf"
    )
    for c in CONFIGS:
        assert Config.from_string(str(c)) == c
    assert Config.from_string("RUN") == Config(right=True, up=True, flip=False)
    assert str(Config(right=False, up=False, flip=True)) == "ldf"


@pytest.mark.parametrize("bad", ["", "ru", "runn", "urn", "rxn", "r u", "run ", "lnu"])
def test_config_from_string_refuses(bad: str) -> None:
    with pytest.raises(KinematicsError, match=r"expected three letters in the order arm"):
        Config.from_string(bad)


def test_config_of_follows_the_geometric_definitions(rtb_puma: Any) -> None:
    """config_of == the flags computed from the toolbox's link frames, by definition:
    wrist centre in front of the plane of axes 1-2 along x1 = z0 × z1 (right), elbow above
    the line from the shoulder to the wrist centre (up), (z3 × z5)·z4 > 0 (flip)."""
    seen = set()
    for q in random_q(N_POSES, seed=13):
        right, up, flip, rho, above = geometric_flags(rtb_puma, q)
        assert abs(rho) > 1e-6 and abs(above) > 1e-6  # no ties in this sample
        c = config_of(q)
        assert (c.right, c.up, c.flip) == (right, up, flip), np.degrees(q)
        seen.add(str(c))
    assert len(seen) == 8


R = math.radians
MIRROR_Q3 = 2 * math.atan2(A3, D4) - math.pi  # θ3' = 2φ − π − θ3 mirrors the arm plane


@pytest.mark.parametrize(
    ("q_deg", "expected"),
    [
        # QN: upper arm raised 45°, forearm down to the wrist at shoulder height in front
        (puma560.QN, "ruf"),
        (np.r_[puma560.QN[:4], R(-45), 0.0], "run"),
        # upper arm lowered 30°, forearm rising to the wrist at shoulder height in front
        (np.radians([0, -30, -30, 0, 30, 0]), "rdf"),
        (np.radians([40, -30, -30, 20, -30, 0]), "rdn"),
        # the same two, mirrored through the plane of axes 1-2: the arm reaches backwards
        # over its shoulder (θ2' = 180° − θ2, θ3' = 2·atan2(a3, d4) − 180° − θ3)
        (np.r_[0.0, R(135), MIRROR_Q3 - R(-180), 0.0, R(30), 0.0], "luf"),
        (np.r_[0.0, R(210), MIRROR_Q3 - R(-30), 0.0, R(-30), 0.0], "ldn"),
        # QR (arm vertical) nudged: the wrist centre is a3 = 2 cm in front of the shoulder, so
        # the steep line shoulder-wrist leans forward and the elbow, just behind it, is above
        # it.  Tilted back by 5°: the wrist centre is 5.5 cm behind (left), the line leans
        # back, and the elbow, still just behind it, is now below it.
        (puma560.QR + np.radians([0, 0, 0, 0, 5, 0]), "ruf"),
        (puma560.QR + np.radians([0, 5, 0, 0, -5, 0]), "ldn"),
    ],
    ids=["qn", "qn-wrist-down", "elbow-down", "elbow-down-2", "left-up", "left-down",
         "qr-up", "qr-tilted-back"],
)  # fmt: skip
def test_config_of_on_poses_seen_by_eye(q_deg: np.ndarray, expected: str) -> None:
    assert str(config_of(q_deg)) == expected


def test_config_of_ties() -> None:
    """θ5 = 0 counts as NOFLIP; the stretched arm (e = 0) as DOWN."""
    assert not config_of(puma560.QZ).flip
    q = np.array([0.0, 0.3, STRETCH_Q3, 0.0, 0.2, 0.0])
    assert not config_of(q).up


# --------------------------------------------------------------------------------------------
# Inverse kinematics


def test_ikine_round_trip_all_configurations() -> None:
    """Every configuration of a reachable pose either solves it within the limits, in that
    configuration, or is refused for the joint limits; the pose's own one always solves it."""
    solved = 0
    for q in random_q(N_POSES, seed=17):
        t = fkine(q)
        own = config_of(q)
        for c in CONFIGS:
            try:
                qi = ikine(t, c)
            except KinematicsError as exc:
                assert c != own
                assert LIMIT_MSG in str(exc) and f"'{c}'" in str(exc)
                continue
            assert_reaches(qi, t, c)
            solved += 1
            if c == own:  # the same solution; only joint 6 may differ, by 2π
                np.testing.assert_allclose(wrap(qi - q), 0.0, atol=Q_TOL)
                np.testing.assert_allclose(qi[:5], q[:5], atol=Q_TOL)
        np.testing.assert_allclose(ikine(t, own, q_ref=q), q, atol=Q_TOL)
    assert solved > 2 * N_POSES  # most poses have several in-limit configurations


def test_ikine_matches_the_toolbox(rtb_puma: Any) -> None:
    """Same letters, same solution (modulo 2π) as the toolbox's ikine_a; we refuse exactly
    when the toolbox's solution (which ignores limits) has no 2π-equivalent within them."""
    for q in random_q(N_TOOLBOX_POSES, seed=19):
        t = fkine(q)
        for c in CONFIGS:
            sol = rtb_puma.ikine_a(t, str(c))
            assert sol.success, sol.reason
            assert config_of(sol.q) == c  # the letters mean the same
            try:
                qi = ikine(t, c)
            except KinematicsError:
                assert not has_equivalent_within_limits(sol.q), np.degrees(sol.q)
                continue
            np.testing.assert_allclose(wrap(qi - sol.q), 0.0, atol=Q_TOL)


@settings(max_examples=300, deadline=None)
@given(
    u=st.lists(st.floats(0.0, 1.0), min_size=6, max_size=6),
    k=st.integers(0, 7),
)
def test_fkine_ikine_property(u: list[float], k: int) -> None:
    """FK(IK(T)) = T for any in-limit pose and configuration, unless refused for limits."""
    q = puma560.Q_MIN + np.array(u) * (puma560.Q_MAX - puma560.Q_MIN)
    t = fkine(q)
    c = CONFIGS[k]
    try:
        qi = ikine(t, c, q_ref=q)
    except KinematicsError as exc:
        assert LIMIT_MSG in str(exc)
        assert c != config_of(q) or singularities(q).wrist < 1e-10
        return
    # q_ref = q: a pose on the wrist singularity gives back q4 (and so q6) too
    assert within_limits(qi)
    np.testing.assert_allclose(fkine(qi), t, rtol=0, atol=IK_TOL)


def test_ikine_accepts_strings_and_writes_into_out() -> None:
    t = fkine(puma560.QN)
    out = np.full(6, np.nan)
    assert ikine(t, Config(True, True, True), out=out) is out
    np.testing.assert_allclose(out, puma560.QN, atol=Q_TOL)
    np.testing.assert_array_equal(ikine(t, "ruf"), out)


@pytest.mark.parametrize("q", [puma560.QZ, puma560.QR, puma560.QS], ids=["qz", "qr", "qs"])
def test_wrist_singularity_takes_q4_from_q_ref(q: np.ndarray) -> None:
    """θ5 = 0: θ4 = q_ref[3] (0 without), θ6 the rest; FLIP and NOFLIP coincide."""
    turned = q + np.array([0.0, 0.0, 0.0, 0.4, 0.0, 0.5])  # θ4 + θ6 = 0.9 rad
    t = fkine(turned)
    c = config_of(q)
    assert not c.flip
    for flip in (False, True):
        cfg = Config(c.right, c.up, flip)
        q0 = ikine(t, cfg)
        np.testing.assert_allclose(q0, np.r_[q[:3], 0.0, 0.0, 0.9], atol=Q_TOL)
        q1 = ikine(t, cfg, q_ref=np.r_[0, 0, 0, -1.0, 0, 0])
        np.testing.assert_allclose(q1, np.r_[q[:3], -1.0, 0.0, 1.9], atol=Q_TOL)
        # a q_ref beyond joint 4's limit (170°): θ4 on the limit
        q2 = ikine(t, cfg, q_ref=np.r_[0, 0, 0, 4.0, 0, 0])
        np.testing.assert_allclose(q2[3], puma560.Q_MAX[3], atol=Q_TOL)
        for qi in (q0, q1, q2):
            assert within_limits(qi)
            np.testing.assert_allclose(fkine(qi), t, rtol=0, atol=IK_TOL)


def test_joint_6_takes_the_equivalent_nearest_q_ref() -> None:
    """Joint 6 spans ±266°: 200° and −160° are both in, q_ref picks (nearest 0 without)."""
    q = np.r_[puma560.QN[:5], math.radians(200.0)]
    t = fkine(q)
    np.testing.assert_allclose(math.degrees(ikine(t, "ruf")[5]), -160.0, atol=1e-6)
    np.testing.assert_allclose(math.degrees(ikine(t, "ruf", q_ref=q)[5]), 200.0, atol=1e-6)
    q_ref = np.r_[puma560.QN[:5], math.radians(20.0)]
    np.testing.assert_allclose(math.degrees(ikine(t, "ruf", q_ref=q_ref)[5]), -160.0, atol=1e-6)


def test_ikine_on_the_shoulder_and_elbow_singularities() -> None:
    """On ρ = 0 both arms, on e = 0 both elbows, are one solution; poses from fkine that
    round off just outside the boundary are still accepted."""
    q_shoulder = shoulder_singular_q(math.radians(60.0))
    q_stretch = np.array([0.3, 0.2, STRETCH_Q3, 0.1, 0.4, 0.0])
    for q in (q_shoulder, q_stretch):
        t = fkine(q)
        solutions = []
        for c in CONFIGS:
            try:
                solutions.append(ikine(t, c))
            except KinematicsError as exc:
                assert LIMIT_MSG in str(exc)
        assert solutions
        for qi in solutions:
            np.testing.assert_allclose(fkine(qi), t, rtol=0, atol=IK_TOL)
        # ρ = √(x² + y² − d3²) (or the elbow's √(L² − n²)) turns a rounding error of 1e-17
        # into 3e-9 m and θ1 then moves by that over d3: the joints are ill-conditioned here
        # (that is the singularity), the pose is not
        np.testing.assert_allclose(ikine(t, config_of(q)), q, atol=1e-6)


# --------------------------------------------------------------------------------------------
# Errors


def pose_at(p: tuple[float, float, float]) -> np.ndarray:
    t = np.eye(4)
    t[:3, 3] = p
    return t


def test_error_is_a_kali_error() -> None:
    assert issubclass(KinematicsError, KaliError)
    with pytest.raises(KinematicsError, match=r"^kinematics: "):
        ikine(pose_at((5.0, 0.0, 0.0)), "run")


def test_unreachable_far_away() -> None:
    with pytest.raises(KinematicsError) as info:
        ikine(pose_at((1.5, 0.0, 0.7)), "run")
    msg = str(info.value)
    assert "out of reach" in msg and "(1.5000, 0.0000, 0.7000) m" in msg
    assert f"{REACH_MIN:.5f} .. {REACH_MAX:.5f} m" in msg and "1.4927 m from the shoulder" in msg


def test_unreachable_near_the_waist_axis() -> None:
    with pytest.raises(KinematicsError, match=r"out of reach.*0\.1000 m from joint 1's axis.*d3"):
        ikine(pose_at((0.1, 0.0, 1.0)), "lun")


def test_reach_boundary() -> None:
    """Just inside the outer radius is reachable, just outside is not."""
    d1 = float(puma560.D[0])
    for r, ok in ((REACH_MAX - 1e-6, True), (REACH_MAX + 1e-6, False)):
        t = pose_at((r, -D3, d1))  # straight in front of the shoulder, at its height
        t[:3, :3] = [[0, 0, 1], [0, 1, 0], [-1, 0, 0]]  # approach along x
        if ok:
            np.testing.assert_allclose(fkine(ikine(t, "rdn")), t, atol=IK_TOL)
        else:
            with pytest.raises(KinematicsError, match="out of reach"):
                ikine(t, "rdn")


@pytest.mark.parametrize(
    ("index", "value", "fragment"),
    [((0, 3), math.nan, r"T\[0, 3\] = nan"), ((1, 1), math.inf, r"T\[1, 1\] = inf")],
)
def test_non_finite_transform(index: tuple[int, int], value: float, fragment: str) -> None:
    t = fkine(puma560.QN)
    t[index] = value
    with pytest.raises(KinematicsError, match=r"T is not finite: " + fragment):
        ikine(t, "ruf")


def test_non_rigid_transforms() -> None:
    t = fkine(puma560.QN)
    scaled = t.copy()
    scaled[:3, :3] *= 1.001
    with pytest.raises(KinematicsError, match=r"not orthonormal: max \|RᵀR − I\| = 0\.002"):
        ikine(scaled, "ruf")
    mirrored = t.copy()
    mirrored[:3, 0] *= -1.0
    with pytest.raises(KinematicsError, match=r"reflection \(det = -1"):
        ikine(mirrored, "ruf")
    bottom = t.copy()
    bottom[3, 0] = 0.5
    with pytest.raises(KinematicsError, match=r"bottom row of T is \[0\.5, 0\.0, 0\.0, 1\.0\]"):
        ikine(bottom, "ruf")
    with pytest.raises(KinematicsError, match=r"T must be a 4×4 array, got ndarray \(3, 3\)"):
        ikine(np.eye(3), "ruf")
    nearly = t.copy()
    nearly[:3, :3] *= 1 + 1e-8  # within RIGID_TOL: solved, as if orthonormal
    np.testing.assert_allclose(ikine(nearly, "ruf"), puma560.QN, atol=1e-6)


def test_joint_5_out_of_limits() -> None:
    """θ5 = ±110° is beyond joint 5's ±100° in both wrist configurations."""
    t = fkine(np.r_[puma560.QN[:4], math.radians(110.0), 0.0])
    for config, value in (("ruf", "110.00°"), ("run", "-110.00°")):
        with pytest.raises(KinematicsError) as info:
            ikine(t, config)
        msg = str(info.value)
        assert f"configuration '{config}' {LIMIT_MSG}" in msg
        assert f"joint 5 = {value} is outside its limits -100.00° .. 100.00°" in msg


def test_joint_2_and_joint_4_out_of_limits() -> None:
    """QN's pose: 'rdn' needs θ2 = −47.76° (limit −45°), 'run' θ4 = ±180° (limits −110..170°)."""
    t = fkine(puma560.QN)
    with pytest.raises(KinematicsError, match=r"'rdn'.*joint 2 = -47\.76° is outside its limits"):
        ikine(t, "rdn")
    with pytest.raises(KinematicsError, match=r"'run'.*joint 4 = -?180\.00° is outside its limits"):
        ikine(t, "run")
    np.testing.assert_allclose(ikine(t, "ruf"), puma560.QN, atol=Q_TOL)


# --------------------------------------------------------------------------------------------
# Singularities


def shoulder_singular_q(q2: float) -> np.ndarray:
    """Joint angles with ρ = 0 (wrist centre d3 from joint 1's axis) for a given θ2."""
    phi = math.atan2(A3, D4)
    q23 = phi - math.asin(-A2 * math.cos(q2) / math.hypot(A3, D4))
    return np.array([0.2, q2, q23 - q2, 0.3, 0.5, 0.0])


def test_singularities_at_known_poses() -> None:
    s = singularities(puma560.QN)
    np.testing.assert_allclose(s, [0.59630, D4, math.pi / 4], atol=1e-5)
    # QR (arm vertical) is a3 from both the shoulder and the elbow singularity, and on the wrist
    np.testing.assert_allclose(singularities(puma560.QR), [A3, A3, 0.0], atol=1e-15)
    q = shoulder_singular_q(math.radians(60.0))
    assert within_limits(q)
    s = singularities(q)
    assert s.shoulder < 1e-12 and s.elbow > 0.1 and s.wrist > 0.4
    w = fkine(q)[:3, 3]
    np.testing.assert_allclose(math.hypot(w[0], w[1]), D3, atol=1e-12)
    s = singularities(np.array([0.3, 0.2, STRETCH_Q3, 0.1, 0.4, 0.0]))
    assert s.elbow < 1e-12 and s.shoulder > 0.8 and s.wrist > 0.3
    np.testing.assert_allclose(math.degrees(STRETCH_Q3), -87.31, atol=0.01)
    s = singularities(np.r_[puma560.QN[:4], 0.0, 0.0])
    assert s.wrist == 0.0 and s.shoulder > 0.5 and s.elbow > 0.4
    np.testing.assert_allclose(singularities(np.r_[0, 0, 0, 0, math.radians(-170), 0]).wrist, R(10))


def test_singularities_factor_the_jacobian_determinant(rtb_puma: Any) -> None:
    """|det J| = a2 · shoulder · elbow · sin(wrist), with the toolbox's geometric Jacobian."""
    for q in random_q(50, seed=23):
        s = singularities(q)
        det = abs(np.linalg.det(rtb_puma.jacob0(q)))
        np.testing.assert_allclose(A2 * s.shoulder * s.elbow * math.sin(s.wrist), det, rtol=1e-9)


def test_stretched_arm_is_at_the_outer_reach() -> None:
    """Distance shoulder-wrist in the arm plane at e = 0 is REACH_MAX."""
    w = fkine(np.array([0.0, 0.3, STRETCH_Q3, 0.0, 0.0, 0.0]))[:3, 3]
    rho = math.sqrt(w[0] ** 2 + w[1] ** 2 - D3**2)
    np.testing.assert_allclose(math.hypot(rho, w[2] - puma560.D[0]), REACH_MAX, atol=1e-12)


def test_a_configuration_argument_that_is_an_array_is_refused_as_a_motion_error() -> None:
    """Found by tests/system/test_fuzz.py: an array where a configuration goes compared
    itself with the configurations element-wise and raised numpy's ValueError."""
    from kali_daemons.client.common import MotionError, _config_arg  # the helper under test

    kin = puma560.ROBOT.kinematics
    with pytest.raises(MotionError, match="is not one of the arm's configurations"):
        _config_arg("move_line", np.array([False, False]), kin)
