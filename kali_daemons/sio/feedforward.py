"""Feed-forward as SIO applies it (thesis 3.3.6: "the SIO reads the compensation torque and
adds it to the amplifier torque demand automatically").

The dynamics process writes a row (torque, velocity, acceleration) for each set-point of a
robot's TG → SIO FIFO, keyed by the set-point's FIFO index (``layout.FEEDFORWARD``).  Each
servo tick SIO interpolates the rows of the segment's two set-points by the demand's own
fraction, so the torque belongs to the position being demanded.  Stale feed-forward is
dropped, never applied, and the weight always fades over ``feedforward.ramp_ms``: the servos
see no torque step.  Nothing another process wrote is taken on trust (DESIGN 7).

SIO runs it compiled (``RobotFeedforward.compiled``, ``csrc/sio.c``'s ``kali_feedforward``);
``update`` is the reference the kernel equals bit for bit (tests/test_sio_kernels.py), so the
two change together.  Staleness, fades and the rows: docs/internals/sio-viewer-core.md.
"""

from __future__ import annotations

import ctypes

import numpy as np

from ..core import layout
from ..core.channels import InterpolatingFifo
from ..core.kernels import Kernel
from ..core.layout import FfMode, FfState

_MODES = frozenset(int(m) for m in FfMode)


class RobotFeedforward:
    """Robot ``k``'s feed-forward, written into ``out`` (its six entries of SIO's torques)
    once per servo tick by ``update``; no allocation in the cycle."""

    __slots__ = (
        "_a",
        "_b",
        "_events",
        "_heartbeat",
        "_keys",
        "_last",
        "_last_acc",
        "_last_tau",
        "_last_vel",
        "_mode",
        "_mode_ok",
        "_ok",
        "_qd",
        "_qdd",
        "_stale_count",
        "_state",
        "_tau",
        "_try",
        "_weight_rec",
        "acc",
        "arm",
        "fifo",
        "heartbeat_limit",
        "missing",
        "missing_limit",
        "out",
        "stale",
        "step",
        "vel",
        "weight",
    )

    def __init__(
        self,
        records: np.ndarray,
        k: int,
        fifo: InterpolatingFifo,
        out: np.ndarray,
        heartbeat_limit: int,
        missing_limit: int,
        step: float,
        vel: np.ndarray | None = None,
        acc: np.ndarray | None = None,
    ) -> None:
        """``heartbeat_limit`` in wall-clock ticks and ``missing_limit`` in servo ticks are
        the staleness limits; ``step`` is how much the weight moves per servo tick; ``vel``
        and ``acc`` (as long as ``out``) receive the demand's velocity and acceleration."""

        def one(field: str) -> np.ndarray:
            return records[k : k + 1][field].reshape(())

        self._mode, self._state = one("mode"), one("state")
        self._heartbeat = one("heartbeat_tick")
        self._stale_count, self._events = one("stale_ticks"), one("stale_events")
        self._weight_rec = one("weight")
        n = out.shape[0]  # the robot's joints: its rows' first n columns
        self._keys = records["key"][k]
        self._tau = records["tau"][k][:, :n]
        self._qd = records["qd"][k][:, :n]
        self._qdd = records["qdd"][k][:, :n]
        self.fifo = fifo
        self.out = out
        self.vel = np.zeros(n) if vel is None else vel
        self.acc = np.zeros(n) if acc is None else acc
        self.arm = False  # SIO: the robot runs a robot-level servo
        self.heartbeat_limit = heartbeat_limit
        self.missing_limit = missing_limit
        self.step = step
        self.weight = float(self._weight_rec)
        self.missing = 0
        self.stale = int(self._state) == FfState.STALE
        # rows 0, 1, 2: torque, velocity, acceleration
        self._last = np.zeros((3, n))  # the last good interpolated values
        self._last_tau, self._last_vel, self._last_acc = self._last  # row views, bound once
        self._try = np.zeros((3, n))  # this tick's, until they are known to be finite
        self._ok = np.zeros((3, n), dtype=bool)
        self._a = np.zeros((3, n))
        self._b = np.zeros((3, n))
        word = int(self._mode)
        self._mode_ok = word if word in _MODES else int(FfMode.OFF)  # the last valid mode

    def compiled(self) -> FfKernel:
        """This robot's feed-forward as ``csrc/sio.c``'s ``kali_feedforward``, bound to the
        same record, FIFO and arrays and starting from this object's state: from then on
        each tick is ``kernel.arm = ...; kernel.step(tick)``, and this object's ``update``
        (the reference) must not be called.  Outside the cycle."""
        return FfKernel(self)

    def _row(self, key: int, out: np.ndarray) -> bool:
        """Copy the row of ``key`` (torque, velocity, acceleration) into ``out``; False if it
        is not there (or changed while being copied: the dynamics process sets its key to
        FF_NO_KEY while writing)."""
        if key < 0:
            return False
        row = key % layout.FF_ROWS
        if self._keys[row] != key:
            return False
        np.copyto(out[0], self._tau[row])
        np.copyto(out[1], self._qd[row])
        np.copyto(out[2], self._qdd[row])
        return self._keys[row] == key

    def update(self, tick: int) -> None:
        """This tick's feed-forward into ``out``, the demand's velocity and acceleration into
        ``vel`` and ``acc`` (inside SIO's cycle)."""
        mode = int(self._mode)
        if mode in _MODES:
            self._mode_ok = mode
        else:  # a client's garbage: the last valid mode stays in force
            mode = self._mode_ok
        if mode == FfMode.OFF and self.weight == 0.0 and not self.arm:
            if self.stale or int(self._state) != FfState.OFF:
                self.stale = False
                self._state[...] = FfState.OFF
                self.out.fill(0.0)
                self.vel.fill(0.0)
                self.acc.fill(0.0)
            return
        good = False
        wanted = mode != FfMode.OFF or self.arm
        if wanted and tick - int(self._heartbeat) <= self.heartbeat_limit:
            key_b = self.fifo.target_index() + 1
            has_b = self._row(key_b, self._b)
            has_a = self._row(key_b - 1, self._a)
            t = self._try
            if has_a and has_b:  # A + (B − A)·progress, as the demand
                np.subtract(self._b, self._a, out=t)
                np.multiply(t, self.fifo.progress(), out=t)
                np.add(t, self._a, out=t)
            elif has_b:
                np.copyto(t, self._b)
            elif has_a:
                np.copyto(t, self._a)
            good = has_a or has_b
            if good:
                np.isfinite(t, out=self._ok)
                good = bool(self._ok.all())
                if good:
                    np.copyto(self._last, t)
            self.missing = 0 if good else self.missing + 1
            stale = not good and self.missing > self.missing_limit
        else:
            stale = wanted  # the dynamics process is silent
        if stale:  # no demand velocity or acceleration rather than an old one
            self._last_vel.fill(0.0)
            self._last_acc.fill(0.0)
        stale = stale and mode != FfMode.OFF  # only feed-forward asked for can be stale
        if stale:
            if not self.stale:
                self._events[...] = int(self._events) + 1
            self._stale_count[...] = int(self._stale_count) + 1
        self.stale = stale
        want = 1.0 if mode != FfMode.OFF and not stale else 0.0
        if self.weight < want:
            self.weight = min(want, self.weight + self.step)
        elif self.weight > want:
            self.weight = max(want, self.weight - self.step)
        self._weight_rec[...] = self.weight
        np.multiply(self._last_tau, self.weight, out=self.out)
        np.copyto(self.vel, self._last_vel)
        np.copyto(self.acc, self._last_acc)
        if stale:
            self._state[...] = FfState.STALE
        else:
            self._state[...] = FfState.ON if mode != FfMode.OFF else FfState.OFF


