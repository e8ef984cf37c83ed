"""Feed-forward dynamics (thesis 3.3.6): gravity and inverse-dynamics torques with Pinocchio, at
about the TG rate.
"""

from .daemon import Dynamics

__all__ = ["Dynamics"]
