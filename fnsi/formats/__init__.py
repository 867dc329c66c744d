"""Measurement files in every supported format, read safely.

``npz``
    The canonical NPZ of ``Measurement.to_npz`` (:mod:`fnsi.formats.npz`).
``csv``
    Header of channel names, one sample per row, an optional ``time`` column; ``fs``
    (unless the time column gives it) and ``inputs`` come with the options
    (:mod:`fnsi.formats.csv`).
``mat``
    MATLAB v5/v7 or v7.3 with the NPZ variables or the ``iddata`` spellings
    (:mod:`fnsi.formats.mat`).
``h5``
    HDF5 with datasets ``u``, ``y``, ``fs`` at the root or in a group
    (:mod:`fnsi.formats.hdf5`).
``uff``
    Universal File Format dataset 58 / 58b of time records, one record per channel
    (:mod:`fnsi.formats.uff`).

Every layout, with a runnable example per format: docs/formats.md.

Every reader knows the decoded size and the channel count from the file's headers before
it decodes any data, refuses them beyond the :class:`DecodeLimits`
(:class:`DecodedTooLargeError`, :class:`TooManyChannelsError`), never unpickles and never follows
a reference out of the file. Every other fault is a ``ValueError`` saying what to change.
Options given with a file (:class:`ReadOptions`) override what it says; when neither
gives the number of periods it is detected from the input.

Examples
--------
>>> from pathlib import Path
>>> import tempfile
>>> import numpy as np
>>> from fnsi.measurement import Measurement
>>> folder = Path(tempfile.mkdtemp())
>>> record = Measurement.from_arrays(np.tile([1.0, -1.0], 4), np.ones((8, 1)), fs=100.0)
>>> record.to_csv(folder / "run.csv")
>>> m, periods = read_measurement(folder / "run.csv", format_of("run.csv"),
...                               ReadOptions(fs=100.0, inputs=("u0",)), DecodeLimits())
>>> m.n_samples, m.output_names, m.periods, periods
(8, ('y0',), 4, 'detected')
"""

from __future__ import annotations

from pathlib import Path

from fnsi.formats import csv, hdf5, mat, npz, uff
from fnsi.formats.fields import MAX_MAGNITUDE, ReadOptions, assemble
from fnsi.formats.limits import (
    DecodedTooLargeError,
    DecodeLimitError,
    DecodeLimits,
    TooManyChannelsError,
)
from fnsi.measurement import Measurement

__all__ = [
    "FORMATS",
    "MAX_MAGNITUDE",
    "DecodeLimitError",
    "DecodeLimits",
    "DecodedTooLargeError",
    "ReadOptions",
    "TooManyChannelsError",
    "format_of",
    "read_measurement",
]

FORMATS = ("npz", "csv", "mat", "h5", "uff")
_EXTENSIONS = {".npz": "npz", ".csv": "csv", ".txt": "csv", ".mat": "mat", ".h5": "h5",
               ".hdf5": "h5", ".hdf": "h5", ".uff": "uff", ".unv": "uff"}


def format_of(filename: str, declared: str | None = None) -> str:
    """The format ``declared``, else the one the file extension names.

    Raises
    ------
    ValueError
        Neither gives one of :data:`FORMATS`.
    """
    if declared is not None:
        if declared not in FORMATS:
            raise ValueError(f"unknown format {declared!r}; choose one of {list(FORMATS)}")
        return declared
    fmt = _EXTENSIONS.get(Path(filename or "").suffix.lower())
    if fmt is None:
        raise ValueError(f"cannot tell the format of {filename!r} from its extension; name the "
                         f"file *.npz, *.csv, *.mat, *.h5 or *.uff, or set the format to one "
                         f"of {list(FORMATS)}")
    return fmt


def read_measurement(path: Path, fmt: str, options: ReadOptions | None = None,
                     limits: DecodeLimits | None = None) -> tuple[Measurement, str]:
    """Read and validate a measurement file.

    Parameters
    ----------
    path : Path
        The file.
    fmt : str
        One of :data:`FORMATS` (see :func:`format_of`).
    options : ReadOptions, optional
        Sampling rate, channels, periods or quantity completing or overriding the file.
    limits : DecodeLimits, optional
        Largest decoded size and channel count accepted; default ``DecodeLimits()``.

    Returns
    -------
    (Measurement, str)
        The measurement and ``"declared"`` or ``"detected"`` for its number of periods.

    Raises
    ------
    DecodeLimitError
        :class:`DecodedTooLargeError` or :class:`TooManyChannelsError`, before decoding.
    ValueError
        Anything else that makes the file no valid measurement; the message says what to
        change.
    """
    path, options, limits = Path(path), options or ReadOptions(), limits or DecodeLimits()
    if fmt == "csv":
        return csv.read(path, options, limits)
    if fmt == "uff":
        return assemble(uff.read_fields(path, options, limits), options)
    readers = {"npz": lambda: npz.read_fields(path, limits),
               "mat": lambda: mat.read_fields(path, limits, options),
               "h5": lambda: hdf5.read_fields(path, limits, matlab=False, group=options.group)}
    if fmt not in readers:
        raise ValueError(f"unknown format {fmt!r}; choose one of {list(FORMATS)}")
    return assemble(readers[fmt](), options)
