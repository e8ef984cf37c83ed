"""SIO's common path of every robot, compiled (``kali_sio_robots``, issue 26 item 2), equals
``SioCycle._robot`` on the robots it takes, and leaves every other robot untouched for it.

A real plant and SIO are hosted in this process on a lockstep instance of the default cell,
as the lockstep executive hosts them; each case writes random robot states (pots, power
state and command, calibration state and command, a guard, hand guiding, the boards' power
registers, a halt this tick) and random set-points into the FIFOs, then runs the kernel and,
from the same state, ``_robot`` for each robot the kernel took: the whole arena, SIO's demand
and fed mask and the FIFO pops' consumer state must come out byte for byte the same.  Since
``_robot`` is then run for every robot the kernel left, the cycle is ``_robot`` for all.
"""

from __future__ import annotations

import contextlib
import ctypes
from collections.abc import Iterator

import numpy as np
import pytest

from kali_daemons.core.errors import ChannelError
from kali_daemons.core.layout import CalibState, GuardState, PowerCmd, PowerState
from kali_daemons.hardware.mcgill.registers import POWER_AMPS_ON as AMPS_ON
from kali_daemons.servo.level import ServoLevel
from kali_daemons.sio.cycle import SioCycle

from .conftest import HostedCell, boards_of

CASES = 400


class Hosted:
    """A plant and SIO hosted in this process (``HostedCell``), with the TG's end of the
    FIFOs and the whole arena as bytes."""

    def __init__(self) -> None:
        self.cell = HostedCell(("plant", "sio"))
        self.inst = self.cell.inst
        self.sio: SioCycle = self.cell["sio"].io  # type: ignore[attr-defined]
        self.level = ServoLevel(self.inst)  # the producer's side of the FIFOs: the TG's
        self.fifos = [self.level.fifo(k) for k in range(self.level.n_robots)]
        self.memory = np.frombuffer(self.inst.arena._mm, dtype=np.uint8)  # the whole arena

    def close(self) -> None:
        del self.memory
        self.level.close()
        self.cell.close()

    def state(self) -> tuple[bytes, ...]:
        """Everything ``_robot`` may write: the arena, SIO's arrays, the pops' own state."""
        sio = self.sio
        pops = (
            ctypes.string_at(ctypes.addressof(p.args), ctypes.sizeof(p.args)) for p in sio._pops
        )
        return (self.memory.tobytes(), sio.demand.tobytes(), sio.fed_mask.tobytes(), *pops)

    def restore(self, saved: tuple[bytes, ...]) -> None:
        sio = self.sio
        self.memory[:] = np.frombuffer(saved[0], dtype=np.uint8)
        sio.demand[:] = np.frombuffer(saved[1])
        sio.fed_mask[:] = np.frombuffer(saved[2], dtype=bool)
        for p, raw in zip(sio._pops, saved[3:], strict=True):
            ctypes.memmove(ctypes.addressof(p.args), raw, len(raw))


@pytest.fixture(scope="module")
def hosted() -> Iterator[Hosted]:
    h = Hosted()
    try:
        yield h
    finally:
        h.close()


def pick(rng: np.random.Generator, common: object, others: list[object], p: float = 0.85):
    """``common`` with probability ``p``, else one of ``others``."""
    return common if rng.random() < p else others[rng.integers(len(others))]


