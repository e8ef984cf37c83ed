"""Six-axis wrist force/torque sensors: the data sheet, the gauges' ADC bank and the
conversion to Newtons, shared by the plant that plays the sensor and SIO that reads it.

A strain-gauge sensor of the ATI/JR3 class: six gauge bridges sampled together by a 16-bit
ADC bank (±10 V), the wrench ``w = C v`` with the sensor's 6×6 calibration matrix ``C``;
offsets that drift (a tare removes them), noise, and rails where a gauge reads nothing
meaningful.  The sensor frame is the flange frame, and ``w`` is the wrench the tool side
exerts on the sensor, about its origin (an idle tool reads its own weight); SIO subtracts the
tool's gravity to give the contact wrench.  The bank's request/ready handshake on
``ft_control``/``ft_status`` and the sign conventions in full:
docs/internals/robots-hardware-plant.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Final

import numpy as np

from ..core.errors import ConfigError
from ..core.layout import WRENCH

AXES: Final = ("Fx", "Fy", "Fz", "Tx", "Ty", "Tz")
AXIS_UNITS: Final = ("N", "N", "N", "N·m", "N·m", "N·m")
GAUGES: Final = WRENCH  # one bridge per axis of the wrench
ADC_BITS: Final = 16
ADC_VOLTS: Final = 10.0  # ± full scale of the gauge ADC bank
FT_RAIL: Final = (1 << (ADC_BITS - 1)) - 1  # 32767: a gauge here (or at -32768) is saturated
VOLTS_PER_CODE: Final = ADC_VOLTS / (FT_RAIL + 1)

# ft_control / ft_status bits (registers.IO_BOARD)
FT_SEQ_MASK: Final = 0x7F
FT_REQUEST: Final = 1 << 7  # control: sample the gauges (a new seq: a new sample)
FT_READY: Final = 1 << 8  # status: the codes in ft_gauge are the sample of seq
FT_PRESENT: Final = 1 << 9  # status: a sensor is connected to the bank


@dataclass(frozen=True)
class FtSheet:
    """A sensor model's data sheet: what the plant simulates and SIO converts with.

    ``rated``: the calibrated range per axis (N, N·m); ``volts_at_rated``: the gauge voltage a
    pure load at the rated value gives (the rest of the ±10 V is headroom before the rail);
    ``coupling``: the cross-talk between axes in the calibration (``C = diag(rated /
    volts_at_rated) (I + coupling)``); ``noise``: standard deviation of one sample per axis
    (N, N·m); ``offset_v``: the largest gauge offset a sensor leaves the factory with;
    ``drift_v_per_sqrt_s``: the offset's random walk (thermal drift).
    """

    name: str
    rated: tuple[float, ...]
    noise: tuple[float, ...]
    coupling: tuple[tuple[float, ...], ...]
    volts_at_rated: float = 8.0
    offset_v: float = 0.2
    drift_v_per_sqrt_s: float = 2e-4
    # where SIO takes the wrench from (``SOURCES``): a board's gauge ADC, or a wrench the
    # hardware gives at the flange (the kinds that give one say which, ``HardwareKind.wrist``)
    source: str = "gauges"

    def __post_init__(self) -> None:
        if len(self.rated) != GAUGES or len(self.noise) != GAUGES:
            raise ConfigError(f"F/T sheet {self.name!r}: rated and noise need {GAUGES} values")
        if len(self.coupling) != GAUGES or any(len(r) != GAUGES for r in self.coupling):
            raise ConfigError(f"F/T sheet {self.name!r}: coupling must be {GAUGES}×{GAUGES}")
        if self.source not in ("gauges", "model", "robot"):
            raise ConfigError(f"F/T sheet {self.name!r}: source {self.source!r} unknown")

    @cached_property
    def calibration(self) -> np.ndarray:
        """``C``: the wrench (N, N·m) of gauge volts, ``w = C v`` (read-only; zero for a
        sheet without gauges)."""
        if self.source != "gauges":
            c = np.zeros((GAUGES, GAUGES))
            c.setflags(write=False)
            return c
        c = np.diag(np.asarray(self.rated) / self.volts_at_rated) @ (
            np.eye(GAUGES) + np.asarray(self.coupling)
        )
        c.setflags(write=False)
        return c

    @cached_property
    def gauges(self) -> np.ndarray:
        """``C⁻¹``: the gauge volts of a wrench, as the bridges produce them (read-only)."""
        g = np.linalg.inv(self.calibration)
        g.setflags(write=False)
        return g

    def error_sd(self, seconds: float) -> np.ndarray:
        """Standard deviation per axis (N, N·m) of one tared sample's error ``seconds`` after
        the tare: the sample's noise, the offsets' random walk since the tare (each gauge's
        ``drift_v_per_sqrt_s`` through the calibration) and the ADC's quantisation.  The walk
        is why a long contact task tares again: a minute after the tare a MINI45's error is
        1.4-1.5 times its noise on the forces and 1.6 times on the torques."""
        per_volt = np.linalg.norm(self.calibration, axis=1)  # one volt on every gauge
        drift = per_volt * self.drift_v_per_sqrt_s * math.sqrt(max(seconds, 0.0))
        quantum = per_volt * VOLTS_PER_CODE / math.sqrt(12.0)
        return np.sqrt(np.square(self.noise) + np.square(drift) + np.square(quantum))

    def describe(self) -> str:
        """One line for ``kalictl`` and the docs: the ranges and noise."""
        parts = [
            f"{a} ±{r:g} {u} (σ {s:g})"
            for a, r, u, s in zip(AXES, self.rated, AXIS_UNITS, self.noise, strict=True)
        ]
        return f"{self.name}: " + ", ".join(parts)


# The default wrist sensor: a 45 mm strain-gauge sensor of the ATI Mini45 SI-290-10 class
# (its published ranges; noise of its order at 1 kHz without filtering; a cross-talk of a few
# per cent between axes, as a real calibration matrix shows).
MINI45: Final = FtSheet(
    name="mini45",
    rated=(290.0, 290.0, 580.0, 10.0, 10.0, 10.0),
    noise=(0.06, 0.06, 0.1, 0.0015, 0.0015, 0.0015),
    coupling=(
        (0.000, 0.012, -0.021, 0.004, 0.018, -0.006),
        (-0.015, 0.000, 0.009, -0.017, 0.003, 0.011),
        (0.019, -0.008, 0.000, 0.006, -0.012, 0.002),
        (0.005, 0.021, -0.004, 0.000, 0.010, -0.014),
        (-0.018, 0.002, 0.007, -0.009, 0.000, 0.016),
        (0.003, -0.013, 0.015, 0.008, -0.005, 0.000),
    ),
)

# No sensor on the wrist: the wrench from the arm's own joint torque sensors.  ``model``: Kali
# estimates it from the measured torques and its model of the arm (the link's, for a robot
# that gives none of its own: franky-sim's FR3); ``robot``: the robot's own estimate (a real
# FR3's O_F_ext_hat_K).  No ADC, no rated range of their own: the contact limit bounds them.
_NO_NOISE: Final = (0.0,) * GAUGES
_NO_COUPLING: Final = ((0.0,) * GAUGES,) * GAUGES
JOINT_TORQUES: Final = FtSheet(
    "joint-torques", (math.inf,) * GAUGES, _NO_NOISE, _NO_COUPLING, source="model"
)
ROBOT_ESTIMATE: Final = FtSheet(
    "robot", (math.inf,) * GAUGES, _NO_NOISE, _NO_COUPLING, source="robot"
)
SOURCES: Final = ("gauges", "model", "robot")

SHEETS: Final = {s.name: s for s in (MINI45, JOINT_TORQUES, ROBOT_ESTIMATE)}


def sheet(name: str) -> FtSheet:
    """The data sheet called ``name``; ConfigError naming the known ones."""
    try:
        return SHEETS[name]
    except KeyError:
        raise ConfigError(
            f"F/T sensor {name!r} unknown; known sensors: {', '.join(SHEETS)}"
        ) from None


def gravity_wrench(mass: float, com: np.ndarray, g_sensor: np.ndarray) -> np.ndarray:
    """The wrench (sensor frame, about its origin) a tool of ``mass`` with centre of mass
    ``com`` exerts on the sensor under gravity ``g_sensor`` (m/s², in the sensor frame):
    ``[m g; c × m g]`` (reference for SIO's compensation)."""
    f = mass * np.asarray(g_sensor, dtype=np.float64)
    return np.concatenate([f, np.cross(com, f)])
