"""``python -m kali_daemons``: the same as ``kalictl``."""

from .tools.cli import main

main()
