"""``python -m kali_daemons.wallclock --instance NAME``: the master wall clock process."""

from ..runtime.daemon import run_daemon
from .clock import WallClock

run_daemon(WallClock)
