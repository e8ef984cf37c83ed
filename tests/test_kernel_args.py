"""The kernels' argument blocks are declared once (``kali_daemons.core.kernel_args``): the
checked-in ``kernel_args.h`` is what the declarations generate, and a library whose structs are
not the ctypes classes is refused at load, naming the block, the field and both offsets."""

from __future__ import annotations

import ctypes
import shutil
from collections.abc import Callable
from pathlib import Path

import pytest

from kali_daemons.core import kernel_args, kernels
from kali_daemons.core.errors import DaemonError


def test_the_checked_in_header_is_what_the_declarations_generate() -> None:
    """Edit ``kernel_args.py``, then ``python -m kali_daemons.core.kernel_args``: never the
    header."""
    assert kernel_args.HEADER.read_text() == kernel_args.header()


@pytest.mark.parametrize("library", list(kernel_args.LIBRARIES))
def test_every_kernel_has_a_declared_block_and_every_block_a_layout(library: str) -> None:
    """Each library lists every declared block with the ctypes class's fields, offsets,
    sizes and kinds, and its size; it holds its owners' kernels and no other owner's: the
    simulator's are in a library of their own."""
    lib = kernels.load(library)
    for name, struct in kernel_args.STRUCTS.items():
        found = kernels.block_fields(lib, name)
        assert found is not None, name
        fields, size = found
        assert fields == kernels.ctypes_fields(struct), name
        assert size == ctypes.sizeof(struct), name
    held = kernel_args.library_kernels(library)
    for name in kernel_args.KERNELS:
        assert hasattr(lib, name) == (name in held), (library, name)
    assert kernels.block_fields(lib, "NoSuchArgs") is None


def test_the_simulators_kernels_are_its_own() -> None:
    """The plant's kernels bind to the simulator's library, everything else to the
    controller's; a copy runs in either."""
    assert kernel_args.library_of("kali_motors") == "simulator"
    assert kernel_args.library_of("kali_sio_tick") == "controller"
    assert "kali_copy" in kernel_args.library_kernels("simulator")
    assert "kali_motors" not in kernel_args.library_kernels("controller")


def test_the_declarations_read_as_the_c_they_generate() -> None:
    """Several names on a row share its type, as in C; a section string is a comment."""
    read = next(b for b in kernel_args.BLOCKS if b.name == "ReadArgs")
    assert read.kernels == {"kali_read": "core.kernels:read_reference"}
    assert ("acc", "View") in read.fields() and ("prev", "View") in read.fields()
    assert "    View acc, prev; /* int32: accumulated counts, last 12-bit reading */" in (
        kernel_args.header()
    )
    sio = next(b for b in kernel_args.BLOCKS if b.name == "SioArgs")
    assert "per tick: from SIO, between the passes, to SIO" in sio.rows
    assert "    const int64_t *gang_sv, *gang_slot, *gang_lag;" in kernel_args.header()


def _doctored(tmp_path: Path, edit: Callable[[str], str]) -> Path:
    """The controller's library built from these sources with an edited kernel_args.h, in
    ``tmp_path``."""
    csrc = tmp_path / "csrc"
    shutil.copytree(kernels.CSRC, csrc)
    text = kernels.HEADER.read_text()
    edited = edit(text)
    assert edited != text
    (csrc / kernels.HEADER.name).write_text(edited)
    return kernels.build(tmp_path / "kernels-doctored.so", csrc / "controller.c")


def test_a_c_struct_with_an_extra_field_is_refused_at_load(tmp_path) -> None:
    """A field added on the C side only shifts every later one: the library is refused with
    the block, the first field moved and both its offsets."""
    start = "/* ReadArgs (sio): kali_read */\ntypedef struct {\n    int64_t n;\n"

    def extra(text: str) -> str:
        return text.replace(start, start + "    int64_t extra;\n")

    path = _doctored(tmp_path, extra)
    refused = (
        r"kernels-doctored.so does not match ReadArgs: field 'encoders' is at offset 16 "
        r"\(8 B, kind 'p'\) in C, offset 8 \(8 B, kind 'p'\) in ctypes"
    )
    with pytest.raises(DaemonError, match=refused):
        kernels.open_library(path)


def test_a_c_struct_of_another_type_is_refused_at_load(tmp_path) -> None:
    """A field of the same size but another type (a double become an int64) is refused by
    its kind."""
    gain = "    double gain; /* rate * a */"
    path = _doctored(tmp_path, lambda text: text.replace(gain, "    int64_t gain;"))
    refused = (
        r"VelocityArgs: field 'gain' is at offset 56 \(8 B, kind 'i'\) in C, "
        r"offset 56 \(8 B, kind 'f'\) in ctypes"
    )
    with pytest.raises(DaemonError, match=refused):
        kernels.open_library(path)


def test_a_ctypes_class_with_fields_swapped_is_refused() -> None:
    """A ctypes block whose fields are not the library's order is refused, whichever side
    moved: here the Python side, ``gain`` and ``b`` swapped (``b`` is met first)."""
    fields = list(kernel_args.STRUCTS["VelocityArgs"]._fields_)
    fields[-2], fields[-1] = fields[-1], fields[-2]
    swapped = type("VelocityArgs", (ctypes.Structure,), {"_fields_": fields})
    refused = (
        r"does not match VelocityArgs: field 'b' is at offset 64 \(8 B, kind 'f'\) in C, "
        r"offset 56 \(8 B, kind 'f'\) in ctypes"
    )
    with pytest.raises(DaemonError, match=refused):
        kernels.check_block(kernels.load(), kernels.library_path(), swapped)


def test_a_block_the_library_lacks_is_refused() -> None:
    """A ctypes class declared after the library was built (a stale header) is refused."""
    stale = type("NoSuchArgs", (ctypes.Structure,), {"_fields_": (("n", ctypes.c_int64),)})
    with pytest.raises(DaemonError, match="has no argument block NoSuchArgs"):
        kernels.check_block(kernels.load(), kernels.library_path(), stale)


def test_every_kernels_reference_is_declared_and_exists() -> None:
    """Each kernel's Python reference, as its declaration names it, imports and is callable;
    a kernel without one (a copy, the wrist sensor's handshake) says so with an empty name."""
    for name in kernel_args.KERNELS:
        found = kernel_args.reference(name)
        assert found is None or callable(found), name
    assert kernel_args.reference("kali_read") is kernels.read_reference
    assert kernel_args.reference("kali_copy") is None
