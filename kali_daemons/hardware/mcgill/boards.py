"""The McGill I/O board, as Kali drives it (thesis appendix C, 3.5): every register bit the
controller writes or reads lives here and nowhere else.

One board per arm (``registers.IO_BOARD``, ``registers.DAC_BOARD``), joint ``j`` on channel ``j``:
counters and DACs through ``driver.JointDriver``; the power switch (CSR bit 7 low disables,
overriding any enable; bit 3 held ``ENABLE_HOLD_MS`` enables); the watchdog, retriggered by a
high-then-low pulse on bit 5; index capture (bit 4 low); the potentiometers' ADC handshake
(``PotReader``); the LEDs; and the simulated cell's e-stop, gripper and conveyor lines.  Each
bit's meaning: docs/internals/robots-hardware-plant.md.

``McGillBoards`` is what SIO holds (the ``hardware.Hardware`` interface); ``cut_all``,
``press_estop``, ``estops_pressed`` and ``grip`` work on the register record from any process,
outside any cycle, without a lock (``raise_fault`` cuts the amplifiers through ``cut_all``
whoever holds what).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np

from ...core.arena import Arena
from ...core.errors import HardwareError
from ...core.kernels import Kernel, McgillArgs
from ...core.layout import PowerState
from ...robots import RobotType
from . import registers
from .driver import JointDriver
from .registers import (
    ADC_DONE,
    ADC_START,
    CSR_ENABLE,
    CSR_GREEN_LED_ON,
    CSR_INDEX_OFF,
    CSR_NO_DISABLE,
    CSR_RED_LED_OFF,
    CSR_RETRIGGER,
    CSR_TIMEOUT_ON,
    POWER_AMPS_ON,
    POWER_BRAKES_RELEASED,
)

if TYPE_CHECKING:
    from ...runtime.config import KaliConfig as CellConfig

BOARD_WAIT_S = 30.0  # how long SIO waits at start for the boards (the plant) to answer
ENABLE_HOLD_MS = 20.0  # enable bit held high this long (the relay needs ~15 ms, C.5.1)
# at rest: enables allowed, watchdog on, index capture off, red LED on, green off
BASE_CSR = CSR_NO_DISABLE | CSR_TIMEOUT_ON | CSR_INDEX_OFF


def retrigger_bit(servo_tick: int, hold_ticks: int) -> int:
    """The watchdog's retrigger bit at ``servo_tick``: high for ``hold_ticks``, low for as many
    (``retrigger_hold_ticks``), so every falling edge reaches the board (C.5)."""
    return CSR_RETRIGGER if (servo_tick // hold_ticks) % 2 == 0 else 0


def retrigger_hold_ticks(servo_period_ms: float, plant_period_ms: float) -> int:
    """How many servo ticks SIO holds the board's watchdog retrigger bit high, and then low
    ("one must set high state then low state to perform a retrigger", thesis C.5): the
    fewest that last two plant periods.  The simulated board reads its registers once a
    plant period, so a level held one 1 ms servo tick can fall between two reads, and when
    the plant reads just as SIO writes, every falling edge can be missed for 20 ms with SIO on
    time at every tick.  Held two reads long, each level is read at least once."""
    servo_ns, plant_ns = round(servo_period_ms * 1e6), round(plant_period_ms * 1e6)
    return max(1, -(-2 * plant_ns // servo_ns))


class PotReader:
    """Reads one arm's potentiometers, one per joint, through its board's TLC532A (C.5):
    START with the channel in the control register, wait for DONE in the analog register,
    START off, and wait for the board to withdraw DONE before the next channel.

    The board converts on START's rising edge and withdraws DONE when START falls, each at
    its own cycle.  Without the last wait, a board cycle that falls behind SIO's (the plant
    keeps its own time in real-time mode) never sees START fall between two channels: no
    rising edge, no conversion, and the previous channel's DONE read as this one's, so the
    joint would be calibrated from another joint's pot.
    """

    def __init__(self, control: np.ndarray, analog: np.ndarray, channels: int) -> None:
        self.control = control  # 0-d views of the board's ADC registers
        self.analog = analog
        self.channels = channels  # the arm's joints: one pot on each of its channels
        self.codes = [0] * channels
        self._channel = 0
        self._waiting = False  # START written for this channel, DONE not seen yet

    def restart(self) -> None:
        """Begin again at channel 0."""
        self._channel = 0
        self._waiting = False
        self.control[...] = 0

    def poll(self) -> bool:
        """One step, once per tick; True once every channel's code is in ``codes``."""
        c = self._channel
        if c >= self.channels:
            return True
        value = int(self.analog)
        if not self._waiting:
            if value & ADC_DONE:
                return False  # the board has not seen START fall since the last conversion
            self.control[...] = ADC_START | c
            self._waiting = True
            return False
        if not value & ADC_DONE:
            return False  # not converted yet
        self.codes[c] = value & registers.ADC_VALUE_MASK
        self.control[...] = 0
        self._waiting = False
        self._channel = c + 1
        return self._channel >= self.channels


