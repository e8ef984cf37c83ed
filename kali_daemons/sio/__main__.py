"""``python -m kali_daemons.sio --instance NAME --name NAME``."""

from ..runtime.daemon import run_daemon
from .daemon import ServoIO

run_daemon(ServoIO)
