"""Numerical inverse kinematics on a Pinocchio model, for robot types without a closed form.

``NumericalKinematics`` is a whole ``Kinematics`` (``profile.py``) for any serial arm of 1 to
8 revolute joints described by a URDF; the Panda uses it, and so can a researcher's own arm.
``DlsIk`` solves by damped least squares (Levenberg-Marquardt, λ² = ``DAMPING`` + |e|²) from
the previous set-point, so it stays on the branch nearest it (one branch, ``NEAREST``); one
joint may be held, which removes a 7-joint arm's redundancy.  An arm of fewer than 6 free
joints gets the least-squares solution, taken if what is left is within ``off_m`` and
``off_rad``.  The iteration in full: docs/internals/robots-hardware-plant.md.

``solve`` with ``out`` allocates nothing numpy on the success path (inside the cycle);
building the solver allocates (outside it).  Pinocchio is imported where a model is built,
not when this module is: every process imports a type's facts, and the wall clock, SIO and
the SVs never build its kinematics (they stay without Pinocchio).

Long on purpose: one numerical inverse kinematics (damped least squares, its nearest-branch
choice) and the ``Kinematics`` a type built on it gets.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from ..core.errors import KinematicsError
from .profile import SINGULAR_MARGINS, FloatArray

if TYPE_CHECKING:
    import pinocchio as pin

DAMPING: Final = 1e-10  # λ² floor, (m or rad)²: keeps the step finite on a singularity
MAX_STEP: Final = 0.3  # rad, the largest joint change in one iteration
TASK: Final = 6  # rows of the Jacobian: 3 translation, 3 rotation
# A step below this fraction of the pose error: what is left lies outside every joint's motion
STALL: Final = 1e-6
# The error an arm of fewer than 6 free joints may leave (least squares): what no joint's
# motion reduces, up to 1 mm and 0.1° (a pose from its measured joints is ~0.1 mm, 0.01° off)
OFF_M: Final = 1e-3
OFF_RAD: Final = math.radians(0.1)

_AXES: Final = {"JointModelRX": 0, "JointModelRY": 1, "JointModelRZ": 2}


def _log3(
    r00: float,
    r01: float,
    r02: float,
    r10: float,
    r11: float,
    r12: float,
    r20: float,
    r21: float,
    r22: float,
) -> tuple[float, float, float]:
    """The rotation vector (axis · angle, |angle| ≤ π) of a rotation matrix, in floats."""
    cos = 0.5 * (r00 + r11 + r22 - 1.0)
    vx, vy, vz = r21 - r12, r02 - r20, r10 - r01  # 2·sin θ · axis
    if cos > 1.0 - 1e-6:  # θ < 1.4e-3 rad: sin θ / θ ≈ 1 − θ²/6, θ² ≈ 2(1 − cos)
        k = 0.5 * (1.0 + (1.0 - cos) / 3.0)
        return k * vx, k * vy, k * vz
    if cos > -0.999:
        theta = math.acos(cos)
        k = 0.5 * theta / math.sin(theta)
        return k * vx, k * vy, k * vz
    # near π: R = cos θ·I + sin θ·[a]× + (1 − cos θ)·a·aᵀ, so a_i² = (R_ii − cos θ)/(1 − cos θ)
    # and the symmetric part gives the signs of a_i·a_j
    theta = math.acos(max(-1.0, cos))
    one_c = 1.0 - cos
    ax = math.sqrt(max(0.0, (r00 - cos) / one_c))
    ay = math.sqrt(max(0.0, (r11 - cos) / one_c))
    az = math.sqrt(max(0.0, (r22 - cos) / one_c))
    # fix relative signs from the off-diagonal (symmetric) part, largest component positive
    if ax >= ay and ax >= az:
        ay = math.copysign(ay, r01 + r10)
        az = math.copysign(az, r02 + r20)
    elif ay >= az:
        ax = math.copysign(ax, r01 + r10)
        az = math.copysign(az, r12 + r21)
    else:
        ax = math.copysign(ax, r02 + r20)
        ay = math.copysign(ay, r12 + r21)
    norm = math.sqrt(ax * ax + ay * ay + az * az)
    # the remaining sign: the skew part (vx, vy, vz) = 2 sin θ · axis, tiny but signed
    if ax * vx + ay * vy + az * vz < 0.0:
        norm = -norm
    return theta * ax / norm, theta * ay / norm, theta * az / norm


def cholesky_solve(a: list[float], b: list[float], m: int) -> bool:
    """Solve a·x = b for a symmetric positive definite ``m``×``m`` ``a`` (row-major list), in
    place: ``a`` becomes its Cholesky factor, ``b`` the solution.  False if ``a`` is not
    positive definite (a pivot ≤ 0).  Floats only: no allocation but loop iterators.
    """
    for i in range(m):
        row = i * m
        for j in range(i + 1):
            s = a[row + j]
            col = j * m
            for k in range(j):
                s -= a[row + k] * a[col + k]
            if i == j:
                if s <= 0.0:
                    return False
                a[row + i] = math.sqrt(s)
            else:
                a[row + j] = s / a[col + j]
    for i in range(m):
        s = b[i]
        row = i * m
        for k in range(i):
            s -= a[row + k] * b[k]
        b[i] = s / a[row + i]
    for i in range(m - 1, -1, -1):
        s = b[i]
        for k in range(i + 1, m):
            s -= a[k * m + i] * b[k]
        b[i] = s / a[i * m + i]
    return True


class DlsIk:
    """Damped-least-squares inverse kinematics of frame ``tip`` of ``model`` (see the module;
    the iteration in full in docs/internals/robots-hardware-plant.md).

    ``model``: a Pinocchio model whose joints are all revolute about their x, y or z axis
    (URDF revolute joints; Kali's generated URDFs turn about z), one configuration entry each.
    ``held``: the index of the joint held at a given angle (the redundancy parameter), or
    None.  ``name`` prefixes error messages.  Not thread-safe: one solver per process.
    """

    def __init__(
        self,
        model: pin.Model,
        tip: str,
        q_min: FloatArray,
        q_max: FloatArray,
        *,
        name: str,
        held: int | None = None,
        tol_m: float = 1e-11,
        tol_rad: float = 1e-11,
        max_iter: int = 60,
        off_m: float | None = None,
        off_rad: float | None = None,
    ) -> None:
        n = model.nq
        if model.nv != n or len(q_min) != n or len(q_max) != n:
            raise KinematicsError(
                f"{name}: the model has nq = {model.nq}, nv = {model.nv}, limits for "
                f"{len(q_min)}/{len(q_max)} joints: expected one angle per joint"
            )
        if not model.existFrame(tip):
            raise KinematicsError(f"{name}: the model has no frame {tip!r}")
        if held is not None and not 0 <= held < n:
            raise KinematicsError(f"{name}: held joint index {held} not in 0..{n - 1}")
        self.name = name
        self.n = n
        self.held = held
        self.tol_m = tol_m
        self.tol_rad = tol_rad
        self.max_iter = max_iter
        reduced = n - (held is not None) < TASK
        self.off_m = (OFF_M if reduced else 0.0) if off_m is None else off_m
        self.off_rad = (OFF_RAD if reduced else 0.0) if off_rad is None else off_rad
        self.lo = [float(v) for v in q_min]
        self.hi = [float(v) for v in q_max]
        self.model = model
        self.data = model.createData()
        import pinocchio as pin  # here, not at load: see the module's last paragraph

        self._forward_kinematics = pin.forwardKinematics
        frame = model.frames[model.getFrameId(tip)]
        chain = list(model.supports[frame.parentJoint])[1:]  # joint ids, base to tip
        if len(chain) != n:
            raise KinematicsError(f"{name}: frame {tip!r} is moved by {len(chain)} of {n} joints")
        self._axis: list[int] = []
        self._idx: list[int] = []
        for jid in chain:
            joint = model.joints[jid]
            kind = joint.shortname()
            if kind not in _AXES:
                raise KinematicsError(
                    f"{name}: joint {model.names[jid]!r} is a {kind}; DlsIk handles revolute "
                    f"joints about their x, y or z axis"
                )
            self._axis.append(_AXES[kind])
            self._idx.append(joint.idx_q)
        # Views into Data: forwardKinematics writes there in place.
        self._rot = [self.data.oMi[jid].rotation for jid in chain]
        self._pos = [self.data.oMi[jid].translation for jid in chain]
        tip_rot, tip_pos = frame.placement.rotation, frame.placement.translation
        self._tip_r = [float(v) for v in tip_rot.flatten()]
        self._tip_p = [float(v) for v in tip_pos]
        # An upper bound on the reach from joint 1's origin: the sum of the link offsets.
        self.reach = float(
            sum(np.linalg.norm(model.jointPlacements[jid].translation) for jid in chain[1:])
            + np.linalg.norm(tip_pos)
        )
        self._base = [float(v) for v in model.jointPlacements[chain[0]].translation]
        # work space
        self._q = np.zeros(n)  # Pinocchio's input
        self.qv = [0.0] * n  # the iterate
        self.jac = [0.0] * (TASK * n)  # column j: jac[6j .. 6j+5]
        self.pose = [0.0] * 12  # R row-major, then p
        self._a = [0.0] * (TASK * TASK)
        self._y = [0.0] * TASK
        self.iterations = 0  # of the last solve

    # ---------------------------------------------------------------- forward kinematics

    def forward(self, q: list[float], jacobian: bool) -> None:
        """The tip pose of ``q`` into ``pose`` and, if asked, the Jacobian into ``jac``."""
        buf = self._q
        for k in range(self.n):
            buf[self._idx[k]] = q[k]
        self._forward_kinematics(self.model, self.data, buf)
        r = self._rot[-1]
        p = self._pos[-1]
        r00, r01, r02 = r.item(0), r.item(1), r.item(2)
        r10, r11, r12 = r.item(3), r.item(4), r.item(5)
        r20, r21, r22 = r.item(6), r.item(7), r.item(8)
        t = self._tip_r
        tp = self._tip_p
        pose = self.pose
        pose[0] = r00 * t[0] + r01 * t[3] + r02 * t[6]
        pose[1] = r00 * t[1] + r01 * t[4] + r02 * t[7]
        pose[2] = r00 * t[2] + r01 * t[5] + r02 * t[8]
        pose[3] = r10 * t[0] + r11 * t[3] + r12 * t[6]
        pose[4] = r10 * t[1] + r11 * t[4] + r12 * t[7]
        pose[5] = r10 * t[2] + r11 * t[5] + r12 * t[8]
        pose[6] = r20 * t[0] + r21 * t[3] + r22 * t[6]
        pose[7] = r20 * t[1] + r21 * t[4] + r22 * t[7]
        pose[8] = r20 * t[2] + r21 * t[5] + r22 * t[8]
        px = p.item(0) + r00 * tp[0] + r01 * tp[1] + r02 * tp[2]
        py = p.item(1) + r10 * tp[0] + r11 * tp[1] + r12 * tp[2]
        pz = p.item(2) + r20 * tp[0] + r21 * tp[1] + r22 * tp[2]
        pose[9], pose[10], pose[11] = px, py, pz
        if jacobian:
            self._jacobian()

    def _jacobian(self) -> None:
        """The geometric Jacobian of the tip at the joint frames ``forward`` left in Data."""
        jac, pose = self.jac, self.pose
        px, py, pz = pose[9], pose[10], pose[11]
        for j in range(self.n):
            rj = self._rot[j]
            c = self._axis[j]
            wx, wy, wz = rj.item(c), rj.item(3 + c), rj.item(6 + c)
            oj = self._pos[j]
            dx, dy, dz = px - oj.item(0), py - oj.item(1), pz - oj.item(2)
            col = TASK * j
            jac[col] = wy * dz - wz * dy
            jac[col + 1] = wz * dx - wx * dz
            jac[col + 2] = wx * dy - wy * dx
            jac[col + 3] = wx
            jac[col + 4] = wy
            jac[col + 5] = wz

    def fkine(self, q: FloatArray | list[float], out: FloatArray | None = None) -> FloatArray:
        """The tip pose (4×4) for joint angles ``q``; into ``out`` without allocating."""
        qv = self.qv
        for k in range(self.n):
            qv[k] = float(q[k])
        self.forward(qv, jacobian=False)
        if out is None:
            out = np.empty((4, 4))
        pose = self.pose
        out[0, 0], out[0, 1], out[0, 2], out[0, 3] = pose[0], pose[1], pose[2], pose[9]
        out[1, 0], out[1, 1], out[1, 2], out[1, 3] = pose[3], pose[4], pose[5], pose[10]
        out[2, 0], out[2, 1], out[2, 2], out[2, 3] = pose[6], pose[7], pose[8], pose[11]
        out[3, 0] = out[3, 1] = out[3, 2] = 0.0
        out[3, 3] = 1.0
        return out

    # ---------------------------------------------------------------- conditioning

    def min_singular_above(self, sigma: float, skip: int | None) -> bool:
        """Whether the smallest singular value of the Jacobian ``forward`` left (without
        column ``skip``) is at least ``sigma``: of its min(6, m) singular values for m
        columns, so J·Jᵀ − σ²·I (6×6) or, with fewer than 6 columns, Jᵀ·J − σ²·I (m×m)
        positive definite (one Cholesky)."""
        m = self.n - (skip is not None)
        if m >= TASK:
            self._normal(skip, -sigma * sigma)
            return cholesky_solve(self._a, self._y, TASK)
        self._gram(skip, -sigma * sigma)
        return cholesky_solve(self._a, self._y, m)

    def singular_values(self, q: FloatArray | list[float], skip: int | None) -> FloatArray:
        """The Jacobian's singular values at ``q`` (without column ``skip``); allocates."""
        qv = [float(v) for v in q]
        self.forward(qv, jacobian=True)
        jac = np.array(self.jac).reshape(self.n, TASK).T
        if skip is not None:
            jac = np.delete(jac, skip, axis=1)
        return np.linalg.svd(jac, compute_uv=False)

    def _gram(self, skip: int | None, diag: float) -> None:
        """``_a`` = Jᵀ·J + diag·I over the joints other than ``skip`` (m×m, lower triangle),
        for a Jacobian of fewer than 6 columns."""
        jac, a = self.jac, self._a
        m = self.n - (skip is not None)
        r = 0
        for i in range(self.n):
            if i == skip:
                continue
            ci = TASK * i
            c = 0
            for j in range(i + 1):
                if j == skip:
                    continue
                cj = TASK * j
                s = 0.0
                for k in range(TASK):
                    s += jac[ci + k] * jac[cj + k]
                a[r * m + c] = s + diag if r == c else s
                c += 1
            r += 1

    def _normal(self, skip: int | None, diag: float) -> None:
        """``_a`` = J·Jᵀ + diag·I over the joints other than ``skip`` (unrolled: this is
        most of an iteration's arithmetic)."""
        jac = self.jac
        a00 = a10 = a11 = a20 = a21 = a22 = a30 = a31 = a32 = a33 = 0.0
        a40 = a41 = a42 = a43 = a44 = a50 = a51 = a52 = a53 = a54 = a55 = 0.0
        for j in range(self.n):
            if j == skip:
                continue
            c = TASK * j
            j0, j1, j2, j3, j4, j5 = (
                jac[c],
                jac[c + 1],
                jac[c + 2],
                jac[c + 3],
                jac[c + 4],
                jac[c + 5],
            )
            a00 += j0 * j0
            a10 += j1 * j0
            a11 += j1 * j1
            a20 += j2 * j0
            a21 += j2 * j1
            a22 += j2 * j2
            a30 += j3 * j0
            a31 += j3 * j1
            a32 += j3 * j2
            a33 += j3 * j3
            a40 += j4 * j0
            a41 += j4 * j1
            a42 += j4 * j2
            a43 += j4 * j3
            a44 += j4 * j4
            a50 += j5 * j0
            a51 += j5 * j1
            a52 += j5 * j2
            a53 += j5 * j3
            a54 += j5 * j4
            a55 += j5 * j5
        a = self._a  # only the lower triangle is read by cholesky_solve
        a[0], a[6], a[7], a[12], a[13], a[14] = a00 + diag, a10, a11 + diag, a20, a21, a22 + diag
        a[18], a[19], a[20], a[21] = a30, a31, a32, a33 + diag
        a[24], a[25], a[26], a[27], a[28] = a40, a41, a42, a43, a44 + diag
        a[30], a[31], a[32], a[33], a[34], a[35] = a50, a51, a52, a53, a54, a55 + diag

    # ---------------------------------------------------------------- inverse kinematics

    def solve(
        self,
        t: FloatArray,
        q_start: FloatArray | list[float],
        out: FloatArray | None = None,
        held_value: float | None = None,
    ) -> FloatArray:
        """Joint angles putting the tip at ``t`` (4×4), found from ``q_start``; the held
        joint at ``held_value`` (default: its value in ``q_start``).  ``KinematicsError``
        with the numbers when the iteration does not converge within the limits.
        """
        n, name = self.n, self.name
        tr00, tr01, tr02, tpx = t.item(0), t.item(1), t.item(2), t.item(3)
        tr10, tr11, tr12, tpy = t.item(4), t.item(5), t.item(6), t.item(7)
        tr20, tr21, tr22, tpz = t.item(8), t.item(9), t.item(10), t.item(11)
        if not math.isfinite(
            tr00 + tr01 + tr02 + tpx + tr10 + tr11 + tr12 + tpy + tr20 + tr21 + tr22 + tpz
        ):
            raise KinematicsError(f"{name} ikine: T is not finite: {t.tolist()}")
        bx, by, bz = self._base
        dist = math.sqrt((tpx - bx) ** 2 + (tpy - by) ** 2 + (tpz - bz) ** 2)
        if dist > self.reach:
            raise KinematicsError(
                f"{name} ikine: pose out of reach: the flange at ({tpx:.4f}, {tpy:.4f}, "
                f"{tpz:.4f}) m is {dist:.4f} m from joint 1's origin, beyond the "
                f"{self.reach:.4f} m the links add up to"
            )
        q = self.qv
        lo, hi, held = self.lo, self.hi, self.held
        for k in range(n):
            q[k] = min(max(float(q_start[k]), lo[k]), hi[k])
        if held is not None and held_value is not None:
            if not lo[held] <= held_value <= hi[held]:
                raise KinematicsError(
                    f"{name} ikine: joint {held + 1} held at {held_value:.4f} rad, outside its "
                    f"limits {lo[held]:.4f} .. {hi[held]:.4f} rad"
                )
            q[held] = held_value
        pose, jac, a, y = self.pose, self.jac, self._a, self._y
        err_p = err_r = math.inf
        for it in range(self.max_iter + 1):
            self.forward(q, jacobian=False)
            ex, ey, ez = tpx - pose[9], tpy - pose[10], tpz - pose[11]
            # R*·Rᵀ
            r0, r1, r2, r3, r4, r5, r6, r7, r8 = (
                pose[0],
                pose[1],
                pose[2],
                pose[3],
                pose[4],
                pose[5],
                pose[6],
                pose[7],
                pose[8],
            )
            wx, wy, wz = _log3(
                tr00 * r0 + tr01 * r1 + tr02 * r2,
                tr00 * r3 + tr01 * r4 + tr02 * r5,
                tr00 * r6 + tr01 * r7 + tr02 * r8,
                tr10 * r0 + tr11 * r1 + tr12 * r2,
                tr10 * r3 + tr11 * r4 + tr12 * r5,
                tr10 * r6 + tr11 * r7 + tr12 * r8,
                tr20 * r0 + tr21 * r1 + tr22 * r2,
                tr20 * r3 + tr21 * r4 + tr22 * r5,
                tr20 * r6 + tr21 * r7 + tr22 * r8,
            )
            err_p = math.sqrt(ex * ex + ey * ey + ez * ez)
            err_r = math.sqrt(wx * wx + wy * wy + wz * wz)
            if err_p <= self.tol_m and err_r <= self.tol_rad:
                self.iterations = it
                return self._answer(q, out)
            if it == self.max_iter:
                break
            self._jacobian()
            self._normal(held, DAMPING + err_p * err_p + err_r * err_r)
            y[0], y[1], y[2], y[3], y[4], y[5] = ex, ey, ez, wx, wy, wz
            if not cholesky_solve(a, y, TASK):  # cannot happen with λ² > 0; be explicit
                break
            y0, y1, y2, y3, y4, y5 = y[0], y[1], y[2], y[3], y[4], y[5]
            biggest = 0.0
            for j in range(n):
                if j != held:
                    c = TASK * j
                    d = (
                        jac[c] * y0
                        + jac[c + 1] * y1
                        + jac[c + 2] * y2
                        + jac[c + 3] * y3
                        + jac[c + 4] * y4
                        + jac[c + 5] * y5
                    )
                    a[j] = d  # reuse: the step, joint by joint
                    if abs(d) > biggest:
                        biggest = abs(d)
            if biggest < STALL * math.sqrt(err_p * err_p + err_r * err_r):
                self.iterations = it
                if err_p <= self.off_m and err_r <= self.off_rad:  # least squares: taken
                    return self._answer(q, out)
                raise KinematicsError(self._refusal(q, err_p, err_r, it, stalled=True))
            scale = MAX_STEP / biggest if biggest > MAX_STEP else 1.0
            for j in range(n):
                if j != held:
                    v = q[j] + scale * a[j]
                    q[j] = lo[j] if v < lo[j] else hi[j] if v > hi[j] else v
        self.iterations = self.max_iter
        if err_p <= self.off_m and err_r <= self.off_rad:
            return self._answer(q, out)
        raise KinematicsError(self._refusal(q, err_p, err_r, self.max_iter, stalled=False))

    def _answer(self, q: list[float], out: FloatArray | None) -> FloatArray:
        """The solution ``q`` into ``out`` (allocated only when None)."""
        if out is None:
            out = np.empty(self.n)
        for k in range(self.n):
            out[k] = q[k]
        return out

    def _refusal(
        self, q: list[float], err_p: float, err_r: float, iterations: int, stalled: bool
    ) -> str:
        """Why ``solve`` gives up at ``q``: the error left, the joints on their limits, and
        whether no joint's motion reduces what is left (outside the cycle: the tick refuses)."""
        n, lo, hi, held = self.n, self.lo, self.hi, self.held
        at_limit = [
            f"joint {k + 1} at {q[k]:.4f} rad (limits {lo[k]:.4f} .. {hi[k]:.4f})"
            for k in range(n)
            if k != held and (q[k] <= lo[k] or q[k] >= hi[k])
        ]
        held_text = "" if held is None else f" with joint {held + 1} held at {q[held]:.4f} rad"
        left = f"{err_p * 1000:.3g} mm and {math.degrees(err_r):.3g}° left"
        limits = f"; on their limits: {'; '.join(at_limit)}" if at_limit else ""
        if stalled:
            free = n - (held is not None)
            why = (
                f"with {free} free joints the flange moves in only {free} of a pose's "
                f"{TASK} directions: a pose more than {self.off_m * 1000:g} mm or "
                f"{math.degrees(self.off_rad):g}° off them, e.g. off a planar arm's plane, "
                f"is out of reach"
                if free < TASK
                else "the flange cannot move that way from here: out of reach or singular"
            )
            return (
                f"{self.name} ikine: no solution{held_text}: {left} after {iterations} "
                f"iterations, which no joint's motion reduces{limits} ({why})"
            )
        return (
            f"{self.name} ikine: no solution{held_text} within {self.max_iter} iterations: "
            f"{left}{limits} (out of reach or out of the joint limits from this start)"
        )


# --------------------------------------------------------------------------------------------
# A whole Kinematics for any serial arm of revolute joints


@dataclass(frozen=True, slots=True)
class Nearest:
    """The only branch of a numerically solved arm: the solution nearest ``q_ref``, reached
    continuously from it."""

    def __str__(self) -> str:
        return "nearest"


NEAREST: Final = Nearest()
SIGMA_MIN: Final = 0.02  # default smallest singular value allowed for a Cartesian path
FLANGE_FRAME: Final = "flange"  # the URDF link every type's kinematics is of (profile.py)


class NumericalKinematics:
    """A robot type's ``Kinematics`` (``profile.py``) by damped least squares on the
    Pinocchio model of its URDF: any serial arm of 1 to 8 revolute joints, so a type needs no
    closed form of its own.

    - ``ikine`` starts from ``q_ref`` (the trajectory generator's previous set-point; default
      ``q_home``) and finds the solution nearest it: one branch, ``NEAREST``.  An arm with
      fewer than 6 joints reaches only some poses (a planar arm: those in its plane, turned
      about its joints' axis): its solution is the least squares one, taken if what no
      joint's motion reduces is within ``off_m`` and ``off_rad`` (``DlsIk``; default 1 mm
      and 0.1°, so a pose read from the measured joints works), else refused naming it.
    - ``redundant_joint``: the index of the joint that is the redundancy parameter of an arm
      with more than 6 joints; ``ikine`` holds it at ``redundancy`` or, when that is None,
      at ``q_ref``'s value, so a Cartesian path keeps it.  None: every joint is solved for.
    - ``singular`` refuses a configuration whose Jacobian (6×n) has a singular value (of its
      min(6, n)) below ``sigma_min``, or, with a redundant joint, whose Jacobian without it
      has (holding it there would make the other joints race).  0.02 (m or rad per rad) is
      what the PUMA's thresholds amount to: its smallest singular value is 0.020 at 5 cm
      from the elbow singularity and 0.039 at 5° from the wrist one.
    - ``name`` starts every message (the type's name); ``label`` is what messages call the
      arm ("Panda"), default ``name``.

    The model is loaded on first use, so importing a type needs no Pinocchio model: a process
    calls ``load`` while it configures, outside the cycle; ``fkine``, ``ikine`` with ``out``,
    ``config_of`` and ``singular`` (on its None path) then run inside it without numpy
    allocation.  One instance per process (the solver keeps work space).
    """

    configs: tuple[object, ...] = (NEAREST,)

    def __init__(
        self,
        urdf: Path | str,
        q_min: FloatArray,
        q_max: FloatArray,
        q_home: FloatArray | None = None,
        *,
        name: str,
        label: str | None = None,
        redundant_joint: int | None = None,
        sigma_min: float = SIGMA_MIN,
        tip: str = FLANGE_FRAME,
        off_m: float | None = None,
        off_rad: float | None = None,
    ) -> None:
        n = len(q_min)
        if len(q_max) != n or (q_home is not None and len(q_home) != n):
            raise KinematicsError(
                f"{name}: q_min, q_max and q_home have {n}, {len(q_max)} and "
                f"{n if q_home is None else len(q_home)} angles: expected one per joint"
            )
        if redundant_joint is not None and not 0 <= redundant_joint < n:
            raise KinematicsError(
                f"{name}: redundant_joint = {redundant_joint}: must be a joint index 0..{n - 1}"
            )
        if not sigma_min > 0.0:
            raise KinematicsError(f"{name}: sigma_min = {sigma_min}: must be > 0")
        self.urdf = Path(urdf)
        self.name = name
        self.label = label or name
        self.n = n
        self.q_min = np.array(q_min, dtype=float)
        self.q_max = np.array(q_max, dtype=float)
        home = (self.q_min + self.q_max) / 2.0 if q_home is None else q_home
        self.redundant_joint = redundant_joint
        self.sigma_min = float(sigma_min)
        self.tip = tip
        self.off_m, self.off_rad = off_m, off_rad
        self._solver: DlsIk | None = None
        self._qv = [0.0] * n
        self._home = [float(v) for v in home]

    def load(self) -> DlsIk:
        """The solver on the URDF's Pinocchio model, loading it the first time (allocates)."""
        if self._solver is None:
            if not self.urdf.is_file():
                raise KinematicsError(f"{self.name}: {self.urdf}: no such file")
            try:
                import pinocchio as pin  # here, not at load: see the module's last paragraph

                model = pin.buildModelFromUrdf(str(self.urdf))
            except (RuntimeError, ValueError) as exc:
                raise KinematicsError(
                    f"{self.name}: {self.urdf}: Pinocchio cannot load it: {exc}"
                ) from None
            self._solver = DlsIk(
                model,
                self.tip,
                self.q_min,
                self.q_max,
                name=self.name,
                held=self.redundant_joint,
                off_m=self.off_m,
                off_rad=self.off_rad,
            )
        return self._solver

    @property
    def solver(self) -> DlsIk:
        """``load()``."""
        return self._solver if self._solver is not None else self.load()

    def fkine(self, q: FloatArray, out: FloatArray | None = None) -> FloatArray:
        """The flange pose (4×4) in the base frame; into ``out`` without allocating."""
        return self.solver.fkine(q, out)

    def ikine(
        self,
        t6: FloatArray,
        config: object = NEAREST,
        q_ref: FloatArray | None = None,
        out: FloatArray | None = None,
        redundancy: float | None = None,
    ) -> FloatArray:
        """Joint angles within the limits putting the flange at ``t6``, found from ``q_ref``
        (default ``q_home``); the redundant joint, if any, at ``redundancy`` (default:
        ``q_ref``'s).

        ``KinematicsError`` for a bad ``t6`` or branch, a pose beyond the arm's reach, one
        its joints cannot reach (off a planar arm's plane), or no convergence (out of reach
        or the limits from this start), with the numbers.
        """
        if config is not NEAREST and config != NEAREST:
            raise KinematicsError(
                f"{self.name} ikine: {config!r} is not a {self.label} configuration"
            )
        if not isinstance(t6, np.ndarray) or t6.shape != (4, 4):
            raise KinematicsError(
                f"{self.name} ikine: T must be a 4×4 array, got {type(t6).__name__} "
                f"{getattr(t6, 'shape', '')}"
            )
        start = self._home if q_ref is None else q_ref
        if len(start) != self.n:
            raise KinematicsError(f"{self.name} ikine: q_ref has {len(start)} angles, not {self.n}")
        return self.solver.solve(t6, start, out, redundancy)

    def config_of(self, q: FloatArray) -> object:
        """Always ``NEAREST``: a numerically solved arm has no discrete branches."""
        return NEAREST

    def parse_config(self, text: str) -> object:
        """``NEAREST`` from "nearest" (case ignored)."""
        if isinstance(text, str) and text.lower() == "nearest":
            return NEAREST
        held = self.redundant_joint
        also = "" if held is None else f"; the redundancy parameter is joint {held + 1}"
        raise KinematicsError(
            f"{self.name}: configuration {text!r}: the {self.label} has one, 'nearest' (the "
            f"solution nearest the present joints{also})"
        )

    def singular(self, q: FloatArray) -> str | None:
        """Why ``q`` is too near a singularity for a Cartesian path, or None.  Inside the
        cycle on the None path (one Cholesky per Jacobian); a refusal computes the singular
        values for its message."""
        qv, n, held, sigma_min = self._qv, self.n, self.redundant_joint, self.sigma_min
        for k in range(n):
            qv[k] = float(q[k])
        solver = self.solver
        solver.forward(qv, jacobian=True)
        if not solver.min_singular_above(sigma_min, None):
            sigma = float(solver.singular_values(qv, None)[-1])
            return (
                f"{sigma:.4f} from a singularity: the 6×{n} Jacobian's smallest singular "
                f"value is below {sigma_min:g}"
            )
        if held is not None and not solver.min_singular_above(sigma_min, held):
            sigma = float(solver.singular_values(qv, held)[-1])
            return (
                f"{sigma:.4f} from a singularity with joint {held + 1} held (at "
                f"{math.degrees(qv[held]):.2f}°): the 6×{n - 1} Jacobian of the other joints "
                f"has a singular value below {sigma_min:g}"
            )
        return None

    def singular_margin(self, q: FloatArray) -> float:
        """How far ``q`` is from a singularity as a multiple of ``sigma_min``, resolved to
        ``SINGULAR_MARGINS`` (the highest the smallest singular value passes; 0 below
        ``sigma_min``), with the redundant joint held as ``singular`` checks it.  Inside the
        cycle: one Cholesky a level."""
        qv, held, solver = self._qv, self.redundant_joint, self.solver
        for k in range(self.n):
            qv[k] = float(q[k])
        solver.forward(qv, jacobian=True)
        passed = 0.0
        for level in (1.0, *SINGULAR_MARGINS):
            sigma = level * self.sigma_min
            if not solver.min_singular_above(sigma, None) or (
                held is not None and not solver.min_singular_above(sigma, held)
            ):
                break
            passed = level
        return passed
