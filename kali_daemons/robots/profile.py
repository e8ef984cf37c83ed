"""What a robot type declares, in one place (thesis 3.1, 3.5: the driver "a set of functions
entered in a table" per robot type).

A robot type is data plus a few functions: a URDF, a joint count, limits, a drive,
kinematics, default servo gains and a calibration sheet.  Each shipped type is a package under
``kali_daemons/robots/`` exposing ``ROBOT``, a ``RobotType``, that
``kali_daemons.robots.robot_type(name)`` finds by the config's ``robots[].model``; a
researcher's own arm is one module file named there by its path (``model: arms/myarm.py``,
checked by ``typefile.py``), with ``numik.NumericalKinematics`` if it has no closed form.
Nothing outside the type's package or file knows which arm it drives.

Conventions every type keeps: per-joint arrays are read-only, indexed ``0 .. n_joints - 1``;
the URDF's revolute joints are ``j1 .. jN`` base to tip, its last link ``flange`` (where tools
and the bar grasp attach) and its base link at the robot's base frame; ``G`` is the signed
gear ratio (motor angle = G · joint angle), through which motor-side quantities reach the
joint; angles in rad, lengths in m, torques in N·m at the joint unless named motor-side.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt

from ..core.errors import ConfigError
from ..core.layout import MAX_JOINTS

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]


# The friction model every drive follows (``Drive.coulomb_pos``/``coulomb_neg``): the Coulomb
# remainder's sign is smoothed over ± this motor speed, so the plant and the feed-forward
# dynamics use one continuous friction law
FRICTION_SMOOTHING_RAD_S = 2.0  # rad/s at the motor

# The built-in PID's integration band of every type tuned by ``servo_gains``: the PUMA's
INTEGRATION_BAND_RAD = 0.01  # rad
# A kinematics' singular_margin: the multiples of its singularity limit a tracking motion
# slows down within (below the last) and a numerical type resolves (its Jacobian's smallest
# singular value tested against each, one Cholesky a level); an analytic type gives the ratio
SINGULAR_MARGINS = (1.25, 1.5, 2.0)


def read_only(values: object, dtype: type = np.float64) -> npt.NDArray:
    """A read-only copy: a robot type's facts, nobody changes them in place."""
    arr: npt.NDArray = np.array(values, dtype=dtype)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class Drive:
    """The drive train of every joint: motor, amplifier, gearbox and encoder.

    Per-joint arrays have ``n_joints`` entries; scalars hold for every joint (one amplifier
    and DAC model per board).
    """

    gear: FloatArray  # signed gear ratio G: motor angle = G · joint angle
    counts_per_rev: IntArray  # encoder counts per motor revolution (one index pulse per rev)
    kt: FloatArray  # N·m/A, motor torque constant (= back-EMF V/(rad/s))
    r_armature: FloatArray  # Ω, motor armature resistance
    max_current: FloatArray  # A, motor peak current (the amplifier clips at it)
    rotor_inertia: FloatArray  # kg·m², motor side (reflected: G² · it)
    viscous: FloatArray  # N·m·s/rad, joint side viscous friction
    coulomb_pos: FloatArray  # N·m, joint side Coulomb friction for qd > 0 (>= 0)
    coulomb_neg: FloatArray  # N·m, joint side Coulomb friction for qd < 0 (<= 0)
    brake_torque: FloatArray  # N·m, joint side holding torque of the brake
    amp_gain_a_per_v: float  # A of motor current per V of DAC output
    amp_bandwidth_hz: float  # current loop bandwidth
    bus_voltage: float  # V: R·i + Kt·ω_m must stay within ± this
    dac_volts: float  # the DAC's full scale is ± this

    @property
    def armature(self) -> FloatArray:
        """Reflected rotor inertia at the joint, kg·m² (MuJoCo armature, Pinocchio armature)."""
        return read_only(self.rotor_inertia * self.gear**2)

    @property
    def rad_per_count(self) -> FloatArray:
        """Joint angle of one encoder count, rad (unsigned)."""
        return read_only(2.0 * np.pi / (self.counts_per_rev * np.abs(self.gear)))

    @property
    def peak_joint_torque(self) -> FloatArray:
        """N·m at the joint at the motor's peak current."""
        return read_only(self.max_current * self.kt * np.abs(self.gear))


