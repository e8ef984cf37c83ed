"""``python -m kali_daemons``: the same as ``kalictl``."""

from .cli import main

main()
