"""Readers turning an uploaded file into a validated :class:`fnsi.measurement.Measurement`.

Supported formats and their layouts (the README documents them for users):

``npz``
    The canonical NPZ of DESIGN.md section 6 (``Measurement.from_npz``).
``csv``
    Header of channel names, one sample per row (``Measurement.from_csv``); ``fs`` and
    ``inputs`` come from the upload's meta.
``mat``
    MATLAB v5 (scipy.io) or v7.3 (HDF5, read with h5py) with the NPZ variables: ``u``
    (samples x m), ``y`` (samples x l), ``fs``; optional ``input_names``, ``output_names``
    (char matrix or cell array of strings), ``periods``, ``quantity``.
``h5``
    HDF5 with root datasets ``u`` (samples x m), ``y`` (samples x l), ``fs`` (dataset or
    root attribute); optional ``input_names``, ``output_names`` (string datasets),
    ``periods``, ``quantity`` (datasets or root attributes). Row-major, as numpy writes.
``uff``
    Universal File Format dataset 58 or 58b, one record per channel (several records in
    one file). The channel name is record line ``id1`` (else node and direction), the
    sampling rate 1 / abscissa increment. Records with ordinate type 13 (excitation force)
    are inputs unless meta names the inputs; the output quantity follows ordinate types
    8, 11, 12 (displacement, velocity, acceleration).

Every value given in the meta (fs, inputs, outputs, periods, quantity) overrides the file.
When neither gives the number of periods it is detected from the input.
"""

from __future__ import annotations

import dataclasses
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import h5py
import numpy as np
import pyuff
import scipy.io

from fnsi.measurement import Measurement
from fnsi.summary import detect_periods

FORMATS = ("npz", "csv", "mat", "h5", "uff")
_EXTENSIONS = {".npz": "npz", ".csv": "csv", ".txt": "csv", ".mat": "mat", ".h5": "h5",
               ".hdf5": "h5", ".hdf": "h5", ".uff": "uff", ".unv": "uff"}
_UFF_QUANTITY = {8: "displacement", 11: "velocity", 12: "acceleration"}
_UFF_FORCE = 13
_UFF_DIRECTIONS = {1: "X", 2: "Y", 3: "Z", -1: "-X", -2: "-Y", -3: "-Z"}


@dataclass(frozen=True)
class ReadOptions:
    """Upload meta that completes or overrides what a file says (None: use the file)."""

    fs: float | None = None
    inputs: tuple[str, ...] | None = None
    outputs: tuple[str, ...] | None = None
    periods: int | None = None
    quantity: str | None = None


def format_of(filename: str, declared: str | None) -> str:
    """Format named in the meta, else guessed from the file extension.

    Raises
    ------
    ValueError
        Neither gives a supported format.
    """
    if declared is not None:
        return declared
    fmt = _EXTENSIONS.get(Path(filename or "").suffix.lower())
    if fmt is None:
        raise ValueError(f"cannot tell the format of {filename!r} from its extension; name the "
                         f"file *.npz, *.csv, *.mat, *.h5 or *.uff, or set meta.format to one "
                         f"of {list(FORMATS)}")
    return fmt


def read_measurement(path: Path, fmt: str, options: ReadOptions) -> tuple[Measurement, str]:
    """Parse and validate an uploaded file.

    Parameters
    ----------
    path : Path
        The uploaded bytes on disk.
    fmt : str
        One of :data:`FORMATS`.
    options : ReadOptions
        Meta given with the upload.

    Returns
    -------
    (Measurement, str)
        The measurement and ``"declared"`` or ``"detected"`` for its number of periods.

    Raises
    ------
    ValueError
        The file does not hold a valid measurement; the message says what to change.
    """
    if fmt == "csv":
        return _from_csv(path, options)
    fields = {"npz": _npz_fields, "mat": _mat_fields, "h5": _h5_fields,
              "uff": _uff_fields}[fmt](path, options)
    return _assemble(fields, options)