class FfKernel:
    """A robot's feed-forward compiled (``RobotFeedforward.compiled``): ``step(tick)`` is
    one ``update`` of its reference, with ``arm`` as SIO sets it; no allocation."""

    __slots__ = ("_args", "_kernel", "ff")

    def __init__(self, ff: RobotFeedforward) -> None:
        n = ff.out.shape[0]
        assert n <= layout.MAX_JOINTS and ff._last.flags.c_contiguous
        assert sorted(_MODES) == list(range(len(_MODES)))  # the kernel's validity: <= max
        head, seg_ticks, seg_done = ff.fifo.segment_addresses()
        words = (
            ("keys", ff._keys), ("tau", ff._tau), ("qd", ff._qd), ("qdd", ff._qdd),
            ("mode", ff._mode), ("state", ff._state), ("heartbeat", ff._heartbeat),
            ("stale_ticks", ff._stale_count), ("stale_events", ff._events),
            ("weight_rec", ff._weight_rec), ("last", ff._last),
        )  # fmt: skip
        self.ff = ff  # keeps its record views and arrays alive
        self._kernel = Kernel(
            "kali_feedforward",
            n=n,
            rows=layout.FF_ROWS,
            row_len=ff._tau.strides[0] // 8,
            head=head,
            seg_ticks=seg_ticks,
            seg_done=seg_done,
            out=ff.out,
            vel=ff.vel,
            acc=ff.acc,
            heartbeat_limit=ff.heartbeat_limit,
            missing_limit=ff.missing_limit,
            mode_max=max(_MODES),
            step=ff.step,
            arm=int(ff.arm),
            mode_ok=ff._mode_ok,
            missing=ff.missing,
            stale=int(ff.stale),
            weight=ff.weight,
            **{name: a.ctypes.data for name, a in words},
        )
        self._args = self._kernel.args

    @property
    def args(self) -> ctypes.Structure:
        """The kernel's argument block (SIO's compiled tick steps it: ``kali_sio_front``)."""
        return self._args

    @property
    def arm(self) -> bool:
        """The robot runs a robot-level servo (SIO sets it each tick)."""
        return bool(self._args.arm)

    @arm.setter
    def arm(self, value: bool) -> None:
        self._args.arm = value

    @property
    def weight(self) -> float:
        return float(self._args.weight)

    @property
    def missing(self) -> int:
        return int(self._args.missing)

    @property
    def stale(self) -> bool:
        return bool(self._args.stale)

    def step(self, tick: int) -> None:
        """This tick's feed-forward (``RobotFeedforward.update``); inside SIO's cycle."""
        self._args.tick = tick
        self._kernel()
