"""Trajectory-generator motion profiles: joint mode, Cartesian paths with Paul transitions,
and stopping by time scaling (kali_daemons/tg/profiles.py; thesis 2.2.1).

Everything is sampled the way the TG does it, at the 10 ms tick (and finer where continuity is
the point), and checked against independent references (scipy rotations, finite differences,
Paul's textbook transition polynomial).  ``python -m tests.test_profiles`` prints the cost of
one ``sample`` call.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from kali_daemons.robots import robot_type
from kali_daemons.tg.profiles import (
    MIN_MOVE_RAD,
    PEAK_SPEED_FACTOR,
    ZERO_MOVE_S,
    CartesianPath,
    JointMotion,
    MotionError,
    StopRamp,
    check_joint_target,
    stop_profile,
    stop_time_for,
)

TICK_S = 0.01
QUINTIC_PEAK_ACCEL = 10.0 / math.sqrt(3.0)  # peak of the quintic's acceleration, × D/T²


def rot(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rot(axis, angle) from scipy, independent of the module's Rodrigues."""
    axis = np.asarray(axis, dtype=np.float64)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()


def pose(r: np.ndarray, p: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = r
    t[:3, 3] = p
    return t


def ticks(duration: float, dt: float) -> np.ndarray:
    """Path times at the tick from 0 through the end (the last tick at or past ``duration``)."""
    return np.arange(math.ceil(duration / dt) + 2) * dt


# ---------------------------------------------------------------------------------------------
# Joint mode


def sample_joint(m: JointMotion, taus: np.ndarray) -> tuple[np.ndarray, ...]:
    n = m.start.size
    q, qd, qdd = np.empty((len(taus), n)), np.empty((len(taus), n)), np.empty((len(taus), n))
    for i, tau in enumerate(taus):
        m.sample(float(tau), q[i], qd[i], qdd[i])
    return q, qd, qdd


joint_vectors = st.lists(st.floats(-3.0, 3.0), min_size=6, max_size=6).map(np.array)
joint_steps = st.lists(st.one_of(st.just(0.0), st.floats(-3.0, 3.0)), min_size=6, max_size=6).map(
    np.array
)
speed_limits = st.lists(st.floats(0.5, 4.0), min_size=6, max_size=6).map(np.array)
accel_limits = st.lists(st.floats(0.5, 20.0), min_size=6, max_size=6).map(np.array)


def test_a_joint_that_stays_put_has_no_peaks_even_beside_a_minute_move() -> None:
    """A move of 1e-300 rad makes the law's jerk overflow; the joints that stay put still
    report zero peaks, not NaN (0 x inf), and numpy warns of nothing (the fuzz test found it)."""
    with np.errstate(all="raise"):
        m = JointMotion(np.zeros(6), np.r_[1e-300, np.zeros(5)], np.ones(6), np.ones(6))
    for peak in (m.peak_speed, m.peak_accel, m.peak_jerk):
        assert not np.isnan(peak).any() and (peak[1:] == 0.0).all()


def test_a_minute_move_samples_finite_positions_on_its_way() -> None:
    """A move of 1.9e-234 rad: the law's constants overflowed and every sample on the way was
    NaN (hypothesis found it); now it is a move that goes nowhere, done at the next tick."""
    start, target = np.zeros(6), np.r_[np.zeros(5), 1.8829589513075994e-234]
    m = JointMotion(start, target, np.ones(6), np.ones(6))
    q = np.empty(6)
    for tau in (0.0, m.duration / 3, m.duration / 2, m.duration):
        m.sample(tau, q)
        assert np.isfinite(q).all() and (q >= start).all() and (q <= target).all(), q
    assert m.duration == ZERO_MOVE_S


@settings(max_examples=40, deadline=None)
@given(start=joint_vectors, step=joint_steps, v_max=speed_limits, a_max=accel_limits)
def test_joint_motion_is_smooth_within_limits_and_arrives_together(
    start: np.ndarray, step: np.ndarray, v_max: np.ndarray, a_max: np.ndarray
) -> None:
    target = start + step
    m = JointMotion(start, target, v_max, a_max)
    moving = np.abs(target - start) > MIN_MOVE_RAD  # shorter moves go nowhere, at once
    assert np.all(m.peak_speed <= v_max * (1 + 1e-12))
    assert np.all(m.peak_accel <= a_max * (1 + 1e-12))
    if moving.any():  # the slowest joint works at one of its limits
        use = np.maximum(m.peak_speed / v_max, m.peak_accel / a_max)
        assert np.max(use) == pytest.approx(1.0, rel=1e-9)
        # and the smoothed trapezoid is never slower than the quintic with the same limits
        d = np.abs(step)
        quintic_s = np.max(
            np.maximum(PEAK_SPEED_FACTOR * d / v_max, np.sqrt(QUINTIC_PEAK_ACCEL * d / a_max))
        )
        assert m.duration <= quintic_s * (1 + 1e-9)
    else:
        assert m.duration == ZERO_MOVE_S

    for dt in (TICK_S, m.duration / 3000):
        q, qd, qdd = sample_joint(m, ticks(m.duration, dt))
        # bounded jumps between ticks: continuity of position and velocity
        assert np.all(np.abs(np.diff(q, axis=0)) <= v_max * dt * (1 + 1e-9) + 1e-12)
        assert np.all(np.abs(np.diff(qd, axis=0)) <= a_max * dt * (1 + 1e-9) + 1e-12)
        assert np.all(np.abs(np.diff(qdd, axis=0)) <= m.peak_jerk * dt * (1 + 1e-9) + 1e-12)
        # the analytic derivatives are the derivatives (trapezoid rule, exact to O(jerk·dt))
        rounding = 4e-16 * (1 + np.max(np.abs(q))) / dt
        mean_qd = 0.5 * (qd[1:] + qd[:-1])
        assert np.all(np.abs(np.diff(q, axis=0) / dt - mean_qd) <= m.peak_jerk * dt**2 + rounding)
        mean_qdd = 0.5 * (qdd[1:] + qdd[:-1])
        assert np.all(np.abs(np.diff(qd, axis=0) / dt - mean_qdd) <= m.peak_jerk * dt + 1e-9)
        # limits, analytic and by finite differences
        assert np.all(np.abs(qd) <= v_max * (1 + 1e-9))
        assert np.all(np.abs(qdd) <= a_max * (1 + 1e-9))
        assert np.all(np.abs(np.diff(q, axis=0)) / dt <= v_max * (1 + 1e-6))
        rounding = 8e-16 * (1 + np.max(np.abs(q))) / dt**2  # of the second difference
        assert np.all(np.abs(np.diff(q, 2, axis=0)) / dt**2 <= a_max * (1 + 1e-6) + rounding)
        # every joint's normalised progress is the same at every tick
        if moving.any():
            progress = (q[:, moving] - start[moving]) / step[moving]
            with np.errstate(over="ignore"):
                rounding = 4e-16 * np.max((1 + np.abs(q[:, moving])) / np.abs(step[moving]))
            assert np.all(np.ptp(progress, axis=1) <= rounding)
            assert np.all(np.diff(progress[:, 0]) >= -1e-15)  # never backwards
        else:  # nowhere to go: within MIN_MOVE_RAD of the start throughout
            assert np.all(np.abs(q - start) <= MIN_MOVE_RAD)
        # exactly at the target and at rest from the end on
        assert np.array_equal(q[-1], target)
        assert not qd[-1].any() and not qdd[-1].any()
    q0, qd0, qdd0 = sample_joint(m, np.array([0.0]))
    assert np.array_equal(q0[0], start) and not qd0.any() and not qdd0.any()


def test_joint_motion_cruises_at_the_speed_limit_on_a_long_move() -> None:
    start = np.zeros(6)
    target = np.array([3.0, -1.5, 0.3, 0.0, 0.0, 1.0])
    v_max = np.full(6, 1.0)
    a_max = np.full(6, 4.0)
    m = JointMotion(start, target, v_max, a_max)
    assert m.law.cruise_time > 0
    _, qd, _ = sample_joint(m, np.array([0.5 * m.duration]))
    assert qd[0][0] == pytest.approx(1.0, rel=1e-12)  # the longest joint at its limit
    assert np.allclose(qd[0], target / 3.0, rtol=1e-12)
    # the quintic with the same limits would take 1.875 × 3 s
    assert m.duration == pytest.approx(3.0 + m.law.accel_time)


def test_zero_length_joint_move_is_brief_and_stays_put() -> None:
    q = np.array([0.1, -0.2, 0.3, 0.4, -0.5, 0.6])
    m = JointMotion(q, q, np.ones(6), np.ones(6))
    assert m.duration == ZERO_MOVE_S
    for tau in (0.0, 0.5 * ZERO_MOVE_S, ZERO_MOVE_S, TICK_S):
        out, qd, qdd = sample_joint(m, np.array([tau]))
        assert np.array_equal(out[0], q) and not qd.any() and not qdd.any()


def test_joint_motion_accepts_scalar_limits_and_any_joint_count() -> None:
    m = JointMotion(np.zeros(12), np.linspace(-1.0, 1.0, 12), 2.0, 5.0)
    assert np.all(m.v_max == 2.0) and m.start.shape == (12,)


# ---------------------------------------------------------------------------------------------
# Cartesian paths


def sample_path(path: CartesianPath, taus: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.empty((len(taus), 4, 4))
    v = np.empty((len(taus), 6))
    for i, tau in enumerate(taus):
        path.sample(float(tau), t[i], v[i])
    return t, v


def cruise_segment(path: CartesianPath, tau: float) -> int | None:
    """The segment (0-based) whose straight cruise holds ``tau``, or None in a window."""
    half = 0.5 * path.transition_s
    for k in range(len(path.segment_times)):
        if path.via_times[k] + half < tau < path.via_times[k + 1] - half:
            return k
    return None


def windows_overlapping(path: CartesianPath, a: np.ndarray, b: np.ndarray) -> list[np.ndarray]:
    """For each transition window, which intervals [a_i, b_i] touch it."""
    masks = []
    for k in range(len(path.via_times)):
        lo, hi = path.blend_window(k)
        masks.append((a <= hi) & (b >= lo))
    return masks


def check_path(path: CartesianPath, given_poses: list[np.ndarray], dt: float) -> None:
    """Every property a TG relies on, sampled at ``dt``."""
    taus = ticks(path.duration, dt)
    t, v = sample_path(path, taus)
    p, r = t[:, :3, 3], t[:, :3, :3]
    n = len(path.segment_times)

    # rigid set-points
    assert np.max(np.abs(np.einsum("nji,njk->nik", r, r) - np.eye(3))) < 1e-12
    assert np.all(t[:, 3] == (0.0, 0.0, 0.0, 1.0))

    # starts at rest at the start pose; ends exactly at the last pose, at rest (without a
    # transition time it starts and stops with a velocity step, as asked)
    smooth = path.transition_s > 0
    assert np.allclose(t[0], given_poses[0], rtol=0, atol=1e-12)
    assert not v[0].any() or not smooth
    assert np.array_equal(t[-1], path.poses[-1])
    assert np.allclose(path.poses[-1], given_poses[-1], rtol=0, atol=1e-12)
    assert not v[-1].any()
    near_end = np.empty((4, 4))
    near_end_v = np.empty(6)
    path.sample(path.duration - 1e-9, near_end, near_end_v)
    assert np.allclose(near_end, path.poses[-1], rtol=0, atol=1e-9)
    assert np.linalg.norm(near_end_v) <= 1e-6 or not smooth

    # speeds never exceed the commanded ones, analytic and by finite differences
    lin = np.linalg.norm(v[:, :3], axis=1)
    ang = np.linalg.norm(v[:, 3:], axis=1)
    assert np.all(lin <= path.speed * (1 + 1e-9))
    assert np.all(ang <= path.angular_speed * (1 + 1e-9))
    assert np.all(np.linalg.norm(np.diff(p, axis=0), axis=1) / dt <= path.speed * (1 + 1e-6))
    turn = Rotation.from_matrix(np.einsum("nji,njk->nik", r[:-1], r[1:])).magnitude()
    assert np.all(turn / dt <= path.angular_speed * (1 + 1e-6))

    # velocity continuous: jumps bounded by the documented transition acceleration
    if smooth:
        lin_bound = np.zeros(len(taus) - 1)
        ang_bound = np.zeros(len(taus) - 1)
        for k, mask in enumerate(windows_overlapping(path, taus[:-1], taus[1:])):
            lin_bound[mask] = np.maximum(lin_bound[mask], path.blend_accel[k])
            ang_bound[mask] = np.maximum(ang_bound[mask], path.blend_angular_accel[k])
        dv = np.diff(v, axis=0)
        assert np.all(np.linalg.norm(dv[:, :3], axis=1) <= lin_bound * dt * (1 + 1e-6) + 1e-12)
        assert np.all(np.linalg.norm(dv[:, 3:], axis=1) <= ang_bound * dt * (1 + 1e-6) + 1e-12)

    # outside the windows: on the segment's line, at its cruise speed, turning about its axis
    half = 0.5 * path.transition_s
    for k in range(n):
        cruising = (taus > path.via_times[k] + half) & (taus < path.via_times[k + 1] - half)
        if not cruising.any():
            continue
        r0, r1 = given_poses[k][:3, :3], given_poses[k + 1][:3, :3]
        p0, p1 = given_poses[k][:3, 3], given_poses[k + 1][:3, 3]
        length = float(np.linalg.norm(p1 - p0))
        rotvec = Rotation.from_matrix(r0.T @ r1).as_rotvec()
        angle = float(np.linalg.norm(rotvec))
        axis = rotvec / angle if angle else np.array([0.0, 0.0, 1.0])
        s = (taus[cruising] - path.via_times[k]) / path.segment_times[k]
        assert np.all((s > 0.0) & (s < 1.0))
        pk = p[cruising]
        if length > 1e-9:
            u = (p1 - p0) / length
            assert np.all(np.linalg.norm(np.cross(pk - p0, u), axis=1) <= 1e-6)  # off the line
        assert np.allclose(pk, p0 + s[:, None] * (p1 - p0), rtol=0, atol=1e-9)
        expected = r0 @ Rotation.from_rotvec(np.outer(s * angle, axis)).as_matrix()
        assert np.allclose(r[cruising], expected, rtol=0, atol=1e-9)
        now = Rotation.from_matrix(np.einsum("ji,njk->nik", r0, r[cruising])).as_rotvec()
        turned = np.linalg.norm(now, axis=1)
        far = turned > 1e-6  # the same fixed axis all along the segment
        assert np.allclose(now[far] / turned[far, None], axis, rtol=0, atol=1e-7)
        if length / path.speed >= angle / path.angular_speed:
            assert np.allclose(lin[cruising], path.speed, rtol=1e-9)
        else:
            assert np.allclose(ang[cruising], path.angular_speed, rtol=1e-9)


def check_velocity_is_the_derivative(path: CartesianPath, taus: np.ndarray) -> None:
    """``v_out`` is dT/dτ: central differences of the pose, linear and angular (ω̂ = Ṙ Rᵀ);
    a difference across an acceleration step (parabolic blends) is off by up to a·h/2."""
    h = 1e-6
    lin_tol = 1e-6 + float(np.max(path.blend_accel, initial=0.0)) * h
    ang_tol = 1e-5 + float(np.max(path.blend_angular_accel, initial=0.0)) * h
    t, v = sample_path(path, taus)
    plus, _ = sample_path(path, taus + h)
    minus, _ = sample_path(path, np.maximum(taus - h, 0.0))
    for i, tau in enumerate(taus):
        width = (tau + h) - max(tau - h, 0.0)
        dp = (plus[i, :3, 3] - minus[i, :3, 3]) / width
        assert np.allclose(dp, v[i, :3], rtol=0, atol=lin_tol)
        w_hat = (plus[i, :3, :3] - minus[i, :3, :3]) / width @ t[i, :3, :3].T
        assert np.allclose(0.5 * (w_hat + w_hat.T), 0.0, rtol=0, atol=ang_tol)
        w = np.array([w_hat[2, 1], w_hat[0, 2], w_hat[1, 0]])
        assert np.allclose(w, v[i, 3:], rtol=0, atol=ang_tol)


def demo_poses() -> list[np.ndarray]:
    """Start plus three targets: a turn-limited segment, a sharp corner, a long diagonal."""
    return [
        pose(np.eye(3), [0.40, 0.00, 0.30]),
        pose(rot((0, 0, 1), 0.5), [0.60, 0.00, 0.30]),
        pose(rot((1, 0, 0), 0.8), [0.60, 0.30, 0.30]),
        pose(rot((0, 1, 1), 0.3), [0.40, 0.30, 0.50]),
    ]


@pytest.mark.parametrize("blend", ["paul", "parabolic"])
def test_cartesian_path_demo(blend: str) -> None:
    poses = demo_poses()
    path = CartesianPath(poses[0], poses[1:], 0.5, 1.0, 0.2, blend=blend)  # type: ignore[arg-type]
    assert path.duration == pytest.approx(float(np.sum(path.segment_times)) + 0.2)
    check_path(path, poses, TICK_S)
    check_path(path, poses, 0.001)
    check_velocity_is_the_derivative(path, np.linspace(0.0, path.duration, 157))


@pytest.mark.parametrize("blend", ["paul", "parabolic"])
def test_blend_acceleration_is_the_documented_one(blend: str) -> None:
    """The peak of the sampled acceleration in each window is ``blend_accel`` (tight bound)."""
    poses = demo_poses()
    path = CartesianPath(poses[0], poses[1:], 0.5, 1.0, 0.2, blend=blend)  # type: ignore[arg-type]
    dt = 1e-4
    for k in range(len(path.via_times)):
        lo, hi = path.blend_window(k)
        taus = np.arange(lo + dt, hi, dt)
        t, v = sample_path(path, taus)
        accel = np.linalg.norm(np.diff(t[:, :3, 3], 2, axis=0), axis=1) / dt**2
        assert np.max(accel) <= path.blend_accel[k] * (1 + 1e-6) + 1e-6
        assert np.max(accel) >= path.blend_accel[k] * 0.99
        ang_accel = np.linalg.norm(np.diff(v[:, 3:], axis=0), axis=1) / dt
        assert np.max(ang_accel) <= path.blend_angular_accel[k] * (1 + 1e-6)


def test_paul_blend_is_pauls_transition_polynomial() -> None:
    """Position in a window equals Paul's quartic: q = ((ΔC τ/T + ΔB)(2 − h)h² − 2ΔB)h + B + ΔB,
    h = (t + τ)/2τ, with A the point τ before the via point B, C the next via point."""
    poses = demo_poses()
    path = CartesianPath(poses[0], poses[1:], 0.5, 1.0, 0.2)
    tau_half = 0.1
    k = 2  # via point B = poses[2]
    a_point = poses[k][:3, 3] - (poses[k][:3, 3] - poses[k - 1][:3, 3]) * (
        tau_half / path.segment_times[k - 1]
    )
    b_point, c_point = poses[k][:3, 3], poses[k + 1][:3, 3]
    d_b, d_c = a_point - b_point, c_point - b_point
    t_bc = path.segment_times[k]
    out = np.empty((4, 4))
    for t in np.linspace(-tau_half, tau_half, 41):
        h = (t + tau_half) / (2 * tau_half)
        paul = ((d_c * tau_half / t_bc + d_b) * (2 - h) * h * h - 2 * d_b) * h + b_point + d_b
        path.sample(float(path.via_times[k] + t), out)
        assert np.allclose(out[:3, 3], paul, rtol=0, atol=1e-12)


def test_path_without_transitions_stays_on_the_lines() -> None:
    poses = demo_poses()
    path = CartesianPath(poses[0], poses[1:], 0.5, 1.0, 0.0)
    assert path.duration == pytest.approx(float(np.sum(path.segment_times)))
    check_path(path, poses, TICK_S)


@st.composite
def path_requests(draw: st.DrawFn) -> tuple[list[np.ndarray], float, float, float, str]:
    speed = draw(st.floats(0.1, 1.0))
    angular_speed = draw(st.floats(0.5, 3.0))
    transition = draw(st.sampled_from([0.02, 0.1, 0.3]))
    blend = draw(st.sampled_from(["paul", "parabolic"]))
    unit = st.lists(st.floats(-1.0, 1.0), min_size=3, max_size=3).map(np.array)
    start_axis = draw(unit)
    assume(np.linalg.norm(start_axis) > 0.1)
    r = rot(start_axis, draw(st.floats(0.0, 3.0)))
    p = draw(st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3).map(np.array))
    poses = [pose(r, p)]
    for _ in range(draw(st.integers(1, 4))):
        direction, axis = draw(unit), draw(unit)
        assume(np.linalg.norm(direction) > 0.1 and np.linalg.norm(axis) > 0.1)
        length = draw(st.floats(0.0, 0.5))
        angle = draw(st.floats(0.0, 2.5))
        if max(length / speed, angle / angular_speed) < 1.01 * transition:
            length = 1.01 * transition * speed  # long enough for the two half-windows
        p = p + length * direction / np.linalg.norm(direction)
        r = r @ rot(axis, angle)
        poses.append(pose(r, p))
    return poses, speed, angular_speed, transition, blend


@settings(max_examples=30, deadline=None)
@given(request=path_requests())
def test_random_cartesian_paths(
    request: tuple[list[np.ndarray], float, float, float, str],
) -> None:
    poses, speed, angular_speed, transition, blend = request
    path = CartesianPath(poses[0], poses[1:], speed, angular_speed, transition, blend=blend)  # type: ignore[arg-type]
    check_path(path, poses, TICK_S)
    check_velocity_is_the_derivative(path, np.linspace(0.0, path.duration, 23))


def test_half_turn_segment_keeps_its_axis() -> None:
    """A rotation of (nearly) π, where the angle-axis is ill-conditioned, still turns about it."""
    poses = [pose(np.eye(3), [0, 0, 0]), pose(rot((1, 2, 3), math.pi - 1e-9), [0.1, 0, 0])]
    path = CartesianPath(poses[0], poses[1:], 0.5, 1.0, 0.1)
    check_path(path, poses, TICK_S)


# ---------------------------------------------------------------------------------------------
# Stopping by time scaling


def test_stop_profile_is_smooth_from_one_to_zero() -> None:
    stop = 0.4
    t = np.linspace(0.0, stop, 4001)
    sigma = np.array([stop_profile(x, stop) for x in t])
    assert sigma[0] == 1.0 and sigma[-1] == 0.0
    assert stop_profile(-1.0, stop) == 1.0 and stop_profile(2 * stop, stop) == 0.0
    assert np.all(np.diff(sigma) <= 0.0)
    slope = np.diff(sigma) / np.diff(t)
    assert abs(slope[0]) < 1e-4 and abs(slope[-1]) < 1e-4  # zero slope at both ends
    assert np.max(np.abs(slope)) <= PEAK_SPEED_FACTOR / stop * (1 + 1e-6)


def test_stop_ramp_tau_is_the_integral_of_sigma() -> None:
    ramp = StopRamp(1.25, 0.6)
    assert ramp.tau_at_rest == pytest.approx(1.25 + 0.3)
    dt = 1e-5
    t = np.arange(0.0, 0.7, dt)
    sigma = np.array([ramp.sigma(x) for x in t])
    integral = 1.25 + np.concatenate(([0.0], np.cumsum(0.5 * (sigma[1:] + sigma[:-1]) * dt)))
    exact = np.array([ramp.tau(x) for x in t])
    assert np.allclose(exact, integral, rtol=0, atol=1e-9)
    assert ramp.tau(0.6) == ramp.tau(5.0) == ramp.tau_at_rest
    assert ramp.time_to_rest(10.0) == 0.6
    # a motion that ends while stopping is at rest when τ reaches its duration
    early = ramp.time_to_rest(1.4)
    assert 0.0 < early < 0.6 and ramp.tau(early) == pytest.approx(1.4, abs=1e-12)


def run_stop(
    sample: Callable[[float], np.ndarray], ramp: StopRamp, exact: bool
) -> tuple[np.ndarray, float]:
    """The TG's loop during a stop, one entry per tick until well after rest: the positions
    it would send and the final τ.  ``exact``: τ = ramp.tau(t); else τ += σ·dt with σ taken at
    the start of each tick, which overshoots ∫σ by dt/2."""
    tau, t, out = ramp.tau_at_stop, 0.0, []
    while t < ramp.stop_time_s + 5 * TICK_S:
        out.append(sample(tau).copy())
        if exact:
            t += TICK_S
            tau = ramp.tau(t)
        else:
            tau += ramp.sigma(t) * TICK_S
            t += TICK_S
    return np.array(out), tau


@pytest.mark.parametrize("exact", [True, False], ids=["tau(t)", "sum of sigma dt"])
@pytest.mark.parametrize("blend", ["paul", "parabolic"])
def test_stopping_a_cartesian_path_stays_on_it_and_comes_to_rest(blend: str, exact: bool) -> None:
    poses = demo_poses()
    path = CartesianPath(poses[0], poses[1:], 0.5, 1.0, 0.2, blend=blend)  # type: ignore[arg-type]
    tau0 = float(path.via_times[2] + 0.15)  # cruising on segment 3
    buf, v = np.empty((4, 4)), np.empty(6)
    path.sample(tau0, buf, v)
    nominal = float(np.linalg.norm(v[:3]))
    decel = 2.0
    ramp = StopRamp(tau0, stop_time_for(nominal, decel))

    def position(tau: float) -> np.ndarray:
        path.sample(tau, buf)
        return buf[:3, 3]

    p, tau_end = run_stop(position, ramp, exact)
    speed = np.linalg.norm(np.diff(p, axis=0), axis=1) / TICK_S
    assert speed[0] == pytest.approx(nominal, rel=1e-3)  # σ × the nominal speed, σ ≈ 1
    assert np.all(np.diff(speed) <= 1e-9)  # slows down monotonically (cruise: speed ∝ σ)
    assert np.all(np.abs(np.diff(speed)) / TICK_S <= decel * (1 + 1e-2))  # the decel asked for
    assert speed[-1] == 0.0 and speed[-6] < 1e-3  # and reaches rest continuously
    # at rest where the ramp says (Euler summing: half a tick of path time further)
    expected_tau = ramp.tau_at_rest + (0.0 if exact else 0.5 * TICK_S)
    assert tau_end == pytest.approx(expected_tau, abs=1e-6)
    # the rest pose lies on the path: on segment 3's line
    assert cruise_segment(path, tau_end) == 2
    path.sample(tau_end, buf)
    assert np.array_equal(p[-1], buf[:3, 3])
    p2, p3 = poses[2][:3, 3], poses[3][:3, 3]
    u = (p3 - p2) / np.linalg.norm(p3 - p2)
    assert np.linalg.norm(np.cross(p[-1] - p2, u)) <= 1e-9


def test_stopping_a_joint_motion_is_smooth_and_keeps_the_joints_in_step() -> None:
    start = np.zeros(6)
    target = np.array([2.0, -1.0, 0.5, 0.0, 1.5, -2.0])
    m = JointMotion(start, target, np.full(6, 1.0), np.full(6, 3.0))
    tau0 = 0.5 * m.duration  # in cruise, the fastest joints at 1 rad/s
    decel = 2.0
    ramp = StopRamp(tau0, stop_time_for(1.0, decel))
    q_buf = np.empty(6)

    def position(tau: float) -> np.ndarray:
        m.sample(tau, q_buf)
        return q_buf

    q, tau_end = run_stop(position, ramp, exact=True)
    qd = np.diff(q, axis=0) / TICK_S
    assert np.max(np.abs(qd[0])) == pytest.approx(1.0, rel=1e-3)
    assert np.all(np.abs(np.diff(qd, axis=0)) <= decel * TICK_S * (1 + 1e-2))
    assert not qd[-1].any() and np.max(np.abs(qd[-6])) < 1e-3
    moving = target != 0
    progress = q[:, moving] / target[moving]
    assert np.all(np.ptp(progress, axis=1) <= 1e-12)  # still together
    assert tau_end == ramp.tau_at_rest < m.duration
    m.sample(ramp.tau_at_rest, q_buf)
    assert np.array_equal(q[-1], q_buf)


def test_a_stop_near_the_end_rests_at_the_end() -> None:
    m = JointMotion(np.zeros(6), np.ones(6), 1.0, 2.0)
    ramp = StopRamp(m.duration - 0.05, 0.5)
    rest = ramp.time_to_rest(m.duration)
    assert rest < 0.5 and ramp.tau(rest) == pytest.approx(m.duration, abs=1e-12)
    q, qd = np.empty(6), np.empty(6)
    m.sample(ramp.tau(0.5), q, qd)
    assert np.array_equal(q, m.target) and not qd.any()


# ---------------------------------------------------------------------------------------------
# Validation


def good_poses() -> list[np.ndarray]:
    return demo_poses()


def scaled(t: np.ndarray, f: float) -> np.ndarray:
    t = t.copy()
    t[:3, :3] *= f
    return t


def with_nan(t: np.ndarray) -> np.ndarray:
    t = t.copy()
    t[1, 3] = math.nan
    return t


def bottom(t: np.ndarray) -> np.ndarray:
    t = t.copy()
    t[3, 0] = 0.5
    return t


def path(**kw: object) -> Callable[[], object]:
    """A factory for a demo path with some arguments replaced."""
    poses = good_poses()
    args: dict[str, object] = {
        "start": poses[0],
        "targets": poses[1:],
        "speed": 0.5,
        "angular_speed": 1.0,
        "transition_s": 0.2,
    }
    args.update(kw)
    return lambda: CartesianPath(**args)  # type: ignore[arg-type]


def joints(**kw: object) -> Callable[[], object]:
    args: dict[str, object] = {
        "start": np.zeros(6),
        "target": np.ones(6),
        "v_max": np.ones(6),
        "a_max": np.ones(6),
    }
    args.update(kw)
    return lambda: JointMotion(**args)  # type: ignore[arg-type]


P = good_poses()
BAD_REQUESTS: list[tuple[str, Callable[[], object], str]] = [
    ("speed zero", path(speed=0.0), "speed 0.0 m/s must be > 0 and ≤ 5.0 m/s"),
    ("speed negative", path(speed=-1), "speed -1.0 m/s must be > 0"),
    ("speed absurd", path(speed=6.0), "speed 6.0 m/s must be > 0 and ≤ 5.0 m/s"),
    ("speed nan", path(speed=math.nan), "speed is nan m/s, not a finite number"),
    ("speed text", path(speed="fast"), "speed is 'fast', not a number"),
    ("angular zero", path(angular_speed=0.0), "angular_speed 0.0 rad/s must be > 0"),
    ("angular absurd", path(angular_speed=11.0), "angular_speed 11.0 rad/s must be > 0 and ≤ 10.0"),
    ("angular inf", path(angular_speed=math.inf), "angular_speed is inf rad/s, not a finite"),
    ("transition negative", path(transition_s=-0.1), "transition_s -0.1 s must be ≥ 0"),
    ("transition nan", path(transition_s=math.nan), "transition_s is nan s, not a finite"),
    ("blend", path(blend="cubic"), "blend 'cubic', expected one of ['paul', 'parabolic']"),
    ("start shape", path(start=np.eye(3)), "start has shape (3, 3), expected (4, 4)"),
    ("start nan", path(start=with_nan(P[0])), "start[1, 3] is nan, not a finite number"),
    (
        "start scaled",
        path(start=scaled(P[0], 1.01)),
        "start is not a rigid pose: max |RᵀR − I| = 0.0201",
    ),
    ("start mirrored", path(start=scaled(P[0], -1.0)), "start is not a rigid pose"),
    ("start bottom row", path(start=bottom(P[0])), "start bottom row is [0.5, 0.0, 0.0, 1.0]"),
    ("targets empty", path(targets=[]), "targets is empty"),
    ("targets one array", path(targets=P[1]), "targets is one (4, 4) array; pass a list"),
    ("target not rigid", path(targets=[P[1], scaled(P[2], 0.9)]), "targets[1] is not a rigid pose"),
    (
        "target shape",
        path(targets=[P[1], np.eye(3)]),
        "targets[1] has shape (3, 3), expected (4, 4)",
    ),
    (
        "target repeats",
        path(targets=[P[1], P[1]]),
        "segment 2 (targets[0] → targets[1]) has zero length",
    ),
    (
        "segment too short",
        path(targets=[P[1], pose(P[1][:3, :3], P[1][:3, 3] + (0.0, 0.05, 0.0))]),
        "segment 2 (targets[0] → targets[1]) lasts 0.1 s (0.05 m at 0.5 m/s, 0 rad at 1 rad/s), "
        "shorter than transition_s 0.2 s",
    ),
    (
        "first segment too short",
        path(transition_s=0.6),
        "segment 1 (start → targets[0]) lasts 0.5 s (0.2 m at 0.5 m/s, 0.5 rad at 1 rad/s), "
        "shorter than transition_s 0.6 s",
    ),
    ("joint target shape", joints(target=np.ones(5)), "target has shape (5,), expected (6,)"),
    ("joint start 2-D", joints(start=np.zeros((2, 3))), "start has shape (2, 3), expected (n,)"),
    (
        "joint target nan",
        joints(target=[0, 0, math.nan, 0, 0, 0]),
        "target[2] is nan, not a finite",
    ),
    ("joint start inf", joints(start=[0, 0, 0, 0, math.inf, 0]), "start[4] is inf, not a finite"),
    ("joint v_max zero", joints(v_max=np.zeros(6)), "v_max[0] is 0.0 rad/s, must be > 0"),
    (
        "joint v_max negative",
        joints(v_max=[1, 1, 1, -1, 1, 1]),
        "v_max[3] is -1.0 rad/s, must be > 0",
    ),
    ("joint a_max zero", joints(a_max=0.0), "a_max[0] is 0.0 rad/s², must be > 0"),
    ("joint a_max shape", joints(a_max=np.ones(3)), "a_max has shape (3,), expected (6,)"),
    ("joint a_max nan", joints(a_max=[1, 1, 1, 1, 1, math.nan]), "a_max[5] is nan, not a finite"),
    ("stop time zero", lambda: StopRamp(1.0, 0.0), "stop_time_s 0.0 s must be > 0"),
]


@pytest.mark.parametrize(
    ("make", "fragment"), [(m, f) for _, m, f in BAD_REQUESTS], ids=[n for n, _, _ in BAD_REQUESTS]
)
def test_bad_requests_are_refused_with_the_value(make: Callable[[], object], fragment: str) -> None:
    with pytest.raises(MotionError) as excinfo:
        make()
    assert fragment in str(excinfo.value)


def test_slightly_imperfect_rotations_are_accepted_and_made_rigid() -> None:
    poses = good_poses()
    noisy = poses[1].copy()
    noisy[:3, :3] += 3e-7 * np.array([[1, -1, 0], [0, 1, 1], [1, 0, -1]])
    path = CartesianPath(poses[0], [noisy], 0.5, 1.0, 0.2)
    r = path.poses[1, :3, :3]
    assert np.allclose(r.T @ r, np.eye(3), rtol=0, atol=1e-15)
    assert np.allclose(r, noisy[:3, :3], rtol=0, atol=1e-6)


# ---------------------------------------------------------------------------------------------
# Joint targets, per robot type


def test_joint_targets_are_checked_over_the_type_s_own_joints() -> None:
    """A 7-joint Panda's target: all seven in range, the seventh's range its own; columns past
    its count (a request record's) are not looked at; fewer values than joints are refused."""
    panda = robot_type("panda")
    q = panda.q_home.copy()
    check_joint_target("right", q, panda)
    check_joint_target("right", np.append(q, 99.0), panda)  # a MAX_JOINTS-wide row's spare
    bad = q.copy()
    bad[6] = panda.q_max[6] + 0.1
    with pytest.raises(MotionError, match=r"robot 'right' joint 7: target .* outside its range"):
        check_joint_target("right", bad, panda)
    with pytest.raises(MotionError, match=r"robot 'right' \(panda\) has 7 joints; 6 target"):
        check_joint_target("right", q[:6], panda)


# ---------------------------------------------------------------------------------------------
# Cost of one sample (a measurement, not a test): python -m tests.test_profiles


def _bench() -> None:
    import timeit

    q, qd = np.empty(6), np.empty(6)
    m = JointMotion(np.zeros(6), np.array([1.0, -0.5, 0.3, 2.0, 0.0, 0.1]), 1.5, 3.0)
    poses = demo_poses()
    path = CartesianPath(poses[0], poses[1:], 0.5, 1.0, 0.2)
    t, v = np.empty((4, 4)), np.empty(6)
    ramp = StopRamp(0.0, 0.5)
    cases = {
        "JointMotion.sample(q)": lambda: m.sample(0.3, q),
        "JointMotion.sample(q, qd)": lambda: m.sample(0.3, q, qd),
        "CartesianPath.sample(T) cruise": lambda: path.sample(0.4, t),
        "CartesianPath.sample(T, v) cruise": lambda: path.sample(0.4, t, v),
        "CartesianPath.sample(T, v) blend": lambda: path.sample(float(path.via_times[2]), t, v),
        "StopRamp.tau": lambda: ramp.tau(0.2),
    }
    for name, call in cases.items():
        best = min(timeit.repeat(call, number=20000, repeat=5)) / 20000
        print(f"{name:36s} {best * 1e6:6.2f} µs")


if __name__ == "__main__":
    _bench()
