"""``python -m kali_daemons.link --instance NAME --name link.ROBOT``."""

from ..runtime.daemon import run_daemon
from .franka import FrankaLink

run_daemon(FrankaLink)
