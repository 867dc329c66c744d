"""MATLAB files: v5/v7 (read with scipy.io) and v7.3 (HDF5, see :mod:`fnsi.formats.hdf5`).

Variables are those of the canonical NPZ: ``u`` (samples x m), ``y`` (samples x l),
``fs``; optional ``input_names``, ``output_names``, ``input_units``, ``output_units``
(char matrix or cell array of char vectors), ``periods``, ``quantity``. The ``iddata``
spellings ``InputData``, ``OutputData``, ``Ts``, ``InputName``, ``OutputName``,
``InputUnit``, ``OutputUnit`` and ``Fs`` are read as those
(:data:`fnsi.formats.fields.MATLAB_SPELLINGS`); an ``iddata`` object itself is not (its
class is MATLAB's own), and the message says which fields to save instead.

A v5 file is a 128-byte header and one data element per variable, each usually
zlib-compressed. Before scipy decodes anything, this reader walks the elements itself,
decompressing only each one's first bytes for its name, class and dimensions, refuses
what the layout forbids (cells or structs for ``u``/``y``, complex or sparse samples)
and checks the declared sizes and channels; it then counts what the variables it uses
really decompress to (in bounded pieces, stopping at the limit), and hands scipy a copy
of the file holding only those variables.
"""

from __future__ import annotations

import io
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import scipy.io

from fnsi.formats import hdf5
from fnsi.formats.fields import (
    MATLAB_SPELLINGS,
    ReadOptions,
    canonical,
    spelling_hint,
    strings,
)
from fnsi.formats.limits import FLOAT_BYTES, DecodeLimits, array_bytes

_FILE_HEADER = 128
_MI_MATRIX, _MI_COMPRESSED = 14, 15
_HEAD_BYTES = 4096  # decompressed bytes enough for flags, 1000 dimensions and a name
_PIECE = 1 << 20
_CELL, _STRUCT, _OBJECT, _CHAR, _SPARSE = 1, 2, 3, 4, 5
# MATLAB array classes holding numbers (mxDOUBLE_CLASS .. mxUINT64_CLASS), bytes per item
_NUMERIC = {6: 8, 7: 4, 8: 1, 9: 1, 10: 2, 11: 2, 12: 4, 13: 4, 14: 8, 15: 8}
_CLASS_NAMES = {_CELL: "cell array", _STRUCT: "struct", _OBJECT: "object", _CHAR: "char array",
                _SPARSE: "sparse matrix"}
_MAX_VARIABLES = 4096  # top-level elements walked; a file of many tiny ones costs time only
_RECORDS = ("u", "y")
_USED = ("u", "y", "fs", "periods", "quantity", "input_names", "output_names", "input_units",
         "output_units")
_TEXT = ("input_names", "output_names", "input_units", "output_units")
_IDDATA_HINT = ("; an iddata object cannot be read (its class is MATLAB's own): save its "
                "fields, e.g. InputData = data.InputData; OutputData = data.OutputData; "
                "Ts = data.Ts; save('run.mat', 'InputData', 'OutputData', 'Ts')")


def _role(name: str) -> str:
    """The canonical variable a MATLAB variable name stands for (itself if none)."""
    return MATLAB_SPELLINGS.get(name, name)


@dataclass(frozen=True)
class _Variable:
    """One top-level data element of a v5 file."""

    name: str
    mclass: int
    complex: bool
    dims: tuple[int, ...]
    start: int          # file offset of the element's tag
    end: int            # file offset after the element
    compressed: bool


def read_fields(path: Path, limits: DecodeLimits,
                options: ReadOptions | None = None) -> dict[str, Any]:
    """Variables of a MATLAB file after its headers passed the checks (``options``: the
    group of a v7.3 file).

    Raises
    ------
    ValueError
        Not a MATLAB file, or a layout the reader cannot use (the message says which).
    DecodeLimitError
        Decoded size or channels beyond ``limits``.
    """
    if h5py.is_hdf5(path):  # v7.3
        return hdf5.read_fields(path, limits, matlab=True,
                                group=None if options is None else options.group)
    with open(path, "rb") as f:
        header = f.read(_FILE_HEADER)
        endian = {b"IM": "<", b"MI": ">"}.get(header[126:128])
        if len(header) < _FILE_HEADER or endian is None:
            raise ValueError("not a readable MATLAB file (no v5 header); save it with "
                             "save(..., '-v7') or '-v7.3'")
        try:
            found = _walk(f, endian)
        except (struct.error, zlib.error, ValueError, UnicodeDecodeError) as err:
            raise ValueError(f"not a readable MATLAB file: {err}") from None
        variables = [v for v in found if _role(v.name) in _USED]
        _check(variables, limits)
        for variable in variables:
            _check_inflated(f, variable, limits)
        trimmed = header + b"".join(_raw(f, v) for v in variables)
    try:
        loaded = scipy.io.loadmat(io.BytesIO(trimmed), squeeze_me=True, chars_as_strings=True)
    except Exception as err:  # scipy raises many types on malformed elements
        raise ValueError(f"not a readable MATLAB file: {err}") from None
    data = canonical({k: v for k, v in loaded.items() if not k.startswith("__")})
    missing = [k for k in _RECORDS if k not in data]
    if missing or "fs" not in data:
        objects = any(v.mclass == _OBJECT or v.mclass > 15 for v in found)
        raise ValueError(f"MATLAB file lacks variables {missing or ['fs']}; it needs u "
                         "(samples x m), y (samples x l) and fs (Hz), or the iddata "
                         "spellings InputData, OutputData and Ts; it holds "
                         f"{[v.name for v in found][:20]}{_IDDATA_HINT if objects else ''}"
                         f"{spelling_hint([v.name for v in found])}")
    quantity = data.get("quantity")
    return {"u": np.asarray(data["u"], dtype=float), "y": np.asarray(data["y"], dtype=float),
            "fs": data["fs"], "periods": data.get("periods"),
            "quantity": None if quantity is None else str(quantity).strip(),
            **{name: strings(data.get(name), name) for name in _TEXT}}