def _assemble(fields: dict[str, Any], options: ReadOptions) -> tuple[Measurement, str]:
    """Measurement from u/y fields, meta overrides, channel selection, period detection."""
    fs = options.fs if options.fs is not None else fields.get("fs")
    if fs is None:
        raise ValueError("the file gives no sampling rate; add meta {\"fs\": <Hz>}")
    periods = options.periods if options.periods is not None else fields.get("periods")
    quantity = options.quantity or fields.get("quantity") or "displacement"
    measurement = Measurement.from_arrays(
        fields["u"], fields["y"], float(fs), input_names=fields.get("input_names"),
        output_names=fields.get("output_names"), periods=int(periods or 1), quantity=quantity)
    if options.inputs is not None or options.outputs is not None:
        measurement = measurement.select(options.inputs, options.outputs)
    return _with_periods(measurement, periods)


def _with_periods(measurement: Measurement, periods: int | None) -> tuple[Measurement, str]:
    if periods is not None:
        return measurement, "declared"
    detected = detect_periods(measurement.u)
    return dataclasses.replace(measurement, periods=detected), "detected"


def _from_csv(path: Path, options: ReadOptions) -> tuple[Measurement, str]:
    if options.fs is None or not options.inputs:
        raise ValueError("a CSV upload needs meta with the sampling rate and the input "
                         "columns, e.g. {\"fs\": 2500, \"inputs\": [\"force\"]}")
    try:
        with open(path, encoding="utf-8") as f:
            measurement = Measurement.from_csv(
                f, fs=options.fs, inputs=options.inputs, outputs=options.outputs,
                periods=options.periods or 1, quantity=options.quantity or "displacement")
    except UnicodeDecodeError:
        raise ValueError("the CSV is not UTF-8 text; export it as plain UTF-8 CSV") from None
    return _with_periods(measurement, options.periods)


def _npz_fields(path: Path, options: ReadOptions) -> dict[str, Any]:
    try:
        measurement = Measurement.from_npz(path)
        with np.load(path, allow_pickle=False) as data:
            declared = "periods" in data.files
    except (zipfile.BadZipFile, zlib.error) as err:  # truncated or corrupted archive
        raise ValueError(f"not a readable NPZ file ({err}); upload the whole file "
                         "again") from None
    return {"u": measurement.u, "y": measurement.y, "fs": measurement.fs,
            "input_names": measurement.input_names, "output_names": measurement.output_names,
            "periods": measurement.periods if declared else None,
            "quantity": measurement.quantity}


def _strings(value: Any) -> list[str] | None:
    """Channel names from a MATLAB char matrix, cell array or string array."""
    if value is None:
        return None
    flat = np.asarray(value, dtype=object).ravel()
    return [str(np.squeeze(v)).strip() for v in flat]


def _mat_fields(path: Path, options: ReadOptions) -> dict[str, Any]:
    try:
        data = scipy.io.loadmat(path, squeeze_me=True, chars_as_strings=True)
    except NotImplementedError:  # v7.3 files are HDF5
        return _hdf5_fields(path, matlab=True)
    except (ValueError, TypeError, OSError) as err:
        raise ValueError(f"not a readable MATLAB file: {err}") from err
    return _uy_fields({k: v for k, v in data.items() if not k.startswith("__")}, ".mat")


def _uy_fields(data: dict[str, Any], what: str) -> dict[str, Any]:
    """Fields of a file holding the NPZ variable names (u, y, fs, ...)."""
    missing = [k for k in ("u", "y") if k not in data]
    if missing:
        raise ValueError(f"{what} file lacks variables {missing}; it needs u (samples x m), "
                         f"y (samples x l) and fs (Hz); found {sorted(data)}")
    scalar = {k: np.asarray(data[k]).ravel()[0] if k in data else None
              for k in ("fs", "periods", "quantity")}
    return {"u": np.asarray(data["u"], dtype=float), "y": np.asarray(data["y"], dtype=float),
            "fs": None if scalar["fs"] is None else float(scalar["fs"]),
            "periods": None if scalar["periods"] is None else int(scalar["periods"]),
            "quantity": None if scalar["quantity"] is None else str(scalar["quantity"]).strip(),
            "input_names": _strings(data.get("input_names")),
            "output_names": _strings(data.get("output_names"))}


def _h5_fields(path: Path, options: ReadOptions) -> dict[str, Any]:
    return _hdf5_fields(path, matlab=False)


