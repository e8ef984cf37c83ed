"""What reset and status promise (issue 51 items 11 and 15).

A power command written raw into the arena during a halt, stamped with the halt's own fault
count as ``kalictl enable`` would stamp it, used to be taken after release and reset, while
reset printed "power stays off until: kalictl enable".  ``status`` used to report a robot
powered with its board's amplifiers already cut (an e-stop SIO had not seen yet: lockstep,
or SIO stalled), and "clock running" after the wall clock process was killed.
"""

from __future__ import annotations

import json
import os
import signal
from collections.abc import Callable

import numpy as np
import pytest

from kali_daemons.core import layout
from kali_daemons.core.layout import PowerCmd, PowerState
from kali_daemons.runtime.instance import Instance
from kali_daemons.wallclock import step_kali_clock

from ..conftest import wait_for
from ..test_launcher import kalictl
from .test_trust_inputs import POTS_TICKS, POWER_TICKS, _ok


def _robots(inst: Instance) -> np.ndarray:
    return inst.arena.existing(layout.KEY_ROBOTS, layout.ROBOT_STATE, 2)


def _powers(inst: Instance) -> list[PowerState]:
    return [PowerState(int(p)) for p in _robots(inst)["power"]]


def test_a_power_command_stamped_during_a_halt_is_void_after_reset(
    kali: Callable[..., str],
) -> None:
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        step_kali_clock(inst, POTS_TICKS)
        _ok("-i", name, "estop")
        robots = _robots(inst)
        robots["cmd_faults"][:] = int(inst.fault["count"]) & 0xFFFFFFFF  # as enable stamps
        robots["power_cmd"][:] = PowerCmd.ENABLE
        robots["calib_cmd"][:] = 1
        _ok("-i", name, "estop", "--release")
        assert "power stays off until: kalictl enable" in _ok("-i", name, "reset")
        step_kali_clock(inst, POWER_TICKS)
        assert _powers(inst) == [PowerState.OFF] * 2
        _ok("-i", name, "enable")  # the way to power on
        step_kali_clock(inst, POWER_TICKS)
        assert _powers(inst) == [PowerState.ON] * 2, inst.fault_text()
        del robots


def test_status_says_power_off_once_the_board_has_cut_it(kali: Callable[..., str]) -> None:
    """An e-stop in lockstep: the board cuts the amplifiers at once, SIO sees it only at its
    next tick; status says what drives the motors."""
    name = kali(lockstep=True)
    with Instance.attach(name) as inst:
        step_kali_clock(inst, POTS_TICKS)
        _ok("-i", name, "enable")
        step_kali_clock(inst, POWER_TICKS)
        assert _powers(inst) == [PowerState.ON] * 2
        _ok("-i", name, "estop", "left")
        robots = json.loads(_ok("-i", name, "status", "--json"))["robots"]
        assert [r["power"] for r in robots] == ["OFF", "OFF"]  # the halt cuts every arm
        assert [r["power_sio"] for r in robots] == ["ON", "ON"]  # not seen by SIO yet
        assert [r["amplifiers_cut"] for r in robots] == [True, True]


@pytest.mark.serial
def test_status_says_the_clock_is_dead_once_its_process_is(kali: Callable[..., str]) -> None:
    name = kali(lockstep=False)
    with Instance.attach(name) as inst:
        pid = int(inst.procs[inst.slot_of("wallclock")]["pid"])
        os.kill(pid, signal.SIGKILL)
        wait_for(lambda: bool(inst.fault["active"]), 10, "the dead clock noticed")
        r = kalictl("-i", name, "status")
        assert r.returncode == 0, r.stderr
        assert "clock dead" in r.stdout, r.stdout
        assert json.loads(_ok("-i", name, "status", "--json"))["clock"]["mode"] == "dead"
