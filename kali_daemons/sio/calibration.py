"""Reading the potentiometers and calibrating against the encoder index pulses (thesis 3.5.1,
appendix C.3, C.5), as SIO does it inside its servo tick.

Encoders are relative: at power-on each joint is known only from its potentiometer, to a
degree or so.  ``Calibration`` makes the angles exact: SEARCH (index capture on, every joint
servoed slowly toward the pulse its angle predicts), SETTLE (capture off, at rest on the
pulses), POTS (each pot reading says which pulse it is, figure 3.6; an ambiguous one is
refused rather than guessed), DONE (offsets set, positions and demands moved by the same
constant, the servos handed over bumplessly with ``SlotReset.SHIFT``).

Everything here is preallocated; messages are encoded only when the state changes.  The
steps in detail: docs/internals/sio-viewer-core.md.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, cast

import numpy as np

from ..core import layout
from ..core.layout import CalibState, SlotReset

if TYPE_CHECKING:
    from ..hardware.interface import IndexedDriver
    from .cycle import SioCycle

SEARCH_S = 1.0  # seconds to sweep one index spacing: about one encoder count per ms
SEARCH_SPAN = 1.2  # index spacings swept before a joint gives up (one always holds a pulse)
SEARCH_GRACE_S = 0.3  # after the sweep ends, time the servo has to catch up with it
LIMIT_MARGIN = 0.02  # rad kept from a joint limit when choosing the direction to sweep
SETTLE_S = 0.3  # rest on the pulses before reading the pots
AMBIGUOUS = 0.4  # pot further than this fraction of a spacing from every pulse: refuse
ACTIVE = (CalibState.SEARCH, CalibState.SETTLE, CalibState.POTS)


class Calibration:
    """Robot ``k``'s calibration state machine, stepped by SIO while the robot is powered."""

    @property
    def capture(self) -> bool:
        """Index capture on: SIO writes the board's CSR bit 4 low, and catches each pulse
        right after reading the encoders (``catch_index``)."""
        return bool(self._capture[0])

    @capture.setter
    def capture(self, on: bool) -> None:
        self._capture[0] = on

    def __init__(self, sio: SioCycle, k: int) -> None:
        self.sio = sio
        self.k = k
        self.r = sio._r[k]  # the robot's views (q, demand, board registers, ...)
        span = sio.level.map.span(k)
        self.base = span.start
        n = self.n = span.stop - span.start
        self.all_found = (1 << n) - 1  # calib_found once every joint's pulse is found
        self.driver = cast("IndexedDriver", sio.driver)  # only arms with index pulses
        self._capture = sio._capture[k : k + 1]  # SIO's flag: CSR bit 4 low while on
        self.capture = False
        self.hw = sio.hw
        self.pots = sio.hw.pots(k)
        rate = sio.rate
        spacing = self.driver.index_spacing[span]
        self.speed_per_tick = spacing / (SEARCH_S * rate)  # rad per servo tick
        self.travel = SEARCH_SPAN * spacing
        self.search_ticks = math.ceil((SEARCH_SPAN * SEARCH_S + SEARCH_GRACE_S) * rate)
        self.settle_ticks = math.ceil(SETTLE_S * rate)
        self.start = np.zeros(n)
        self.direction = np.ones(n)
        self.shift = np.zeros(n)
        self.ticks = 0

    @property
    def state(self) -> CalibState:
        """Where the robot's calibration is."""
        return CalibState(int(self.r.calib_state))

    def _say(self, state: CalibState, message: str) -> None:
        self.r.calib_state[...] = state
        self.r.message[...] = message.encode()[: layout.MESSAGE_BYTES]

    # ------------------------------------------------------------------ transitions

    def begin(self) -> None:
        """Start: choose each joint's sweep, capture on (the register starts clear)."""
        d, b = self.driver, self.base
        q = self.r.q
        for j in range(self.n):
            i = b + j
            ahead = d.nearest_index(i, float(q[j])) - float(q[j])
            sign = 1.0 if ahead >= 0.0 else -1.0
            end = float(q[j]) + sign * float(self.travel[j])
            if not d.q_min[i] + LIMIT_MARGIN <= end <= d.q_max[i] - LIMIT_MARGIN:
                sign = -sign  # sweep away from the limit: a pulse lies within one spacing
            self.direction[j] = sign
        np.copyto(self.start, q)
        np.copyto(self.r.demand, q)
        self.r.calib_found[...] = 0
        self.r.calibrated[...] = 0
        self.ticks = 0
        self.capture = True
        self._say(CalibState.SEARCH, "calibrating: searching for the index pulses")

    def fail(self, why: str) -> None:
        """Give up: capture off, hold where the arm is."""
        self.capture = False
        np.copyto(self.r.demand, self.r.q)
        self._say(CalibState.FAILED, f"calibration failed: {why}")

    def step(self) -> None:
        """One servo tick of an active calibration: writes the robot's demand."""
        self.ticks += 1
        state = int(self.r.calib_state)
        if state == CalibState.SEARCH:
            self._search()
        elif state == CalibState.SETTLE:
            if self.ticks >= self.settle_ticks:
                self.pots.restart()
                self.ticks = 0
                self._say(CalibState.POTS, "calibrating: reading the potentiometers")
        elif state == CalibState.POTS and self.pots.poll():
            self._finish()

    def catch_index(self) -> None:
        """While capture is on, right after the encoders are read and before velocities:
        a joint whose bit appeared in the index register had its counter reset by the pulse
        since the last reading.  Count from the pulse from now on and servo onto it."""
        r, d, b = self.r, self.driver, self.base
        found = int(r.calib_found)
        new = self.hw.index_hits(self.k) & self.all_found & ~found
        if not new:
            return
        q, q_prev = self.sio.q, self.sio.q_prev
        for j in range(self.n):
            if new >> j & 1:
                # the pulse lies between the last reading and this one, about a count apart:
                # take it at the last reading's angle
                i = b + j
                index_angle = float(q_prev[i])
                self.hw.at_index(self.k, j, i, index_angle)
                q[i] = index_angle + float(d.acc[i]) * float(d.rad_per_count[i])
                r.demand[j] = index_angle
        r.calib_found[...] = found | new

    def _search(self) -> None:
        r = self.r
        found = int(r.calib_found)
        for j in range(self.n):
            if not found >> j & 1:
                step = min(self.ticks * float(self.speed_per_tick[j]), float(self.travel[j]))
                r.demand[j] = self.start[j] + self.direction[j] * step
        if found == self.all_found:
            self.capture = False
            self.ticks = 0
            self._say(CalibState.SETTLE, "calibrating: every index pulse found, settling")
        elif self.ticks > self.search_ticks:
            missing = [str(j + 1) for j in range(self.n) if not found >> j & 1]
            self.fail(
                f"no index pulse on joint {', '.join(missing)} within "
                f"{SEARCH_SPAN:g} index spacings of travel (is the encoder's index connected?)"
            )

    def _finish(self) -> None:
        d, b, r = self.driver, self.base, self.r
        worst, worst_j = 0.0, 0
        for j in range(self.n):
            i = b + j
            pot = d.pot_angle(i, self.pots.codes[j])
            rpc = float(d.rad_per_count[i])
            index_by_pot = pot - float(d.acc[i]) * rpc  # the pulse's angle as the pot says
            exact = d.nearest_index(i, index_by_pot)
            residual = abs(index_by_pot - exact) / float(d.index_spacing[i])
            if residual > worst:
                worst, worst_j = residual, j
            self.shift[j] = exact - float(d.offset[i])
        if worst > AMBIGUOUS:
            self.fail(
                f"joint {worst_j + 1}'s potentiometer reads {worst:.0%} of an index spacing "
                f"from the nearest pulse (limit {AMBIGUOUS:.0%}): which pulse it is, is "
                f"ambiguous; check the pot table"
            )
            return
        for j in range(self.n):
            i = b + j
            s = float(self.shift[j])
            d.offset[i] += s
            self.sio.q[i] += s
            self.sio.q_prev[i] += s
            r.demand[j] += s  # the same error in the new coordinates: hold on the pulse
        np.copyto(r.calib_shift, self.shift)
        r.slot_reset[:] = SlotReset.SHIFT
        r.calibrated[...] = 1
        moved = float(np.max(np.abs(self.shift)))
        self._say(
            CalibState.DONE,
            f"calibrated: angles moved by up to {math.degrees(moved):.2f}° (pots were "
            f"{worst:.0%} of a spacing from the pulses at most)",
        )


class Absolute:
    """An arm with absolute encoders (its robot type's ``absolute_encoders``): its angles are
    exact from power-up, so there is nothing to calibrate (thesis 3.5.1 does not apply)."""

    capture = False

    def __init__(self, sio: SioCycle, k: int) -> None:
        self.r = sio._r[k]
        self.what = f"robot '{sio.level.names[k]}' ({sio.inst.config.robots[k].model})"

    def begin(self) -> None:
        """Refused, saying why."""
        self.r.calib_state[...] = CalibState.FAILED
        self.r.message[...] = (
            f"nothing to calibrate: {self.what} has absolute encoders, its angles are exact"
        ).encode()[: layout.MESSAGE_BYTES]

    def fail(self, why: str) -> None:
        """Nothing runs, so nothing to give up."""

    def step(self) -> None:
        """Never active."""

    def catch_index(self) -> None:
        """No index pulses."""

