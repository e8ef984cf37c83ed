"""The one Kali error hierarchy.

Every message names the subsystem, the object, the value and the limit, e.g.
``arena: block 'sv.3.cmd' needs 4096 B, 1024 B free in 3 fragments``.  ``assert`` is kept
for programming errors only.
"""

from __future__ import annotations


class KaliError(Exception):
    """Base of every error Kali raises on purpose; ``subsystem`` prefixes the message."""

    subsystem = "kali"

    def __init__(self, message: str) -> None:
        super().__init__(f"{self.subsystem}: {message}")


class ConfigError(KaliError):
    """A configuration file is malformed: names the field, the value and what is allowed."""

    subsystem = "config"


class ArenaError(KaliError):
    """Shared-memory arena: attach, layout version, allocation."""

    subsystem = "arena"


class ArenaFullError(ArenaError):
    """``shmalloc`` cannot satisfy a request (too little memory, or too fragmented)."""


class LockError(KaliError):
    """A spinlock could not be taken in time."""

    subsystem = "lock"


class ChannelError(KaliError):
    """Type 1-4 channels: queue full, FIFO overflow, bad payload."""

    subsystem = "channel"


class QueueFullError(ChannelError):
    """A bounded queue refused an entry; nothing was overwritten."""


class ClockError(KaliError):
    """Wall clock: registration, rates, control commands."""

    subsystem = "wallclock"


class DaemonError(KaliError):
    """A daemon's lifecycle failed (configure, activate, cycle)."""

    subsystem = "daemon"


class HardwareError(KaliError):
    """The hardware behind an arm: not answering, or refusing what it was asked."""

    subsystem = "hardware"


class InstanceError(KaliError):
    """Starting, stopping or finding a Kali instance."""

    subsystem = "instance"


class ModelError(KaliError):
    """The robot model: URDF loading, building the simulated cell."""

    subsystem = "model"


class ServoError(KaliError):
    """A servo-level request that cannot be carried out (bad robot, joint, algorithm, power,
    calibration, a joint move)."""

    subsystem = "servo"


class ScheduleError(KaliError):
    """The schedulability check: nothing to measure yet, or a change that would not fit the
    servo period on its CPUs (``kalictl check``)."""

    subsystem = "schedule"


class KinematicsError(KaliError):
    """Inverse kinematics: a pose out of reach, a joint out of its limits, a bad transform."""

    subsystem = "kinematics"


class MotionError(KaliError):
    """A motion request that cannot be carried out (bad target, speed, path or limits)."""

    subsystem = "motion"
