"""Plant (thesis 3.7, appendix C): the simulated PUMA 560 arms, motors, amplifiers, I/O and DAC
boards in MuJoCo.
"""

from .daemon import Plant

__all__ = ["Plant"]
