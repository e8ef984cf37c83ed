"""Servo executor with dynamic loading (thesis 3.3.4, 3.3.5); N of them claim servo slots by test-
and-set.
"""

from .daemon import ServoWorker

__all__ = ["ServoWorker"]
