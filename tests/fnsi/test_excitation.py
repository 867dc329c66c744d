"""Excitation signals: reproducibility, RMS, band limits, periodicity, directions."""

import tracemalloc

import numpy as np
import pytest

from fnsi.excitation import (
    Excitation,
    excited_line_range,
    excited_lines,
    multisine,
    periodic_noise,
)

FS, N, BAND = 2500.0, 5000, (5.0, 50.0)


def spectrum_support(x):
    """Lines whose amplitude is above rounding (1e-9 of the largest)."""
    a = np.abs(np.fft.rfft(x, axis=-1))
    return a > 1e-9 * a.max()


@pytest.mark.parametrize("make", [
    lambda seed: periodic_noise(N, FS, BAND, 100.0, realisations=2, seed=seed),
    lambda seed: multisine(N, FS, BAND, 100.0, realisations=2, seed=seed),
    lambda seed: multisine(N, FS, BAND, 100.0, lines="odd", detection=4, realisations=2,
                           seed=seed),
], ids=["noise", "multisine", "random-odd"])
def test_signals_reproducible_exact_rms_and_band_limited(make):
    x = make(7)
    np.testing.assert_array_equal(x, make(7))  # bit for bit
    assert not np.array_equal(x, make(8))
    assert not np.array_equal(x[0], x[1])  # realisations are independent
    np.testing.assert_allclose(np.sqrt(np.mean(x**2, axis=1)), 100.0, rtol=1e-12)
    support = spectrum_support(x)
    f = np.fft.rfftfreq(N, 1 / FS)
    assert np.all((f[np.any(support, axis=0)] >= BAND[0]) & (f[np.any(support, axis=0)]
                                                             <= BAND[1]))
    # exactly periodic: the DFT of one period has no leakage, so two periods of the signal
    # have energy on even lines of the doubled grid only
    doubled = np.fft.rfft(np.tile(x, 2), axis=1)
    assert np.max(np.abs(doubled[:, 1::2])) < 1e-9 * np.max(np.abs(doubled))


def test_periodic_noise_is_gaussian_on_all_band_lines():
    x = periodic_noise(N, FS, BAND, 1.0, realisations=4)
    lines = excited_lines(N, FS, BAND)
    assert lines.size == 91 and np.all(spectrum_support(x)[:, lines])
    # Gaussian samples: kurtosis 3 within its sampling spread (~0.05 for 20,000 samples)
    z = x.ravel()
    assert abs(np.mean(z**4) / np.mean(z**2) ** 2 - 3.0) < 0.15


def test_multisine_flat_spectrum_odd_lines_and_detection_lines():
    full = multisine(N, FS, BAND, 1.0)
    amplitude = np.abs(np.fft.rfft(full[0]))[excited_lines(N, FS, BAND)]
    np.testing.assert_allclose(amplitude, amplitude[0], rtol=1e-9)
    odd = multisine(N, FS, BAND, 1.0, lines="odd", detection=3, seed=2)
    excited = np.flatnonzero(spectrum_support(odd[0]))
    assert np.all(excited % 2 == 1)
    odd_in_band = [k for k in excited_lines(N, FS, BAND) if k % 2]
    groups = len(odd_in_band) // 3
    assert len(excited) == len(odd_in_band) - groups  # one detection line per group of 3


def test_excitation_directions_and_loads():
    x = periodic_noise(100, 100.0, (5.0, 20.0), 1.0)
    e = Excitation.along(x, 100.0, {"W_X": 1.0, "W_Y": 1.0}, name="F_W_XY")
    loads = e.loads(("W_X", "W_Y", "W_Z"))
    np.testing.assert_allclose(loads[:, 0], [2**-0.5, 2**-0.5, 0.0])
    assert e.names == ("F_W_XY",) and e.u.shape == (1, 100, 1)
    assert Excitation.at_dof(x[0], 100.0, "NC2w_Z").names == ("F_NC2w_Z",)
    with pytest.raises(ValueError, match="unknown DOF"):
        e.loads(("a", "b"))
    with pytest.raises(ValueError, match="not all zero"):
        Excitation.along(x, 100.0, {"a": 0.0})


@pytest.mark.parametrize(("call", "match"), [
    (lambda: periodic_noise(N, FS, (60.0, 50.0), 1.0), "band"),
    (lambda: periodic_noise(N, FS, (5.0, 2000.0), 1.0), "band"),
    (lambda: periodic_noise(10, 10.0, (0.1, 0.2), 1.0), "no DFT line"),
    (lambda: periodic_noise(N, FS, BAND, -1.0), "rms"),
    (lambda: periodic_noise(N, FS, BAND, 1.0, realisations=0), "realisations"),
    (lambda: multisine(N, FS, BAND, 1.0, lines="even"), "lines"),
    (lambda: multisine(N, FS, BAND, 1.0, detection=1), "detection"),
])
def test_bad_input_is_rejected(call, match):
    with pytest.raises(ValueError, match=match):
        call()


def test_excited_line_range_is_the_lines_in_band_without_listing_them():
    """The few-step search returns exactly the lines whose frequency k fs / N lies in the
    band within 1e-9 fs, on bands that end on a line or a rounding error away from one;
    and checking a 10-million-sample period allocates nothing of its size."""
    rng = np.random.default_rng(7)
    for _ in range(3000):
        samples, fs = int(rng.integers(4, 3000)), float(rng.uniform(1.0, 5e4))
        k = np.arange(1, (samples + 1) // 2)
        f = k * fs / samples
        on_line = rng.integers(0, samples // 2 + 1) * fs / samples
        low = min(fs / 2, max(0.0, on_line * (1 + rng.choice([0.0, 1e-12, -1e-12, 1e-8]))))
        high = min(fs / 2, low + rng.integers(0, 4) * fs / samples)
        inside = k[(f >= low - 1e-9 * fs) & (f <= high + 1e-9 * fs)]
        if inside.size == 0:
            with pytest.raises(ValueError, match="no DFT line"):
                excited_line_range(samples, fs, (low, high))
        else:
            assert excited_line_range(samples, fs, (low, high)) == (inside[0], inside[-1])
    tracemalloc.start()
    assert excited_line_range(10_000_000, 2500.0, (0.0, 1250.0)) == (1, 4_999_999)
    assert tracemalloc.get_traced_memory()[1] < 100_000  # bytes; the lines would be 40 MB
    tracemalloc.stop()
