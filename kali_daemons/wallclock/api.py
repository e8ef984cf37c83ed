"""The wall clock functions of thesis 3.6.2, callable from any process of an instance.

``control`` makes a function a periodic process, blocking: the calling process becomes it
(``client.Kali.control`` runs one in a thread of a program that goes on instead);
``set_control_rate`` changes a process's period; ``start_kali_clock``/``stop_kali_clock``/
``set_kali_clock`` run, halt and set the clock; ``step_kali_clock`` advances a lockstep
instance by a number of ticks (single-stepping, which the thesis names as a use of
``set_control_rate``); ``release`` ends a periodic function from another process.
"""

from __future__ import annotations

import time
from collections.abc import Callable

from ..core import futex
from ..core.errors import ClockError
from ..core.layout import ClockCommand, RunMode
from ..runtime.config import MAX_PERIOD_MS, ms_to_ns, ns_to_ms, period_ticks
from ..runtime.daemon import FunctionDaemon
from ..runtime.instance import Instance, decode

COMMAND_TIMEOUT_S = 5.0
WAIT_SLICE_S = 0.01  # a program waiting on the clock looks at its other reasons this often


def _command(inst: Instance, cmd: ClockCommand, arg: float = 0.0) -> None:
    """Hand one command to the wall clock and wait until it has applied it.

    START and STEP are refused here at once while a fault is active, with the clock's own
    words: the fault may be a clock that no longer takes commands (a lockstep executive
    stuck in a daemon's cycle), and the answer is the fault, not a timeout."""
    c = inst.clock
    fault = inst.fault_text()
    if cmd in (ClockCommand.START, ClockCommand.STEP) and fault:
        raise ClockError(f"fault active, kalictl reset first: {fault}")
    with inst.cmd_lock:
        c["cmd"] = int(cmd)
        c["cmd_arg"] = arg
        seq = int(c["cmd_seq"]) + 1
        c["cmd_seq"] = seq
        inst.command_semaphore().release()
        deadline = time.monotonic() + COMMAND_TIMEOUT_S
        waiter, done_addr = futex.Waiter(WAIT_SLICE_S), c["cmd_done"].ctypes.data
        while (done := int(c["cmd_done"])) < seq:
            if inst.shutting_down:  # the clock has left (kalictl stop): nobody will take it
                raise ClockError(f"{cmd.name}: instance '{inst.name}' was stopped")
            if time.monotonic() > deadline:
                fault = inst.fault_text()
                raise ClockError(
                    f"wall clock (pid {int(c['pid'])}) did not take command {cmd.name} "
                    f"within {COMMAND_TIMEOUT_S:g} s; "
                    + (f"the system is halted: {fault}" if fault else "is it running?")
                )
            waiter.wait(done_addr, done)  # the clock wakes it as it takes the command
        if int(c["cmd_status"]) != 0:
            raise ClockError(decode(c["cmd_message"]))


def start_kali_clock(inst: Instance) -> None:
    """Run the clock: every periodic process is signalled again (thesis 3.6.2)."""
    _command(inst, ClockCommand.START)


def stop_kali_clock(inst: Instance) -> None:
    """Stop the clock: no periodic process is signalled until it is started."""
    _command(inst, ClockCommand.STOP)


def set_kali_clock(inst: Instance, time_ms: float) -> None:
    """Set the running time (ms) the clock reports from now on."""
    _command(inst, ClockCommand.SET_TIME, float(time_ms))


def step_kali_clock(inst: Instance, ticks: int, wait: bool = True, timeout: float = 600.0) -> int:
    """Lockstep: run ``ticks`` more ticks, then stop; returns the tick reached."""
    if ticks < 0:
        raise ClockError(f"step of {ticks} ticks: must be >= 0")
    _command(inst, ClockCommand.STEP, float(ticks))
    if wait:
        target = int(inst.clock["step_target"])
        deadline = time.monotonic() + timeout
        waiter, mode_addr = futex.Waiter(WAIT_SLICE_S), inst.clock["mode"].ctypes.data
        while (mode := int(inst.clock["mode"])) != RunMode.STOPPED:
            if inst.shutting_down:
                raise ClockError(f"step to tick {target}: instance '{inst.name}' was stopped")
            if time.monotonic() > deadline:
                raise ClockError(f"step to tick {target} not finished within {timeout:g} s")
            waiter.wait(mode_addr, mode)  # the clock wakes it once stopped
    return int(inst.clock["tick"])


