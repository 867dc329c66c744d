"""HDF5 files, and MATLAB v7.3 files (HDF5 with arrays transposed).

Datasets ``u`` (samples x m), ``y`` (samples x l), ``fs`` (dataset or attribute);
optional ``input_names``, ``output_names``, ``input_units``, ``output_units`` (string
datasets; MATLAB: cell arrays of char), ``periods``, ``quantity`` (datasets or
attributes), and a string attribute ``units`` on ``u`` or ``y`` (one unit, or one per
column). Row-major, as numpy writes; MATLAB's ``iddata`` spellings are read too
(:data:`fnsi.formats.fields.MATLAB_SPELLINGS`). They sit at the root, or in the group
the option ``group`` names; without it, when the root holds no ``u`` and exactly one of
its groups does, that group is read.

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

from fnsi.formats.fields import MATLAB_SPELLINGS, canonical, scalar, spelling_hint, strings
from fnsi.formats.limits import FLOAT_BYTES, DecodeLimits, array_bytes, is_numeric

_RECORDS = ("u", "y")
_SCALARS = ("fs", "periods", "quantity")
_NAMES = ("input_names", "output_names", "input_units", "output_units")
_CANONICAL = (*_RECORDS, *_SCALARS, *_NAMES)
#: Every name looked up: the canonical ones and MATLAB's spellings of them.
_LOOKED_UP = (*_CANONICAL, *MATLAB_SPELLINGS)
#: Scalars that may be attributes of the record's group instead of datasets.
_ATTRIBUTES = (*_SCALARS, "Fs", "Ts")
_UNITS_OF = {"u": "input_units", "y": "output_units"}
_MAX_LINKS = 1000  # root links examined for groups holding a record


def _role(name: str) -> str:
    return MATLAB_SPELLINGS.get(name, name)


def read_fields(path: Path, limits: DecodeLimits, *, matlab: bool,
                group: str | None = None) -> dict[str, Any]:
    """Variables of an HDF5 (or MATLAB v7.3, ``matlab=True``) file, checked before reading.

    ``group`` is the path of the group holding the record (default: see the module).

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
            where = _record_group(f, group)
            nodes = {name: _dataset(where, name) for name in _LOOKED_UP}
            if where != f:  # rate, names, units shared by the file's groups at its root
                nodes |= {name: _dataset(f, name) for name, node in nodes.items()
                          if node is None and _role(name) not in _RECORDS}
            nodes = {name: node for name, node in nodes.items() if node is not None}
            _check(where, nodes, limits, what, matlab)
            data = {name: _value(f, node, matlab, limits) for name, node in nodes.items()}
            for name in _ATTRIBUTES:
                holder = next((g for g in (where, f) if name in g.attrs), None)
                if name not in data and holder is not None:
                    data[name] = holder.attrs[name]
            data = canonical(data)
            for record, units in _UNITS_OF.items():
                if units not in data and record in nodes:
                    data[units] = _units_attribute(nodes[record], limits)
            missing = [k for k in _RECORDS if k not in data]
            if missing:
                raise ValueError(f"{what} file lacks datasets {missing} in {where.name}; it "
                                 "needs u (samples x m), y (samples x l) and fs (Hz) there; "
                                 f"{where.name} holds {_members(where)}"
                                 f"{spelling_hint(_hard_links(where))}; name a group "
                                 "holding them with the option group (meta {\"group\": "
                                 "\"run1\"}, fnsi --group run1)")
    except (OSError, TypeError, KeyError, RuntimeError) as err:  # h5py's errors on bad files
        raise ValueError(f"not a readable {what} file: {err}") from None
    quantity = None if data.get("quantity") is None else scalar(data["quantity"], "quantity")
    return {"u": np.asarray(data["u"], dtype=float), "y": np.asarray(data["y"], dtype=float),
            "fs": data.get("fs"), "periods": data.get("periods"),
            "quantity": None if quantity is None else (
                quantity.decode() if isinstance(quantity, bytes) else str(quantity)).strip(),
            **{name: strings(data.get(name), name) for name in _NAMES}}


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