def _walk(f: io.BufferedReader, endian: str) -> list[_Variable]:
    """Name, class and dimensions of every top-level element, from their first bytes."""
    size = f.seek(0, io.SEEK_END)
    position, found = _FILE_HEADER, []
    while position + 8 <= size:
        f.seek(position)
        mdtype, nbytes = struct.unpack(endian + "II", f.read(8))
        end = position + 8 + nbytes
        if mdtype not in (_MI_MATRIX, _MI_COMPRESSED) or end > size:
            raise ValueError(f"unexpected data element (type {mdtype}, {nbytes} bytes) at "
                             f"byte {position}")
        if mdtype == _MI_COMPRESSED:
            head = _inflate_head(f, nbytes)
            matrix, offset = struct.unpack_from(endian + "I", head)[0], 8  # into the matrix
            if matrix != _MI_MATRIX:
                raise ValueError(f"compressed element at byte {position} holds no matrix")
        else:
            head, offset = f.read(min(nbytes, _HEAD_BYTES)), 0
        found.append(_variable(head, offset, endian, position, end, mdtype == _MI_COMPRESSED))
        position = end
        if len(found) > _MAX_VARIABLES:
            raise ValueError(f"more than {_MAX_VARIABLES} variables; save only u, y, fs and "
                             "the channel names")
    return found


def _inflate_head(f: io.BufferedReader, nbytes: int) -> bytes:
    """The first decompressed bytes of a compressed element of ``nbytes``."""
    inflater, head, left = zlib.decompressobj(), b"", nbytes
    while len(head) < _HEAD_BYTES and left > 0:
        piece = f.read(min(left, 65536))
        left -= len(piece)
        head += inflater.decompress(piece, _HEAD_BYTES - len(head))
        if not piece:
            break
    return head


def _element(data: bytes, offset: int, endian: str) -> tuple[int, bytes, int]:
    """Type, contents and next offset of the (possibly small) element at ``offset``."""
    mdtype, nbytes = struct.unpack_from(endian + "II", data, offset)
    if mdtype >> 16:  # small element: size in the upper half, data in the tag's 4 bytes
        nbytes, mdtype = mdtype >> 16, mdtype & 0xFFFF
        return mdtype, data[offset + 4: offset + 4 + nbytes], offset + 8
    body = data[offset + 8: offset + 8 + nbytes]
    return mdtype, body, offset + 8 + -(-nbytes // 8) * 8


def _variable(head: bytes, offset: int, endian: str, start: int, end: int,
              compressed: bool) -> _Variable:
    """Array flags, dimensions and name: the first three sub-elements of a matrix."""
    _, flags, offset = _element(head, offset, endian)
    _, dims, offset = _element(head, offset, endian)
    _, name, _ = _element(head, offset, endian)
    if len(flags) < 8 or len(dims) % 4:
        raise ValueError(f"malformed matrix header at byte {start}")
    word = struct.unpack_from(endian + "I", flags)[0]
    shape = struct.unpack(f"{endian}{len(dims) // 4}i", dims)
    if any(n < 0 for n in shape):
        raise ValueError(f"negative dimension {shape} at byte {start}")
    return _Variable(name.decode("latin1"), word & 0xFF, bool(word & 0x800), tuple(shape),
                     start, end, compressed)


def _check(variables: list[_Variable], limits: DecodeLimits) -> None:
    """Layout, channels and declared decoded size of the variables used."""
    for v in variables:
        if _role(v.name) in _RECORDS and (v.mclass not in _NUMERIC or v.complex):
            kind = "complex matrix" if v.complex else _CLASS_NAMES.get(v.mclass, "non-numeric")
            raise ValueError(f"{v.name} is a MATLAB {kind}; save {v.name} as a real numeric "
                             f"matrix (samples x channels), e.g. {v.name} = double("
                             f"cell2mat({v.name})) for a cell array")
        if _role(v.name) in _TEXT and v.mclass not in (_CHAR, _CELL):
            raise ValueError(f"{v.name} is a MATLAB {_CLASS_NAMES.get(v.mclass, 'number')}; "
                             "save it as a cell array of char vectors, e.g. {'force', 'x1'}")
    limits.check_records({v.name: v.dims for v in variables if _role(v.name) in _RECORDS},
                         "the MATLAB file")
    declared = sum(array_bytes(v.dims, FLOAT_BYTES if _role(v.name) in _RECORDS
                               else _NUMERIC.get(v.mclass, 4)) for v in variables)
    limits.check_bytes(declared, "the MATLAB file")


def _check_inflated(f: io.BufferedReader, variable: _Variable, limits: DecodeLimits) -> None:
    """Decompress ``variable`` in pieces, keeping none, and refuse it past the limit:
    its header's dimensions may understate what the stream holds."""
    if not variable.compressed:
        return
    f.seek(variable.start + 8)
    inflater, left, total = zlib.decompressobj(), variable.end - variable.start - 8, 0
    pending = b""
    while left > 0 or pending:
        if not pending:
            pending = f.read(min(left, _PIECE))
            left -= len(pending)
        total += len(inflater.decompress(pending, _PIECE))
        pending = inflater.unconsumed_tail
        limits.check_bytes(total, f"MATLAB variable {variable.name}")
        if inflater.eof:
            break


def _raw(f: io.BufferedReader, variable: _Variable) -> bytes:
    f.seek(variable.start)
    return f.read(variable.end - variable.start)