class Kinematics(Protocol):
    """A robot type's forward and inverse kinematics of the flange in its base frame.

    ``configs`` lists the type's inverse-kinematics branches (the PUMA's and the UR5's eight:
    arm, elbow, wrist); a type without branches has one.  A branch's index in ``configs``
    is how requests carry it through the arena.  Each branch prints as a short string and
    ``parse_config`` reads it back.

    ``fkine`` and ``ikine`` with ``out`` given, ``config_of`` and ``singular`` run inside the
    trajectory generator's cycle: no numpy allocation on the success path.
    """

    @property
    def configs(self) -> tuple[object, ...]:
        """The branches, in the order their indices name them (read-only: a type's fact)."""
        ...

    def fkine(self, q: FloatArray, out: FloatArray | None = None) -> FloatArray:
        """The flange pose (4×4) in the base frame for joint angles ``q``."""
        ...

    def ikine(
        self,
        t6: FloatArray,
        config: Any,  # one of ``configs`` or its string: each type takes its own branch type
        q_ref: FloatArray | None = None,
        out: FloatArray | None = None,
        redundancy: float | None = None,
    ) -> FloatArray:
        """Joint angles within the limits that put the flange at ``t6`` in branch ``config``,
        nearest ``q_ref``.  ``redundancy``: for a redundant arm, the value of the type's
        redundancy parameter (None: keep ``q_ref``'s).  ``KinematicsError`` if none."""
        ...

    def config_of(self, q: FloatArray) -> object:
        """The branch joint angles ``q`` are in (one of ``configs``)."""
        ...

    def parse_config(self, text: str) -> object:
        """A branch from its string; ``KinematicsError`` naming the accepted forms."""
        ...

    def singular(self, q: FloatArray) -> str | None:
        """Why ``q`` is too near a singularity for a Cartesian path, or None if it is not."""
        ...

    def singular_margin(self, q: FloatArray) -> float:
        """How far ``q`` is from the nearest singularity, as a multiple of the type's limit
        (``singular`` refuses below 1): what a tracking motion slows down by.  At least
        ``SINGULAR_MARGINS[-1]`` may be answered as that.  Inside the cycle: no allocation."""
        ...


def servo_gains(
    j_home: FloatArray,
    wn: FloatArray,
    zeta: float,
    viscous: FloatArray,
    hold: FloatArray,
) -> tuple[tuple[dict[str, float], ...], tuple[dict[str, float], ...]]:
    """The built-in PID's and PD's init data per joint, by the rule the PUMA's gains were
    tuned with (``robots/puma560/facts.py``): kp = J·ωn², kv = 2ζ·J·ωn − viscous,
    ki = 20 s⁻¹ · kp, integration_reset = 1.2 · ``hold`` rounded up to a whole N·m,
    integration_band = ``INTEGRATION_BAND_RAD`` (the PUMA's 0.01 rad).  ``j_home``: the
    joint-side inertia at the home pose with armature; ``hold``: the largest gravity plus
    Coulomb friction torque per joint (N·m).  A type without a tuning of its own uses it.

    The band must be 2.5 · reset / kp or wider, or a joint sagging or stuck on friction
    outside it never integrates; the PUMA's stiff joints meet that at 0.01 rad.  A joint
    whose load is large for its inertia gets a higher ωn, until kp · 0.01 rad = 2.5 · reset,
    rather than a wider band: inside the band the integral winds up during a step, so a
    wide band overshoots (the figures: docs/internals/robots-hardware-plant.md)."""
    pid: list[dict[str, float]] = []
    for j, inertia in enumerate(j_home):
        reset = float(max(1.0, math.ceil(1.2 * hold[j])))
        w = max(float(wn[j]), math.sqrt(2.5 * reset / (INTEGRATION_BAND_RAD * inertia)))
        kp = float(inertia * w**2)
        pid.append(
            {
                "kp": kp,  # N·m/rad
                "ki": 20.0 * kp,  # N·m/(rad·s)
                "kv": float(2.0 * zeta * inertia * w - viscous[j]),  # N·m·s/rad
                "fe": 50.0,  # Hz, error filter (thesis figure 3.4)
                "fv": 25.0,  # Hz, velocity filter
                "integration_band": INTEGRATION_BAND_RAD,  # rad
                "integration_reset": reset,  # N·m
                "bias_tau": 0.5,  # s, hand-over bias
            }
        )
    pd = [{"kp": g["kp"], "kv": g["kv"], "fv": g["fv"], "bias_tau": 0.5} for g in pid]
    return tuple(pid), tuple(pd)


