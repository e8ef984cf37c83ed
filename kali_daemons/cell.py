"""The cell's dimensions and the controller's arm model, without MuJoCo (see ``model.py``).

The stand, the bar and the grasp sites are the plant's world (``model.build_world``) and what
the viewer draws; ``load_pinocchio`` is the arm model of the dynamics process, the viewer and
programs.  Pinocchio is imported where a model is loaded, so the plant, which needs these
dimensions, does not import it.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Final

import numpy as np

from kali_daemons.errors import ModelError

if TYPE_CHECKING:
    import pinocchio as pin

    from kali_daemons.robots import RobotType

FLANGE_FRAME: Final = "flange"  # the URDF link of the flange (Pinocchio frame, MuJoCo body)

# The cell (metres, kilograms).  A table-like stand at the origin, between the arms, and a
# square bar lying on it along x; each arm grasps the end nearer to it from above.
STAND_SIZE: Final = (0.24, 0.30, 0.565)  # x, y, height; centred on the world origin
BAR_SIZE: Final = (0.36, 0.04, 0.04)  # length (along x), width, height
BAR_MASS: Final = 1.5
# A grasp site sits above a bar end: the flange (the wrist centre, as d6 = 0) stays this far
# above the bar's axis so that the flange disc (0.035-0.045 m out) just touches the bar top.
GRASP_HEIGHT: Final = 0.065
GRASP_INSET: Final = 0.02  # from the bar's end towards its middle
# Something to touch (issue 27): a rigid table in front of the stand (−y), its top reachable by
# both arms' tools pointing down (PUMAs at x = ±0.6: configurations run / luf) over
# x ∈ [−0.2, 0.2], y ∈ [−0.45, −0.3].  Only the tools' pads and the bar touch it.
TABLE_SIZE: Final = (0.5, 0.24, 0.40)  # x, y, height (its top)
TABLE_CENTRE_XY: Final = (0.0, -0.38)
TOOL_RADIUS_M: Final = 0.012  # each arm's tool: a pad, a sphere ending at the tool point
# The pad is a felt polishing pad, not steel: sliding friction 0.3 on the table, and soft
# (MuJoCo's contact time constant, s, and damping ratio): about 20 N/mm, critically damped,
# pressed by a PUMA at the table.  A rigid sphere on the rigid table chattered (lifting off
# 30 % of the time at 90 Hz, 0-37 N) whenever a soft impedance slid it, whatever the gains.
PAD_FRICTION: Final = 0.3
PAD_SOLREF: Final = (0.1, 1.0)


def load_pinocchio(
    robot: RobotType, tool: tuple[float, tuple[float, float, float]] | None = None
) -> pin.Model:
    """An arm of type ``robot`` as a Pinocchio model, base at the origin, with its armature
    and gravity; with ``tool`` (mass in kg, centre of mass in the flange frame: the config's
    ``FtConfig``) the tool the plant's arm carries on its wrist sensor, so the dynamics
    process's feed-forward holds its weight too.

    ``rnea`` / ``crba`` / ``aba`` on it include the drive's rotor inertia.  The flange is the
    frame named ``FLANGE_FRAME``.
    """
    import pinocchio as pin  # here, not at load: the plant imports this module

    urdf = robot.urdf
    if not Path(urdf).is_file():
        raise ModelError(f"{urdf}: no such file")
    try:
        model = pin.buildModelFromUrdf(str(urdf))
    except (RuntimeError, ValueError) as exc:
        raise ModelError(f"{urdf}: Pinocchio cannot load it: {exc}") from None
    if model.nv != robot.n_joints or not model.existFrame(FLANGE_FRAME):
        raise ModelError(
            f"{urdf}: robot type {robot.name!r} expects {robot.n_joints} joints and a "
            f"{FLANGE_FRAME!r} frame, found {model.nv} joints"
        )
    model.armature = np.array(robot.drive.armature, dtype=float)
    if tool is not None and tool[0] > 0.0:
        mass, com = tool
        frame = model.frames[model.getFrameId(FLANGE_FRAME)]
        inertia = mass * TOOL_RADIUS_M**2 / 2.0  # as the plant's tool (model._add_tool)
        body = pin.Inertia(mass, np.asarray(com, dtype=float), np.eye(3) * inertia)
        model.appendBodyToJoint(frame.parentJoint, body, frame.placement)
    model.gravity = pin.Motion(np.array([0.0, 0.0, -robot.gravity]), np.zeros(3))
    return model


def bar_rest_pose() -> np.ndarray:
    """The bar's pose (4×4, world) lying on the stand, as the cell is built."""
    t = np.eye(4)
    t[2, 3] = STAND_SIZE[2] + BAR_SIZE[2] / 2
    return t
