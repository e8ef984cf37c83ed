"""The built-in servos (``builtins.py``: the PID of thesis figure 3.4 and the PD) compiled, to
run over many joints in one call (the servo path near the floor).

An algorithm's private data for every joint of the cell is one arena block, one record per
slot (``layout.KEY_SERVO_DATA``), so a set of joints is a structured array and a row index
each.  ``csrc/servo.c``'s ``pid_row`` and ``pd_row`` are ``pid_step`` and ``pd_step`` on one
record, the same operations in the same order with no contraction, so they give the per-joint
Python step's numbers (``tests/test_servo_vector.py`` checks it to 1e-12; in practice bit
for bit); its structs mirror PID_DTYPE and PD_DTYPE, which ``kernels.load`` checks.
``pid_vector_step`` and ``pd_vector_step`` run them over a set of rows; the SV's unit
(``kali_daemons.servo.sv.units``) runs them inside its claiming loop.

C through ctypes, like SIO's kernels (``kali_daemons.core.kernels`` says why not numba): a kernel
is bound once to its arrays (``vector_kernel``) and then called with no arguments.
"""

from __future__ import annotations

import numpy as np

from ...core.kernels import Kernel
from .algorithm import STATUS_OK
from .builtins import PD_DTYPE, PID_DTYPE

_C_NAMES = {"pid": ("kali_pid_vector", PID_DTYPE), "pd": ("kali_pd_vector", PD_DTYPE)}


def vector_kernel(
    algo: str,
    data: np.ndarray,
    rows: np.ndarray,
    demand: np.ndarray,
    position: np.ndarray,
    torque: np.ndarray,
    error: np.ndarray,
    status: np.ndarray,
) -> Kernel:
    """Built-in ``algo`` ("pid" or "pd") bound to its arrays: each call steps rows ``rows``
    of ``data`` (records of the algorithm's dtype) with ``demand[k]``, ``position[k]`` for
    row ``rows[k]``, torques, errors and statuses into the output arrays.  Outside the
    cycle; the arrays must not move (the kernel keeps them alive), calling it is in-cycle."""
    name, dtype = _C_NAMES[algo]
    n = len(rows)
    assert data.dtype == dtype and data.ndim == 1, (algo, data.dtype, data.shape)
    assert data.strides[0] == dtype.itemsize, f"{algo} records must be contiguous"
    assert rows.dtype == np.int64 and status.dtype == np.int32, (rows.dtype, status.dtype)
    assert all(a.dtype == np.float64 for a in (demand, position, torque, error))
    assert n == len(demand) == len(position) == len(torque) == len(error) == len(status)
    assert n == 0 or (rows.min() >= 0 and rows.max() < len(data)), (rows, len(data))
    return Kernel(
        name,
        (data,),
        n=n,
        data=data.ctypes.data,
        rows=rows,
        demand=demand,
        position=position,
        torque=torque,
        error=error,
        status=status,
        ok=STATUS_OK,
    )


def pid_vector_step(
    data: np.ndarray,
    rows: np.ndarray,
    demand: np.ndarray,
    position: np.ndarray,
    torque: np.ndarray,
    error: np.ndarray,
    status: np.ndarray,
) -> None:
    """The PID of figure 3.4 on rows ``rows`` of ``data`` (PID_DTYPE records), once
    (``vector_kernel`` binds it for repeated calls).  Outside the cycle: it binds."""
    vector_kernel("pid", data, rows, demand, position, torque, error, status)()


def pd_vector_step(
    data: np.ndarray,
    rows: np.ndarray,
    demand: np.ndarray,
    position: np.ndarray,
    torque: np.ndarray,
    error: np.ndarray,
    status: np.ndarray,
) -> None:
    """The PD on rows ``rows`` of ``data`` (PD_DTYPE records), like ``pid_vector_step``."""
    vector_kernel("pd", data, rows, demand, position, torque, error, status)()


VECTOR_STEPS = {"pid": pid_vector_step, "pd": pd_vector_step}  # by built-in name