class _Arm:
    """One board's registers, viewed once (indexing a record by field name builds a new view
    every time, which has no place in the cycle)."""

    __slots__ = ("codes", "csr", "encoder", "index", "pots", "power")

    def __init__(self, boards: np.ndarray, dacs: np.ndarray, k: int, n_joints: int) -> None:
        def one(field: str) -> np.ndarray:
            return boards[k : k + 1][field].reshape(())

        self.csr, self.index, self.power = one("csr"), one("index"), one("power")
        self.encoder = boards["encoder"][k]
        self.codes = dacs["code"][k, :n_joints]
        self.pots = PotReader(one("adc_control"), one("adc_analog"), n_joints)


class McGillBoards:
    """The cell's boards as SIO drives them, tick by tick (``hardware.Hardware``).

    ``boards`` and ``dacs`` are the register records (one per arm, config order); ``types``
    the arms' robot types; ``index_phase`` their calibration sheets, flat; ``hold_ticks``
    the servo ticks of the enable pulse and ``retrigger_ticks`` those of each retrigger level.
    """

    def __init__(
        self,
        boards: np.ndarray,
        dacs: np.ndarray,
        types: list[RobotType],
        index_phase: np.ndarray,
        hold_ticks: int,
        retrigger_ticks: int,
    ) -> None:
        self.driver = JointDriver(types, boards["encoder"], dacs["code"], index_phase=index_phase)
        self._arms = [_Arm(boards, dacs, k, t.n_joints) for k, t in enumerate(types)]
        self._power = boards["power"]  # every arm's power register (amps_register)
        self.hold_ticks = hold_ticks
        self.retrigger_ticks = retrigger_ticks
        self._boards, self._dacs, self._types = boards, dacs, types
        # end_tick's state: the servo ticks whose registers were written, the retrigger level
        # of this tick and of the last; in the control kernel's block once it is bound
        # (tick_kernels), so the kernel and this reference step the same fields
        self._state = McgillArgs(
            ticks=0,
            bit=retrigger_bit(1, retrigger_ticks),
            prev_bit=retrigger_bit(0, retrigger_ticks),
        )

    @classmethod
    def attach(
        cls,
        arena: Arena,
        cfg: CellConfig,
        servo_ticks: Callable[[float], int],
        semaphore: Callable[[str], object] | None = None,
    ) -> McGillBoards:
        """The cell's boards once every one answers (``BOARD_WAIT_S``), with the arms'
        calibration sheets (thesis 3.5.1) from ``cfg``; ``servo_ticks(ms)``: at least ``ms``
        of servo ticks (the boards wake no process: ``semaphore`` unused).  HardwareError if
        a board does not answer."""
        n = len(cfg.robots)
        boards = records(arena, n)
        if not boards_present(boards, BOARD_WAIT_S):
            raise HardwareError(
                f"mcgill: the boards did not answer within {BOARD_WAIT_S:g} s "
                "(is the plant running?)"
            )
        return cls(
            boards,
            dac_records(arena, n),
            [r.type for r in cfg.robots],
            np.concatenate([r.index_phases for r in cfg.robots]),
            hold_ticks=servo_ticks(ENABLE_HOLD_MS),
            retrigger_ticks=retrigger_hold_ticks(
                cfg.clock.servo_period_ms, cfg.process("plant").period_ms
            ),
        )

    # ------------------------------------------------------------------ set-up

    def start(self) -> None:
        """First start: registers at rest (enables allowed, amplifiers off, no conversion),
        the counters' readings taken as the reference."""
        self.driver.start()
        for arm in self._arms:
            arm.csr[...] = BASE_CSR
            arm.pots.control[...] = 0

    # ------------------------------------------------------------------ read and write

    def read(self, q: np.ndarray) -> None:
        """Joint angles (rad, flat) from the counters."""
        self.driver.read(q)

    def write(self, torque: np.ndarray, current: np.ndarray, clamped: np.ndarray) -> None:
        """Joint torques (N·m, flat) to the DACs; motor currents and clamping out."""
        self.driver.output(torque, current, clamped)

    def zero(self) -> None:
        """Every joint's DAC to 0 V (a halt)."""
        self.driver.zero()

    # ------------------------------------------------------------------ power (C.5.1)

    def amps_on(self, k: int) -> bool:
        """Whether arm ``k``'s amplifiers are on, as its board reports."""
        return bool(int(self._arms[k].power) & POWER_AMPS_ON)

    def amps_register(self) -> tuple[np.ndarray, int]:
        """The arms' power registers and the bit ``amps_on`` reads (``Hardware``)."""
        return self._power, POWER_AMPS_ON

    def powered(self, k: int) -> bool:
        """Whether arm ``k`` is ready to servo: amplifiers on and brakes released."""
        bits = int(self._arms[k].power)
        return bool(bits & POWER_AMPS_ON and bits & POWER_BRAKES_RELEASED)

    def power_text(self, k: int) -> str:
        """Arm ``k``'s power register for a message: ``0x16 (brakes released, ...)``."""
        return f"board power register {registers.power_text(int(self._arms[k].power))}"

    def control(self, k: int, power: int, enable_ticks: int, capture: bool, halted: bool) -> None:
        """Write arm ``k``'s command register for this tick: the power switch (the enable
        pulse for the first ``hold_ticks`` of ENABLING, the disable while halted or off with
        the amplifiers on), this tick's retrigger level, index capture and the LEDs; DACs at
        0 V while the arm is off."""
        arm = self._arms[k]
        csr = BASE_CSR | self._state.bit
        if power == PowerState.ON and not halted:
            csr |= CSR_GREEN_LED_ON | CSR_RED_LED_OFF
        if halted:
            csr &= ~CSR_NO_DISABLE
        elif power == PowerState.ENABLING and enable_ticks <= self.hold_ticks:
            csr |= CSR_ENABLE
        if capture:
            csr &= ~CSR_INDEX_OFF  # index capture on: the pulse resets the counter (C.3)
        if power == PowerState.OFF:
            arm.codes[:] = registers.DAC_ZERO
            if int(arm.power) & POWER_AMPS_ON:
                csr &= ~CSR_NO_DISABLE  # bit 7 low cuts the amplifiers (disable, C.5.1)
        arm.csr[...] = csr

    def end_tick(self) -> bool:
        """After every arm's ``control``: True when this tick's writes were a retrigger
        (the level fell, C.4)."""
        st = self._state
        fell = bool(st.prev_bit) and not st.bit
        st.ticks += 1
        st.prev_bit, st.bit = st.bit, retrigger_bit(st.ticks + 1, self.retrigger_ticks)
        return fell

    @property
    def ticks(self) -> int:
        """Servo ticks whose registers were written (``end_tick``)."""
        return int(self._state.ticks)

    def tick_kernels(
        self,
        power: np.ndarray,
        enable_ticks: np.ndarray,
        capture: np.ndarray,
        fault_active: np.ndarray,
    ) -> tuple[Kernel, Kernel, Kernel]:
        """``Hardware.tick_kernels``: the driver's read and DAC kernels, and ``control``
        for every arm then ``end_tick`` compiled (``kali_mcgill_control``).  From now on
        ``control`` and ``end_tick`` step the control kernel's state."""
        read, dac = self.driver.kernels()
        return read, dac, self._control_kernel(power, enable_ticks, capture, fault_active)

    def _control_kernel(
        self,
        power: np.ndarray,
        enable_ticks: np.ndarray,
        capture: np.ndarray,
        fault_active: np.ndarray,
    ) -> Kernel:
        st = self._state
        codes = self._dacs["code"]
        kernel = Kernel(
            "kali_mcgill_control",
            (self._boards, self._dacs, capture, fault_active),
            n_arms=len(self._arms),
            csr=self._boards["csr"],
            power_reg=self._power,
            power=power,
            enable_ticks=enable_ticks,
            capture=capture,
            codes=codes.ctypes.data,
            codes_row=codes.strides[0],
            n_joints=np.array([t.n_joints for t in self._types], dtype=np.int64),
            fault_active=fault_active.ctypes.data,
            base_csr=BASE_CSR,
            green_red=CSR_GREEN_LED_ON | CSR_RED_LED_OFF,
            no_disable=CSR_NO_DISABLE,
            enable=CSR_ENABLE,
            index_off=CSR_INDEX_OFF,
            amps_on=POWER_AMPS_ON,
            on=PowerState.ON,
            enabling=PowerState.ENABLING,
            off=PowerState.OFF,
            hold_ticks=self.hold_ticks,
            dac_zero=registers.DAC_ZERO,
            retrigger=CSR_RETRIGGER,
            retrigger_ticks=self.retrigger_ticks,
            ticks=st.ticks,
            bit=st.bit,
            prev_bit=st.prev_bit,
        )
        self._state = kernel.args
        return kernel

    def close(self) -> None:
        """Nothing opened."""

    # ------------------------------------------------------------------ calibration (3.5.1)

    def gauges(self, k: int) -> np.ndarray:
        """Arm ``k``'s wrist sensor's gauge ADC registers (0-d: ``ft_gauge``, ``ft_control``,
        ``ft_status``; ``ftsensor``), on its board."""
        return self._boards[k : k + 1].reshape(())

    def gauge_cycles(self, k: int) -> np.ndarray | None:
        """Arm ``k``'s board's scans (``scans``): the board is simulated, and one the plant
        does not run answers no request (the clock judges the plant for that)."""
        return self._boards["scans"][k : k + 1].reshape(())

    def wrench(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        raise HardwareError("mcgill: a board gives no wrench of its own (a sensor's gauges do)")

    def pots(self, k: int) -> PotReader:
        """Arm ``k``'s potentiometer reader."""
        return self._arms[k].pots

    def absolute_angles(self, k: int) -> str | None:
        """One step of reading arm ``k``'s pots at start (``PotReader``); once every joint's
        is read, the driver's angles set from them (coarse: the pots' 8 bits, 3.5.1)."""
        reader = self._arms[k].pots
        if not reader.poll():
            return None
        base = sum(t.n_joints for t in self._types[:k])
        for j in range(reader.channels):
            self.driver.set_angle(base + j, self.driver.pot_angle(base + j, reader.codes[j]))
        return "joint angles from the potentiometers (not calibrated)"

    def index_hits(self, k: int) -> int:
        """Arm ``k``'s index register: bit j set once joint j's pulse reset its counter."""
        return int(self._arms[k].index)

    def at_index(self, k: int, j: int, i: int, angle: float) -> None:
        """Arm ``k``'s joint ``j`` (flat joint ``i``) passed its index pulse: count from it,
        the pulse reading ``angle`` (``JointDriver.at_index`` with this tick's counter)."""
        self.driver.at_index(i, int(self._arms[k].encoder[j]), angle)


# ---------------------------------------------------------------------------------------------
# From any process, outside any cycle, on the register record (``records``, ``McGillOps``)


def records(arena: Arena, n_robots: int) -> np.ndarray:
    """The I/O board registers, one record per robot (laid out by ``kalictl start``, answered
    by the plant); ArenaError if they are not laid out."""
    return arena.existing(registers.KEY_BOARDS, registers.IO_BOARD, n_robots)


def dac_records(arena: Arena, n_robots: int) -> np.ndarray:
    """The DAC board registers, one record per robot."""
    return arena.existing(registers.KEY_DACS, registers.DAC_BOARD, n_robots)


class McGillOps:
    """The boards' operations outside any cycle (``hardware.Operations``): from any process,
    on the register record, without a lock."""

    def __init__(self, arena: Arena, n_robots: int) -> None:
        self._arena, self._n = arena, n_robots
        self._boards: np.ndarray | None = None  # viewed once laid out

    def _view(self) -> np.ndarray | None:
        if self._boards is None and self._arena.lookup(registers.KEY_BOARDS) is not None:
            self._boards = records(self._arena, self._n)
        return self._boards

    def cut(self) -> None:
        boards = self._view()
        if boards is not None:  # not laid out: nothing is powered
            cut_all(boards)

    def reset(self) -> None:
        """Nothing: SIO's next tick writes the disable bit back up (the halt is cleared)."""

    def amplifiers_cut(self) -> list[bool]:
        boards = self._view()
        return [False] * self._n if boards is None else amplifiers_cut(boards.copy())

    def press_estop(self, k: int, pressed: bool) -> None:
        boards = self._view()
        if boards is not None:
            press_estop(boards, k, pressed)

    def estops_pressed(self) -> list[bool]:
        boards = self._view()
        return [False] * self._n if boards is None else estops_pressed(boards)

    def grip(self, k: int, close: bool) -> int:
        grip(records(self._arena, self._n), k, close)
        return 0  # a line: set at once, no outcome reported

    def grip_result(self, k: int, ticket: int) -> bool | None:
        return True

    def run_conveyor(self, run: bool) -> None:
        run_conveyor(records(self._arena, self._n), run)

    def link_status(self, k: int) -> str:
        return ""  # the boards are registers: no link

    def link_text(self, k: int) -> str:
        return ""


def boards_present(boards: np.ndarray, timeout_s: float) -> bool:
    """Wait up to ``timeout_s`` until every board answers (its ``present`` register is set:
    the plant has laid out its registers; a real board would from power-up)."""
    deadline = time.monotonic() + timeout_s
    while not boards["present"].all():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.005)
    return True


