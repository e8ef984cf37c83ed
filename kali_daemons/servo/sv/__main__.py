"""``python -m kali_daemons.servo.sv --instance NAME --name NAME``."""

from ...runtime.daemon import run_daemon
from .daemon import ServoWorker

run_daemon(ServoWorker)
