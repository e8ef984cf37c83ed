"""``python -m kali_daemons.dynamics --instance NAME --name NAME``."""

from ..runtime.daemon import run_daemon
from .daemon import Dynamics

run_daemon(Dynamics)
