"""``python -m kali_daemons.sv --instance NAME --name NAME``."""

from ..daemon import run_daemon
from .daemon import ServoWorker

run_daemon(ServoWorker)
