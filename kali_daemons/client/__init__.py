"""What a user program imports to attach to a running Kali instance (thesis 3.3.2).

    from kali_daemons import client
    with client.attach("default") as kali:
        print(kali.clock["tick"])

``Kali`` moves the arms through the trajectory generator (``motion.py``; an arm's moves in
``robot.py``, a motion system's in ``system.py``, a request's handle in ``handle.py``): motions
that change while they run through shared transforms, TG functions and streams
(``streams.py``), motion systems started together (``together.py``); and it runs the
program's functions periodically on the wall clock while it goes on (``Kali.control``, a
``Control`` each: ``periodic.py``).  ``control`` (thesis 3.6.2) makes the calling process
itself the periodic function, blocking until it is released.
"""

from ..runtime.instance import Instance
from ..wallclock import (
    control,
    release,
    set_control_rate,
    set_kali_clock,
    start_kali_clock,
    step_kali_clock,
    stop_kali_clock,
)
from .common import Contact, MotionFailedError, pose
from .handle import MotionHandle
from .motion import Kali
from .periodic import Control
from .robot import Robot
from .streams import JointStream, SharedTransform, Stream, TgFunctionHandle
from .system import MotionSystem
from .together import Together


def attach(instance: str = "default") -> Instance:
    """Attach to a running instance by name; close it (or use ``with``) when done."""
    return Instance.attach(instance)


__all__ = [
    "Contact",
    "Control",
    "Instance",
    "JointStream",
    "Kali",
    "MotionFailedError",
    "MotionHandle",
    "MotionSystem",
    "Robot",
    "SharedTransform",
    "Stream",
    "TgFunctionHandle",
    "Together",
    "attach",
    "control",
    "pose",
    "release",
    "set_control_rate",
    "set_kali_clock",
    "start_kali_clock",
    "step_kali_clock",
    "stop_kali_clock",
]
