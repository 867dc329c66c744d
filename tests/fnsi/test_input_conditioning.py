"""How well the realisations' inputs determine a multiple-input FRF: the singular value
ratio of each line's input matrix against its closed form, orthogonal multisines, and
the warning an identification and a study give when the inputs are nearly parallel."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi.identification import IdentificationSettings, identify
from fnsi.input_conditioning import WEAK_RATIO, input_conditioning
from fnsi.measurement import Measurement
from fnsi.study import Study

SAMPLES, FS, BAND = 1024, 1024.0, (9.5, 409.5)      # 400 excited lines of 1 Hz


def _record(phases: np.ndarray, periods: int = 2) -> Measurement:
    """Unit-amplitude multisines with ``phases`` (R, lines, m) on lines 10-409 and one
    output (the first input: the FRF does not matter here)."""
    spectrum = np.zeros((phases.shape[0], SAMPLES // 2 + 1, phases.shape[2]), dtype=complex)
    spectrum[:, 10:410] = np.exp(1j * phases)
    u = np.tile(np.fft.irfft(spectrum, n=SAMPLES, axis=1), (1, periods, 1))
    return Measurement.from_arrays(u, u[:, :, :1], FS, periods=periods)


def test_two_random_phase_realisations_of_two_inputs_leave_an_eighth_of_the_lines_weak():
    """With unit amplitudes U_k^H U_k = [[2, c], [c*, 2]], |c| = 2 |cos(theta_k / 2)|,
    theta_k = (phi_12 - phi_11) - (phi_22 - phi_21): s_min / s_max = |tan(theta_k / 4)|
    (theta_k in [-pi, pi]), to rounding; below 0.1 for |theta_k| < 4 atan(0.1), 12.7 % of
    uniform phase differences (400 lines: 1.7 % standard deviation of the share, the
    bounds are 2.5 of them)."""
    phases = np.random.default_rng(5).uniform(0, 2 * np.pi, (2, 400, 2))
    conditioning = input_conditioning(_record(phases), BAND, 1)
    theta = np.angle(np.exp(1j * ((phases[0, :, 1] - phases[0, :, 0])
                                  - (phases[1, :, 1] - phases[1, :, 0]))))
    np.testing.assert_allclose(conditioning.ratios, np.abs(np.tan(theta / 4)), atol=1e-10)
    assert conditioning.frequencies.tolist() == list(np.arange(10.0, 410.0))
    assert 0.085 < conditioning.weak_share < 0.17
    warning = conditioning.warning()
    assert warning.startswith("the 2 realisations' inputs are nearly parallel on ")
    assert "orthogonal multisines" in warning


def test_orthogonal_multisines_determine_every_line():
    """Input i of realisation r shifted by 2 pi r i / m: every U_k is a scaled unitary
    (DFT) matrix, ratio 1 on every line and no warning; with three inputs too."""
    rng = np.random.default_rng(6)
    for m in (2, 3):
        shifts = 2 * np.pi * np.outer(np.arange(m), np.arange(m)) / m        # (r, i)
        phases = rng.uniform(0, 2 * np.pi, (1, 400, m)) + shifts[:, None, :]
        conditioning = input_conditioning(_record(phases), BAND, 1)
        np.testing.assert_allclose(conditioning.ratios, 1.0, atol=1e-10)
        assert conditioning.warning() is None


def test_fewer_realisations_than_inputs_see_no_line_whole_and_one_input_needs_no_check():
    phases = np.random.default_rng(7).uniform(0, 2 * np.pi, (1, 400, 2))
    conditioning = input_conditioning(_record(phases), BAND, 1)
    assert conditioning.weak_share == 1.0 and np.all(conditioning.ratios < WEAK_RATIO)
    assert conditioning.warning().startswith("1 realisation of 2 inputs: on every line the "
                                             "record sees the FRF only along 1 input vector")
    assert input_conditioning(_record(phases[:, :, :1]), BAND, 1) is None


@pytest.fixture(scope="module")
def two_shakers(chain, simulate_record):
    """A 3-DOF chain driven at a and c by independent random-phase multisines, two
    realisations (as most labs draw them): estimation and validation records."""
    model = chain(3)
    return [simulate_record(model, ["a", "c"], fs=100.0, period=500, periods=2,
                            band=(3.0, 45.0), rms=[1.0, 1.0], seed=seed) for seed in (1, 2)]


def test_an_identification_and_a_study_say_when_the_inputs_are_nearly_parallel(two_shakers):
    estimation, validation = two_shakers
    settings = IdentificationSettings(band=(3.0, 45.0), order=6, uncertainty=False)
    conditioning = input_conditioning(estimation, settings.band, settings.discard_periods)
    assert conditioning.warning() is not None      # 210 lines: about 27 of them weak
    result = identify(estimation, settings)
    assert conditioning.warning() in result.warnings
    study = Study.create(estimation, validation, IdentificationSettings(band=(3.0, 45.0)))
    assert study.warnings == [conditioning.warning()]
