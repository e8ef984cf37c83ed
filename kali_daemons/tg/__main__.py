"""``python -m kali_daemons.tg --instance NAME --name NAME``."""

from ..runtime.daemon import run_daemon
from .daemon import TrajectoryGenerator

run_daemon(TrajectoryGenerator)
