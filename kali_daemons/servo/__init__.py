"""The servo programming interface (thesis 3.4, DESIGN 4): servo algorithms by name, their
private data in shared memory, the built-in PID of figure 3.4 and a PD, and plugins.

The SV daemon builds ``registry_for(cfg.plugins, cfg.base_dir)`` once, views each joint's
private data with ``struct_view`` and calls ``step`` every tick; see ``registry.py``.
"""

from .algorithms.algorithm import (
    MAX_DATA_BYTES,
    STATUS_OK,
    Handover,
    JointInfo,
    Param,
    ServoAlgorithm,
    defaults,
    resolve_params,
    struct_type,
    struct_view,
)
from .algorithms.arm import ArmInput, ArmServoAlgorithm
from .algorithms.builtins import PD, PID
from .algorithms.registry import Registry, registry_for

__all__ = [
    "MAX_DATA_BYTES",
    "PD",
    "PID",
    "STATUS_OK",
    "ArmInput",
    "ArmServoAlgorithm",
    "Handover",
    "JointInfo",
    "Param",
    "Registry",
    "ServoAlgorithm",
    "defaults",
    "registry_for",
    "resolve_params",
    "struct_type",
    "struct_view",
]