def random_case(h: Hosted, rng: np.random.Generator) -> bool:
    """Write a random state into the hosted SIO's records and FIFOs; the tick's ``faulted``."""
    sio, rs = h.sio, h.sio.level.robots
    boards = boards_of(h.inst)
    for k in range(sio.level.n_robots):
        rs["pots_read"][k] = pick(rng, 1, [0])
        rs["power"][k] = pick(rng, PowerState.ON, [PowerState.OFF, PowerState.ENABLING])
        rs["power_cmd"][k] = pick(rng, PowerCmd.NONE, [PowerCmd.ENABLE, PowerCmd.DISABLE, 7])
        rs["calib_cmd"][k] = pick(rng, 0, [1, 3])
        rs["calib_state"][k] = pick(rng, CalibState.DONE, list(CalibState))
        rs["guided"][k] = pick(rng, 0, [1])
        sio._guard_state[k] = pick(rng, GuardState.IDLE, list(GuardState))
        sio.ft_records["guard_q"][k] = rng.uniform(-1.0, 1.0, sio.ft_records["guard_q"].shape[1])
        boards["power"][k] = rng.integers(256) | AMPS_ON if rng.random() < 0.85 else 0
        for _ in range(rng.integers(4)):  # set-points the pop may take, or none
            with contextlib.suppress(ChannelError):  # full: the pops keep up on average
                h.fifos[k].push(rng.uniform(-2.0, 2.0, h.fifos[k].width))
    sio.q[:] = rng.uniform(-2.0, 2.0, sio.q.size)  # where the arm is: not any demand
    sio.demand[:] = rng.uniform(-2.0, 2.0, sio.demand.size)
    sio.fed_mask[:] = rng.random(sio.fed_mask.size) < 0.5
    return bool(rng.random() < 0.1)


def test_the_robots_kernel_equals_robot_on_what_it_takes(hosted: Hosted) -> None:
    h, sio = hosted, hosted.sio
    rng = np.random.default_rng(20261128)
    taken = left = 0
    n = sio.level.n_robots
    for case in range(CASES):
        faulted = random_case(h, rng)
        before = h.state()
        sio._robots_args.faulted = faulted
        others = sio._robots()
        after_kernel = h.state()
        h.restore(before)
        sio.fed_mask[:] = False
        for k in range(sio.level.n_robots):
            if not others >> k & 1:
                sio._robot(k, case, faulted)
        after_robot = h.state()
        names = ("the arena", "SIO's demand", "SIO's fed mask", *(f"pop {k}" for k in range(n)))
        for what, a, b in zip(names, after_kernel, after_robot, strict=True):
            if a != b:
                at = next(i for i in range(len(a)) if a[i] != b[i])
                pytest.fail(f"case {case} (kernel left {others:#b}): {what} differs at byte {at}")
        left += bin(others).count("1")
        taken += n - bin(others).count("1")
    # both ways were exercised: about half of the robots take the common path
    assert taken > CASES // 4 and left > CASES // 4, (taken, left)


def test_a_robot_in_the_common_case_is_taken_and_any_other_is_left(hosted: Hosted) -> None:
    """Each condition of the common case, alone broken, leaves the robot to ``_robot``."""
    sio, rs = hosted.sio, hosted.sio.level.robots
    boards = boards_of(hosted.inst)

    def common() -> None:
        for k in range(sio.level.n_robots):
            rs["pots_read"][k], rs["power"][k], rs["power_cmd"][k] = 1, PowerState.ON, 0
            rs["calib_cmd"][k], rs["calib_state"][k], rs["guided"][k] = 0, CalibState.IDLE, 0
            sio._guard_state[k] = GuardState.ARMED
            boards["power"][k] = AMPS_ON
        sio._robots_args.faulted = False

    common()
    assert sio._robots() == 0
    breaks = [
        ("pots_read", 0),
        ("power", PowerState.ENABLING),
        ("power_cmd", PowerCmd.DISABLE),
        ("calib_cmd", 1),
        ("calib_state", CalibState.SEARCH),
        ("calib_state", CalibState.SETTLE),
        ("calib_state", CalibState.POTS),
        ("guided", 1),
    ]
    for field, value in breaks:
        common()
        rs[field][1] = value
        assert sio._robots() == 0b10, (field, value)
    common()
    sio._guard_state[0] = GuardState.TRIPPED
    assert sio._robots() == 0b01
    common()
    boards["power"][0] = 0xFF & ~AMPS_ON
    assert sio._robots() == 0b01
    common()
    sio._robots_args.faulted = True
    assert sio._robots() == 0b11
