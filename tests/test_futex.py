"""futex.py: a wait on an arena word ends at the writer's wake, or at its timeout, and at once
when the word no longer holds what the waiter saw."""

from __future__ import annotations

import threading
import time

import numpy as np

from kali_daemons.core import futex
from kali_daemons.core.arena import Arena


def test_a_wait_ends_at_the_wake_not_the_timeout(arena: Arena) -> None:
    word = arena.record("w", np.dtype("<u4"), 1)
    addr = word.ctypes.data
    waiter = futex.Waiter(5.0)

    def writer() -> None:
        time.sleep(0.05)
        word[0] = 1
        futex.wake(addr)

    t = threading.Thread(target=writer)
    t0 = time.monotonic()
    t.start()
    while int(word[0]) == 0:
        waiter.wait(addr, 0)
    took = time.monotonic() - t0
    t.join()
    assert 0.04 < took < 1.0, took


def test_a_wait_on_a_changed_word_returns_at_once_and_an_unwoken_one_at_its_timeout(
    arena: Arena,
) -> None:
    word = arena.record("w", np.dtype("<u4"), 1)
    word[0] = 7
    t0 = time.monotonic()
    futex.Waiter(5.0).wait(word.ctypes.data, 6)  # not 6 any more: no sleep
    assert time.monotonic() - t0 < 0.5
    t0 = time.monotonic()
    futex.Waiter(0.05).wait(word.ctypes.data, 7)  # nobody wakes it
    assert 0.04 < time.monotonic() - t0 < 1.0
