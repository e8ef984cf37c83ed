"""Robot-level servos (thesis 3.3.4: a Cartesian servo mode "activated instead of
the joint servo one", 2.2.3: the computed-torque law H(q)u + h): an algorithm that servos a
whole arm at once.

An ``ArmServoAlgorithm`` is registered in the same ``Registry`` as joint servos (by a
plugin's ``register(registry)`` too) and has the same life: private data in the arena (one
record per robot), on-line parameters and get/put through the robot's mailbox.  Each servo
tick the SV that claims the robot fills one ``ArmInput`` and calls the active algorithm's
``step``.  A robot runs either its joint servos or one robot-level servo; the switch is
bumpless both ways.  ``data`` is the robot's record, a 0-d numpy structured array in the
arena: ``data["kx"]`` reads a field, ``data["kx"] = v`` writes it, and an array field
(``("bias", "<f8", (8,))``) is a view to compute in place.

- ``step(data, inp, tau) -> status``: inside the servo cycle.  Writes the n joint torques
  (N·m) into ``tau``; returns 0 when all is well.  Numpy in place, no I/O, no logging.
- ``handover(data, inp, tau_prev)``: inside the cycle, just before the first ``step`` after
  the robot switches to this algorithm, in the same tick: ``tau_prev`` is the torque the
  motors got last tick (servo plus feed-forward), which that step should continue from.
- ``init(data, init_data, sample_interval_s)``, ``set_params``, ``get_params``: outside.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from ...core import layout
from ...core.errors import ConfigError

MAX_DATA_BYTES = layout.SERVO_STAGING_BYTES  # a robot's record must fit its put/get mailbox
MAX_ARRAY = 64  # elements of one array field of a robot-level servo's private data
NUMERIC_KINDS = "biuf"


class ArmInput:
    """What a robot-level servo sees each tick, for one robot of ``n`` joints: every array
    preallocated once (outside the cycle) and refilled in place by the SV each tick.

    Joint vectors (n,): ``q_d``, ``qd_d``, ``qdd_d`` the demand (rad, rad/s, rad/s²: the TG's
    set-points interpolated, their derivatives from the dynamics process's rows), ``q``,
    ``qd`` the measurement, ``tau_ff`` the feed-forward SIO would add to joint servos (not
    added to a robot-level servo's torque: include it or not), ``h`` the nonlinear effects
    C(q, q̇) q̇ + g(q) and ``g`` gravity, both at the measurement, with the rotor inertias.
    ``M`` (n, n) the joint-space mass matrix.  ``J`` (6, n) the tool point's geometric
    Jacobian, world axes (linear rows first).  ``pose`` and ``pose_d`` (4, 4) the tool point
    in the world at ``q`` and at ``q_d``.  ``wrench`` (``layout.WRENCH``) the contact wrench
    the environment applies at the tool point, world axes (N, N·m; SIO's, tared and
    gravity-compensated; zeros when the robot has no sensor, ``has_sensor`` False).
    ``wrenches`` (robots, ``layout.WRENCH``) every robot's contact wrench the same way, in
    config order (SIO's records, read-only: an arm sharing an object with another, as in a
    squeeze, sees both).  ``friction(qd, out)``: the drive's friction torque at joint velocity
    ``qd``.  ``dt`` the servo period, s.
    ``work`` (4, n) and ``work6`` (4, 6) are scratch an algorithm may use within a call.
    """

    __slots__ = (
        "J",
        "M",
        "dt",
        "friction",
        "g",
        "h",
        "has_sensor",
        "n",
        "pose",
        "pose_d",
        "q",
        "q_d",
        "qd",
        "qd_d",
        "qdd_d",
        "robot",
        "tau_ff",
        "work",
        "work6",
        "wrench",
        "wrenches",
    )
    # the joint vectors (n,), made in ``__init__``
    q_d: np.ndarray
    qd_d: np.ndarray
    qdd_d: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau_ff: np.ndarray
    h: np.ndarray
    g: np.ndarray

    def __init__(self, n: int, dt: float, robot: str = "") -> None:
        self.n, self.dt, self.robot = n, dt, robot
        for name in ("q_d", "qd_d", "qdd_d", "q", "qd", "tau_ff", "h", "g"):
            setattr(self, name, np.zeros(n))
        self.M = np.eye(n)
        self.J = np.zeros((layout.WRENCH, n))
        self.pose, self.pose_d = np.eye(4), np.eye(4)
        self.wrench = np.zeros(layout.WRENCH)
        self.wrenches = np.zeros((1, layout.WRENCH))  # the SV binds SIO's records
        self.has_sensor = False
        self.work = np.zeros((4, n))
        self.work6 = np.zeros((4, layout.WRENCH))
        self.friction: Callable[[np.ndarray, np.ndarray], None] = _no_friction


def _no_friction(qd: np.ndarray, out: np.ndarray) -> None:
    out.fill(0.0)


@dataclass(frozen=True)
class ArmServoAlgorithm:
    """One robot-level servo algorithm as the SV runs it; ``data`` is the robot's record."""

    name: str  # registry name, unique among joint and robot-level servos
    dtype: np.dtype  # private data: aligned structured dtype, numeric scalars or 1-D arrays
    params: tuple[str, ...]  # parameter names: init/set_params accept, get_params returns
    init: Callable[[Any, Mapping[str, float], float], None]
    step: Callable[[Any, ArmInput, np.ndarray], int]
    handover: Callable[[Any, ArmInput, np.ndarray], None]
    set_params: Callable[[Any, Mapping[str, float]], None]
    get_params: Callable[[Any], dict[str, float]]
    doc: str = ""
    # True: the algorithm guides the arm by hand (``admittance.GUIDING``): while it runs,
    # SIO's demand follows the measured arm and the TG moves it not (``ROBOT_STATE.guided``)
    guides: bool = False
    # True: the wrist sensor moves the arm (``admittance``): selecting it is refused on an arm
    # without a sensor or whose sensor was never tared (its offsets would move the arm)
    senses: bool = False
    # a compiled ``step``: ``bind(data, inp, tau)`` at configure returns a call that steps
    # that robot's record on what is then in ``inp`` into ``tau`` and returns the status,
    # equal to ``step`` (the built-ins': ``kernels.arm_step``); None: the SV calls ``step``
    bind: Callable[[Any, ArmInput, np.ndarray], Callable[[], int]] | None = None


def check_arm_dtype(dtype: Any) -> str | None:
    """What is wrong with ``dtype`` as a robot-level servo's private data, or None."""
    if not isinstance(dtype, np.dtype):
        return f"dtype {dtype!r} is a {type(dtype).__name__}, not a numpy dtype (use np.dtype)"
    if dtype.fields is None:
        return f"dtype {dtype} is not a structured dtype (give named fields)"
    if not dtype.isalignedstruct:
        return f"dtype {dtype} is not aligned (build it with np.dtype([...], align=True))"
    for field, (ft, _offset, *_title) in dtype.fields.items():
        base = ft.base if ft.subdtype is not None else ft
        if ft.subdtype is not None and (len(ft.shape) != 1 or ft.shape[0] > MAX_ARRAY):
            return (
                f"dtype field {field!r} has shape {ft.shape}; arrays must be 1-D, at most "
                f"{MAX_ARRAY} elements"
            )
        if base.kind not in NUMERIC_KINDS or not base.isnative or base.itemsize > 8:
            return (
                f"dtype field {field!r} has type {base.str}; only native-endian numeric "
                f"values of at most 8 bytes (bool, int, uint, float) are allowed"
            )
    if dtype.itemsize > MAX_DATA_BYTES:
        return (
            f"private data is {dtype.itemsize} B, at most {MAX_DATA_BYTES} B "
            f"(the put/get mailbox, layout.SERVO_STAGING_BYTES)"
        )
    return None


PROBE_JOINTS = 6  # the test input ``register`` steps a new robot-level algorithm with
PROBE_INTERVAL_S = 0.001


def probe_input(n: int = PROBE_JOINTS) -> ArmInput:
    """A unit arm for ``register``'s check: identity mass matrix and Jacobian rows, no
    gravity, at rest, with a 0.01 rad demand on every joint (outside any cycle)."""
    inp = ArmInput(n, PROBE_INTERVAL_S, "probe")
    inp.q_d.fill(0.01)
    inp.J[: min(n, layout.WRENCH), : min(n, layout.WRENCH)] = np.eye(min(n, layout.WRENCH))
    inp.pose_d[:3, 3] = 0.01
    return inp


def probe_arm_step(algo: ArmServoAlgorithm, what: str) -> None:
    """Initialise ``algo`` at its defaults on a scratch record, hand a unit arm over and step
    it once; ConfigError unless ``step`` returns an integer status and finite torques."""
    record = np.zeros((), dtype=algo.dtype)
    inp = probe_input()
    tau = np.zeros(inp.n)
    try:
        algo.init(record, {}, PROBE_INTERVAL_S)
        algo.handover(record, inp, np.zeros(inp.n))
        status = algo.step(record, inp, tau)
    except ConfigError:
        raise
    except Exception as exc:
        raise ConfigError(
            f"{what}: step on a unit arm at its defaults raised {type(exc).__name__}: {exc}"
        ) from None
    if isinstance(status, bool) or not isinstance(status, int | np.integer):
        raise ConfigError(
            f"{what}: step returned {status!r:.60}; it must return an integer status "
            f"(0 = ok) and write the torques into its tau argument"
        )
    if not all(math.isfinite(float(t)) for t in tau):
        raise ConfigError(f"{what}: step on a unit arm at its defaults wrote torques {tau}")
