"""What a user program imports to attach to a running Kali instance (thesis 3.3.2).

    from kali_daemons import client
    with client.attach("default") as kali:
        print(kali.clock["tick"])

``control`` runs one of the program's functions periodically on the wall clock.  ``Kali``
moves the arms through the trajectory generator (``motion.py``).
"""

from ..instance import Instance
from ..wallclock import (
    control,
    release,
    set_control_rate,
    set_kali_clock,
    start_kali_clock,
    step_kali_clock,
    stop_kali_clock,
)
from .motion import Contact, Kali, MotionFailedError, MotionHandle, MotionSystem, Robot, pose


def attach(instance: str = "default") -> Instance:
    """Attach to a running instance by name; close it (or use ``with``) when done."""
    return Instance.attach(instance)


__all__ = [
    "Contact",
    "Instance",
    "Kali",
    "MotionFailedError",
    "MotionHandle",
    "MotionSystem",
    "Robot",
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
