"""Measured periodic input-output records (paper Section II.B, IV.A).

A measurement holds the input forces u and outputs y of one or several independent
realisations of a periodic excitation, each recorded over an integer number of periods.
Array convention: ``(realisations, samples, channels)``.
"""

from __future__ import annotations

import csv
import zipfile
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Literal, get_args

import numpy as np

from fnsi.units import NOT_GIVEN, ModelUnits

Quantity = Literal["displacement", "velocity", "acceleration"]
QUANTITIES: tuple[str, ...] = get_args(Quantity)

FileLike = str | Path | IO

NPZ_VARIABLES = ("u", "y", "fs", "input_names", "output_names", "periods", "quantity",
                 "input_units", "output_units")
"""The arrays of the canonical NPZ dataset (docs/design.md section 6)."""

NOT_A_ZIP = ("not an NPZ (zip) file: save the arrays with numpy.savez or "
             "numpy.savez_compressed, or name the file after its real format")
"""Why bytes that are no zip archive are refused as an NPZ dataset."""


def _as_record(array: np.ndarray, name: str) -> np.ndarray:
    """Return ``array`` as (realisations, samples, channels) float64, rejecting other ranks."""
    a = np.asarray(array, dtype=np.float64)
    if a.ndim == 1:
        return a[None, :, None]
    if a.ndim == 2:
        return a[None]
    if a.ndim == 3:
        return a
    raise ValueError(
        f"{name} must be 1-D (samples,), 2-D (samples, channels) or 3-D "
        f"(realisations, samples, channels); got an array of shape {a.shape}"
    )


def _names(names, count: int, prefix: str, what: str) -> tuple[str, ...]:
    """Validated channel names, defaulting to ``prefix0, prefix1, ...``."""
    if names is None:
        return tuple(f"{prefix}{k}" for k in range(count))
    result = tuple(str(n) for n in np.atleast_1d(np.asarray(names, dtype=str)))
    if len(result) != count:
        raise ValueError(
            f"{what} has {len(result)} names for {count} channels; give one per column"
        )
    if len(set(result)) != len(result):
        raise ValueError(f"{what} must be unique; got {list(result)}")
    return result


def _units(units, count: int, what: str) -> tuple[str, ...]:
    """One unit per channel (empty string: not given); a single unit applies to every
    channel; none given by default."""
    given = () if units is None else tuple(
        str(u).strip() for u in np.atleast_1d(np.asarray(units, dtype=str)))
    if len(given) in (0, 1):
        return (given[0] if given else NOT_GIVEN,) * count
    if len(given) != count:
        raise ValueError(f"{what} has {len(given)} units for {count} channels; give one per "
                         "channel (an empty string for a unit not known), or one for all")
    return given


def check_channels(chosen, valid: tuple[str, ...], kind: str) -> None:
    """ValueError unless every name of ``chosen`` is one of ``valid``, each once.

    A channel chosen twice would enter the data matrices twice, as two outputs that no
    model can tell apart, and make the channel names of the result ambiguous.

    Parameters
    ----------
    chosen : sequence of str
        Channel names chosen, in order.
    valid : tuple of str
        Names of the channels there are.
    kind : str
        What they are, for the message (``"input"``, ``"output"``).

    Examples
    --------
    >>> check_channels(("y1", "y1"), ("y0", "y1"), "output")
    Traceback (most recent call last):
    ValueError: outputs ['y1'] are chosen more than once; name each output channel once
    """
    for name in chosen:
        _index(valid, name, kind)
    repeated = sorted(name for name, count in Counter(chosen).items() if count > 1)
    if repeated:
        raise ValueError(f"{kind}s {repeated} are chosen more than once; name each {kind} "
                         "channel once")


def _index(names: tuple[str, ...], name: str, kind: str) -> int:
    """Position of channel ``name`` among ``names``; ValueError listing the valid names."""
    try:
        return names.index(name)
    except ValueError:
        raise ValueError(f"unknown {kind} channel {name!r}; {kind}s are {list(names)}") from None


