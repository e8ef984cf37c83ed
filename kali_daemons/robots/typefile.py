"""A robot type from a module file named in the config (bring your own arm).

A researcher's own arm needs no edit to Kali: ``robots[].model`` names a ``.py`` file (the
config resolves it against its own directory, so every process loads the same file), whose
module declares ``ROBOT``, a ``RobotType`` (``profile.py``).  ``load_type_file`` imports it
under a module name of its own and checks everything Kali will rely on before any process
starts, so ``kalictl start`` refuses a bad file with the file, the field, the value and the
rule instead of a daemon failing later:

- the file exists and imports (what it raised, and on which of its lines);
- it defines ``ROBOT``, a ``RobotType`` (whose ``__post_init__`` checks the fields: joint
  count, per-joint lists, limits, drive, the URDF's existence);
- the URDF loads in Pinocchio (the controller's model) and in MuJoCo (the plant's), has
  exactly the revolute joints ``j1 .. jN`` of the type's ``n_joints`` and a ``flange`` link;
- ``ROBOT.kinematics.fkine(q_home)`` is where the URDF puts the flange (the kinematics
  describe the same arm).

Everything here runs outside the cycle, once per process while it parses the config.
"""

from __future__ import annotations

import traceback
from pathlib import Path
from typing import Final

import numpy as np

from ..core.errors import ConfigError, KaliError
from ..core.pyfile import guarded, import_file
from .profile import RobotType

FLANGE_LINK: Final = "flange"
FKINE_TOL_M: Final = 1e-6  # m and rotation-matrix entries: the kinematics agree with the URDF
_KINEMATICS_METHODS: Final = (
    "fkine", "ikine", "config_of", "parse_config", "singular", "singular_margin",
)  # fmt: skip


def is_type_file(model: str) -> bool:
    """Whether a config's ``robots[].model`` names a module file rather than a shipped type:
    it ends in ``.py``."""
    return model.endswith(".py")


def load_type_file(path: Path) -> RobotType:
    """The ``ROBOT`` of the module file at ``path`` (absolute), checked as the module says;
    ``ConfigError`` naming the file, what is wrong and the rule.  Its code runs guarded
    (``pyfile.guarded``): a file that exits or does not load in time is refused too."""
    where = f"robot type file {path}"
    if not path.is_file():
        raise ConfigError(f"{where}: no such file")
    with guarded(where, path):
        return _load(path, where)


def _load(path: Path, where: str) -> RobotType:
    """``load_type_file`` of an existing file, inside its guard."""
    try:
        module = import_file(path, "kali_robot_type")
    except KaliError as exc:  # a RobotType or kinematics refusing its fields: says which
        raise ConfigError(f"{where}{_line_in(exc, path)}: {_without_prefix(exc)}") from exc
    except Exception as exc:
        raise ConfigError(
            f"{where}: importing it raised {type(exc).__name__}{_line_in(exc, path)}: {exc}"
        ) from exc
    if module is None:
        raise ConfigError(f"{where}: cannot be imported as a Python file")
    robot = getattr(module, "ROBOT", None)
    if robot is None:
        raise ConfigError(
            f"{where}: defines no ROBOT; the module must set ROBOT = RobotType(...) "
            f"(kali_daemons.robots.profile)"
        )
    if not isinstance(robot, RobotType):
        raise ConfigError(
            f"{where}: ROBOT is {type(robot).__name__} {robot!r:.60}, not a RobotType "
            f"(kali_daemons.robots.profile)"
        )
    check_urdf(robot, where)
    check_kinematics(robot, where)
    return robot


