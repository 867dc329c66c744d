"""The claim rule's statistics (fnsi.claim) against known truth."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi.claim import claim_test, improvement_z, unexplained, validation_spectra

N, PERIODS, FS = 256, 4, 256.0
LINES = np.arange(1, N // 2)


def _truth() -> np.ndarray:
    """One period of two channels: a sum of sines on every line, (1, N, 2)."""
    rng = np.random.default_rng(0)
    t = np.arange(N) / FS
    y = sum(np.cos(2 * np.pi * k * t + rng.uniform(0, 2 * np.pi)) for k in LINES)
    return np.stack([y, 0.5 * y], axis=-1)[None]


def _measured(truth: np.ndarray, rng: np.random.Generator, sigma: float) -> np.ndarray:
    """PERIODS noisy periods of the truth, (1, PERIODS * N, 2)."""
    record = np.tile(truth, (1, PERIODS, 1))
    return record + sigma * rng.standard_normal(record.shape)


def test_z_is_standard_normal_when_the_candidate_is_no_better():
    """Two models equally far from the truth (errors +d and -d): the true improvement is
    zero, so z must be N(0, 1) over noise draws, whatever the size of the model error."""
    truth = _truth()
    d = 0.05 * np.roll(truth, 3, axis=1)
    rng = np.random.default_rng(1)
    draws = [improvement_z(validation_spectra(_measured(truth, rng, 0.3), PERIODS, LINES),
                           truth + d, truth - d) for _ in range(400)]
    # 400 draws: the mean's standard error is 0.05 and the std's about 0.035; 4 of each
    assert abs(np.mean(draws)) < 0.2
    assert np.std(draws) == pytest.approx(1.0, abs=0.15)


def test_z_finds_a_real_improvement_and_its_sign():
    truth = _truth()
    d = 0.05 * np.roll(truth, 3, axis=1)
    spectra = validation_spectra(_measured(truth, np.random.default_rng(2), 0.3), PERIODS,
                                 LINES)
    assert improvement_z(spectra, truth + d, truth) > 10.0
    assert improvement_z(spectra, truth, truth + d) < -10.0


def test_unexplained_names_the_channel_and_the_lines():
    """A model that misses only the lines above 60 Hz of the second channel."""
    truth = _truth()
    spectrum = np.fft.rfft(truth, axis=1)
    spectrum[:, 61:, 1] = 0.0
    model = np.fft.irfft(spectrum, n=N, axis=1)
    spectra = validation_spectra(_measured(truth, np.random.default_rng(3), 0.01), PERIODS,
                                 LINES)
    frequencies = LINES * FS / N
    left = unexplained(spectra, model, np.ones(LINES.size, bool), frequencies, (5.0, 60.0),
                       ("a", "b"), 20.0)
    channel, where, share, level = left.groups[0]
    assert (channel, where) == ("b", "lines above the band (harmonics)")
    assert share > 0.99 and level > 40.0


def test_a_claim_must_remove_more_than_the_noise():
    # 0.161 % -> 0.140 % for a 0.128 % floor removes 66 % of the excess but less squared
    # error than the floor's: two models of a linear chain differing by less than the
    # noise of one record, whatever the z (a false alarm of the benchmark's dev seed)
    near = claim_test(0.161, 0.140, 0.128, 1, z=10.0, candidates=5)
    assert near.significant and not near.worth_parameters and not near.passed
    assert "squared noise floor" in near.words()
    assert claim_test(1.0, 0.2, 0.128, 1, z=10.0, candidates=5).passed


def test_the_test_is_of_the_pooled_error_the_claim_reports():
    """Seed 45 case 7 of the hidden benchmark: the true clearance lowered the pooled
    validation error 18.9 -> 13.5 % and a test weighting each line by 1 / v (its noise
    variance) vetoed it at z = -96, for a worse fit where the noise is smallest. Here
    channel 0 is measured 100 times more noisily than channel 1; the revision misses
    channel 0 by 20 % and the candidate misses it by 2 % but channel 1 by 1 %."""
    truth = _truth()
    rng = np.random.default_rng(4)
    record = np.tile(truth, (1, PERIODS, 1))
    sigma = np.array([0.3, 0.003])
    spectra = validation_spectra(record + sigma * rng.standard_normal(record.shape),
                                 PERIODS, LINES)
    revision, candidate = truth.copy(), truth.copy()
    revision[..., 0] *= 1.2
    candidate[..., 0] *= 1.02
    candidate[..., 1] *= 1.01

    def pooled(model: np.ndarray) -> float:
        return float(np.sum(np.abs(spectra.mean - spectra.of(model)) ** 2))

    def weighted(model: np.ndarray) -> float:
        return float(np.sum(np.abs(spectra.mean - spectra.of(model)) ** 2
                            / spectra.variance[None]))

    assert pooled(candidate) < 0.1 * pooled(revision)        # the claim: a 10x fall
    assert weighted(candidate) > weighted(revision)           # what 1 / v weights saw
    assert improvement_z(spectra, revision, candidate) > 10.0
