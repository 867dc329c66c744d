"""What every reader hands over, and how it becomes a validated measurement.

The NPZ, MAT, HDF5 and UFF readers return the variables of the canonical NPZ
(``u``, ``y``, ``fs`` and the optional names, ``periods``, ``quantity``); the options
given with a file complete or override them; the result is one
:class:`~fnsi.measurement.Measurement` whose values the identification can compute with.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np

from fnsi.measurement import Measurement
from fnsi.summary import detect_periods

MAX_MAGNITUDE = 1e15
"""Largest sample magnitude accepted, in the channel's unit.

The identification computes in float64 (largest number ~1.8e308): its nonlinear bases
raise outputs to the power p, spectra sum N samples, and least squares square them
again, so a value B reaches about (N B^p)^2 N. With B = 1e15 and N = 1e8 samples (the
decode limit's order) that is 1e114 for a cubic and 1e294 for p = 9, still finite; at
B = 1e200 the squares are already infinite and every result would be NaN (a 5-DOF chain
with a cubic spring, scaled to 5e12, identifies its modes within 3e-6 and its
coefficient within 2e-5 of the unscaled record; scaled to 1e200 its eigenvalues do not
converge). Physical records stay far below: a 1 MN force in micronewtons is 1e12.
"""


@dataclass(frozen=True)
class ReadOptions:
    """What completes or overrides a file (None: use the file).

    Attributes
    ----------
    fs : float, optional
        Sampling rate [Hz]; a CSV needs it.
    inputs, outputs : tuple of str, optional
        Channels to keep (a CSV needs the inputs: they tell forces from responses).
    periods : int, optional
        Excitation periods per record; without it from the file, else detected.
    quantity : str, optional
        What the outputs measure.
    """

    fs: float | None = None
    inputs: tuple[str, ...] | None = None
    outputs: tuple[str, ...] | None = None
    periods: int | None = None
    quantity: str | None = None


def scalar(value: Any, name: str) -> Any:
    """The single element of a file's scalar variable ``name`` (0-d or one-element array);
    ValueError for anything else, so ``fs = []`` or a two-element ``periods`` is named."""
    array = np.asarray(value)
    if array.size != 1:
        raise ValueError(f"{name} must be a single value; the file holds an array of shape "
                         f"{array.shape}: store {name} as a scalar")
    return array.ravel()[0]


def number(value: Any, name: str, kind: type) -> float | int | None:
    """``scalar`` converted to ``kind`` (float or int), None when absent."""
    if value is None:
        return None
    item = scalar(value, name)
    if (isinstance(item, np.generic) and not np.issubdtype(item.dtype, np.number)) \
            or isinstance(item, str | bytes):
        raise ValueError(f"{name} must be a number; the file holds {item!r}")
    try:
        converted = kind(item)
    except OverflowError:  # int(inf)
        raise ValueError(f"{name} must be finite; the file holds {item}") from None
    if kind is int and converted != item:
        raise ValueError(f"{name} must be a whole number; the file holds {item}")
    return converted


def assemble(fields: dict[str, Any], options: ReadOptions) -> tuple[Measurement, str]:
    """Measurement from a reader's variables, the options overriding them.

    Parameters
    ----------
    fields : dict
        ``u``, ``y`` (arrays, see :meth:`Measurement.from_arrays`); optional ``fs`` [Hz],
        ``periods``, ``quantity``, ``input_names``, ``output_names`` (None when absent).
    options : ReadOptions
        Given with the file.

    Returns
    -------
    (Measurement, str)
        The measurement and ``"declared"`` or ``"detected"`` for its number of periods.
    """
    fs = options.fs if options.fs is not None else number(fields.get("fs"), "fs", float)
    if fs is None:
        raise ValueError("the file gives no sampling rate; add the option fs (Hz)")
    periods = options.periods if options.periods is not None else number(
        fields.get("periods"), "periods", int)
    quantity = options.quantity or fields.get("quantity") or "displacement"
    measurement = Measurement.from_arrays(
        fields["u"], fields["y"], fs, input_names=fields.get("input_names"),
        output_names=fields.get("output_names"), periods=periods or 1, quantity=quantity)
    if options.inputs is not None or options.outputs is not None:
        measurement = measurement.select(options.inputs, options.outputs)
    return finish(measurement, periods)


def finish(measurement: Measurement, periods: int | None) -> tuple[Measurement, str]:
    """Refuse values the identification cannot compute with; detect the periods when
    neither the file nor the options declared them (``periods`` None)."""
    for name, values in (("u", measurement.u), ("y", measurement.y)):
        largest = float(np.max(np.abs(values)))
        if largest > MAX_MAGNITUDE:
            raise ValueError(
                f"{name} holds values up to {largest:.3g} in magnitude; the identification "
                "computes in float64 and raises outputs to powers, which overflows beyond "
                f"{MAX_MAGNITUDE:.0e}: rescale the channels (express them in a larger unit) "
                f"so that every value stays below {MAX_MAGNITUDE:.0e}")
    if periods is not None:
        return measurement, "declared"
    detected = detect_periods(measurement.u)
    return dataclasses.replace(measurement, periods=detected), "detected"


def strings(value: Any, name: str) -> list[str] | None:
    """Channel names from a string array, MATLAB char matrix or cell array of strings."""
    if value is None:
        return None
    flat = np.asarray(value, dtype=object).ravel()
    if any(np.asarray(v).dtype.kind not in "SU" for v in flat):
        raise ValueError(f"{name} must hold strings, one channel name each; store it as a "
                         "string array (or a MATLAB cell array of char vectors)")
    return [str(np.squeeze(v)).strip() for v in flat]
