"""Recordings of a run: the recorder that drains the flight recorder's ring to MCAP
(``recorder``, ``kali.record``, ``kalictl record``) and reading one back (``log``).
"""