def _record_group(f: h5py.File, group: str | None) -> h5py.Group:
    """The group ``group`` names (each step a hard link), else the root, else the one
    group below the root that holds ``u`` (or ``InputData``)."""
    if group is not None:
        where: h5py.Group = f
        for step in (s for s in group.split("/") if s):
            link = where.get(step, getlink=True)
            if not isinstance(link, h5py.HardLink) or not isinstance(where[step], h5py.Group):
                raise ValueError(f"the file has no group {group!r} (hard-linked, links are "
                                 f"not followed); its root holds {_members(f)}")
            where = where[step]
        return where
    if _holds_record(f):
        return f
    holding = [key for key in _hard_links(f) if isinstance(f[key], h5py.Group)
               and _holds_record(f[key])]
    if len(holding) > 1:
        raise ValueError(f"groups {holding[:10]} each hold a record (u, y); choose one with "
                         f"the option group, e.g. meta {{\"group\": \"{holding[0]}\"}} or "
                         f"fnsi --group {holding[0]}")
    return f[holding[0]] if holding else f


def _hard_links(group: h5py.Group) -> list[str]:
    """Names of the first :data:`_MAX_LINKS` hard links of ``group`` (others unresolved)."""
    return [key for key in itertools.islice(group, _MAX_LINKS)
            if isinstance(group.get(key, getlink=True), h5py.HardLink)]


def _holds_record(group: h5py.Group) -> bool:
    return any(isinstance(group.get(name, getlink=True), h5py.HardLink)
               for name in ("u", "InputData"))


def _members(group: h5py.Group) -> list[str]:
    """Up to 50 names of ``group``'s members, groups with a trailing slash."""
    return [f"{key}/" if isinstance(group[key], h5py.Group) else key
            for key in _hard_links(group)[:50]]


def _units_attribute(node: h5py.Dataset, limits: DecodeLimits) -> list[str] | None:
    """The string attribute ``units`` of a record dataset (one unit for every column, or
    one per column), its size checked before it is read."""
    if "units" not in node.attrs:
        return None
    attribute = h5py.h5a.open(node.id, b"units")
    limits.check_bytes(array_bytes(attribute.shape or (), attribute.dtype.itemsize),
                       f"attribute units of {node.name}")
    values = np.atleast_1d(node.attrs["units"]).ravel()
    return strings([v.decode() if isinstance(v, bytes) else v for v in values],
                   f"the units attribute of {node.name}")


def _check_storage(node: h5py.Dataset, name: str) -> None:
    """Refuse data stored outside the file (external raw files, virtual datasets)."""
    plist = node.id.get_create_plist()
    if plist.get_layout() == h5py.h5d.VIRTUAL:
        raise ValueError(f"{name} is a virtual dataset (its data live in other files); "
                         f"store the data of {name} in the file itself")
    if plist.get_external_count() > 0:
        raise ValueError(f"{name} has external storage (its data live in a raw file outside "
                         f"the HDF5 file); store the data of {name} in the file itself")


def _check(where: h5py.Group, nodes: dict[str, h5py.Dataset], limits: DecodeLimits, what: str,
           matlab: bool) -> None:
    """Storage, types, channels and decoded size of the datasets used, from metadata."""
    for name, node in nodes.items():
        _check_storage(node, name)
        if _role(name) in _RECORDS and not is_numeric(node.dtype):
            raise ValueError(f"{name} has type {node.dtype}; store {name} as a float array "
                             "(samples x channels)")
    shapes = {name: (node.shape or ())[::-1] if matlab else node.shape or ()
              for name, node in nodes.items()}
    limits.check_records({name: shapes[name] for name in nodes if _role(name) in _RECORDS},
                         f"the {what} file")
    limits.check_bytes(sum(array_bytes(shapes[name], FLOAT_BYTES if _role(name) in _RECORDS
                                       else node.dtype.itemsize)
                           for name, node in nodes.items()), f"the {what} file")
    for name in _ATTRIBUTES:
        for holder in (where, where.file):
            if name not in nodes and name in holder.attrs:
                attribute = h5py.h5a.open(holder.id, name.encode())
                limits.check_bytes(array_bytes(attribute.shape or (),
                                               attribute.dtype.itemsize), f"attribute {name}")


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
