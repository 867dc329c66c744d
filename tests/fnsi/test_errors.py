"""Model errors and the noise floor against known perturbations and injected noise."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fnsi.errors import model_errors

FS = 1000.0
N = 1000          # samples per period
P = 8             # periods
SIGMA = 0.02      # injected noise standard deviation [m]


def _multisine(rng: np.random.Generator, channels: int) -> np.ndarray:
    """One period of a random-phase multisine on lines 5..100, RMS about 1 per channel."""
    t = np.arange(N) / FS
    lines = np.arange(5, 101)
    phases = rng.uniform(0, 2 * np.pi, (channels, lines.size))
    y = np.cos(2 * np.pi * lines[None, :, None] * t / (N / FS) + phases[..., None]).sum(1)
    return (y / np.sqrt(np.mean(y**2, axis=1, keepdims=True))).T


@pytest.fixture(scope="module")
def noisy():
    rng = np.random.default_rng(0)
    clean = _multisine(rng, 2)
    measured = np.tile(clean, (P, 1)) + SIGMA * rng.normal(size=(P * N, 2))
    return clean, measured


def test_nrmse_of_known_perturbations_in_percent_and_db():
    clean = _multisine(np.random.default_rng(1), 2)
    measured = np.tile(clean, (2, 1))
    t = np.arange(N) / FS
    model = clean.copy()
    model[:, 0] *= 0.97                                   # 3 % gain error
    model[:, 1] += 0.05 * np.sqrt(2) * np.sin(2 * np.pi * 7 * t)   # RMS 0.05 on RMS 1
    e = model_errors(measured, model, FS, periods=2, output_names=("a", "b"))
    # closed forms; rounding only
    np.testing.assert_allclose(e.nrmse_percent, [3.0, 5.0], rtol=1e-9)
    np.testing.assert_allclose(e.nrmse_db, 20 * np.log10([0.03, 0.05]), rtol=1e-9)
    assert e.overall_percent == pytest.approx(np.sqrt((9 + 25) / 2), rel=1e-9)
    # noiseless periodic measurement: no period-to-period variation
    np.testing.assert_allclose(e.noise_floor_percent, 0.0, atol=1e-10)


def test_frequency_error_sits_on_the_perturbed_line():
    clean = _multisine(np.random.default_rng(2), 1)
    t = np.arange(N) / FS
    model = clean + 0.1 * np.sin(2 * np.pi * 150 * t)[:, None]   # out of the excited band
    e = model_errors(np.tile(clean, (2, 1)), model, FS, periods=2, band=(1.0, 200.0))
    assert e.frequencies[np.argmax(e.error_spectrum[:, 0])] == pytest.approx(150.0)
    # Parseval with the 1/sqrt(N) scaling of Eq. 6: the one-sided line holds half the energy
    assert e.error_spectrum.max() ** 2 == pytest.approx(0.1**2 / 4 * N, rel=1e-9)


def test_noise_floor_matches_injected_noise(noisy):
    clean, measured = noisy
    e = model_errors(measured, clean, FS, periods=P)
    mean = measured.reshape(P, N, 2).mean(0)
    expected = 100 * SIGMA / np.sqrt(P) / np.sqrt(np.mean(mean**2, axis=0))
    # sigma^2 is estimated with N (P - 1) = 7000 degrees of freedom: relative standard
    # deviation of sigma 1 / sqrt(2 * 7000) = 0.85 %; 4 % is beyond 4.5 standard deviations
    np.testing.assert_allclose(e.noise_floor_percent, expected, rtol=0.04)
    # an exact model is judged at the floor (its error is the averaged noise); the RMS of
    # that error over 1000 samples scatters by 1 / sqrt(2000) = 2.2 %: 6 % is ~2.5 sigma
    np.testing.assert_allclose(e.nrmse_percent, e.noise_floor_percent, rtol=0.06)
    # per line: white noise of variance sigma^2 has E|N(k)|^2 = sigma^2 with Eq. 6
    # scaling, and sigma^2 / P on the average; 499 lines x 7 dof -> 1 % scatter, 5 % bound
    assert np.mean(e.noise_spectrum**2) == pytest.approx(SIGMA**2 / P, rel=0.05)


def test_realisations_and_one_period_model_are_accepted(noisy):
    clean, measured = noisy
    stacked = np.stack((measured, measured[::-1]))
    e = model_errors(stacked, np.stack((clean, clean[::-1])), FS, periods=P)
    assert e.nrmse_percent.shape == (2,)
    assert e.measured_spectrum.shape == (N // 2, 2)


def test_single_period_has_unknown_floor_and_json_null():
    clean = _multisine(np.random.default_rng(3), 1)
    e = model_errors(clean, 0.9 * clean, FS, periods=1)
    assert np.isnan(e.noise_floor_percent[0])
    data = json.loads(json.dumps(e.to_json(spectra=True)))
    assert data["channels"][0]["noise_floor_percent"] is None
    assert data["channels"][0]["nrmse_percent"] == pytest.approx(10.0)
    assert data["overall_nrmse_db"] == pytest.approx(-20.0)
    assert len(data["spectra"]["error_db"]) == N // 2


def test_bad_shapes_are_rejected_with_a_hint():
    y = np.ones((10, 2))
    with pytest.raises(ValueError, match="multiple of periods"):
        model_errors(y, y, FS, periods=3)
    with pytest.raises(ValueError, match="do not match"):
        model_errors(y, np.ones((5, 3)), FS, periods=2)
    with pytest.raises(ValueError, match="identically zero"):
        model_errors(np.zeros((10, 1)), np.zeros((10, 1)), FS, periods=2)
