"""The servo programming interface (thesis 3.4): built-in PID and PD, private data in shared
memory, the registry and plugins, and the default PUMA 560 gains in closed loop.

The closed-loop tests run one arm of the plant in-process at 1 kHz, as SIO and an SV would
(encoders → driver → servo step per joint → driver → DAC → ``PlantSim.cycle``), with the
servos' private data in the arena.  No daemons, so the same run gives the same figures.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from kali_daemons.core.arena import Arena
from kali_daemons.core.errors import ConfigError
from kali_daemons.hardware.mcgill import JointDriver
from kali_daemons.hardware.mcgill.registers import CSR_ENABLE, CSR_INDEX_OFF, CSR_NO_DISABLE
from kali_daemons.plant.sim import PlantSim
from kali_daemons.robots import puma560
from kali_daemons.servo import (
    PD,
    PID,
    Handover,
    Registry,
    ServoAlgorithm,
    registry_for,
    struct_type,
    struct_view,
)

from .conftest import make_config

N = puma560.ROBOT.n_joints  # the loop servos one PUMA

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = "kali_daemons/examples/servo_plugin_example.py"
T = 0.001  # s, the servo interval of every test here (1 kHz)

# --------------------------------------------------------------------------------------------
# Closed loop: one arm, in-process

ONE_ARM = {
    r"(?s)^robots:\n(  - .*?\n)+": (
        "robots:\n  - {name: arm, model: puma560, base_xyz: [0.0, 0.0, 0.0], base_yaw_deg: 0}\n"
    )
}
CFG = make_config("servo", ONE_ARM)
COUNT = 2.0 * math.pi / (puma560.COUNTS_PER_MOTOR_REV * np.abs(puma560.G))  # rad per count
GAINS = {"pid": puma560.PID_DEFAULTS, "pd": puma560.PD_DEFAULTS}
POWER_TICKS = 20  # enable bit held this long (the relay needs 15 ms)


class ServoLoop:
    """One PUMA 560 of the plant under servo control, stepped tick by tick (1 ms).

    Every joint has a private data record for every registered algorithm in the arena
    (``servo.<joint>.<algo>``), initialised with ``puma560.<ALGO>_DEFAULTS``; ``select``
    switches a joint's algorithm with a hand-over, as the SV does.  The loop logs the
    measured angles, torques and whether the current was clamped, tick by tick.
    """

    def __init__(
        self,
        arena: Arena,
        registry: Registry,
        algos: Sequence[str] = ("pid",) * N,
        pose: np.ndarray | None = None,
    ) -> None:
        self.sim = sim = PlantSim(CFG, arena)
        if pose is not None:
            sim.place_arm(0, pose)
        self.registry = registry
        self.driver = JointDriver([puma560.ROBOT], sim.regs["encoder"], sim.dac["code"])
        self.driver.start()
        self.driver.offset[:] = sim.joint_truth["q"][CFG.joints.span(0)]  # starts calibrated
        self.q = np.zeros(N)
        self.q_prev = self.driver.offset.copy()
        self.demand = self.driver.offset.copy()
        self.torque = np.zeros(N)
        self.error = np.zeros(N)
        self.current = np.zeros(N)
        self.clamped = np.zeros(N, dtype=bool)
        self.data = [
            [struct_view(arena.record(f"servo.{j}.{a.name}", a.dtype)) for a in registry]
            for j in range(N)
        ]
        for j in range(N):
            for i, algo in enumerate(registry):
                gains = GAINS[algo.name][j] if algo.name in GAINS else {}
                algo.init(self.data[j][i], gains, T)
        self.active = [registry.index(name) for name in algos]
        self.ticks = 0
        self.log_q: list[np.ndarray] = []
        self.log_torque: list[np.ndarray] = []
        self.log_clamped: list[np.ndarray] = []
        self._pending: dict[int, int] = {}
        regs = sim.boards[0].regs
        regs["csr"] = CSR_NO_DISABLE | CSR_ENABLE | CSR_INDEX_OFF  # index capture off: the
        self.run(POWER_TICKS)  # driver accumulates counts, an index reset would corrupt them
        regs["csr"] = CSR_NO_DISABLE | CSR_INDEX_OFF  # watchdog timeout mode stays off

    def select(self, joint: int, name: str) -> None:
        """Switch ``joint`` to algorithm ``name`` at the next tick, handing over bumplessly."""
        self._pending[joint] = self.registry.index(name)

    def tick(self) -> None:
        """One servo interval: read, hand over where asked, step every joint, write, plant."""
        self.driver.read(self.q)
        q, demand = self.q.tolist(), self.demand.tolist()
        for j, index in self._pending.items():
            v = (q[j] - float(self.q_prev[j])) / T  # as SIO measures it: backward difference
            h = Handover(q[j], v, demand[j], float(self.error[j]), float(self.torque[j]))
            self.registry[index].handover(self.data[j][index], h)
            self.active[j] = index
        self._pending.clear()
        for j in range(N):
            i = self.active[j]
            tau, err, status = self.registry[i].step(self.data[j][i], demand[j], q[j])
            assert status == 0
            self.torque[j] = tau
            self.error[j] = err
        self.driver.output(self.torque, self.current, self.clamped)
        self.sim.cycle()
        np.copyto(self.q_prev, self.q)
        self.log_q.append(self.q.copy())
        self.log_torque.append(self.torque.copy())
        self.log_clamped.append(self.clamped.copy())
        self.ticks += 1

    def run(self, ticks: int, each: Callable[[int], None] | None = None) -> None:
        """``ticks`` servo intervals; ``each(t)`` before each one (to move the demand)."""
        for t in range(ticks):
            if each is not None:
                each(t)
            self.tick()

    def counts_off(self) -> np.ndarray:
        """Each joint's distance from its demand, in encoder counts (as the encoder reads)."""
        return np.array(
            [self.driver.acc[j] - self.driver.counts_of(j, float(self.demand[j])) for j in range(N)]
        )

    def history(self, start: int = 0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(angles, torques, clamped) logged from tick ``start`` on, one row per tick."""
        return (
            np.array(self.log_q[start:]),
            np.array(self.log_torque[start:]),
            np.array(self.log_clamped[start:]),
        )


@dataclass
class StepResult:
    """A joint's response to a step of its demand."""

    overshoot: float  # fraction of the step beyond the target
    settle_s: float  # time after which the angle stays within the settling band
    max_clamped_ticks: int  # longest run of ticks with the current demand clamped


def step_response(loop: ServoLoop, joint: int, step: float, ticks: int, band: float) -> StepResult:
    """Step ``joint``'s demand by ``step`` (rad) and measure its response over ``ticks``."""
    start = loop.ticks
    target = float(loop.demand[joint]) + step
    loop.demand[joint] = target
    loop.run(ticks)
    q, _torque, clamped = loop.history(start)
    x = (q[:, joint] - (target - step)) / step  # 0 before, 1 at the target
    overshoot = max(0.0, float(x.max()) - 1.0)
    outside = np.flatnonzero(np.abs(q[:, joint] - target) > band)
    settle = 0.0 if outside.size == 0 else (int(outside[-1]) + 1) * T
    return StepResult(overshoot, settle, longest_run(clamped[:, joint]))


def longest_run(flags: np.ndarray) -> int:
    """The longest run of consecutive True values."""
    best = run = 0
    for f in flags.tolist():
        run = run + 1 if f else 0
        best = max(best, run)
    return best


# --------------------------------------------------------------------------------------------
# Private data in shared memory


def fresh(algo: ServoAlgorithm, params: dict[str, float] | None = None) -> tuple[np.ndarray, Any]:
    """A zeroed record of ``algo``'s dtype, its struct view, initialised with ``params``."""
    rec = np.zeros((), dtype=algo.dtype)
    data = struct_view(rec)
    algo.init(data, params or {}, T)
    return rec, data


def test_struct_view_maps_an_arena_record_in_place(arena: Arena) -> None:
    rec = arena.record("servo.test", PID.dtype)
    data = struct_view(rec)
    data.kp = 123.5
    data.primed = 7
    assert rec["kp"] == 123.5 and rec["primed"] == 7  # struct → numpy
    rec["integral"] = -4.25
    assert data.integral == -4.25  # numpy → struct
    one = arena.record("servo.test1", PD.dtype, 1)  # a 1-element array works too
    struct_view(one).kv = 2.0
    assert one[0]["kv"] == 2.0
    same = np.dtype([(n, PID.dtype.fields[n][0]) for n in PID.dtype.names], align=True)
    assert struct_type(PID.dtype) is struct_type(same)  # cached per (equal) dtype
    for name, (_ft, offset, *_) in PID.dtype.fields.items():
        assert getattr(struct_type(PID.dtype), name).offset == offset
    del data


def test_struct_view_refuses_what_it_cannot_map() -> None:
    rec = np.zeros((), dtype=PID.dtype)
    rec.setflags(write=False)
    with pytest.raises(ValueError, match="writable"):
        struct_view(rec)
    with pytest.raises(ValueError, match="one record"):
        struct_view(np.zeros(2, dtype=PID.dtype))
    with pytest.raises(TypeError, match="structured"):
        struct_view(np.zeros(4))


# --------------------------------------------------------------------------------------------
# The PID of figure 3.4 against hand computation


def lowpass(xs: Sequence[float], f: float, y0: float) -> list[float]:
    """y_k = (a·x_k + y_{k-1}) / (1 + a), a = T·2π·f: the filter as the thesis states it."""
    a = T * 2 * math.pi * f
    out, y = [], y0
    for x in xs:
        y = (a * x + y) / (1 + a)
        out.append(y)
    return out


def test_pid_filters_match_the_backward_difference_formula() -> None:
    # kp = 1, nothing else: the torque is the filtered error
    _, d = fresh(PID, {"kp": 1.0, "kv": 0.0, "fe": 50.0})
    errors = [0.0, 0.01, 0.01, 0.01, -0.02, 0.005, 0.0, 0.0]
    got = [PID.step(d, e, 0.0)[0] for e in errors]
    assert got == pytest.approx(lowpass(errors, 50.0, 0.0), rel=1e-12, abs=1e-15)
    # kv = 1, kp = 0: the torque is minus the filtered velocity of the position differences
    _, d = fresh(PID, {"kp": 0.0, "kv": 1.0, "fv": 25.0})
    positions = [0.3, 0.3, 0.3001, 0.3003, 0.3006, 0.3006, 0.3004]
    got = [-PID.step(d, 0.0, p)[0] for p in positions]
    raw = [0.0] + [(b - a) / T for a, b in itertools.pairwise(positions)]
    assert got == pytest.approx(lowpass(raw, 25.0, 0.0), rel=1e-9, abs=1e-12)


def test_pid_torque_is_kp_e_plus_ki_integral_minus_kv_v() -> None:
    g = {"kp": 200.0, "ki": 3000.0, "kv": 7.0, "fe": 40.0, "fv": 20.0}
    g |= {"integration_band": 1.0, "integration_reset": 1e4}  # the bound: never reached here
    _, d = fresh(PID, g)
    demand = [0.1, 0.1, 0.1, 0.12, 0.12, 0.12]
    pos = [0.0, 0.001, 0.003, 0.006, 0.01, 0.015]
    e = lowpass([x - p for x, p in zip(demand, pos, strict=True)], 40.0, 0.1)
    raw = [0.0] + [(b - a) / T for a, b in itertools.pairwise(pos)]
    v = lowpass(raw, 20.0, 0.0)
    integral = 0.0
    for k in range(len(pos)):
        integral += g["ki"] * T * e[k]
        want = g["kp"] * e[k] + integral - g["kv"] * v[k]
        torque, error, status = PID.step(d, demand[k], pos[k])
        assert (torque, error, status) == (pytest.approx(want, rel=1e-12), pytest.approx(e[k]), 0)


def test_pid_integral_only_inside_the_band_and_limited_by_the_reset() -> None:
    g = {"kp": 0.0, "ki": 1000.0, "kv": 0.0, "fe": 1e9}  # fe huge: the error is unfiltered
    _, d = fresh(PID, g | {"integration_band": 0.01, "integration_reset": 0.05})
    PID.step(d, 0.02, 0.0)  # |e| = 0.02 > band: nothing accumulates
    assert d.integral == 0.0
    torques = [PID.step(d, 0.005, 0.0)[0] for _ in range(20)]  # inside: + ki·T·e = 0.005 N·m
    assert torques[:10] == pytest.approx([0.005 * (k + 1) for k in range(10)], rel=1e-5)
    assert torques[-1] == 0.05  # held at the reset, in N·m
    PID.step(d, -0.03, 0.0)  # out of the band again: the integral is held, not reset
    assert d.integral == 0.05
    for _ in range(30):
        PID.step(d, -0.009, 0.0)
    assert d.integral == -0.05


def test_set_params_keeps_the_state_and_recomputes_the_precomputed_terms() -> None:
    g = dict(puma560.PID_DEFAULTS[1])
    _, d = fresh(PID, g)
    for k in range(50):
        PID.step(d, 0.001, 0.0001 * k)
    state = (d.error, d.old_position, d.old_velocity, d.integral, d.bias)
    PID.set_params(d, {"kp": 5000.0, "ki": 1000.0, "fe": 30.0, "fv": 10.0})
    assert (d.error, d.old_position, d.old_velocity, d.integral, d.bias) == state
    assert PID.get_params(d) == g | {"kp": 5000.0, "ki": 1000.0, "fe": 30.0, "fv": 10.0}
    assert d.ki_t == 1000.0 * T
    assert d.lpfe1 == pytest.approx(T * 2 * math.pi * 30.0)
    assert d.lpfv2 == pytest.approx(1 / (1 + T * 2 * math.pi * 10.0))
    # ki → 0 or a lower reset: what the integral held moves to the bias, the output stays
    before = d.integral + d.bias
    PID.set_params(d, {"ki": 0.0})
    assert (d.integral, d.bias) == (0.0, pytest.approx(before))
    _, d = fresh(PID, g)
    d.integral = 40.0
    PID.set_params(d, {"integration_reset": 25.0})
    assert (d.integral, d.bias) == (25.0, 15.0)


HANDOVERS = [  # position, velocity, demand, error, torque: at rest, moving, beyond the reset
    Handover(0.5, 0.0, 0.5, 0.0, 0.0),
    Handover(0.5, 0.3, 0.502, 0.0019, 35.0),
    Handover(-1.2, -0.8, -1.1995, 0.0, -12.5),
    Handover(0.1, 0.05, 0.13, 0.02, 80.0),  # error outside the integration band
    Handover(0.1, 0.0, 0.1001, 0.0, -500.0),  # more than integration_reset
]


@pytest.mark.parametrize("h", HANDOVERS)
@pytest.mark.parametrize(
    ("algo", "params"),
    [
        (PID, puma560.PID_DEFAULTS[1]),
        (PID, {**puma560.PID_DEFAULTS[1], "ki": 0.0}),  # no integral: all in the bias
        (PD, puma560.PD_DEFAULTS[1]),
    ],
    ids=["pid", "pid-ki0", "pd"],
)
def test_handover_makes_the_first_step_output_the_given_torque(
    algo: ServoAlgorithm, params: dict[str, float], h: Handover
) -> None:
    _, d = fresh(algo, params)
    for k in range(30):  # some unrelated history, which the hand-over must override
        algo.step(d, 0.2, 0.1 + 0.001 * k)
    algo.handover(d, h)
    torque, error, status = algo.step(d, h.demand, h.position)
    assert torque == pytest.approx(h.torque, abs=1e-9)
    assert error == pytest.approx(h.demand - h.position, abs=1e-12)
    assert status == 0
    # and the next tick, tracking on at the measured velocity, continues without a step:
    # only the integral (ki·T·e) and the bias's decay (0.2 % per tick) move the torque
    dx = h.velocity * T
    nxt, _, _ = algo.step(d, h.demand + dx, h.position + dx)
    assert abs(nxt - torque) < 1.5


def test_pd_bias_decays_with_bias_tau() -> None:
    tau = 0.2
    _, d = fresh(PD, {"kp": 100.0, "kv": 5.0, "bias_tau": tau})
    PD.handover(d, Handover(0.0, 0.0, 0.0, 0.0, 30.0))
    torques = [PD.step(d, 0.0, 0.0)[0] for _ in range(1001)]
    for k in (0, 100, 200, 600, 1000):
        assert torques[k] == pytest.approx(30.0 * math.exp(-k * T / tau), rel=1e-9)


def test_first_step_after_init_starts_at_rest() -> None:
    for algo in (PID, PD):
        _, d = fresh(algo, {"kp": 10.0, "kv": 100.0})
        torque, _, _ = algo.step(d, 1.5, 1.5)  # far from 0: no velocity kick from θ_{-1} = 0
        assert torque == 0.0


@pytest.mark.parametrize(
    ("algo", "init_data", "interval", "message"),
    [
        (PID, {"kq": 1.0}, T, "servo pid: unknown parameter 'kq'; parameters: kp, ki, kv, fe"),
        (PID, {"kp": -1.0}, T, "servo pid: parameter kp = -1 N·m/rad must be >= 0"),
        (PID, {"fe": 0.0}, T, "servo pid: parameter fe = 0 Hz must be > 0"),
        (PID, {"ki": math.nan}, T, "servo pid: parameter ki = nan must be finite"),
        (PID, {"kv": "fast"}, T, "servo pid: parameter kv = 'fast' is not a number"),
        (PD, {"bias_tau": -0.1}, T, "servo pd: parameter bias_tau = -0.1 s must be >= 0"),
        (PD, {}, 0.0, "servo pd: sample interval 0.0 s must be > 0"),
    ],
)
def test_init_refuses_bad_parameters_and_changes_nothing(
    algo: ServoAlgorithm, init_data: dict[str, Any], interval: float, message: str
) -> None:
    rec, d = fresh(algo, {"kp": 42.0})
    before = rec.tobytes()
    with pytest.raises(ConfigError) as info:
        algo.init(d, init_data, interval)
    assert message in str(info.value)
    assert rec.tobytes() == before
    with pytest.raises(ConfigError):
        algo.set_params(d, init_data or {"kp": -1.0})  # on line too, and nothing changes
    assert rec.tobytes() == before


# --------------------------------------------------------------------------------------------
# Registry and plugins


def test_registry_builtins_first_then_plugins_in_order() -> None:
    reg = registry_for([EXAMPLE], ROOT)
    assert reg.names() == ["pid", "pd", "bwpd"]
    assert [reg.index(n) for n in reg.names()] == [0, 1, 2]
    assert reg[0] is PID and reg.by_name("pd") is PD and reg[2].name == "bwpd"
    assert reg.origin("bwpd") == f"plugin '{EXAMPLE}'"
    assert reg.max_itemsize() == max(PID.dtype.itemsize, PD.dtype.itemsize, reg[2].dtype.itemsize)
    with pytest.raises(ConfigError, match=r"no algorithm 'pidd'; known: pid, pd, bwpd"):
        reg.index("pidd")
    with pytest.raises(IndexError, match=r"index 3 outside 0..2"):
        reg[3]
    with pytest.raises(ConfigError, match=f"already registered by plugin '{EXAMPLE}'"):
        reg.load_plugin(str(ROOT / EXAMPLE))  # the same file again, by absolute path


def test_example_plugin_is_a_critically_damped_pd_with_handover() -> None:
    bw = registry_for([EXAMPLE], ROOT).by_name("bwpd")
    _, d = fresh(bw, {"bandwidth_hz": 4.0, "inertia": 2.0})
    w = 2 * math.pi * 4.0
    assert (d.kp, d.kv) == (pytest.approx(2.0 * w * w), pytest.approx(2 * 2.0 * w))
    assert bw.step(d, 0.01, 0.0) == (pytest.approx(d.kp * 0.01), 0.01, 0)
    bw.handover(d, Handover(0.2, 0.4, 0.201, 0.0, 17.0))
    assert bw.step(d, 0.201, 0.2)[0] == pytest.approx(17.0)
    bw.set_params(d, {"bandwidth_hz": 2.0})
    assert bw.get_params(d) == {"bandwidth_hz": 2.0, "inertia": 2.0}
    assert d.kp == pytest.approx(2.0 * (2 * math.pi * 2.0) ** 2)


PLUGIN_TEMPLATE = """
import numpy as np
from kali_daemons.servo import ServoAlgorithm, PD
{prelude}
def register(registry):
    {body}
"""
GOOD_DTYPE = "PD.dtype"  # the functions' own: registering steps the algorithm once


def plugin_source(
    name: str = "'mine'", dtype: str = GOOD_DTYPE, step: str = "PD.step", prelude: str = ""
) -> str:
    body = (
        f"registry.register(ServoAlgorithm(name={name}, dtype={dtype}, params=('kp',), "
        f"init=PD.init, step={step}, handover=PD.handover, set_params=PD.set_params, "
        "get_params=PD.get_params))"
    )
    return PLUGIN_TEMPLATE.format(prelude=prelude, body=body)


PLUGIN_FAULTS = [  # (id, file text or None for no file, spec, substrings of the message)
    ("missing-file", None, "nope.py", ["plugin 'nope.py': file ", "nope.py does not exist"]),
    (
        "no-module",
        None,
        "no_such_servo_module",
        ["plugin 'no_such_servo_module': import failed: ModuleNotFoundError"],
    ),
    (
        "import-error",
        "x = 1 / 0\n",
        "bad.py",
        ["plugin 'bad.py': import of ", "bad.py failed: ZeroDivisionError: division by zero"],
    ),
    ("no-register", "X = 1\n", "bad.py", ["plugin 'bad.py': defines no register(registry)"]),
    (
        "register-raises",
        "def register(registry):\n    raise RuntimeError('boom')\n",
        "bad.py",
        ["plugin 'bad.py': register() raised RuntimeError: boom"],
    ),
    (
        "registers-nothing",
        "def register(registry):\n    pass\n",
        "bad.py",
        ["plugin 'bad.py': register() registered no algorithm"],
    ),
    (
        "duplicate",
        plugin_source(name="'pid'"),
        "bad.py",
        ["plugin 'bad.py': algorithm name 'pid' is already registered by builtins; known: pid"],
    ),
    (
        "bad-name",
        plugin_source(name="'My Servo'"),
        "bad.py",
        ["plugin 'bad.py': algorithm name 'My Servo' must be lower case letters"],
    ),
    (
        "non-numeric",
        plugin_source(dtype="np.dtype([('kp', '<f8'), ('label', '<U8')], align=True)"),
        "bad.py",
        ["plugin 'bad.py': algorithm 'mine': dtype field 'label' has type <U8; only native"],
    ),
    (
        "sub-array",
        plugin_source(dtype="np.dtype([('hist', '<f8', (4,))], align=True)"),
        "bad.py",
        ["algorithm 'mine': dtype field 'hist' is an array <f8 (4,); only scalars"],
    ),
    (
        "not-aligned",
        plugin_source(dtype="np.dtype([('kp', '<f8'), ('n', '<u4')])"),
        "bad.py",
        ["algorithm 'mine': dtype [('kp', '<f8'), ('n', '<u4')] is not aligned"],
    ),
    (
        "not-a-dtype",
        plugin_source(dtype="[('kp', '<f8')]"),
        "bad.py",
        ["algorithm 'mine': dtype [('kp', '<f8')] is a list, not a numpy dtype"],
    ),
    (
        "too-big",
        plugin_source(dtype="np.dtype([(f'x{i}', '<f8') for i in range(129)], align=True)"),
        "bad.py",
        ["algorithm 'mine': private data is 1032 B, at most 1024 B (the put/get mailbox"],
    ),
    (
        "missing-callable",
        plugin_source(step="None"),
        "bad.py",
        ["plugin 'bad.py': algorithm 'mine': step is None, not a callable"],
    ),
    (
        "step-returns-a-bare-torque",
        plugin_source(step="lambda data, demand, position: 0.5"),
        "bad.py",
        ["algorithm 'mine': step(data, 0.01, 0.0) at its defaults returned 0.5; it must "],
    ),
    (
        "step-returns-a-nan-torque",
        plugin_source(step="lambda data, demand, position: (float('nan'), 0.0, 0)"),
        "bad.py",
        ["algorithm 'mine': step(data, 0.01, 0.0) at its defaults returned (nan, 0.0, 0)"],
    ),
    (
        "step-raises",
        plugin_source(step="lambda data, demand, position: data.missing"),
        "bad.py",
        ["algorithm 'mine': step(data, 0.01, 0.0) at its defaults raised AttributeError"],
    ),
]


@pytest.mark.parametrize(
    ("text", "spec", "substrings"),
    [case[1:] for case in PLUGIN_FAULTS],
    ids=[case[0] for case in PLUGIN_FAULTS],
)
def test_plugin_faults_name_the_plugin_what_is_wrong_and_the_value(
    tmp_path: Path, text: str | None, spec: str, substrings: list[str]
) -> None:
    if text is not None:
        (tmp_path / spec).write_text(text)
    reg = Registry()
    with pytest.raises(ConfigError) as info:
        reg.load_plugin(spec, tmp_path)
    message = str(info.value)
    assert message.startswith("config: ")
    for part in substrings:
        assert part in message, message
    assert reg.names() == ["pid", "pd"]  # a failed plugin registers nothing


def test_a_well_formed_plugin_from_a_template_loads(tmp_path: Path) -> None:
    (tmp_path / "good.py").write_text(plugin_source())
    reg = registry_for(["good.py"], tmp_path)
    assert reg.names() == ["pid", "pd", "mine"] and reg.max_itemsize() == PID.dtype.itemsize


# --------------------------------------------------------------------------------------------
# The default gains in closed loop through the plant (1 kHz, one arm at QN)

SETTLE_TICKS = 2000  # 2 s from power-on: brakes release at 70 ms, joint 2 sags, I catches it
HOLD_TICKS = 500
STEP = 0.02  # rad
STEP_TICKS = 1000
SETTLE_BAND = 0.05 * STEP  # settled: within 5 % of the step (1 mrad, 9-14 counts)
MAX_OVERSHOOT = 0.30
MAX_SETTLE_S = 0.5
MAX_CLAMPED_TICKS = 20  # a step saturates joints 1-2 briefly; SIO trips after 100 ms
RAMP = 0.1  # rad/s, every joint, while switching algorithms
SWITCHES = {500: "pd", 1000: "pid"}  # tick into the ramp → algorithm selected on every joint
JITTER_WINDOW = 200  # ticks before a switch whose tick-to-tick torque changes are the baseline
AFTER_WINDOW = 30  # ticks after a switch checked against twice that baseline


@pytest.fixture
def loop(arena: Arena) -> Iterator[ServoLoop]:
    """The arm powered up at QN under the built-in PID with ``puma560.PID_DEFAULTS``."""
    yield ServoLoop(arena, registry_for([]))


@pytest.mark.parametrize(
    ("pose", "gravity"),
    [(puma560.QN, puma560.GRAVITY_QN), (puma560.QZ, puma560.GRAVITY_QZ)],
    ids=["QN", "QZ"],
)
def test_default_pid_holds_every_joint_within_one_count_at_rest(
    arena: Arena, pose: np.ndarray, gravity: np.ndarray
) -> None:
    loop = ServoLoop(arena, registry_for([]), pose=np.array(pose))
    loop.run(SETTLE_TICKS)
    worst = np.zeros(N, dtype=np.int64)
    for _ in range(HOLD_TICKS):
        loop.tick()
        worst = np.maximum(worst, np.abs(loop.counts_off()))
    assert worst.max() <= 1, f"encoder counts off the demand, per joint: {worst}"
    # gravity is not compensated: joint 2's integral holds it, less what friction takes
    assert loop.torque[1] > gravity[1] - puma560.COULOMB_POS[1]
    assert loop.data[1][0].integral == pytest.approx(loop.torque[1], abs=0.5)


def test_default_pid_steps_every_joint_with_bounded_overshoot(loop: ServoLoop) -> None:
    loop.run(SETTLE_TICKS)
    results = [step_response(loop, j, STEP, STEP_TICKS, SETTLE_BAND) for j in range(N)]
    for j, r in enumerate(results):
        where = f"joint {j + 1}: {r}"
        assert r.overshoot < MAX_OVERSHOOT, where
        assert r.settle_s < MAX_SETTLE_S, where
        assert r.max_clamped_ticks <= MAX_CLAMPED_TICKS, where


def test_switching_pid_and_pd_on_moving_joints_is_bumpless(loop: ServoLoop) -> None:
    loop.run(SETTLE_TICKS)
    start, d0 = loop.ticks, loop.demand.copy()

    def ramp(t: int) -> None:
        loop.demand[:] = d0 + RAMP * t * T
        if t in SWITCHES:
            for j in range(N):
                loop.select(j, SWITCHES[t])

    loop.run(max(SWITCHES) + 200, ramp)
    q, torque, _ = loop.history(start)
    jumps = np.abs(np.diff(torque, axis=0))  # jumps[k]: from tick k to tick k + 1
    assert [loop.registry[i].name for i in loop.active] == [SWITCHES[max(SWITCHES)]] * 6
    for t, name in SWITCHES.items():
        at_switch = jumps[t - 1]
        baseline = jumps[t - 1 - JITTER_WINDOW : t - 1].max(axis=0)
        after = jumps[t : t + AFTER_WINDOW].max(axis=0)
        assert at_switch.max() < 1e-6, f"to {name}: torque jumps at the switch {at_switch}"
        assert np.all(after <= 2.0 * baseline), f"to {name}: {after} vs jitter {baseline}"
    lag = np.abs(q - (d0 + RAMP * np.arange(len(q))[:, None] * T)).max(axis=0)
    assert lag.max() < 0.01, f"tracking error during the switches (rad): {lag}"
