"""Trajectory generator (thesis 3.3.1): one process computes set-points for every motion system
each TG tick.
"""

from .daemon import TrajectoryGenerator

__all__ = ["TrajectoryGenerator"]