def _hdf5_fields(path: Path, *, matlab: bool) -> dict[str, Any]:
    """Read the u/y layout from HDF5; MATLAB v7.3 stores arrays transposed."""
    try:
        with h5py.File(path, "r") as f:
            data = dict(f.attrs)
            for key, node in f.items():
                if isinstance(node, h5py.Dataset):
                    data[key] = _h5_value(f, node, matlab)
    except OSError as err:
        raise ValueError(f"not a readable HDF5 file: {err}") from err
    return _uy_fields(data, "MATLAB v7.3" if matlab else "HDF5")


def _h5_value(f: h5py.File, node: h5py.Dataset, matlab: bool) -> Any:
    if node.attrs.get("MATLAB_class") in (b"char", "char"):
        chars = np.atleast_2d(node[()]).T if matlab else np.atleast_2d(node[()])
        return ["".join(map(chr, row)).strip() for row in chars]
    if h5py.check_dtype(ref=node.dtype) is h5py.Reference:  # MATLAB cell array
        return [_h5_value(f, f[ref], matlab)[0] for ref in np.ravel(node[()])]
    if h5py.check_string_dtype(node.dtype) is not None or node.dtype.kind in "SU":
        return [v.decode() if isinstance(v, bytes) else str(v) for v in np.ravel(node[()])]
    value = node[()]
    return value.T if matlab and np.ndim(value) >= 2 else value


def _uff_fields(path: Path, options: ReadOptions) -> dict[str, Any]:
    try:
        sets = pyuff.UFF(str(path)).read_sets()
    except Exception as err:  # pyuff raises bare Exception on malformed files
        raise ValueError(f"not a readable UFF file: {err}") from err
    records = [s for s in (sets if isinstance(sets, list) else [sets]) if s.get("type") == 58]
    if not records:
        raise ValueError("the UFF file holds no dataset 58/58b (function at nodal DOF) records")
    empty = [_uff_name(r) for r in records if len(np.atleast_1d(r.get("data", []))) == 0]
    if empty:
        raise ValueError(f"UFF records {empty} hold no samples (truncated file?); every "
                         "input and output channel needs its data")
    names = [_uff_name(r) for r in records]
    if len(set(names)) != len(names):
        raise ValueError(f"UFF channel names repeat: {names}; give each record a unique id1")
    lengths = {len(r["data"]) for r in records}
    if len(lengths) != 1:
        raise ValueError(f"UFF records have different lengths {sorted(lengths)}; every channel "
                         "must cover the same samples")
    types = {n: int(r.get("ordinate_spec_data_type", 0)) for n, r in zip(names, records,
                                                                            strict=True)}
    inputs = list(options.inputs or [n for n in names if types[n] == _UFF_FORCE])
    if not inputs:
        raise ValueError("no UFF record is an excitation force (ordinate type 13); name the "
                         "input channels in meta {\"inputs\": [...]}")
    outputs = list(options.outputs or [n for n in names if n not in inputs])
    if not outputs:
        raise ValueError(f"the UFF file holds no output (response) record, only {names}; "
                         "include the measured responses (truncated file?)")
    unknown = [n for n in (*inputs, *outputs) if n not in names]
    if unknown:
        raise ValueError(f"UFF file has no channel(s) {unknown}; channels are {names}")
    column = dict(zip(names, records, strict=True))
    quantities = {_UFF_QUANTITY.get(types[n]) for n in outputs}
    return {"u": np.column_stack([np.real(column[n]["data"]) for n in inputs]),
            "y": np.column_stack([np.real(column[n]["data"]) for n in outputs]),
            "fs": 1.0 / float(records[0]["abscissa_inc"]),
            "input_names": inputs, "output_names": outputs,
            "quantity": quantities.pop() if len(quantities) == 1 else None}


def _uff_name(record: dict[str, Any]) -> str:
    name = str(record.get("id1", "")).strip()
    if name and name.upper() != "NONE":
        return name
    direction = _UFF_DIRECTIONS.get(int(record.get("rsp_dir", 0)), str(record.get("rsp_dir")))
    return f"{record.get('rsp_node')}{direction}"