def cut_all(boards: np.ndarray) -> None:
    """Disable every arm's amplifiers (CSR bit 7 low overrides any enable); no lock taken."""
    csr = boards["csr"]
    csr &= ~np.uint8(CSR_NO_DISABLE)


def press_estop(boards: np.ndarray, k: int, pressed: bool) -> None:
    """Press (or release) arm ``k``'s emergency-stop button: the board cuts its amplifiers
    while pressed."""
    boards["estop"][k] = 1 if pressed else 0


def amplifiers_cut(boards: np.ndarray) -> list[bool]:
    """Each arm's amplifiers off or being cut, whatever SIO has seen yet: the board reports
    them off, its disable bit is low (a halt, ``cut_all``) or its e-stop is pressed."""
    off = (boards["power"] & POWER_AMPS_ON) == 0
    disabled = (boards["csr"] & CSR_NO_DISABLE) == 0
    return [bool(v) for v in off | disabled | (boards["estop"] != 0)]


def estops_pressed(boards: np.ndarray) -> list[bool]:
    """Each arm's e-stop button: True while pressed."""
    return [bool(b) for b in boards["estop"]]


def run_conveyor(boards: np.ndarray, run: bool) -> None:
    """Start (or stop) the conveyor belt: its motor's line on the first arm's board (the
    simulated cell's ``plant.conveyor_m_s``)."""
    boards["conveyor"][0] = 1 if run else 0


def grip(boards: np.ndarray, k: int, close: bool) -> None:
    """Close (or open) arm ``k``'s gripper."""
    boards["gripper"][k] = 1 if close else 0