@dataclass(frozen=True)
class Layout:
    """The shape of a measurement without its samples.

    What checks of identification settings need (:func:`fnsi.identification.
    check_settings`), so that a service holding only a dataset's summary can refuse bad
    settings before any data are loaded.

    Attributes
    ----------
    fs : float
        Sampling rate [Hz].
    periods : int
        Periods in each record.
    period_length : int
        Samples per period.
    n_realisations : int
        Independent realisations.
    input_names, output_names : tuple of str
        Channel names.
    """

    fs: float
    periods: int
    period_length: int
    n_realisations: int
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]

    @property
    def n_inputs(self) -> int:
        """Number m of input channels."""
        return len(self.input_names)

    @property
    def n_outputs(self) -> int:
        """Number l of output channels."""
        return len(self.output_names)

    @property
    def n_samples(self) -> int:
        """Samples per realisation."""
        return self.periods * self.period_length

    def input_index(self, name: str) -> int:
        """Column of input ``name``; ValueError listing the valid names."""
        return _index(self.input_names, name, "input")

    def output_index(self, name: str) -> int:
        """Column of output ``name``; ValueError listing the valid names."""
        return _index(self.output_names, name, "output")

    def select(self, inputs=None, outputs=None) -> Layout:
        """Layout of the named inputs and outputs (None keeps all), in order."""
        check_channels(inputs or (), self.input_names, "input")
        check_channels(outputs or (), self.output_names, "output")
        return Layout(self.fs, self.periods, self.period_length, self.n_realisations,
                      self.input_names if inputs is None else tuple(inputs),
                      self.output_names if outputs is None else tuple(outputs))


