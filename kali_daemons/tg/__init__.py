"""Trajectory generator (thesis 3.3.1): one process computes set-points for every motion system
each TG tick (``daemon.TrajectoryGenerator``).  Importing the package loads nothing else, so
``kalictl`` can load the TG function plugins (``functions``) without the TG's kinematics.
"""
