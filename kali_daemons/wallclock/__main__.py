"""``python -m kali_daemons.wallclock --instance NAME``: the master wall clock process."""

from ..daemon import run_daemon
from .clock import WallClock

run_daemon(WallClock)
