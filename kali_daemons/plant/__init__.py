"""Plant (thesis 3.7, appendix C): the simulated arms (PUMA 560 or another robot type), motors,
amplifiers, I/O and DAC boards in MuJoCo.
"""

from .daemon import Plant

__all__ = ["Plant"]
