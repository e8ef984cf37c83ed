"""A Franka Research 3 through libfranka, Franka Robotics' own library (its real 1 kHz
protocol): each arm's link process (``kali_daemons.link.franka``) holds its connection, SIO
drives the arms' records (``arms``, ``registers``).  In simulation the plant is franky-sim,
a MuJoCo FR3 serving the same protocol (``kali_daemons.plant.franky``).
"""

from __future__ import annotations

from ...robots import RobotType
from ..registry import HardwareKind
from . import registers
from .arms import FrankaArms, FrankaDriver, FrankaOps

FR3_JOINTS = 7  # libfranka's arms: every state and command holds 7 joints


def refuses(rtype: RobotType, period_s: float) -> str:
    """Why libfranka cannot drive an arm of ``rtype`` at this servo period: an FR3 (a
    7-joint arm with absolute encoders) at its 1 ms cycle."""
    if rtype.n_joints != FR3_JOINTS or not rtype.absolute_encoders:
        return "libfranka drives 7-joint Franka arms with absolute encoders (model: fr3)"
    if abs(period_s - 0.001) > 1e-12:
        return f"the FR3 runs a 1 ms cycle; clock.servo_period_ms is {period_s * 1e3:g}"
    return ""


KIND = HardwareKind(
    name="franka",
    description="a Franka Research 3 through libfranka (torque control at 1 kHz over its "
    "network protocol); simulated by franky-sim",
    channels=FR3_JOINTS,
    operations=FrankaOps,
    drive=FrankaArms.attach,
    records=registers.RECORDS,
    links=True,
    hands=True,
    compensates_gravity=True,
    wrist=("model", "robot"),  # no gauges: the wrench from its joint torque sensors
    simulator="plant.franky:FrankySim",
    refuses=refuses,
)

__all__ = ["KIND", "FrankaArms", "FrankaDriver", "FrankaOps", "registers"]
