"""HDF5 files, and MATLAB v7.3 files (HDF5 with arrays transposed).

Root datasets ``u`` (samples x m), ``y`` (samples x l), ``fs`` (dataset or root
attribute); optional ``input_names``, ``output_names`` (string datasets; MATLAB: cell
arrays of char), ``periods``, ``quantity`` (datasets or root attributes). Row-major, as
numpy writes.

HDF5 can point outside the file: a dataset with *external storage* reads raw files of
the machine that opens it, an *external link* opens another HDF5 file, a *virtual
dataset* maps other files' datasets. Reading those on a server would hand its files to
the uploader, so only hard links are followed, and every dataset is checked before its
data are read: contiguous, chunked or compact layout only, no external files, a plain
numeric or string type, and its shape times its item size within the
:class:`~fnsi.formats.limits.DecodeLimits` (a compressed dataset of fill values is tiny
on disk and huge in memory). Links are looked up by name, never visited, so nothing the
reader does not use is touched.
"""

from __future__ import annotations

import itertools
from pathlib import Path
from typing import Any

import h5py
import numpy as np

from fnsi.formats.fields import scalar, strings
from fnsi.formats.limits import FLOAT_BYTES, DecodeLimits, array_bytes, channels_of, is_numeric

_RECORDS = ("u", "y")
_SCALARS = ("fs", "periods", "quantity")
_NAMES = ("input_names", "output_names")


def read_fields(path: Path, limits: DecodeLimits, *, matlab: bool) -> dict[str, Any]:
    """Variables of an HDF5 (or MATLAB v7.3, ``matlab=True``) file, checked before reading.

    Raises
    ------
    ValueError
        Not HDF5, a reference out of the file, or a layout the reader cannot use.
    DecodeLimitError
        Decoded size or channels beyond ``limits``.
    """
    what = "MATLAB v7.3" if matlab else "HDF5"
    try:
        with h5py.File(path, "r") as f:
            nodes = {name: _dataset(f, name) for name in (*_RECORDS, *_SCALARS, *_NAMES)}
            nodes = {name: node for name, node in nodes.items() if node is not None}
            _check(f, nodes, limits, what, matlab)
            data = {name: _value(f, node, matlab, limits) for name, node in nodes.items()}
            for name in _SCALARS:
                if name not in data and name in f.attrs:
                    data[name] = f.attrs[name]
            missing = [k for k in _RECORDS if k not in data]
            if missing:
                raise ValueError(f"{what} file lacks datasets {missing} at its root; it "
                                 "needs u (samples x m), y (samples x l) and fs (Hz); found "
                                 f"{list(itertools.islice(f, 50))}{_groups_holding(f, missing)}")
    except (OSError, TypeError, KeyError, RuntimeError) as err:  # h5py's errors on bad files
        raise ValueError(f"not a readable {what} file: {err}") from None
    quantity = None if data.get("quantity") is None else scalar(data["quantity"], "quantity")
    return {"u": np.asarray(data["u"], dtype=float), "y": np.asarray(data["y"], dtype=float),
            "fs": data.get("fs"), "periods": data.get("periods"),
            "quantity": None if quantity is None else (
                quantity.decode() if isinstance(quantity, bytes) else str(quantity)).strip(),
            "input_names": strings(data.get("input_names"), "input_names"),
            "output_names": strings(data.get("output_names"), "output_names")}


def _dataset(group: h5py.Group, name: str) -> h5py.Dataset | None:
    """The dataset hard-linked as ``name`` in ``group``; links that may leave the file
    (external, soft: a path that can cross an external link) are refused unresolved."""
    link = group.get(name, getlink=True)
    if link is None:
        return None
    if not isinstance(link, h5py.HardLink):
        kind = ("an external link to another file" if isinstance(link, h5py.ExternalLink)
                else "a soft link" if isinstance(link, h5py.SoftLink) else "a user-defined link")
        raise ValueError(f"{name} is {kind}; links are not followed: store the data of "
                         f"{name} in the file itself")
    node = group[name]
    if not isinstance(node, h5py.Dataset):
        raise ValueError(f"{name} is a group (a MATLAB struct?), not a dataset; store {name} "
                         "as an array at the file's root")
    return node


