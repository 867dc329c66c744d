"""Model vs measurement: an exact model reaches the noise floor, a wrong one does not."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi.measurement import Measurement
from fnsi.statespace import StateSpaceModel
from fnsi.validation import compare

FS = 200.0
PERIOD = 400


def _model(pole_radius: float) -> StateSpaceModel:
    # a lightly damped discrete resonator at 10 Hz, input u, displacement output y
    angle = 2 * np.pi * 10.0 / FS
    A = pole_radius * np.array([[np.cos(angle), -np.sin(angle)],
                                [np.sin(angle), np.cos(angle)]])
    return StateSpaceModel(A, np.array([[1.0], [0.0]]), np.array([[0.0, 1.0]]),
                           np.zeros((1, 1)), FS, ("u",), ("y",))


def _steady_response(model: StateSpaceModel, u: np.ndarray) -> np.ndarray:
    # exact periodic steady state in the frequency domain
    H = model.frequency_response(np.fft.rfftfreq(u.size, 1 / FS))[:, 0, 0]
    return np.fft.irfft(H * np.fft.rfft(u), n=u.size)


@pytest.fixture(scope="module")
def measured() -> tuple[StateSpaceModel, Measurement, float]:
    rng = np.random.default_rng(1)
    truth = _model(0.99)
    u = rng.standard_normal(PERIOD)
    y = _steady_response(truth, u)
    noise = 0.01 * y.std()
    periods = 4
    y_noisy = np.tile(y, periods) + noise * rng.standard_normal(periods * PERIOD)
    data = Measurement.from_arrays(np.tile(u, periods), y_noisy, FS, input_names=["u"],
                                   output_names=["y"], periods=periods)
    return truth, data, noise / y.std()


def test_exact_model_error_equals_the_noise_floor(measured) -> None:
    truth, data, _ = measured
    comparison = compare(truth, data, discard_periods=1, band_high=40.0)
    errors = comparison.errors
    assert comparison.simulated.shape == (1, PERIOD, 1)
    # the exact model's residual is the noise left on the 3-period average: NRMSE equals
    # the floor up to the sampling spread of that noise (~1/sqrt(400 samples) = 5 %)
    assert errors.overall_percent == pytest.approx(errors.overall_noise_floor_percent, rel=0.15)


def test_wrong_damping_is_seen_far_above_the_floor(measured) -> None:
    _, data, _ = measured
    errors = compare(_model(0.97), data, discard_periods=1, band_high=40.0).errors
    assert errors.overall_percent > 10 * errors.overall_noise_floor_percent


def test_velocity_measurement_is_compared_in_velocity(measured) -> None:
    truth, data, _ = measured
    # the model predicts displacement; a velocity record of the same motion must match
    v = np.fft.irfft(np.fft.rfft(data.y, axis=1)
                     * 2j * np.pi * np.fft.rfftfreq(data.n_samples, 1 / FS)[None, :, None],
                     n=data.n_samples, axis=1)
    velocity = Measurement.from_arrays(data.u[0], v[0], FS, input_names=["u"],
                                       output_names=["y"], periods=data.periods,
                                       quantity="velocity")
    errors = compare(truth, velocity, discard_periods=1, band_high=40.0).errors
    assert errors.overall_percent < 3 * errors.overall_noise_floor_percent


def test_missing_channel_is_named() -> None:
    data = Measurement.from_arrays(np.zeros(800), np.ones(800), FS, input_names=["f"],
                                   output_names=["y"], periods=2)
    with pytest.raises(ValueError, match="u"):
        compare(_model(0.99), data, discard_periods=1, band_high=40.0)


def test_model_npz_round_trip(tmp_path) -> None:
    model = _model(0.99)
    model.to_npz(tmp_path / "model.npz")
    again = StateSpaceModel.from_npz(tmp_path / "model.npz")
    np.testing.assert_array_equal(again.A, model.A)
    assert again.input_names == ("u",) and again.fs == FS and again.elements == ()
    np.savez(tmp_path / "other.npz", A=model.A)
    with pytest.raises(ValueError, match="missing"):
        StateSpaceModel.from_npz(tmp_path / "other.npz")
