"""What every reader hands over, and how it becomes a validated measurement.

The NPZ, MAT, HDF5 and UFF readers return the variables of the canonical NPZ
(``u``, ``y``, ``fs`` and the optional names, ``periods``, ``quantity``, units); the
options given with a file complete or override them; the result is one
:class:`~fnsi.measurement.Measurement` whose values the identification can compute with.
MATLAB files may use the property names of a System Identification Toolbox ``iddata``
object instead (:data:`MATLAB_SPELLINGS`). Layouts: docs/formats.md.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
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
    units : mapping of str to str, optional
        Channel name -> unit ("N", "mm", "V"), overriding the file's; a name heading an
        input and an output sets both.
    group : str, optional
        HDF5 / MATLAB v7.3: path of the group holding the record (default: the root, or
        the one group that holds ``u`` and ``y``).
    """

    fs: float | None = None
    inputs: tuple[str, ...] | None = None
    outputs: tuple[str, ...] | None = None
    periods: int | None = None
    quantity: str | None = None
    units: Mapping[str, str] | None = None
    group: str | None = None


MATLAB_SPELLINGS = {"InputData": "u", "OutputData": "y", "Fs": "fs", "Ts": "fs",
                    "InputName": "input_names", "OutputName": "output_names",
                    "InputUnit": "input_units", "OutputUnit": "output_units"}
"""Variable names a MATLAB user may save (``iddata`` properties, ``Fs`` of the Signal
Processing Toolbox) -> canonical name; ``Ts`` is the sampling interval [s], fs = 1 / Ts."""


def canonical(variables: Mapping[str, Any]) -> dict[str, Any]:
    """``variables`` under their canonical names (:data:`MATLAB_SPELLINGS`), ``Ts``
    turned into ``fs``; ValueError when a variable is given under two spellings."""
    out: dict[str, Any] = {}
    for name, value in variables.items():
        key = MATLAB_SPELLINGS.get(name, name)
        if key in out:
            spellings = [n for n in variables if MATLAB_SPELLINGS.get(n, n) == key]
            raise ValueError(f"the file gives {key} twice, as {spellings}; keep one of them")
        out[key] = _rate_of_interval(value) if name == "Ts" else value
    return out


_CANONICAL_NAMES = ("u", "y", "fs", "periods", "quantity", "input_names", "output_names",
                    "input_units", "output_units")


def spelling_hint(found: list[str]) -> str:
    """A hint naming variables spelled like a canonical or MATLAB name in another case
    (``U`` for ``u``, ``FS`` for ``fs``, ``inputdata`` for ``InputData``), else ""."""
    known = {name.lower(): name for name in (*MATLAB_SPELLINGS, *_CANONICAL_NAMES)}
    renames = [f"{name} to {known[name.lower()]}" for name in found
               if name.lower() in known and name != known[name.lower()]]
    return f"; names are case-sensitive: rename {', '.join(renames[:5])}" if renames else ""


def _rate_of_interval(value: Any) -> float:
    interval = number(value, "Ts", float)
    if not (np.isfinite(interval) and interval > 0):
        raise ValueError(f"Ts must be a positive sampling interval [s]; the file holds "
                         f"{interval}")
    return 1.0 / interval


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
        output_names=fields.get("output_names"), periods=periods or 1, quantity=quantity,
        input_units=fields.get("input_units"), output_units=fields.get("output_units"))
    if options.inputs is not None or options.outputs is not None:
        measurement = measurement.select(options.inputs, options.outputs)
    return finish(measurement, periods, options.units)


def with_units(measurement: Measurement, units: Mapping[str, str] | None) -> Measurement:
    """``measurement`` with the channels named in ``units`` given those units."""
    if not units:
        return measurement
    unknown = sorted(set(units) - set(measurement.input_names) - set(measurement.output_names))
    if unknown:
        raise ValueError(f"units name channels {unknown} the record does not hold; channels "
                         f"are {[*measurement.input_names, *measurement.output_names]}")
    return dataclasses.replace(
        measurement,
        input_units=tuple(units.get(n, u) for n, u in zip(
            measurement.input_names, measurement.input_units, strict=True)),
        output_units=tuple(units.get(n, u) for n, u in zip(
            measurement.output_names, measurement.output_units, strict=True)))


def finish(measurement: Measurement, periods: int | None,
           units: Mapping[str, str] | None = None) -> tuple[Measurement, str]:
    """Refuse values the identification cannot compute with; set the ``units`` given
    with the file; detect the periods when neither the file nor the options declared them
    (``periods`` None)."""
    measurement = with_units(measurement, units)
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
    """Channel names or units from a string array, MATLAB char matrix or cell array of
    strings."""
    if value is None:
        return None
    flat = np.asarray(value, dtype=object).ravel()
    if any(np.asarray(v).dtype.kind not in "SU" for v in flat):
        raise ValueError(f"{name} must hold strings, one channel name each; store it as a "
                         "string array (or a MATLAB cell array of char vectors)")
    return [str(np.squeeze(v)).strip() for v in flat]
