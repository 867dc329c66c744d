"""Model versus measurement: run an identified model with the measured input.

docs/design.md section 3, step 7. The identified nonlinear state-space model is driven to
periodic steady state by one period of each realisation's measured input, at a finer
internal rate when its elements are non-smooth and fs is low (:func:`fnsi.oversampling.
simulate_oversampled`); FNSI models predict displacement, so the
prediction is differentiated exactly (periodic data) into the measured quantity and
compared with the kept periods of the measurement (:func:`fnsi.errors.model_errors`),
per channel and per line, against the noise floor.

Both sides are compared without their 0 Hz line, which no identification band contains
(:mod:`fnsi.offsets`): the measured outputs lose their mean over the kept periods (their
sensor offsets, reported in :attr:`Comparison.offsets`) and the simulated outputs theirs.
The input drives the model as the estimation saw it: without its offset when the model
was identified with ``remove_offsets``; and as the structure received it, the average of
the kept periods without the lines where the force sensor measured only its noise
(:func:`fnsi.spectra.measured_excitation`). The elements' motion is shifted by the
model's ``motion_offsets``; a model without them is given those with which its elements
see the measurement's mean as the identification did (:func:`fnsi.offsets.motion_mean`):
on the estimation record, where the identification finds them (:mod:`fnsi.offsets`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from fnsi.errors import ModelErrors, model_errors
from fnsi.measurement import Measurement
from fnsi.offsets import Offsets, motion_mean, remove_offsets
from fnsi.oversampling import simulate_oversampled
from fnsi.spectra import INTEGRATIONS, integrate_periodic, kept_record, measured_excitation
from fnsi.statespace import StateSpaceModel

if TYPE_CHECKING:
    from fnsi.identification import IdentificationResult

#: The error spectra reach this multiple of the band's upper edge, so that harmonics
#: created by an unmodelled nonlinearity show up above the identification band.
ERROR_BAND_FACTOR = 3.0
#: Periods after which the simulated state is moved to the linear part's periodic state
#: under the last period's forces, until the response repeats (``corrections`` of
#: :func:`fnsi.simulation.simulate_periodic`; the steady state is declared on periods run
#: freely after them). A model whose nonlinear forces excite a slow mode (a stop's or a
#: quadratic spring's static shift on a pole at |z| = 0.9999) otherwise drifts for more
#: than the 100 periods allowed: a clearance model that the order search had simulated
#: with corrections could not be compared on the validation record without them.
CORRECTIONS = 30


@dataclass(frozen=True)
class Comparison:
    """A model's prediction of a measurement and its errors.

    Attributes
    ----------
    simulated : ndarray, shape (realisations, period_length, l)
        One steady-state period of the model's outputs per realisation, in the measured
        quantity, with zero mean like the measurement it is compared with.
    errors : ModelErrors
        NRMSE per channel and line against the noise floor of the kept periods, without
        the 0 Hz line.
    offsets : Offsets
        Sensor offsets removed from the measurement (:mod:`fnsi.offsets`).
    motion_offsets : ndarray, shape (E,)
        Offsets of the elements' relative displacements in the simulation: the model's
        (:attr:`fnsi.statespace.StateSpaceModel.motion_offsets`), or, for a model
        without them, those that gave the elements the measurement's mean
        (:func:`fnsi.offsets.motion_mean`), averaged over the realisations.
    """

    simulated: np.ndarray
    errors: ModelErrors
    offsets: Offsets
    motion_offsets: np.ndarray


def compare(model: StateSpaceModel, measurement: Measurement, *, discard_periods: int,
            band_high: float, oversampling: int | None = None,
            feedthrough: str = "implicit", offsets_removed: bool = False,
            max_periods: int = 100, corrections: int = CORRECTIONS) -> Comparison:
    """Simulate ``model`` with the input of ``measurement`` and compare the outputs.

    Parameters
    ----------
    model : StateSpaceModel
        Identified model; its input and output names select the measured channels. Its
        rate is the measurement's, or a whole multiple of it for a model refined at the
        internal rate of :mod:`fnsi.oversampling` (simulated at its own rate).
    measurement : Measurement
        Periodic measurement with at least ``discard_periods + 1`` periods.
    discard_periods : int
        Leading (transient) periods left out of the comparison.
    band_high : float
        Upper edge of the identification band [Hz]; the error spectra reach
        ``ERROR_BAND_FACTOR`` times it (at most fs / 2).
    oversampling : int, optional
        Internal samples per sample of the model; default the model's
        :func:`fnsi.oversampling.oversampling_factor`. Give 1 for a refined model, which
        was fitted through the simulation at its own rate.
    feedthrough : {"implicit", "explicit"}
        Treatment of the nonlinear feed-through (:mod:`fnsi.simulation`): ``"explicit"``
        runs a model whose implicit output equation folds.
    offsets_removed : bool
        The model was identified on data without their sensor offsets
        (``IdentificationSettings.remove_offsets``), so it is driven by the measured input
        without its offset too.
    max_periods, corrections : int
        Most periods simulated to reach the steady state (a model that takes more cannot
        be compared: :class:`fnsi.simulation.SimulationDivergedError`), and periods
        after which the state is corrected towards it (:data:`CORRECTIONS`).

    Returns
    -------
    Comparison
        Simulated outputs and errors with the 0 Hz line of both sides removed, and the
        measurement's offsets.

    Raises
    ------
    ValueError
        If the measurement lacks a channel of the model, or the model cannot be
        simulated (:class:`fnsi.simulation.SimulationDivergedError`).
    """
    data = measurement.select(inputs=model.input_names, outputs=model.output_names)
    centred, offsets = remove_offsets(data, discard_periods)
    measured = kept_record(centred.y, data.periods, discard_periods)
    u = measured_excitation(kept_record((centred if offsets_removed else data).u, data.periods,
                                        discard_periods), data.periods - discard_periods)
    # a model without offsets: the elements see the mean the identification saw
    mean = motion_mean(centred if offsets_removed else data, discard_periods)
    periods, motion_offsets = simulate_oversampled(model, u, band_high, oversampling,
                                                   feedthrough, max_periods, corrections,
                                                   output_mean=mean, fs=data.fs)
    simulated = integrate_periodic(periods, data.fs, -INTEGRATIONS[data.quantity])
    simulated = simulated - simulated.mean(axis=1, keepdims=True)
    high = min(data.fs / 2, ERROR_BAND_FACTOR * band_high)
    errors = model_errors(measured, simulated, data.fs, periods=data.periods - discard_periods,
                          output_names=data.output_names, band=(0.0, high))
    return Comparison(simulated, errors, offsets, motion_offsets)


def compare_identified(result: IdentificationResult, measurement: Measurement,
                       feedthrough: str = "implicit") -> Comparison:
    """:func:`compare` for an identification: its transient periods, band and offset
    rule, and a refined model simulated at its own rate, through the simulation refinement
    fitted it (the internal rate of :mod:`fnsi.oversampling`, or fs).

    Parameters
    ----------
    result : IdentificationResult
        The identification whose model is compared.
    measurement : Measurement
        Estimation or validation data.
    feedthrough : {"implicit", "explicit"}
        As in :func:`compare`.

    Returns
    -------
    Comparison
    """
    refined = result.refinement is not None and result.refinement.iterations > 0
    return compare(result.model, measurement, discard_periods=result.settings.discard_periods,
                   band_high=result.settings.band[1], oversampling=1 if refined else None,
                   feedthrough=feedthrough, offsets_removed=result.settings.remove_offsets)
