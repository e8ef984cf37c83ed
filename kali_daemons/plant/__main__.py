"""``python -m kali_daemons.plant --instance NAME --name NAME``."""

from ..runtime.daemon import run_daemon
from .daemon import Plant

run_daemon(Plant)
