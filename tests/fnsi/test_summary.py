"""Dataset summaries: period detection and SNR against signals of known content."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi.measurement import Measurement
from fnsi.summary import channel_rms, detect_periods, snr_db, summarize

RNG = np.random.default_rng(3)
PERIOD = 256


def test_detects_the_number_of_repeated_periods() -> None:
    u = np.tile(RNG.standard_normal(PERIOD), 6)[None, :, None]
    assert detect_periods(u + 0.01 * RNG.standard_normal(u.shape)) == 6
    assert detect_periods(RNG.standard_normal((1, 6 * PERIOD, 1))) == 1


def test_snr_matches_the_injected_noise() -> None:
    periods, noise = 8, 0.1
    signal = np.tile(np.sin(2 * np.pi * 5 * np.arange(PERIOD) / PERIOD), periods)
    x = (signal + noise * RNG.standard_normal(signal.size))[None, :, None]
    # true SNR = 10 log10(0.5 / 0.01) = 16.99 dB; 7 x 256 noise samples estimate the
    # noise power within a few percent, i.e. about +-0.3 dB
    assert snr_db(x, periods)[0] == pytest.approx(16.99, abs=0.3)
    assert snr_db(x[:, :PERIOD], 1) is None


def test_summary_lists_every_channel_with_its_role() -> None:
    data = Measurement.from_arrays(np.ones(4 * PERIOD), np.zeros((4 * PERIOD, 2)), 100.0,
                                   output_names=["a", "b"], periods=4)
    summary = summarize(data, "declared")
    assert [(c["name"], c["role"]) for c in summary["channels"]] == [
        ("u0", "input"), ("a", "output"), ("b", "output")]
    assert summary["periods"] == 4 and summary["fs"] == 100.0


def test_rms_is_finite_where_squares_overflow():
    """Squares of 1e200 are infinite in float64; the peak-scaled RMS of a square wave is
    its amplitude, to rounding."""
    x = np.array([1e200, -1e200] * 4).reshape(1, 8, 1) * np.array([1.0, 0.5])
    np.testing.assert_allclose(channel_rms(x), [1e200, 5e199], rtol=1e-15)
    assert channel_rms(np.zeros((1, 4, 1))).tolist() == [0.0]
