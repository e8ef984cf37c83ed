"""``python -m kali_daemons.tg --instance NAME --name NAME``."""

from ..runtime.daemon import run_daemon
from .planner import TrajectoryGenerator

run_daemon(TrajectoryGenerator)
