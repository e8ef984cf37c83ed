"""SIO acknowledges a tick for the SVs it can vouch for once every servo is done
(``kali_daemons/sio/gang.py``, thesis 3.3.4): driven here on arrays laid out as the arena's."""

from __future__ import annotations

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.sio.gang import GangAcknowledger

SLOTS = [3, 4]  # sv.0 on SIO's CPU, sv.1 on the other one


def _gang(
    fed: list[int], sig: list[int], ack: list[int]
) -> tuple[GangAcknowledger, np.ndarray, np.ndarray]:
    procs = np.zeros(8, layout.PROCESS)
    procs["signal_tick"] = procs["ack_tick"] = procs["vouched_tick"] = -1
    procs["signal_tick"][SLOTS], procs["ack_tick"][SLOTS] = sig, ack
    gang = GangAcknowledger(
        np.array(fed, np.int64),
        procs["signal_tick"],
        procs["ack_tick"],
        procs["vouched_tick"],
        SLOTS,
        [True, False],
    )
    return gang, procs["ack_tick"], procs["vouched_tick"]


def test_an_sv_that_took_its_feed_is_acknowledged() -> None:
    gang, ack, vouched = _gang(fed=[100, 100], sig=[100, 100], ack=[99, 99])
    gang.acknowledge(100)
    assert ack[SLOTS].tolist() == [100, 100]
    assert vouched[SLOTS].tolist() == [-1, -1]  # nothing for the clock to look into


def test_the_sv_on_sios_cpu_whose_share_the_other_ran_is_acknowledged() -> None:
    """SIO feeds and sleeps; before sv.0, below it on its CPU, has taken the feed, sv.1
    (polling on the other CPU) runs both arms' units and posts done, and SIO preempts sv.0.
    sv.0 took the previous tick's feed: it is acknowledged, not left to acknowledge behind
    SIO's output (the failure test_servo_level's two-SV test saw on 8-39 ticks of 1000 in
    2 runs of 8), and the tick is noted for the clock to look whether sv.0 is alive."""
    gang, ack, vouched = _gang(fed=[99, 100], sig=[100, 100], ack=[99, 99])
    gang.acknowledge(100)
    assert ack[SLOTS].tolist() == [100, 100]
    assert vouched[SLOTS].tolist() == [100, -1]


@pytest.mark.parametrize(
    ("fed", "expected"),
    [([98, 100], [99, 100]), ([100, 99], [100, 99]), ([98, 98], [99, 99])],
    ids=["sv.0-a-tick-behind", "sv.1-no-feed", "neither"],
)
def test_an_sv_that_may_be_stalled_or_dead_is_not_acknowledged(
    fed: list[int], expected: list[int]
) -> None:
    """sv.0 that missed the previous feed too, or sv.1 (a CPU of its own) that has not
    taken this one: the clock must see it late and name it."""
    gang, ack, vouched = _gang(fed=fed, sig=[100, 100], ack=[99, 99])
    gang.acknowledge(100)
    assert ack[SLOTS].tolist() == expected
    assert vouched[SLOTS].tolist() == [-1, -1]


def test_an_sv_not_signalled_for_the_tick_is_not_acknowledged() -> None:
    """The clock did not signal it (its gang sat the tick out, or it was still late)."""
    gang, ack, _ = _gang(fed=[100, 100], sig=[99, 100], ack=[98, 99])
    gang.acknowledge(100)
    assert ack[SLOTS].tolist() == [98, 100]


def test_slots_and_cpu_flags_must_match() -> None:
    with pytest.raises(ValueError, match="2 SV slots but 1 CPU flags"):
        z = np.zeros(8, np.int64)
        GangAcknowledger(np.zeros(2, np.int64), z, z, z, SLOTS, [True])
