"""Servo I/O (thesis 3.3.3): encoders to angles, checks, set-point interpolation, feeds the servos,
torques to the DAC.
"""

from .daemon import ServoIO

__all__ = ["ServoIO"]
