"""Standard deviations of the identification (fnsi.uncertainty) against Monte Carlo truth."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fnsi.errors import model_errors
from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.study import pooled_percent, pooled_std_percent
from fnsi.uncertainty import NO_PERIODS_NOTE

REALISATIONS = 50
NOISE = 0.01
SETTINGS = dict(band=(3.0, 45.0), block_rows=8, order=6, discard_periods=1)


@pytest.fixture(scope="module")
def clean(chain, simulate_record):
    """3-DOF chain with a cubic spring at a, noise-free: 9 periods of 1,000 samples."""
    element = NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(1e9,))
    record = simulate_record(chain(3, (element,)), ["a"], fs=200.0, period=1000, periods=9,
                             oversample=4, rms=70.0)
    return record, dataclasses.replace(element, coefficients=None)


def _quantities(result) -> np.ndarray:
    """Frequencies, damping ratios, coefficient and the real parts of the shape components
    that are not the normalised one (whose value is 1 and std 0)."""
    shapes = result.modal.shapes.real
    free = np.abs(result.modal.shapes - 1) > 1e-12
    return np.concatenate([result.modal.frequencies, result.modal.damping_ratios,
                           [c.mean_real for c in result.coefficients], shapes[free]])


def _predicted(result) -> np.ndarray:
    u = result.uncertainty
    free = np.abs(result.modal.shapes - 1) > 1e-12
    return np.concatenate([u.frequencies, u.damping_ratios, u.coefficients,
                           u.shapes[:, :, 0][free]])


@pytest.mark.parametrize("options", [
    {"line_set": "excited"}, {"line_set": "all"},
    {"line_set": "all", "weighting": True, "frequency_warping": True}])
def test_predicted_std_agrees_with_monte_carlo(clean, options):
    """Mean predicted std over 50 noise realisations against the observed scatter.

    Tolerance +-30 %: the observed std of 50 realisations has a relative standard error
    of 1 / sqrt(2 x 49) = 10 %, and each prediction rests on the 8 degrees of freedom of
    the eight kept periods (mean of the square root about 3 % low); 30 % is three
    standard errors. Frequencies, damping ratios, the cubic coefficient and 6 free shape
    components are checked, on the harmonic lines, on all lines of the record, and with
    the noise weighting and the warped variable (the SmallSat settings).
    """
    record, element = clean
    settings = IdentificationSettings(**SETTINGS, elements=(element,), **options)
    rng = np.random.default_rng(7)
    level = NOISE * record.y.std(axis=1, keepdims=True)
    estimates, predictions = [], []
    for _ in range(REALISATIONS):
        noisy = dataclasses.replace(record, y=record.y + rng.standard_normal(record.y.shape)
                                    * level)
        result = identify(noisy, settings)
        assert result.order == 6 and result.modal.n_modes == 3
        estimates.append(_quantities(result))
        predictions.append(_predicted(result))
    observed = np.std(estimates, axis=0, ddof=1)
    ratio = np.mean(predictions, axis=0) / observed
    assert ratio.size == 3 + 3 + 1 + 6
    assert np.all((ratio > 0.7) & (ratio < 1.3)), ratio


def test_json_gives_each_std_beside_its_value(clean):
    record, element = clean
    result = identify(record, IdentificationSettings(**SETTINGS, elements=(element,)))
    document = result.to_json()
    mode = document["modes"][0]
    assert mode["frequency_hz_std"] == pytest.approx(result.uncertainty.frequencies[0])
    # noise-free data: the period-to-period scatter is rounding, far below any real noise
    assert 0 <= mode["frequency_hz_std"] < 1e-6 * mode["frequency_hz"]
    assert np.shape(mode["shape_std"]) == (3, 2)
    assert document["coefficients"][0]["mean_real_std"] >= 0
    assert document["uncertainty"]["note"] is None
    assert document["uncertainty"]["draws"] == 8


def test_one_kept_period_gives_no_error_bar(clean):
    record, element = clean
    result = identify(record, IdentificationSettings(**(SETTINGS | {"discard_periods": 8}),
                                                     elements=(element,)))
    assert not result.uncertainty.available
    assert result.uncertainty.note == NO_PERIODS_NOTE
    document = result.to_json()
    assert document["modes"][0]["frequency_hz_std"] is None
    assert document["coefficients"][0]["mean_real_std"] is None
    assert "at least two periods" in document["uncertainty"]["note"]


def test_uncertainty_can_be_switched_off(clean):
    record, element = clean
    result = identify(record, IdentificationSettings(**SETTINGS, elements=(element,),
                                                     uncertainty=False))
    assert result.uncertainty is None and "uncertainty" not in result.timings
    assert result.to_json()["modes"][0]["frequency_hz_std"] is None


def test_validation_error_std_agrees_with_monte_carlo():
    """Jackknife std of a study's pooled validation NRMSE against its scatter over noise.

    A model 2 % off a periodic two-channel response, 6 periods with white noise at 5 %
    of each channel's RMS; 400 realisations. Tolerance +-30 %: the observed std of 400
    realisations is known to 3.5 %, the mean of the jackknife estimates (5 degrees of
    freedom each) to about 2 %, and the jackknife of a smooth statistic is first-order
    exact; 30 % leaves room for its small-sample bias.
    """
    rng = np.random.default_rng(3)
    t = np.arange(256) / 256
    clean = np.column_stack([np.sin(2 * np.pi * 3 * t) + 0.3 * np.sin(2 * np.pi * 11 * t),
                             0.5 * np.cos(2 * np.pi * 5 * t)])[None]     # (1, 256, 2)
    simulated = 0.98 * clean
    periods, power = 6, np.mean(clean[0] ** 2, axis=0)
    values, spreads = [], []
    for _ in range(400):
        measured = np.tile(clean, (1, periods, 1)) + 0.05 * np.sqrt(power) * \
            rng.standard_normal((1, periods * 256, 2))
        errors = model_errors(measured, simulated, 256.0, periods=periods)
        values.append(pooled_percent(errors.nrmse_percent, power))
        spreads.append(pooled_std_percent(measured, simulated, periods, power))
    ratio = np.mean(spreads) / np.std(values, ddof=1)
    assert 0.7 < ratio < 1.3, ratio
    assert pooled_std_percent(measured[:, :256], simulated, 1, power) is None
