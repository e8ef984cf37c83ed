"""An SV's unit of work: one robot's joints that run a built-in servo (PID, PD) this tick,
claimed and run in one compiled call, ``csrc/servo.c``'s ``kali_serve_unit`` (thesis 3.3.5
for the claiming).

A slot joins the unit when it is fed and unclaimed, has no mailbox operation, reset or shadow
trial, is enabled and runs the PID or the PD; it is claimed by the same test-and-set of
``busy`` as the per-slot path and re-checked after the claim (a client's operation posted
meanwhile leaves it to the per-slot path: ``left``).  Everything else stays unclaimed for the
per-slot path.  The row functions equal the Python steps, so which path ran a joint does not
change its numbers; ``serve_unit_reference`` is the kernel's reference
(``tests/test_servo_vector.py``).  More: docs/internals/servo-level.md.
"""

from __future__ import annotations

import ctypes
import math

import numpy as np

from ...core import layout
from ...core.kernels import Kernel
from ..algorithms.algorithm import STATUS_OK, struct_view
from ..algorithms.builtins import PD, PD_DTYPE, PID, PID_DTYPE

ALGORITHMS = (PID.name, PD.name)  # the built-ins a unit runs, in one compiled call per arm


class Unit:
    """``kali_serve_unit`` bound at configure to robot slots ``lo..hi-1`` of ``slots`` (the
    cell's SERVO_SLOT records) and the PID's and PD's blocks (a record per slot).

    ``run(tick)`` claims and runs the unit (inside the cycle: no allocation) and returns the
    slots run here; then ``left()`` slots of ``left`` are claimed for the per-slot path,
    ``fault()`` is the first slot whose torque was not finite (or -1) and ``bad()`` that
    torque.  Every slot run or left counts as done for SIO.  Each slot run notes as its
    ``exec_ns`` the unit's previous cost per slot (the kernel measures it)."""

    __slots__ = ("_args", "_kernel")

    def __init__(
        self,
        slots: np.ndarray,
        pid: np.ndarray,
        pd: np.ndarray,
        lo: int,
        hi: int,
        pid_a: int,  # the PID's registry index
        pd_a: int,
        me: int,  # the SV's busy value: its number + 1
        sv: int,  # its number
        left: np.ndarray,  # int64, at least hi - lo
        exec_ns: int = 0,
    ) -> None:
        for a, dtype in ((slots, layout.SERVO_SLOT), (pid, PID_DTYPE), (pd, PD_DTYPE)):
            assert a.dtype == dtype and a.ndim == 1 and a.strides[0] == dtype.itemsize, a.dtype
        assert 0 <= lo <= hi <= len(slots) == len(pid) == len(pd), (lo, hi, len(slots))
        assert left.dtype == np.int64 and left.flags.c_contiguous and len(left) >= hi - lo
        self._kernel = Kernel(
            "kali_serve_unit",
            (slots, pid, pd, left),
            slots=slots.ctypes.data,
            pid=pid.ctypes.data,
            pd=pd.ctypes.data,
            lo=lo,
            hi=hi,
            pid_a=pid_a,
            pd_a=pd_a,
            me=me,
            sv=sv,
            ok=STATUS_OK,
            left=left.ctypes.data,
            exec_ns=exec_ns,
            fault=-1,
        )
        self._args = self._kernel.args

    @property
    def args(self) -> ctypes.Structure:
        """The kernel's argument block (an SV's compiled serve steps it: ``kali_sv_serve``)."""
        return self._args

    def run(self, tick: int) -> int:
        """Claim and run the unit for ``tick``; the slots run.  Inside the cycle."""
        self._args.tick = tick
        return self._kernel()

    def left(self) -> int:
        """Slots the last ``run`` claimed for the per-slot path (the first of ``left``)."""
        return self._args.n_left

    def fault(self) -> int:
        """The first slot of the last ``run`` whose torque was not finite, or -1."""
        return self._args.fault

    def bad(self) -> float:
        """That slot's torque."""
        return self._args.bad


def serve_unit(
    slots: np.ndarray, pid: np.ndarray, pd: np.ndarray, lo: int, hi: int, pid_a: int,
    pd_a: int, me: int, tick: int, sv: int, exec_ns: int, left: np.ndarray,
) -> tuple[int, int, int, float]:  # fmt: skip
    """Bind a ``Unit`` and run it once (outside the cycle: it binds): (slots run, slots put
    into ``left``, first slot whose torque was not finite or -1, its torque)."""
    unit = Unit(slots, pid, pd, lo, hi, pid_a, pd_a, me, sv, left, exec_ns)
    ran = unit.run(tick)
    return ran, unit.left(), unit.fault(), unit.bad()


def serve_unit_reference(
    slots: np.ndarray, pid: np.ndarray, pd: np.ndarray, lo: int, hi: int, pid_a: int,
    pd_a: int, me: int, tick: int, sv: int, exec_ns: int, left: np.ndarray,
) -> tuple[int, int, int, float]:  # fmt: skip
    """What ``kali_serve_unit`` computes, in Python over the per-joint ``PID.step`` and
    ``PD.step``, one process (a plain test-and-set): the property tests' reference."""
    ran, n_left, fault, bad = 0, 0, -1, 0.0

    def joins(s: np.void) -> bool:
        nothing_first = s["op"] == 0 and s["reset"] == 0 and s["enabled"] != 0
        return bool(
            nothing_first
            and s["shadow_state"] != layout.ShadowState.RUNNING
            and s["algo"] in (pid_a, pd_a)
        )

    for i in range(lo, hi):
        s = slots[i]
        if s["busy"] != 0 or not joins(s):
            continue
        s["busy"] = me
        alg, block = (PID, pid) if s["algo"] == pid_a else (PD, pd)
        torque, error, _ = alg.step(
            struct_view(block[i : i + 1]), float(s["demand"]), float(s["position"])
        )
        ran += 1
        s["exec_ns"] = exec_ns
        if not math.isfinite(torque):
            s["torque"] = 0.0
            if fault < 0:
                fault, bad = i, torque
            continue
        s["torque"], s["error"], s["status"] = torque, error, STATUS_OK
        s["ran_tick"], s["sv"] = tick, sv
    return ran, n_left, fault, bad
