"""The McGill I/O board's registers (thesis appendix C): every bit and record of it, laid out
in the arena per arm as this kind's records (``RECORDS``), so that nothing outside this
package knows the board.

Each record is an array with one entry per robot in the config's order (the rack of boards),
so the plant and SIO touch every arm's registers with one array operation.  A real board could
replace the plant by implementing these records (DESIGN 6, thesis 3.7).
"""

from __future__ import annotations

import numpy as np

from ...core.layout import WRENCH, Record

KEY_BOARDS = "hw.mcgill.boards"  # McGill I/O boards, IO_BOARD per robot
KEY_DACS = "hw.mcgill.dacs"  # DAC boards, DAC_BOARD per robot

# Command/status register bits (appendix C.5.1).  Note the inverted senses of the thesis.
CSR_RED_LED_OFF = 1 << 0  # 0 = red LED on, 1 = off
CSR_GREEN_LED_ON = 1 << 1  # 1 = green LED on
CSR_INTERRUPT = 1 << 2  # read only, reserved
CSR_ENABLE = 1 << 3  # hold high ~15 ms, then low: enables the robot (power switch relay)
CSR_INDEX_OFF = 1 << 4  # 0 = index pulse capture enabled, 1 = disabled (and cleared)
CSR_RETRIGGER = 1 << 5  # high then low retriggers the watchdog
CSR_TIMEOUT_ON = 1 << 6  # 1 = safety timeout (watchdog) on
CSR_NO_DISABLE = 1 << 7  # 0 = robot disabled, overriding enables; 1 = allows enables

# Power status: the Robot Power Switch circuit's state as the board reports it (an addition:
# the original CSR did not expose it; a real board would latch it in a spare register).
POWER_AMPS_ON = 1 << 0  # amplifiers enabled
POWER_BRAKES_RELEASED = 1 << 1  # brake solenoids released (0: brakes holding)
POWER_WATCHDOG_TRIPPED = 1 << 2  # the watchdog timed out; cleared by a retrigger
POWER_ESTOP = 1 << 3  # the emergency-stop input is pressed
POWER_BUZZER = 1 << 4  # the timeout buzzer sounds
_POWER_NAMES = (
    (POWER_AMPS_ON, "amplifiers on"),
    (POWER_BRAKES_RELEASED, "brakes released"),
    (POWER_WATCHDOG_TRIPPED, "watchdog tripped"),
    (POWER_ESTOP, "e-stop pressed"),
    (POWER_BUZZER, "buzzer"),
)


def power_text(bits: int) -> str:
    """The board power register as a fault message gives it: ``0x16 (brakes released,
    watchdog tripped, buzzer)``; never in a cycle (it builds a string)."""
    names = [name for bit, name in _POWER_NAMES if bits & bit] or ["amplifiers off"]
    return f"0x{bits:02x} ({', '.join(names)})"


# TLC532A analog register: bit 8 = conversion complete, low 8 bits = value (±1/2 LSB).
ADC_START = 1 << 7  # control register: start a conversion of channel (bits 0-3)
ADC_CHANNEL_MASK = 0x0F
ADC_DONE = 1 << 8
ADC_VALUE_MASK = 0xFF

BOARD_CHANNELS = 8  # encoder/pot channels per board
DAC_CHANNELS = 8
DAC_BITS = 12
DAC_ZERO = 1 << (DAC_BITS - 1)  # offset binary: 0 = -10 V, 2048 = 0 V, 4095 = +9.995 V

IO_BOARD = np.dtype(
    [
        ("encoder", "<u2", (BOARD_CHANNELS,)),  # plant: HCTL-2000 counters, low 12 bits
        ("index", "u1"),  # plant: index capture register, bit j = channel j captured
        ("csr", "u1"),  # Kali: command/status register, CSR_* bits
        ("power", "u1"),  # plant: POWER_* bits
        ("estop", "u1"),  # operator: emergency-stop button (kalictl estop), 1 = pressed
        ("adc_control", "<u2"),  # Kali: TLC532A control register
        ("adc_digital", "<u2"),  # plant: TLC532A digital register, bit j = channel j > 2.5 V
        ("adc_analog", "<u2"),  # plant: TLC532A analog register, ADC_DONE | value
        ("gripper", "u1"),  # Kali: 1 = close the gripper (weld to the object if in reach)
        ("present", "u1"),  # plant: 1 once the board answers (its registers are valid)
        ("conveyor", "u1"),  # Kali: 1 = run the conveyor belt's motor (the first arm's board)
        ("_pad", "u1"),
        ("clamped", "<u4"),  # plant: out-of-range register values clamped, as hardware does
        ("scans", "<u4"),  # plant: the board's scans of its registers, one a plant cycle
        # the wrist F/T sensor's gauge ADC bank (ftsensor.py): one simultaneous sample of its
        # six bridges per request, signed 16-bit codes over ±10 V
        ("ft_gauge", "<i2", (WRENCH,)),  # plant: the codes of the sample ft_status names
        ("ft_control", "<u2"),  # Kali: FT_REQUEST | seq asks for a new sample
        ("ft_status", "<u2"),  # plant: FT_READY | FT_PRESENT | seq once that sample is in
    ],
    align=True,
)

DAC_BOARD = np.dtype(
    [
        ("code", "<u2", (DAC_CHANNELS,)),  # Kali: 12-bit offset-binary codes; more is clamped
        ("clamped", "<u4"),  # plant: codes above 4095 clamped
    ],
    align=True,
)


RECORDS: tuple[Record, ...] = (
    Record(KEY_BOARDS, IO_BOARD, lambda c, i: len(c.robots), "SIO and the plant", "SIO"),
    Record(KEY_DACS, DAC_BOARD, lambda c, i: len(c.robots), "SIO", "the plant"),
)
