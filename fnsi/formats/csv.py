"""CSV: a header of channel names, one sample per row (``Measurement.from_csv``).

The sampling rate and the input columns come with the options. Before parsing, one pass
over the bytes counts the header's columns and the rows, so the channel cap and the
decoded size (rows x columns float64) are checked first.
"""

from __future__ import annotations

from pathlib import Path

from fnsi.formats.fields import ReadOptions, finish
from fnsi.formats.limits import FLOAT_BYTES, DecodeLimits
from fnsi.measurement import Measurement

_CHUNK = 1 << 20


def read(path: Path, options: ReadOptions, limits: DecodeLimits) -> tuple[Measurement, str]:
    """Measurement of a CSV file; see :func:`fnsi.formats.read_measurement`."""
    if options.fs is None or not options.inputs:
        raise ValueError("a CSV needs the sampling rate and the input columns given with it, "
                         "e.g. {\"fs\": 2500, \"inputs\": [\"force\"]}")
    columns, rows = _count(path)
    limits.check_channels(columns, "the CSV header")
    limits.check_bytes(rows * columns * FLOAT_BYTES, "the CSV body")
    try:
        measurement = Measurement.from_csv(
            path, fs=options.fs, inputs=options.inputs, outputs=options.outputs,
            periods=options.periods or 1, quantity=options.quantity or "displacement")
    except UnicodeDecodeError:
        raise ValueError("the CSV is not UTF-8 text; export it as plain UTF-8 CSV") from None
    return finish(measurement, options.periods)


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
