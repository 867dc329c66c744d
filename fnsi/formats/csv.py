"""CSV: a header of channel names, one sample per row (``Measurement.from_csv``).

The input columns come with the options; the sampling rate too, unless a column headed
``time`` or ``t`` (optionally with its unit, ``time [s]``, ``t (ms)``) holds the sample
times: the rate is then read from it, and the column is dropped from the channels.
Before parsing, one pass over the bytes counts the header's columns and the rows, so the
channel cap and the decoded size (rows x columns float64) are checked first.
"""

from __future__ import annotations

import csv
import dataclasses
import re
from pathlib import Path

import numpy as np

from fnsi.formats.fields import ReadOptions, finish
from fnsi.formats.limits import FLOAT_BYTES, DecodeLimits
from fnsi.measurement import Measurement

_CHUNK = 1 << 20
_TIME = re.compile(r"^(t|time)\s*(?:[\[(]\s*(s|ms)\s*[\])])?$", re.IGNORECASE)
_SECONDS = {None: 1.0, "s": 1.0, "ms": 1e-3}
#: Largest relative deviation of a time step from the mean step: a record with a missing
#: or repeated sample deviates by 100 %, rounding of printed times by far less than 1 %.
_STEP_TOLERANCE = 0.01
#: Largest relative difference between a rate given and the time column's.
_RATE_TOLERANCE = 1e-3


def read(path: Path, options: ReadOptions, limits: DecodeLimits) -> tuple[Measurement, str]:
    """Measurement of a CSV file; see :func:`fnsi.formats.read_measurement`."""
    columns, rows = _count(path)
    limits.check_channels(columns, "the CSV header")
    limits.check_bytes(rows * columns * FLOAT_BYTES, "the CSV body")
    header = _header(path)
    time = next((name for name in header if _TIME.match(name)), None)
    if (options.fs is None and time is None) or not options.inputs:
        raise ValueError("a CSV needs the sampling rate and the input columns given with it, "
                         "e.g. {\"fs\": 2500, \"inputs\": [\"force\"]}, or a time column "
                         "(headed time or t) for the rate")
    outputs = options.outputs
    if time is not None:
        outputs = (*(options.outputs or [h for h in header if h not in options.inputs
                                         and h != time]), time)
    try:
        measurement = Measurement.from_csv(
            path, fs=options.fs or 1.0, inputs=options.inputs, outputs=outputs,
            periods=options.periods or 1, quantity=options.quantity or "displacement")
    except UnicodeDecodeError:
        raise ValueError("the CSV is not UTF-8 text; export it as plain UTF-8 CSV") from None
    if time is not None:
        measurement = _timed(measurement, time, options.fs)
    return finish(measurement, options.periods, options.units)


def _header(path: Path) -> list[str]:
    """The channel names of the first row."""
    try:
        with open(path, encoding="utf-8", newline="") as f:
            return [h.strip() for h in next(csv.reader([f.readline()]), [])]
    except UnicodeDecodeError:
        raise ValueError("the CSV is not UTF-8 text; export it as plain UTF-8 CSV") from None


def _timed(measurement: Measurement, time: str, fs: float | None) -> Measurement:
    """``measurement`` without its time column (the last output), at the column's rate."""
    t = measurement.y[0, :, -1] * _SECONDS[(_TIME.match(time).group(2) or "s").lower()]
    steps = np.diff(t)
    if steps.size == 0 or not np.all(steps > 0):
        raise ValueError(f"the time column {time!r} must increase from row to row; it is "
                         "what the sampling rate is read from")
    mean = (t[-1] - t[0]) / steps.size
    worst = float(np.max(np.abs(steps - mean)) / mean)
    if worst > _STEP_TOLERANCE:
        raise ValueError(f"the time column {time!r} is not evenly sampled (a step differs "
                         f"from the mean {mean:.6g} s by {100 * worst:.0f} %): samples are "
                         "missing or repeated; FNSI needs an evenly sampled record")
    rate = 1.0 / mean
    if fs is not None and abs(fs - rate) > _RATE_TOLERANCE * rate:
        raise ValueError(f"fs = {fs} Hz was given but the time column {time!r} is sampled at "
                         f"{rate:.6g} Hz; drop the option fs or correct it")
    kept = measurement.output_names[:-1]
    if not kept:
        raise ValueError("the CSV holds no output column besides the inputs and the time")
    return dataclasses.replace(measurement.select(None, kept), fs=fs or rate)


def _count(path: Path) -> tuple[int, int]:
    """Columns of the header (separators + 1; a quoted comma counts too) and body rows,
    in one pass over the bytes without decoding them."""
    commas = rows = 0
    in_header = True
    last = b"\n"
    with open(path, "rb") as f:
        while chunk := f.read(_CHUNK):
            if in_header:
                end = chunk.find(b"\n")
                commas += chunk[: None if end < 0 else end].count(b",")
                in_header = end < 0
                chunk = b"" if end < 0 else chunk[end:]
            rows += chunk.count(b"\n")
            last = chunk[-1:] or last
    body_rows = rows - 1 + (last != b"\n")  # the header's newline; a last row without one
    return commas + 1, max(body_rows, 0)
