"""Wall clock process and the thesis 3.6.2 clock functions."""

from .api import (
    control,
    release,
    set_control_rate,
    set_kali_clock,
    start_kali_clock,
    step_kali_clock,
    stop_kali_clock,
)

__all__ = [
    "control",
    "release",
    "set_control_rate",
    "set_kali_clock",
    "start_kali_clock",
    "step_kali_clock",
    "stop_kali_clock",
]
