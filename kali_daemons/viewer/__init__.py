"""Viewer (thesis 3.3.7): reads the arena without locking and logs the live dashboard to rerun at
25 Hz.
"""

from .daemon import Viewer

__all__ = ["Viewer"]
