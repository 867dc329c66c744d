"""Universal File Format dataset 58 or 58b, one record per channel (several in one file).

Only time records are read: function type 1 (time response) or 0 (general), abscissa
in seconds (abscissa data type 17 or 0); an FRF, spectrum or other function of
frequency is refused. The channel name is record line ``id1`` (else node and direction),
the sampling rate 1 / abscissa increment, the unit the ordinate's axis units label. Records
with ordinate type 13 (excitation force) are inputs unless the options name the inputs;
the output quantity follows ordinate types 8, 11, 12 (displacement, velocity,
acceleration), and outputs of different quantities are refused with the channels of
each, to be read one quantity at a time with the option ``outputs``.

pyuff reads a whole file at once, so the decoded size is bounded from the file's size:
at worst binary single-precision samples (4 bytes) become a float64 ordinate and a
float64 abscissa, four times the file.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pyuff

from fnsi.formats.fields import ReadOptions
from fnsi.formats.limits import DecodeLimits

_GROWTH = 4  # decoded bytes per file byte, at most (module docstring)
_QUANTITY = {8: "displacement", 11: "velocity", 12: "acceleration"}
_FORCE = 13
_TIME_FUNCTIONS = (0, 1)        # general, time response
_TIME_ABSCISSAE = (0, 17)       # unknown, time
_FUNCTIONS = {2: "auto-spectrum", 3: "cross-spectrum", 4: "frequency response function",
              5: "transmissibility", 6: "coherence", 7: "auto-correlation",
              8: "cross-correlation", 9: "power spectral density", 12: "spectrum"}
_DIRECTIONS = {1: "X", 2: "Y", 3: "Z", -1: "-X", -2: "-Y", -3: "-Z"}


def read_fields(path: Path, options: ReadOptions, limits: DecodeLimits) -> dict[str, Any]:
    """Variables of a UFF file (``u``, ``y``, ``fs``, names, quantity).

    Raises
    ------
    ValueError
        Not a UFF file, or records that do not make one periodic record.
    DecodeLimitError
        The file could decode beyond ``limits``, or has too many channels.
    """
    limits.check_bytes(_GROWTH * path.stat().st_size, "the UFF file (read whole, up to "
                       f"{_GROWTH} times its size)")
    try:
        sets = pyuff.UFF(str(path)).read_sets()
    except Exception as err:  # pyuff raises bare Exception on malformed files
        raise ValueError(f"not a readable UFF file: {err}") from err
    records = [s for s in (sets if isinstance(sets, list) else [sets]) if s.get("type") == 58]
    if not records:
        raise ValueError("the UFF file holds no dataset 58/58b (function at nodal DOF) records")
    limits.check_channels(len(records), "the UFF file")
    names = _names(records)
    _check_time_records(names, records)
    column = dict(zip(names, records, strict=True))
    types = {n: int(r.get("ordinate_spec_data_type", 0)) for n, r in column.items()}
    inputs = list(options.inputs or [n for n in names if types[n] == _FORCE])
    if not inputs:
        raise ValueError("no UFF record is an excitation force (ordinate type 13); name the "
                         "input channels in the options, e.g. {\"inputs\": [...]}")
    outputs = list(options.outputs or [n for n in names if n not in inputs])
    if not outputs:
        raise ValueError(f"the UFF file holds no output (response) record, only {names}; "
                         "include the measured responses (truncated file?)")
    unknown = [n for n in (*inputs, *outputs) if n not in column]
    if unknown:
        raise ValueError(f"UFF file has no channel(s) {unknown}; channels are {names}")
    quantities = _quantity(outputs, types)
    return {"u": np.column_stack([np.real(column[n]["data"]) for n in inputs]),
            "y": np.column_stack([np.real(column[n]["data"]) for n in outputs]),
            "fs": 1.0 / _increment(records), "input_names": inputs, "output_names": outputs,
            "quantity": quantities, "input_units": [_unit(column[n]) for n in inputs],
            "output_units": [_unit(column[n]) for n in outputs]}


def _check_time_records(names: list[str], records: list[dict[str, Any]]) -> None:
    """Refuse records that are no sampled time history (an FRF, a spectrum)."""
    for name, record in zip(names, records, strict=True):
        function = int(record.get("func_type", 0))
        abscissa = int(record.get("abscissa_spec_data_type", 0))
        if function not in _TIME_FUNCTIONS or abscissa not in _TIME_ABSCISSAE:
            what = _FUNCTIONS.get(function, f"function type {function}")
            axis = "frequency [Hz]" if abscissa == 18 else f"abscissa data type {abscissa}"
            raise ValueError(
                f"UFF record {name!r} is a {what} (function type {function}) over "
                f"{axis}, not a time record: FNSI needs the measured time histories of "
                "forces and responses (function type 1, abscissa time in s); export the "
                "time data from the acquisition system instead of the processed functions")


def _quantity(outputs: list[str], types: dict[str, int]) -> str | None:
    """The one quantity the outputs measure (None when their records do not say);
    ValueError naming the channels of each when they mix quantities."""
    kinds: dict[str, list[str]] = {}
    for name in outputs:
        kinds.setdefault(_QUANTITY.get(types[name], "unknown"), []).append(name)
    known = sorted(set(kinds) - {"unknown"})
    if len(known) > 1:
        groups = "; ".join(f"{q}: {kinds[q][:10]}" for q in known)
        raise ValueError(f"the UFF outputs mix quantities ({groups}); one identification "
                         "takes outputs of one quantity: choose them with the option outputs, "
                         f"e.g. {json.dumps({'outputs': kinds[known[0]][:3]})}, and upload "
                         "the file once per quantity")
    return known[0] if known else None


def _unit(record: dict[str, Any]) -> str:
    """The ordinate's unit label of a record ("NONE" and blanks: not given)."""
    label = str(record.get("ordinate_axis_units_lab", "")).strip()
    return "" if label.upper() in ("", "NONE") else label


def _names(records: list[dict[str, Any]]) -> list[str]:
    """Unique channel names of records that all hold the same number of samples."""
    names = [_name(r) for r in records]
    empty = [n for n, r in zip(names, records, strict=True)
             if len(np.atleast_1d(r.get("data", []))) == 0]
    if empty:
        raise ValueError(f"UFF records {empty} hold no samples (truncated file?); every "
                         "input and output channel needs its data")
    if len(set(names)) != len(names):
        raise ValueError(f"UFF channel names repeat: {names}; give each record a unique id1")
    lengths = {len(r["data"]) for r in records}
    if len(lengths) != 1:
        raise ValueError(f"UFF records have different lengths {sorted(lengths)}; every channel "
                         "must cover the same samples")
    return names


def _increment(records: list[dict[str, Any]]) -> float:
    """The common abscissa increment [s] of the records."""
    steps = [float(r.get("abscissa_inc", 0.0)) for r in records]
    if not all(math.isfinite(dt) and dt > 0 for dt in steps):
        raise ValueError(f"UFF abscissa increments must be positive sampling intervals [s]; "
                         f"got {sorted(set(steps))[:5]}: write 1 / fs in each record")
    if max(steps) - min(steps) > 1e-9 * max(steps):
        raise ValueError(f"UFF records are sampled at different intervals "
                         f"{sorted(set(steps))[:5]} s; every channel needs the same fs")
    return steps[0]


def _name(record: dict[str, Any]) -> str:
    name = str(record.get("id1", "")).strip()
    if name and name.upper() != "NONE":
        return name
    direction = _DIRECTIONS.get(int(record.get("rsp_dir", 0)), str(record.get("rsp_dir")))
    return f"{record.get('rsp_node')}{direction}"
