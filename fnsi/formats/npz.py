"""NPZ: the canonical dataset (``Measurement.from_npz``), checked from its array headers.

An NPZ is a zip of ``.npy`` members. Before anything is decompressed, each member this
reader uses is opened as a stream and only its ``.npy`` header is read
(``numpy.lib.format``): the dtype must be plain numbers or strings (never objects, which
would need unpickling, nor structured records), the header's shape must fit in the bytes
the zip declares for the member, and the decoded total and channel count must fit the
:class:`~fnsi.formats.limits.DecodeLimits`.
"""

from __future__ import annotations

import zipfile
import zlib
from pathlib import Path
from typing import Any

import numpy as np
from numpy.lib import format as npy

from fnsi.formats.limits import FLOAT_BYTES, DecodeLimits, array_bytes, is_numeric
from fnsi.measurement import NOT_A_ZIP, NPZ_VARIABLES, Measurement

_RECORDS = ("u", "y")
_SCALARS = ("fs", "periods")
_TEXT = ("input_names", "output_names", "quantity", "input_units", "output_units")


def read_fields(path: Path, limits: DecodeLimits) -> dict[str, Any]:
    """Variables of an NPZ file after its headers passed the checks.

    Raises
    ------
    ValueError
        Not a zip, a member unreadable, of a refused dtype or inconsistent with its size.
    DecodeLimitError
        Decoded size or channels beyond ``limits``.
    """
    if not zipfile.is_zipfile(path):
        with open(path, "rb") as f:
            started = f.read(4) == b"PK\x03\x04"  # a zip's first member, its end missing
        raise ValueError("not a readable NPZ file (the zip ends early); upload the whole file "
                         "again" if started else NOT_A_ZIP)
    try:
        with zipfile.ZipFile(path) as archive:
            headers = {name: _header(archive, member, name)
                       for name, member in _members(archive).items()}
        _check(headers, limits)
        measurement = Measurement.from_npz(path)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError) as err:
        raise ValueError(f"not a readable NPZ file ({err}); upload the whole file "
                         "again") from None
    return {"u": measurement.u, "y": measurement.y, "fs": measurement.fs,
            "input_names": measurement.input_names, "output_names": measurement.output_names,
            "periods": measurement.periods if "periods" in headers else None,
            "quantity": measurement.quantity, "input_units": measurement.input_units,
            "output_units": measurement.output_units}


def _members(archive: zipfile.ZipFile) -> dict[str, str]:
    """Member of each variable this reader uses that the archive holds (``u.npy`` or
    ``u``, as numpy.load names them)."""
    present = {member.removesuffix(".npy"): member for member in archive.namelist()}
    return {name: present[name] for name in NPZ_VARIABLES if name in present}


def _header(archive: zipfile.ZipFile, member: str,
            name: str) -> tuple[tuple[int, ...], np.dtype]:
    """Shape and dtype from a member's ``.npy`` header, decompressing only the header."""
    info = archive.getinfo(member)
    with archive.open(info) as stream:
        try:
            version = npy.read_magic(stream)
            reader = {(1, 0): npy.read_array_header_1_0, (2, 0): npy.read_array_header_2_0}
            shape, _, dtype = reader[version](stream, max_header_size=10_000)
        except (ValueError, KeyError) as err:
            raise ValueError(f"member {member} has no valid .npy header ({err}); save the "
                             "arrays with numpy.savez") from None
        if dtype.hasobject:
            raise ValueError(f"{name} is an object array; NPZ object arrays are refused for "
                             "safety (they need unpickling): store names as unicode arrays "
                             "and samples as float arrays")
        if dtype.fields is not None:
            raise ValueError(f"{name} has a structured dtype {dtype}; store {name} as a "
                             "plain float array (samples x channels)")
        body = info.file_size - stream.tell()
    if array_bytes(shape, dtype.itemsize) > body:
        raise ValueError(f"the header of {name} declares shape {shape} of {dtype} "
                         f"({array_bytes(shape, dtype.itemsize)} bytes) but the member holds "
                         f"{body} bytes of data; the file is corrupt: save it again")
    return tuple(shape), dtype


def _check(headers: dict[str, tuple[tuple[int, ...], np.dtype]], limits: DecodeLimits) -> None:
    """Kinds, channel count and decoded size, all from the headers."""
    for name in _RECORDS:
        if name in headers and not is_numeric(headers[name][1]):
            raise ValueError(f"{name} has dtype {headers[name][1]}; store {name} as a float "
                             "array (samples x channels)")
    for name in _SCALARS:
        if name in headers and not is_numeric(headers[name][1]):
            raise ValueError(f"{name} has dtype {headers[name][1]}; store it as a number")
    for name in _TEXT:
        if name in headers and headers[name][1].kind not in "SU":
            raise ValueError(f"{name} has dtype {headers[name][1]}; store it as a unicode "
                             "string array")
    limits.check_records({name: headers[name][0] for name in _RECORDS if name in headers},
                         "the NPZ file")
    decoded = sum(array_bytes(shape, FLOAT_BYTES if name in _RECORDS else dtype.itemsize)
                  for name, (shape, dtype) in headers.items())
    limits.check_bytes(decoded, "the NPZ file")
