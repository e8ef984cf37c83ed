"""``python -m kali_daemons.viewer --instance NAME --name NAME``."""

from ..runtime.daemon import run_daemon
from .daemon import Viewer

run_daemon(Viewer)
