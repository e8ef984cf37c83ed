"""Atomic operations on arena words, through Debian's libatomic (thesis appendix A, 3.6.1).

Through ctypes into ``libatomic.so.1``, several times cheaper than the ``atomics`` PyPI
package (``scripts/bench_atomic.py``; docs/decisions/0005-atomics-through-libatomic.md).
Only naturally aligned 4- and 8-byte words are used: those are lock-free on x86-64 and so
atomic across processes sharing the mapping.

Every function takes an absolute address (``Arena.address(offset)``); callers keep offsets
and convert once.  All operations are sequentially consistent.
"""

from __future__ import annotations

import ctypes
import ctypes.util

from .errors import KaliError

_SEQ_CST = 5


class AtomicError(KaliError):
    """libatomic could not be loaded."""

    subsystem = "atomic"


def _load_libatomic() -> ctypes.CDLL:
    name = ctypes.util.find_library("atomic") or "libatomic.so.1"
    try:
        return ctypes.CDLL(name)
    except OSError as exc:  # pragma: no cover - depends on the machine
        raise AtomicError(
            f"cannot load {name} ({exc}); install Debian's libatomic1 (apt-get install libatomic1)"
        ) from exc


_lib = _load_libatomic()


def _fn(name: str, restype: type | None, *argtypes: type):
    fn = getattr(_lib, name)
    fn.restype = restype
    fn.argtypes = list(argtypes)
    return fn


_u32, _u64, _ptr, _int = ctypes.c_uint32, ctypes.c_uint64, ctypes.c_void_p, ctypes.c_int

_load4 = _fn("__atomic_load_4", _u32, _ptr, _int)
_store4 = _fn("__atomic_store_4", None, _ptr, _u32, _int)
_xchg4 = _fn("__atomic_exchange_4", _u32, _ptr, _u32, _int)
_cas4 = _fn("__atomic_compare_exchange_4", ctypes.c_bool, _ptr, _ptr, _u32, _int, _int)
_add4 = _fn("__atomic_fetch_add_4", _u32, _ptr, _u32, _int)
_load8 = _fn("__atomic_load_8", _u64, _ptr, _int)
_store8 = _fn("__atomic_store_8", None, _ptr, _u64, _int)
_add8 = _fn("__atomic_fetch_add_8", _u64, _ptr, _u64, _int)
_cas8 = _fn("__atomic_compare_exchange_8", ctypes.c_bool, _ptr, _ptr, _u64, _int, _int)


def load32(addr: int) -> int:
    """Atomically read the 32-bit word at ``addr``."""
    return _load4(addr, _SEQ_CST)


def store32(addr: int, value: int) -> None:
    """Atomically write the 32-bit word at ``addr`` (a full barrier)."""
    _store4(addr, value, _SEQ_CST)


def exchange32(addr: int, value: int) -> int:
    """Atomically write ``value`` and return the previous word: the test-and-set primitive."""
    return _xchg4(addr, value, _SEQ_CST)


class CompareExchange32:
    """Compare-and-swap on 32-bit words with a preallocated ``expected`` cell.

    libatomic writes the observed value back through a pointer; keeping one cell per user
    avoids allocating it on every call inside a cycle.  Not shared between threads.
    """

    __slots__ = ("_cell", "_cell_addr")

    def __init__(self) -> None:
        self._cell = ctypes.c_uint32(0)
        self._cell_addr = ctypes.addressof(self._cell)

    def __call__(self, addr: int, expected: int, desired: int) -> tuple[bool, int]:
        """Swap in ``desired`` if the word equals ``expected``; return (swapped, observed)."""
        self._cell.value = expected
        ok = _cas4(addr, self._cell_addr, desired, _SEQ_CST, _SEQ_CST)
        return bool(ok), self._cell.value


class CompareExchange64:
    """Compare-and-swap on 64-bit words, like ``CompareExchange32``."""

    __slots__ = ("_cell", "_cell_addr")

    def __init__(self) -> None:
        self._cell = ctypes.c_uint64(0)
        self._cell_addr = ctypes.addressof(self._cell)

    def __call__(self, addr: int, expected: int, desired: int) -> tuple[bool, int]:
        """Swap in ``desired`` if the word equals ``expected``; return (swapped, observed)."""
        self._cell.value = expected
        ok = _cas8(addr, self._cell_addr, desired & 0xFFFFFFFFFFFFFFFF, _SEQ_CST, _SEQ_CST)
        return bool(ok), self._cell.value


def fetch_add32(addr: int, delta: int) -> int:
    """Atomically add ``delta`` (mod 2**32) and return the previous value."""
    return _add4(addr, delta & 0xFFFFFFFF, _SEQ_CST)


def load64(addr: int) -> int:
    """Atomically read the 64-bit word at ``addr``."""
    return _load8(addr, _SEQ_CST)


def store64(addr: int, value: int) -> None:
    """Atomically write the 64-bit word at ``addr`` (a full barrier)."""
    _store8(addr, value & 0xFFFFFFFFFFFFFFFF, _SEQ_CST)


def fetch_add64(addr: int, delta: int) -> int:
    """Atomically add ``delta`` (mod 2**64) and return the previous value."""
    return _add8(addr, delta & 0xFFFFFFFFFFFFFFFF, _SEQ_CST)