def check_urdf(robot: RobotType, where: str) -> None:
    """The type's URDF loads in Pinocchio and MuJoCo with joints ``j1 .. jN`` (N = the type's
    ``n_joints``, revolute, base to tip) and a ``flange`` link; ``ConfigError`` otherwise."""
    import mujoco  # here: both loaders only when a type file is checked (kalictl start, types)
    import pinocchio as pin

    urdf = Path(robot.urdf)
    at = f"{where}: ROBOT.urdf {urdf}"
    want = [f"j{j + 1}" for j in range(robot.n_joints)]
    try:
        model = pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as exc:
        raise ConfigError(f"{at}: Pinocchio cannot load it: {_one_line(exc)}") from None
    names = [model.names[j] for j in range(1, model.njoints)]
    kinds = [model.joints[j].shortname() for j in range(1, model.njoints)]
    if names != want or model.nq != robot.n_joints:
        raise ConfigError(
            f"{at}: moving joints {names} (Pinocchio): must be exactly {want}, one per joint "
            f"of ROBOT.n_joints = {robot.n_joints}, named base to tip"
        )
    bad = [
        f"{n} ({k})" for n, k in zip(names, kinds, strict=True) if not k.startswith("JointModelR")
    ]
    if bad:
        raise ConfigError(f"{at}: joints {', '.join(bad)}: must be revolute")
    if not model.existFrame(FLANGE_LINK):
        raise ConfigError(f"{at}: no link {FLANGE_LINK!r}: the arm's last link must be named so")
    try:
        arm = mujoco.MjSpec.from_file(str(urdf))
        arm.compile()
    except ValueError as exc:
        raise ConfigError(f"{at}: MuJoCo cannot load it: {_one_line(exc)}") from None
    found = [j.name for j in arm.joints]
    if found != want:
        raise ConfigError(f"{at}: moving joints {found} (MuJoCo): must be exactly {want}")


def check_kinematics(robot: RobotType, where: str) -> None:
    """``ROBOT.kinematics`` has the ``Kinematics`` methods and at least one branch, and its
    ``fkine(q_home)`` is the flange pose the URDF gives (Pinocchio); ``ConfigError``
    otherwise."""
    import pinocchio as pin  # here: only when a type file is checked

    kin = robot.kinematics
    missing = [m for m in _KINEMATICS_METHODS if not callable(getattr(kin, m, None))]
    configs = getattr(kin, "configs", ())
    if missing or not isinstance(configs, tuple) or not configs:
        raise ConfigError(
            f"{where}: ROBOT.kinematics = {kin!r:.60}: must have configs (a non-empty tuple) "
            f"and methods {', '.join(_KINEMATICS_METHODS)} (kali_daemons.robots.profile."
            f"Kinematics; kali_daemons.robots.numik.NumericalKinematics is one for any arm)"
            + (f"; missing: {', '.join(missing)}" if missing else "")
        )
    try:
        got = np.asarray(kin.fkine(robot.q_home.copy()), dtype=float)
    except Exception as exc:
        raise ConfigError(
            f"{where}: ROBOT.kinematics.fkine(q_home) raised {type(exc).__name__}: {exc}"
        ) from exc
    model = pin.buildModelFromUrdf(str(robot.urdf))
    data = model.createData()
    pin.framesForwardKinematics(model, data, np.array(robot.q_home, dtype=float))
    want = data.oMf[model.getFrameId(FLANGE_LINK)].homogeneous
    if got.shape != (4, 4) or not np.isfinite(got).all():
        raise ConfigError(
            f"{where}: ROBOT.kinematics.fkine(q_home) = {got.tolist()!r:.80}: must be a finite "
            f"4×4 pose"
        )
    apart = float(np.linalg.norm(got[:3, 3] - want[:3, 3]))
    turned = float(np.abs(got[:3, :3] - want[:3, :3]).max())
    if apart > FKINE_TOL_M or turned > FKINE_TOL_M:
        raise ConfigError(
            f"{where}: ROBOT.kinematics.fkine(q_home) puts the flange at {_xyz(got)} m, the "
            f"URDF at {_xyz(want)} m ({apart * 1000:.3f} mm apart, rotation entries up to "
            f"{turned:.2g} apart): they must agree within {FKINE_TOL_M:g} (the kinematics "
            f"and the URDF describe different arms)"
        )


def _xyz(t: np.ndarray) -> str:
    """A pose's position as ``(x, y, z)``, 4 decimals."""
    return "({:.4f}, {:.4f}, {:.4f})".format(*(float(v) for v in t[:3, 3]))


def _without_prefix(exc: BaseException) -> str:
    """A ConfigError's text without its leading ``config: `` (the caller adds context)."""
    return str(exc).removeprefix("config: ")


def _line_in(exc: BaseException, path: Path) -> str:
    """`` (line N)`` of the deepest traceback frame in ``path``, or nothing."""
    line = None
    for frame in traceback.extract_tb(exc.__traceback__):
        if Path(frame.filename) == path:
            line = frame.lineno
    return "" if line is None else f" (line {line})"


def _one_line(exc: BaseException) -> str:
    """An exception's text on one line (MuJoCo's and Pinocchio's span several)."""
    return " ".join(str(exc).split())
