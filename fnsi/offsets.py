"""Sensor offsets: the constant (0 Hz) part of measured channels, reported and removed.

FNSI never identifies the 0 Hz line. The analysis band holds the DFT lines k >= 1 only
(:func:`fnsi.spectra.band_lines`), and a displacement integrated from a velocity or an
acceleration record has no mean (:func:`fnsi.spectra.integrate_periodic`). The mean of a
measured channel over the kept (steady-state) periods is the sum of a sensor offset (the
bias of an amplifier or conditioner, a displacement sensor zeroed away from the
equilibrium) and of the true static response, e.g. the static displacement that the
nonlinear force's own mean causes. The data cannot tell the two apart, because both are
the 0 Hz line. The library therefore handles the mean as follows:

* Comparison (:func:`fnsi.validation.compare`, the study's errors and figures): always
  without 0 Hz. The measured outputs lose their mean and the simulated outputs lose
  theirs, the model's 0 Hz output, which is an extrapolation outside the band for
  displacement and is zero for velocity or acceleration. The NRMSE then covers the lines
  k >= 1, the lines of the error spectra, and by Parseval's theorem the two agree. The
  removed means are reported in each channel's unit (:meth:`Offsets.to_json`,
  :meth:`Offsets.summary`).
* Estimation and simulation: as ``IdentificationSettings.remove_offsets`` says. The
  nonlinear elements act on the true displacement about the equilibrium: a clearance's
  dead zone, a polynomial |x|^p sign(x) and a spline with g(0) = 0 are centred on x = 0
  (:mod:`fnsi.nonlinear`). Seen through a displacement sensor with offset o, a cubic
  spring k x^3 becomes k (x + o)^3, which adds a spurious quadratic term 3 k o x^2 and a
  linear spring 3 k o^2 x. With ``remove_offsets`` the means of inputs and outputs are
  removed before the estimation and before a measured input drives the model (a force
  sensor's offset would push the model to a static operating point where it was never
  identified), so the elements see zero-mean displacement, as they always do with
  velocity or acceleration data. Without it (the default), a measured displacement keeps
  its mean, which is right for a sensor that reads the true displacement: there the
  mean is the static displacement the elements see.
* Simulation of a model with elements (:func:`fnsi.simulation.simulate_periodic`,
  ``output_mean``): the elements see the simulated motion with the mean they were
  identified on (:func:`motion_mean`), not the model's own 0 Hz response to the forces'
  mean. That response is an extrapolation outside the band, and with velocity or
  acceleration data it counts twice what the data already hold: an asymmetric law's
  static shift is inside the zero-mean gap or coefficient FNSI identified, and the
  model's static response to the same force shifts the motion again (5-DOF chains with
  a one-sided stop, measured in velocity: the stop at its identified gap validated at
  6.2 and 8.9 % with the model's own mean, 1.4 and 1.0 % with the identified one).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fnsi.errors import json_float
from fnsi.measurement import Measurement
from fnsi.spectra import kept_record
from fnsi.units import INPUT_PLACEHOLDER, NOT_GIVEN, OUTPUT_PLACEHOLDER


@dataclass(frozen=True)
class Offsets:
    """Offsets of a measurement: each channel's mean over the kept periods, removed from
    every comparison and, with ``remove_offsets``, from the estimation.

    Attributes
    ----------
    input_names, output_names : tuple of str
        The m input and l output channels.
    inputs : ndarray, shape (R, m)
        Offset of each input in each realisation [input unit].
    outputs : ndarray, shape (R, l)
        Offset of each output in each realisation [output unit, the measured quantity].
    input_units, output_units : tuple of str
        Unit of each channel (empty when not given).
    """

    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    inputs: np.ndarray
    outputs: np.ndarray
    input_units: tuple[str, ...]
    output_units: tuple[str, ...]

    def _channels(self, kind: str) -> list[tuple[str, np.ndarray, str]]:
        """(name, offsets over realisations (R,), unit) of the inputs or the outputs."""
        names, values, units, placeholder = (
            (self.input_names, self.inputs, self.input_units, INPUT_PLACEHOLDER)
            if kind == "inputs" else
            (self.output_names, self.outputs, self.output_units, OUTPUT_PLACEHOLDER))
        return [(name, values[:, k], unit if unit != NOT_GIVEN else placeholder)
                for k, (name, unit) in enumerate(zip(names, units, strict=True))]

    def to_json(self) -> dict:
        """JSON: per input and per output channel its ``offset`` (mean over the
        realisations), ``per_realisation`` offsets and ``unit``."""
        return {kind: [{"channel": name, "offset": json_float(float(np.mean(values))),
                        "per_realisation": [json_float(v) for v in values], "unit": unit}
                       for name, values, unit in self._channels(kind)]
                for kind in ("inputs", "outputs")}

    def summary(self, data: str) -> str:
        """One line naming the offsets of the ``data`` ("validation", ...)."""
        return describe(self.to_json(), data)


def describe(offsets: dict, data: str) -> str:
    """One line naming the offsets of :meth:`Offsets.to_json` in the ``data``
    ("validation", ...), outputs first."""
    words = [f"{c['channel']} {'-' if c['offset'] is None else format(c['offset'], '.3g')} "
             f"{c['unit']}" for kind in ("outputs", "inputs") for c in offsets[kind]]
    return (f"offsets of the {data} data (mean of the kept periods; 0 Hz is not "
            f"compared): {', '.join(words)}")


def remove_offsets(measurement: Measurement, discard_periods: int,
                   ) -> tuple[Measurement, Offsets]:
    """The measurement without its offsets, and the offsets (module docstring).

    Parameters
    ----------
    measurement : Measurement
        Periodic record with more than ``discard_periods`` periods.
    discard_periods : int
        Leading transient periods. They are left out of the mean but lose it too, because
        a sensor offset is constant.

    Returns
    -------
    centred : Measurement
        Every channel of every realisation minus its mean over the kept periods.
    offsets : Offsets

    Examples
    --------
    >>> m = Measurement.from_arrays(np.array([1.0, -1.0, 1.0, -1.0]),
    ...                             np.array([3.0, 1.0, 2.5, 1.5]), fs=4.0, periods=2)
    >>> centred, offsets = remove_offsets(m, 1)
    >>> float(offsets.outputs[0, 0]), centred.y[0, :, 0].tolist()
    (2.0, [1.0, -1.0, 0.5, -0.5])
    """
    offsets = measured_offsets(measurement, discard_periods)
    return replace(measurement, u=measurement.u - offsets.inputs[:, None],
                   y=measurement.y - offsets.outputs[:, None]), offsets


def measured_offsets(measurement: Measurement, discard_periods: int) -> Offsets:
    """The offsets of :func:`remove_offsets` without a centred copy of the record.

    Parameters
    ----------
    measurement : Measurement
    discard_periods : int
        Leading transient periods left out of the mean.
    """
    means = [kept_record(x, measurement.periods, discard_periods).mean(axis=1)
             for x in (measurement.u, measurement.y)]
    return Offsets(measurement.input_names, measurement.output_names, *means,
                   measurement.input_units, measurement.output_units)


def motion_mean(measurement: Measurement, discard_periods: int) -> np.ndarray:
    """The mean of each output's displacement as the identification evaluates the
    elements on it, shape (l,) [displacement unit]: the measured mean over the kept
    periods (averaged over the realisations) for displacement data; zero for velocity or
    acceleration data, whose displacement is integrated without mean, and for data whose
    offsets were removed (their mean is zero).

    Examples
    --------
    >>> m = Measurement.from_arrays(np.array([1.0, -1.0, 1.0, -1.0]),
    ...                             np.array([3.0, 1.0, 2.5, 1.5]), fs=4.0, periods=2)
    >>> motion_mean(m, 1).tolist()
    [2.0]
    """
    if measurement.quantity != "displacement":
        return np.zeros(measurement.n_outputs)
    return measured_offsets(measurement, discard_periods).outputs.mean(axis=0)