@dataclass(frozen=True)
class Measurement:
    """Periodic input-output record of a structure.

    Attributes
    ----------
    u : ndarray, shape (realisations, samples, m)
        Input forces [input unit].
    y : ndarray, shape (realisations, samples, l)
        Outputs [output unit], measuring ``quantity``.
    fs : float
        Sampling rate [Hz].
    input_names, output_names : tuple of str
        Channel names, unique within inputs and within outputs. An input named like an
        output marks a force applied at that measured DOF (a driving point).
    periods : int
        Number of excitation periods in each realisation record; divides ``samples``.
    quantity : {"displacement", "velocity", "acceleration"}
        What ``y`` measures.
    input_units, output_units : tuple of str
        Unit of each channel as free text ("N", "mm", "V"); an empty string when not
        given (labels then say "input unit", "output unit": :mod:`fnsi.units`). Given as
        an empty tuple (none given) or a single unit, they are one per channel after
        construction.

    Examples
    --------
    >>> import numpy as np
    >>> m = Measurement.from_arrays(np.ones(8), np.zeros((8, 2)), fs=100.0, periods=2)
    >>> m.n_outputs, m.period_length, m.output_names
    (2, 4, ('y0', 'y1'))
    """

    u: np.ndarray
    y: np.ndarray
    fs: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    periods: int = 1
    quantity: str = "displacement"
    input_units: tuple[str, ...] = ()
    output_units: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        u, y = self.u, self.y
        if u.ndim != 3 or y.ndim != 3:
            raise ValueError("u and y must be 3-D (realisations, samples, channels); "
                             "use Measurement.from_arrays for 1-D or 2-D arrays")
        if u.shape[:2] != y.shape[:2]:
            raise ValueError(
                f"u and y must have the same realisations and samples; got u {u.shape[:2]} "
                f"and y {y.shape[:2]} (realisations, samples)"
            )
        if u.shape[1] == 0 or u.shape[2] == 0 or y.shape[2] == 0:
            raise ValueError(f"empty record: u {u.shape}, y {y.shape}; need samples, "
                             "at least one input and one output")
        for name, a in (("u", u), ("y", y)):
            if not np.all(np.isfinite(a)):
                bad = np.argwhere(~np.isfinite(a))[0]
                raise ValueError(f"{name} contains NaN or infinite values (first at "
                                 f"realisation {bad[0]}, sample {bad[1]}, channel {bad[2]})")
        if not (np.isfinite(self.fs) and self.fs > 0):
            raise ValueError(f"fs must be a positive sampling rate in Hz; got {self.fs}")
        if int(self.periods) != self.periods or self.periods < 1:
            raise ValueError(f"periods must be a positive integer; got {self.periods}")
        if u.shape[1] % int(self.periods):
            raise ValueError(f"periods={self.periods} does not divide the {u.shape[1]} samples "
                             "per realisation; trim the record to whole periods")
        if self.quantity not in QUANTITIES:
            raise ValueError(f"quantity must be one of {QUANTITIES}; got {self.quantity!r}")
        if len(self.input_names) != u.shape[2] or len(self.output_names) != y.shape[2]:
            raise ValueError("one name per input and per output channel is required")
        for what, names in (("input_names", self.input_names),
                            ("output_names", self.output_names)):
            if len(set(names)) != len(names):
                raise ValueError(f"{what} must be unique; got {list(names)}")
        object.__setattr__(self, "periods", int(self.periods))
        object.__setattr__(self, "fs", float(self.fs))
        object.__setattr__(self, "input_units", _units(self.input_units, u.shape[2],
                                                       "input_units"))
        object.__setattr__(self, "output_units", _units(self.output_units, y.shape[2],
                                                        "output_units"))

    @classmethod
    def from_arrays(cls, u, y, fs: float, *, input_names=None, output_names=None,
                    periods: int = 1, quantity: str = "displacement", input_units=None,
                    output_units=None) -> Measurement:
        """Build a measurement from 1-D, 2-D or 3-D arrays (see class docstring for axes).

        Parameters
        ----------
        u, y : array_like
            (samples,), (samples, channels) or (realisations, samples, channels).
        fs : float
            Sampling rate [Hz].
        input_names, output_names : sequence of str, optional
            Default ``u0, u1, ...`` and ``y0, y1, ...``.
        periods : int
            Periods per realisation record.
        quantity : str
            "displacement", "velocity" or "acceleration".
        input_units, output_units : sequence of str or str, optional
            One unit per channel, or one for all; default not given.
        """
        u3, y3 = _as_record(u, "u"), _as_record(y, "y")
        return cls(u3, y3, float(fs), _names(input_names, u3.shape[2], "u", "input_names"),
                   _names(output_names, y3.shape[2], "y", "output_names"), periods, quantity,
                   input_units, output_units)  # one per channel after __post_init__

    # -- properties ------------------------------------------------------------------------
    @property
    def n_inputs(self) -> int:
        """Number m of input channels."""
        return int(self.u.shape[2])

    @property
    def n_outputs(self) -> int:
        """Number l of output channels."""
        return int(self.y.shape[2])

    @property
    def n_samples(self) -> int:
        """Samples per realisation."""
        return int(self.u.shape[1])

    @property
    def n_realisations(self) -> int:
        """Number of independent realisations."""
        return int(self.u.shape[0])

    @property
    def period_length(self) -> int:
        """Samples per period."""
        return self.n_samples // self.periods

    @property
    def units(self) -> ModelUnits:
        """Units of what is identified from this record (FRF, coefficients, curves)."""
        return ModelUnits.of(self.input_units, self.output_units, self.quantity)

    @property
    def layout(self) -> Layout:
        """The shape of this measurement without its samples."""
        return Layout(self.fs, self.periods, self.period_length, self.n_realisations,
                      self.input_names, self.output_names)

    # -- channels --------------------------------------------------------------------------
    def output_index(self, name: str) -> int:
        """Column of output ``name`` in ``y``; ValueError listing the valid names."""
        return _index(self.output_names, name, "output")

    def input_index(self, name: str) -> int:
        """Column of input ``name`` in ``u``; ValueError listing the valid names."""
        return _index(self.input_names, name, "input")

    def select(self, inputs=None, outputs=None) -> Measurement:
        """Measurement restricted to the named inputs and outputs (None keeps all), in order."""
        self.layout.select(inputs, outputs)  # names valid, none twice
        iu = [self.input_index(n) for n in inputs] if inputs is not None else None
        iy = [self.output_index(n) for n in outputs] if outputs is not None else None
        return Measurement(
            self.u if iu is None else self.u[:, :, iu],
            self.y if iy is None else self.y[:, :, iy],
            self.fs,
            self.input_names if iu is None else tuple(inputs),
            self.output_names if iy is None else tuple(outputs),
            self.periods,
            self.quantity,
            self.input_units if iu is None else tuple(self.input_units[k] for k in iu),
            self.output_units if iy is None else tuple(self.output_units[k] for k in iy),
        )

    # -- NPZ -------------------------------------------------------------------------------
    @classmethod
    def from_npz(cls, file: FileLike) -> Measurement:
        """Read the canonical NPZ dataset (docs/design.md section 6), never unpickling.

        Arrays ``u`` and ``y`` (2-D samples x channels, 1-D, or 3-D with realisations first),
        scalar ``fs``; optional ``input_names``, ``output_names``, ``periods``, ``quantity``,
        ``input_units``, ``output_units`` (docs/formats.md).
        Files from elsewhere go through :func:`fnsi.formats.read_measurement`, which checks
        their sizes before decoding.
        """
        try:
            with np.load(file, allow_pickle=False) as data:
                missing = [k for k in ("u", "y", "fs") if k not in data.files]
                if missing:
                    raise ValueError(f"NPZ dataset lacks required arrays {missing}; it needs "
                                     "u (samples x m), y (samples x l) and fs (scalar, Hz)")
                # only the dataset's own arrays: any other member stays compressed
                fields = {k: data[k] for k in NPZ_VARIABLES if k in data.files}
        except (OSError, EOFError) as err:
            raise ValueError(f"not a readable NPZ file: {err}") from err
        except ValueError as err:
            if "pickle" not in str(err).lower():
                raise
            if not zipfile.is_zipfile(file):  # np.load takes other bytes for a pickle
                raise ValueError(NOT_A_ZIP) from None
            raise ValueError("NPZ contains object arrays; store names as unicode arrays "
                             "(object arrays are refused for safety)") from err
        fs, periods = (np.asarray(fields.get(k, 1)) for k in ("fs", "periods"))
        for name, value in (("fs", fs), ("periods", periods)):
            if value.size != 1:
                raise ValueError(f"{name} must be a scalar; got an array of shape "
                                 f"{value.shape}")
        quantity = str(fields["quantity"]) if "quantity" in fields else "displacement"
        return cls.from_arrays(fields["u"], fields["y"], float(fs), periods=periods.item(),
                               input_names=fields.get("input_names"),
                               output_names=fields.get("output_names"), quantity=quantity,
                               input_units=fields.get("input_units"),
                               output_units=fields.get("output_units"))

    def to_npz(self, file: FileLike) -> None:
        """Write the canonical NPZ dataset (2-D u, y for a single realisation, else 3-D)."""
        squeeze = self.n_realisations == 1
        np.savez(file, u=self.u[0] if squeeze else self.u, y=self.y[0] if squeeze else self.y,
                 fs=np.float64(self.fs), input_names=np.array(self.input_names, dtype=str),
                 output_names=np.array(self.output_names, dtype=str),
                 periods=np.int64(self.periods), quantity=np.str_(self.quantity),
                 input_units=np.array(self.input_units, dtype=str),
                 output_units=np.array(self.output_units, dtype=str))

    # -- CSV -------------------------------------------------------------------------------
    @classmethod
    def from_csv(cls, file: FileLike, *, fs: float, inputs, outputs=None, periods: int = 1,
                 quantity: str = "displacement") -> Measurement:
        """Read a CSV whose header names the channels, one sample per row.

        Linear in the file's size: the body is parsed by numpy from the open file, and
        names are looked up in dictionaries.

        Parameters
        ----------
        file : path or text file
            Comma-separated, first row channel names; UTF-8.
        fs : float
            Sampling rate [Hz].
        inputs : sequence of str
            Header names of the input (force) columns.
        outputs : sequence of str, optional
            Header names of the output columns; default every non-input column.
        periods, quantity
            As in :meth:`from_arrays`.
        """
        if isinstance(file, str | Path):
            with open(file, encoding="utf-8", newline="") as f:
                return cls.from_csv(f, fs=fs, inputs=inputs, outputs=outputs, periods=periods,
                                    quantity=quantity)
        header = [h.strip() for h in next(csv.reader([file.readline()]), [])]
        if not header:
            raise ValueError("CSV is empty; the first row must name the channels")
        # a name may head two columns (force and response at one DOF, as to_csv writes
        # them): inputs take the first such column, outputs the last
        first = {h: k for k, h in reversed(list(enumerate(header)))}
        last = {h: k for k, h in enumerate(header)}
        inputs = [inputs] if isinstance(inputs, str) else list(inputs)
        if outputs is None:
            taken = {first[n] for n in inputs if n in first}
            outputs = [h for k, h in enumerate(header) if k not in taken]
        unknown = [n for n in (*inputs, *outputs) if n not in first]
        if unknown:
            raise ValueError(f"CSV has no column(s) {unknown[:20]}; header is "
                             f"{header[:50]}{' ...' if len(header) > 50 else ''}")
        try:
            data = np.loadtxt(file, delimiter=",", ndmin=2)
        except ValueError as err:
            raise ValueError(f"CSV body must be numeric: {err}") from err
        if data.shape[1] != len(header):
            raise ValueError(f"CSV rows have {data.shape[1]} values for {len(header)} header names")
        u = data[:, [first[n] for n in inputs]]
        y = data[:, [last[n] for n in outputs]]
        return cls.from_arrays(u, y, fs, input_names=inputs, output_names=outputs, periods=periods,
                               quantity=quantity)

    def to_csv(self, file: FileLike) -> None:
        """Write inputs then outputs, header of channel names (single realisation only)."""
        if self.n_realisations != 1:
            raise ValueError(f"CSV holds one realisation; this measurement has "
                             f"{self.n_realisations}: use to_npz or select a realisation")
        table = np.hstack([self.u[0], self.y[0]])
        header = ",".join(self.input_names + self.output_names)
        np.savetxt(file, table, delimiter=",", header=header, comments="", fmt="%.17g")