def check_period(inst: Instance, what: str, period_ms: object) -> int:
    """``period_ms`` in base ticks: a whole multiple of the base tick (which may be a
    fraction of a ms: 1.5 with a 0.5 ms tick is 3 ticks) up to MAX_PERIOD_MS; ClockError
    starting with ``what`` otherwise."""
    base_ms = ns_to_ms(int(inst.clock["base_tick_ns"]))
    try:
        if isinstance(period_ms, bool) or not isinstance(period_ms, int | float):
            raise ValueError(period_ms)
        ticks = period_ticks(period_ms, base_ms)
    except ValueError:
        raise ClockError(
            f"{what}: {period_ms!r:.60} ms must be a whole multiple of the {base_ms} ms base tick"
        ) from None
    if ticks * int(inst.clock["base_tick_ns"]) > ms_to_ns(MAX_PERIOD_MS):
        raise ClockError(
            f"{what}: period {period_ms:g} ms is longer than {MAX_PERIOD_MS} ms, "
            f"the longest a Kali process may have"
        )
    return ticks


def set_control_rate(inst: Instance, process: str, period_ms: float) -> None:
    """Change the period of ``process`` to ``period_ms`` (a whole multiple of the base tick,
    which may be a fraction of a ms: 1.5 with a 0.5 ms tick is 3 ticks).

    A TG period is at least the servo period: SIO spends one servo tick or more on each
    set-point (the FIFO ratio, thesis 2.2.2, is >= 1).  The TG follows its new period from
    its next tick, and its FIFOs from the next set-point it pushes.
    """
    ticks = check_period(inst, f"rate of '{process}'", period_ms)
    i = inst.slot_of(process)
    if not inst.procs[i]["periodic"]:
        raise ClockError(f"process '{process}' is not driven by the wall clock")
    cfg = inst.config
    servo_ms = cfg.clock.servo_period_ms
    kind = next((p.kind for p in cfg.processes if p.name == process), "")
    if kind in ("sio", "sv"):
        raise ClockError(
            f"rate of '{process}': the servo period ({servo_ms:g} ms) is fixed while Kali runs "
            f"(the servos' gains, filters and the FIFO ratio are set for it); change "
            f"clock.servo_period_ms in the config and restart"
        )
    is_tg = kind == "tg"
    if is_tg and ticks * int(inst.clock["base_tick_ns"]) < ms_to_ns(servo_ms):
        raise ClockError(
            f"rate of '{process}': period {period_ms:g} ms is shorter than the servo period "
            f"{servo_ms:g} ms; the TG must run at most as fast as the servos (FIFO ratio >= 1)"
        )
    inst.procs[i]["period_ticks"] = ticks
    inst.bump_rates()


def control(
    instance: str,
    func: Callable[[int], object],
    *,
    name: str,
    serious: bool = False,
    period_ms: float = 1,
    stage: int = 8,
    cpu: int | None = None,
    priority: int = 0,
) -> int:
    """Run ``func(tick)`` as a periodic process of ``instance`` until it is released.

    Blocks the calling process, which must call it from its main thread (it becomes the
    periodic process, as in the thesis, and takes SIGTERM and SIGINT to leave); the function
    returning ``False`` releases it, as do ``release`` from another process and ``kalictl
    stop``.  Returns the exit status (0, or 1 if the function raised: the system then halts
    with the reason, serious or not).  A program that goes on meanwhile uses
    ``client.Kali.control``, which runs the function in a thread.
    """
    daemon = FunctionDaemon(
        instance,
        name,
        func,
        period_ms=period_ms,
        serious=serious,
        stage=stage,
        cpu=cpu,
        priority=priority,
        lock_memory=False,
    )
    return daemon.main()


def release(inst: Instance, process: str) -> None:
    """Stop the wall clock from signalling ``process`` (thesis ``release``, from another
    process): a function a program registered with ``control``, which then ends within
    ``daemon.IDLE_WAIT_S``.  (A program ends its own with ``Control.release(message)``.)
    Kali's own daemons are refused (ClockError): a released SIO would leave the arms
    unservoed with nothing noticing; ``kalictl stop`` ends them."""
    daemons = [p.name for p in inst.config.processes]
    if process in daemons:
        raise ClockError(
            f"release: '{process}' is one of Kali's daemons ({', '.join(daemons)}), not a "
            f"function registered with control(); kalictl stop ends them"
        )
    i = inst.slot_of(process)
    inst.procs[i]["periodic"] = 0
    inst.bump_registry()
