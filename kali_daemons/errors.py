"""The error hierarchy where programs import it (``from kali_daemons.errors import
MotionError``); it lives in ``core.errors``, under everything else."""

from .core.errors import (
    ArenaError,
    ArenaFullError,
    ChannelError,
    ClockError,
    ConfigError,
    DaemonError,
    InstanceError,
    KaliError,
    KinematicsError,
    LockError,
    ModelError,
    MotionError,
    QueueFullError,
    ScheduleError,
    ServoError,
)

__all__ = [
    "ArenaError",
    "ArenaFullError",
    "ChannelError",
    "ClockError",
    "ConfigError",
    "DaemonError",
    "InstanceError",
    "KaliError",
    "KinematicsError",
    "LockError",
    "ModelError",
    "MotionError",
    "QueueFullError",
    "ScheduleError",
    "ServoError",
]