def drive_from_facts(facts: Any) -> Drive:
    """A type's ``Drive`` from its facts module, by the names every shipped type's facts use
    (``G``, ``COUNTS_PER_MOTOR_REV``, ``KT``, ``R_ARMATURE``, ``MAX_CURRENT``, ``JM``,
    ``VISCOUS``, ``COULOMB_POS``/``_NEG``, ``BRAKE_TORQUE``, ``AMP_GAIN_A_PER_V``,
    ``AMP_BANDWIDTH_HZ``, ``BUS_VOLTAGE``, ``DAC_VOLTS``)."""
    f = facts
    return Drive(
        gear=f.G,
        counts_per_rev=f.COUNTS_PER_MOTOR_REV,
        kt=f.KT,
        r_armature=f.R_ARMATURE,
        max_current=f.MAX_CURRENT,
        rotor_inertia=f.JM,
        viscous=f.VISCOUS,
        coulomb_pos=f.COULOMB_POS,
        coulomb_neg=f.COULOMB_NEG,
        brake_torque=f.BRAKE_TORQUE,
        amp_gain_a_per_v=f.AMP_GAIN_A_PER_V,
        amp_bandwidth_hz=f.AMP_BANDWIDTH_HZ,
        bus_voltage=f.BUS_VOLTAGE,
        dac_volts=f.DAC_VOLTS,
    )


@dataclass(frozen=True)
class RobotType:
    """One robot type: everything Kali knows about an arm model, found by ``name``."""

    name: str  # the config's robots[].model (a type file's own name for it: messages)
    description: str  # one line: maker, model and where the numbers come from
    urdf: Path  # joints j1..jN, a 'flange' link
    n_joints: int  # 1 .. MAX_JOINTS
    q_min: FloatArray  # rad
    q_max: FloatArray  # rad
    qd_max: FloatArray  # rad/s, what the trajectory generator plans with
    qdd_max: FloatArray  # rad/s², likewise
    q_home: FloatArray  # rad: the pose the simulated arm starts in, and a reference pose
    drive: Drive
    kinematics: Kinematics
    pid_defaults: tuple[dict[str, float], ...]  # per joint: the built-in PID's init data
    pd_defaults: tuple[dict[str, float], ...]  # per joint: the built-in PD's
    # The calibration sheet (thesis 3.5.1, C.3): each joint's index-pulse motor angle, rad in
    # [0, 2π), measured once per arm; a robot's config may name its own.
    index_phases: FloatArray = field(default_factory=lambda: read_only([]))
    # The arm knows its joint angles at power-up (absolute encoders): it has nothing to
    # calibrate, thesis 3.5.1's calibration does not apply, and its sheet is empty.
    absolute_encoders: bool = False
    gravity: float = 9.81  # m/s²

    def __post_init__(self) -> None:
        """Refuse a declaration Kali cannot drive, naming the type, field, value and rule."""

        def bad(what: str, value: object, rule: str) -> ConfigError:
            # a file is named whole (its name ends the path); anything else within 80
            shown = repr(str(value)) if isinstance(value, (str, Path)) else f"{value!r:.80}"
            return ConfigError(f"robot type {self.name!r}: {what} = {shown}: {rule}")

        n = self.n_joints
        if not (isinstance(n, int) and 1 <= n <= MAX_JOINTS):
            raise bad(
                "n_joints", n, f"must be 1 .. {MAX_JOINTS} (the joints Kali's per-arm records hold)"
            )
        per_joint = [(f.name, getattr(self, f.name)) for f in fields(self)]
        per_joint += [(f"drive.{f.name}", getattr(self.drive, f.name)) for f in fields(Drive)]
        for what, value in per_joint:
            skip = not isinstance(value, np.ndarray) or what == "index_phases"
            if not skip and (value.shape != (n,) or not np.isfinite(value).all()):
                raise bad(what, value, f"must be {n} finite numbers, one per joint")
        for what, table in (("pid_defaults", self.pid_defaults), ("pd_defaults", self.pd_defaults)):
            if len(table) != n:
                raise bad(what, len(table), f"must have {n} entries, one per joint")
        if not (self.q_min < self.q_max).all():
            raise bad("q_min", self.q_min, "must be below q_max on every joint")
        if not ((self.q_min <= self.q_home) & (self.q_home <= self.q_max)).all():
            raise bad("q_home", self.q_home, "must be within q_min .. q_max")
        for what in ("qd_max", "qdd_max"):
            if not (getattr(self, what) > 0).all():
                raise bad(what, getattr(self, what), "must be > 0 on every joint")
        d = self.drive
        if (d.gear == 0).any() or (d.counts_per_rev <= 0).any() or (d.kt <= 0).any():
            raise bad("drive", d.gear, "gear ratios must be non-zero, counts and Kt > 0")
        if (d.max_current <= 0).any():
            raise bad("drive.max_current", d.max_current, "must be > 0 on every joint")
        sheet = self.index_phases
        if len(sheet) not in (0, n) or not ((sheet >= 0) & (sheet < 2 * np.pi)).all():
            raise bad("index_phases", sheet, f"must be {n} motor angles in [0, 2π) rad")
        if not Path(self.urdf).is_file():
            raise bad("urdf", str(self.urdf), "no such file")