def _groups_holding(f: h5py.File, names: list[str]) -> str:
    """A hint naming the groups (one level down, hard links only, among the first 1000
    root links) that hold ``names``."""
    groups = [key for key in itertools.islice(f, 1000)
              if isinstance(f.get(key, getlink=True), h5py.HardLink)
              and isinstance(f[key], h5py.Group)
              and all(isinstance(f[key].get(n, getlink=True), h5py.HardLink) for n in names)]
    if not groups:
        return ""
    return (f"; groups {groups[:10]} hold {names}: move one record's datasets to the root, "
            f"e.g. with h5py f.move('{groups[0]}/{names[0]}', '{names[0]}')")


def _check_storage(node: h5py.Dataset, name: str) -> None:
    """Refuse data stored outside the file (external raw files, virtual datasets)."""
    plist = node.id.get_create_plist()
    if plist.get_layout() == h5py.h5d.VIRTUAL:
        raise ValueError(f"{name} is a virtual dataset (its data live in other files); "
                         f"store the data of {name} in the file itself")
    if plist.get_external_count() > 0:
        raise ValueError(f"{name} has external storage (its data live in a raw file outside "
                         f"the HDF5 file); store the data of {name} in the file itself")


def _check(f: h5py.File, nodes: dict[str, h5py.Dataset], limits: DecodeLimits, what: str,
           matlab: bool) -> None:
    """Storage, types, channels and decoded size of the datasets used, from metadata."""
    for name, node in nodes.items():
        _check_storage(node, name)
        if name in _RECORDS and not is_numeric(node.dtype):
            raise ValueError(f"{name} has type {node.dtype}; store {name} as a float array "
                             "(samples x channels)")
    shapes = {name: (node.shape or ())[::-1] if matlab else node.shape or ()
              for name, node in nodes.items()}
    limits.check_channels(sum(channels_of(shapes[name]) for name in _RECORDS if name in nodes),
                          f"the {what} file")
    limits.check_bytes(sum(array_bytes(shapes[name], FLOAT_BYTES if name in _RECORDS
                                       else node.dtype.itemsize)
                           for name, node in nodes.items()), f"the {what} file")
    for name in _SCALARS:
        if name not in nodes and name in f.attrs:
            attribute = h5py.h5a.open(f.id, name.encode())
            limits.check_bytes(array_bytes(attribute.shape or (), attribute.dtype.itemsize),
                               f"attribute {name}")


def _value(f: h5py.File, node: h5py.Dataset, matlab: bool, limits: DecodeLimits) -> Any:
    """A checked dataset's contents; MATLAB char arrays as strings, cells dereferenced
    (object references stay inside the file; each target is checked like the dataset)."""
    if node.attrs.get("MATLAB_class") in (b"char", "char"):
        chars = np.atleast_2d(node[()]).T if matlab else np.atleast_2d(node[()])
        return ["".join(map(chr, row)).strip() for row in chars]
    if h5py.check_dtype(ref=node.dtype) is h5py.Reference:  # MATLAB cell array
        refs = np.ravel(node[()])
        limits.check_channels(refs.size, f"cell array {node.name}")
        cells = []
        for ref in refs:
            target = f[ref]
            if not isinstance(target, h5py.Dataset) or h5py.check_dtype(ref=target.dtype):
                raise ValueError(f"cell array {node.name} holds a group or another cell array; "
                                 "use a cell array of char vectors")
            _check_storage(target, node.name)
            limits.check_bytes(array_bytes(target.shape or (), target.dtype.itemsize),
                               f"cell of {node.name}")
            cells.append(_value(f, target, matlab, limits)[0])
        return cells
    if h5py.check_string_dtype(node.dtype) is not None or node.dtype.kind in "SU":
        return [v.decode() if isinstance(v, bytes) else str(v) for v in np.ravel(node[()])]
    value = node[()]
    return value.T if matlab and np.ndim(value) >= 2 else value
