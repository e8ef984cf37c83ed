"""``python -m kali_daemons.bridge --instance NAME --name NAME``."""

from ..runtime.daemon import run_daemon
from .daemon import Bridge

run_daemon(Bridge)
