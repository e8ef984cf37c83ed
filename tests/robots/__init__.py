"""Robot types (kali_daemons/robots), each against independent oracles; shared helpers here.

``numpy_data_allocations`` counts the data buffers numpy allocates while a function runs, by
installing a counting memory handler through numpy's public C API (NEP 49,
``PyDataMem_SetHandler``) with ctypes: exact where tracemalloc cannot tell a short-lived
numpy temporary from the Python floats and loop iterators around it.  Views and numpy
scalars own no buffer and are not counted.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

_MALLOC = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t)
_CALLOC = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t, ctypes.c_size_t)
_REALLOC = ctypes.CFUNCTYPE(ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t)
_FREE = ctypes.CFUNCTYPE(None, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_size_t)
_SET_HANDLER_SLOT = 304  # PyDataMem_SetHandler in numpy's C-API table (numpy >= 1.22)


class _Allocator(ctypes.Structure):
    _fields_ = [
        ("ctx", ctypes.c_void_p),
        ("malloc", _MALLOC),
        ("calloc", _CALLOC),
        ("realloc", _REALLOC),
        ("free", _FREE),
    ]


class _Handler(ctypes.Structure):
    _fields_ = [
        ("name", ctypes.c_char * 127),
        ("version", ctypes.c_uint8),
        ("allocator", _Allocator),
    ]


_libc = ctypes.CDLL(None)
_libc.malloc.restype = ctypes.c_void_p
_libc.malloc.argtypes = [ctypes.c_size_t]
_libc.calloc.restype = ctypes.c_void_p
_libc.calloc.argtypes = [ctypes.c_size_t, ctypes.c_size_t]
_libc.realloc.restype = ctypes.c_void_p
_libc.realloc.argtypes = [ctypes.c_void_p, ctypes.c_size_t]
_libc.free.argtypes = [ctypes.c_void_p]

_count = [0]


def _malloc(_ctx: int, size: int) -> int:
    _count[0] += 1
    return _libc.malloc(size or 1)


def _calloc(_ctx: int, n: int, size: int) -> int:
    _count[0] += 1
    return _libc.calloc(n or 1, size or 1)


def _realloc(_ctx: int, ptr: int, size: int) -> int:
    _count[0] += 1
    return _libc.realloc(ptr, size or 1)


def _free(_ctx: int, ptr: int, _size: int) -> None:
    _libc.free(ptr)


# Module-level, so the callbacks outlive every array allocated through them.
_CALLBACKS = (_MALLOC(_malloc), _CALLOC(_calloc), _REALLOC(_realloc), _FREE(_free))
_HANDLER = _Handler(b"kali_test_counting", 1, _Allocator(None, *_CALLBACKS))


def _capsule() -> object:
    new = ctypes.pythonapi.PyCapsule_New
    new.restype = ctypes.py_object
    new.argtypes = [ctypes.c_void_p, ctypes.c_char_p, ctypes.c_void_p]
    return new(ctypes.addressof(_HANDLER), b"mem_handler", None)


def _set_handler() -> Callable[[object], object]:
    from numpy._core import _multiarray_umath

    get = ctypes.pythonapi.PyCapsule_GetPointer
    get.restype = ctypes.c_void_p
    get.argtypes = [ctypes.py_object, ctypes.c_char_p]
    table = ctypes.cast(get(_multiarray_umath._ARRAY_API, None), ctypes.POINTER(ctypes.c_void_p))
    return ctypes.PYFUNCTYPE(ctypes.py_object, ctypes.py_object)(table[_SET_HANDLER_SLOT])


@contextmanager
def _counting() -> Iterator[list[int]]:
    set_handler = _set_handler()
    previous = set_handler(_capsule())
    try:
        yield _count
    finally:
        set_handler(previous)


def numpy_data_allocations(fn: Callable[[], object], calls: int = 50) -> int:
    """How many numpy data buffers ``calls`` calls of ``fn`` allocate, after one warm-up."""
    fn()
    with _counting() as count:
        start = count[0]
        for _ in range(calls):
            fn()
        return count[0] - start


def pin_model_of(facts: Any) -> Any:
    """Pinocchio's model of a type's URDF with its rotors and gravity (``facts``: the type's
    facts module: URDF_PATH, ARMATURE, GRAVITY)."""
    import numpy as np
    import pinocchio as pin

    model = pin.buildModelFromUrdf(str(facts.URDF_PATH))
    model.armature = np.array(facts.ARMATURE)
    model.gravity = pin.Motion(np.array([0.0, 0.0, -facts.GRAVITY]), np.zeros(3))
    return model


def mj_model_of(facts: Any) -> Any:
    """MuJoCo's model of the same URDF, rotors and gravity; contacts off (the links' shapes
    overlap)."""
    import mujoco

    model = mujoco.MjModel.from_xml_path(str(facts.URDF_PATH))
    model.dof_armature[:] = facts.ARMATURE
    model.opt.gravity[:] = (0.0, 0.0, -facts.GRAVITY)
    model.opt.disableflags |= mujoco.mjtDisableBit.mjDSBL_CONTACT
    return model


def mj_qpos_of(model: Any, n_joints: int) -> Any:
    """The qpos addresses of joints j1 .. jN in a MuJoCo model."""
    import numpy as np

    return np.array([model.joint(f"j{j + 1}").qposadr[0] for j in range(n_joints)])
