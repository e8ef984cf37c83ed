"""``python -m kali_daemons.recording --instance NAME --out PATH``: the recorder process."""

from .recorder import main

main()
