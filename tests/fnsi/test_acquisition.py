"""Synthetic acquisition: exact linear steady state, anti-aliasing, noise level and band,
clearance exceedance counts, output quantities."""

import numpy as np
import pytest

from fnsi.acquisition import FIR_HALF, acquire, decimate, upsample
from fnsi.excitation import Excitation, periodic_noise
from fnsi.newmark import newmark
from fnsi.nonlinear import NonlinearElement
from fnsi.structure import StructuralModel

FS, FS_INT, N, PERIODS = 500.0, 4000.0, 1000, 4
FACTOR = int(FS_INT / FS)
M = np.diag([1.0, 0.5])
K = np.array([[2.0, -1.0], [-1.0, 1.0]]) * (2 * np.pi * 12) ** 2
C = 0.002 * K + np.diag([2.0, 0.0])  # modes 9.2 and 22.2 Hz, 6.6 % and 14 % damping
STOP = NonlinearElement("clearance", "b", "a", gap=1e-3, coefficients=(2 * K[0, 0],))
LINEAR = StructuralModel(M, C, K, ("a", "b"))
NONLINEAR = StructuralModel(M, C, K, ("a", "b"), (STOP,))
EXCITATION = Excitation.at_dof(periodic_noise(N, FS, (5.0, 50.0), 10.0, realisations=2), FS, "a")


def run(model, **kwargs):
    options = {"fs": FS, "fs_int": FS_INT, "periods": PERIODS, "noise_percent": 0.0} | kwargs
    return acquire(model, EXCITATION, **options)


@pytest.fixture(scope="session")
def linear():
    return {q: run(LINEAR, quantity=q)[0] for q in ("displacement", "velocity", "acceleration")}


@pytest.fixture(scope="session")
def nonlinear():
    return (run(NONLINEAR)[0],
            run(NONLINEAR, noise_percent=0.5, noise_reference="b", seed=3)[0])


def last_period_spectrum(y):
    return np.fft.rfft(y[:, -N:], axis=1)


def frf(model, omega):
    w = omega[:, None, None]
    return np.linalg.inv(-(w**2) * model.M + 1j * w * model.C + model.K)


def test_linear_steady_state_equals_frf_times_input(linear):
    measured = linear["displacement"]
    Y, U = last_period_spectrum(measured.y), np.fft.rfft(EXCITATION.u[..., 0], axis=1)
    omega = 2 * np.pi * np.fft.rfftfreq(N, 1 / FS)
    warped = 2 * FS_INT * np.tan(omega / (2 * FS_INT))  # Newmark's frequency at fs_int
    excited = slice(10, 101)
    exact = frf(LINEAR, warped)[None, :, :, 0] * U[:, :, None]
    # exact: transient left after 3 periods ~ e^-23 and rounding
    np.testing.assert_allclose(Y, exact, atol=1e-9 * np.abs(exact).max())
    analytic = frf(LINEAR, omega)[None, :, :, 0] * U[:, :, None]
    # the 20 kHz-like warping at 8x oversampling: (omega dt)^2 / 12 <= 5e-4 in the band
    np.testing.assert_allclose(Y[:, excited], analytic[:, excited],
                               atol=2e-3 * np.abs(analytic).max())
    np.testing.assert_array_equal(measured.u[:, :N], EXCITATION.u)
    assert measured.periods == PERIODS and measured.fs == FS and measured.y.shape == (2, 4000, 2)


def test_velocity_and_acceleration_are_newmark_derivatives(linear):
    omega = 2 * np.pi * np.fft.rfftfreq(N, 1 / FS)
    s = 2j * FS_INT * np.tan(omega / (2 * FS_INT))  # trapezoidal derivative at fs_int
    q, v, a = (last_period_spectrum(linear[k].y) for k in ("displacement", "velocity",
                                                             "acceleration"))
    np.testing.assert_allclose(v, s[None, :, None] * q, atol=1e-8 * np.abs(v).max())
    np.testing.assert_allclose(a, s[None, :, None] ** 2 * q, atol=1e-8 * np.abs(a).max())
    assert linear["acceleration"].quantity == "acceleration"


def test_decimation_keeps_fine_spectrum_below_nyquist_and_removes_aliases(nonlinear):
    clean = nonlinear[0]
    fine_force = np.zeros((PERIODS * N * FACTOR, 2))
    fine_force[:, 0] = np.tile(upsample(EXCITATION.u, FACTOR)[0, :, 0], PERIODS)
    fine = newmark(NONLINEAR, fine_force, 1 / FS_INT).displacement[-N * FACTOR:]
    reference = np.fft.rfft(fine, axis=0)[: N // 2] / FACTOR
    measured = last_period_spectrum(clean.y)[0, : N // 2]
    np.testing.assert_allclose(measured, reference, atol=1e-10 * np.abs(reference).max())
    # impacts put energy above fs/2 that plain subsampling would fold into the band: small
    # in displacement (~1e-5 here), yet 1e5 times the decimation's own error
    aliased = np.fft.rfft(fine[::FACTOR], axis=0)[: N // 2]
    assert np.max(np.abs(aliased - reference)) > 1e-6 * np.abs(reference).max()


def test_transient_first_period_has_no_edge_ringing():
    measured = run(LINEAR, periods=2, discard_periods=0)[0].y[0]
    fine_force = np.zeros((2 * N * FACTOR, 2))
    fine_force[:, 0] = np.tile(upsample(EXCITATION.u, FACTOR)[0, :, 0], 2)
    fine = newmark(LINEAR, fine_force, 1 / FS_INT).displacement
    scale = np.abs(fine).max()
    # the linear response to a 5-50 Hz input has (almost) nothing above fs/2, so the
    # decimated record equals the response at the fs instants, edges of period 1 included
    np.testing.assert_allclose(measured, fine[::FACTOR], atol=2e-4 * scale)
    # a circular filter over the (non-periodic) first period would ring at its edges
    circular = decimate(fine[None, : N * FACTOR], FACTOR)[0]
    assert np.max(np.abs(circular - fine[: N * FACTOR: FACTOR])) > 1e-2 * scale
    # a single period ends with the FIR taking rest (zeros) after the record
    single = run(LINEAR, periods=1, discard_periods=0)[0].y[0]
    np.testing.assert_allclose(single[:-FIR_HALF], fine[: (N - FIR_HALF) * FACTOR: FACTOR],
                               atol=2e-4 * scale)


def test_noise_level_and_band(nonlinear):
    clean, noisy = nonlinear
    noise = noisy.y - clean.y
    kept = clean.y[:, 2 * N:, 1]
    target = 0.005 * np.sqrt(np.mean(kept**2))
    # scaled exactly per channel; 5 % is the acceptance margin
    np.testing.assert_allclose(np.sqrt(np.mean(noise**2, axis=(0, 1))), target, rtol=0.05)
    spectrum = np.abs(np.fft.rfft(noise, axis=1)) ** 2
    f = np.fft.rfftfreq(noise.shape[1], 1 / FS)
    assert spectrum[:, f > 100.0].sum() < 1e-20 * spectrum.sum()
    # measurement noise differs from period to period (it is not periodic)
    assert np.max(np.abs(noise[:, :N] - noise[:, N:2 * N])) > target


def test_exceedances_count_contacts_in_kept_periods():
    _, truth = run(NONLINEAR, discard_periods=1)
    fine_force = np.zeros((PERIODS * N * FACTOR, 2))
    counts = 0
    for rr in range(2):
        fine_force[:, 0] = np.tile(upsample(EXCITATION.u, FACTOR)[rr, :, 0], PERIODS)
        q = newmark(NONLINEAR, fine_force, 1 / FS_INT).displacement[::FACTOR]
        x = (q[:, 1] - q[:, 0])[N:]
        counts += np.count_nonzero(np.abs(x) > 1e-3)
    assert truth.exceedances == {"clearance b-a": counts} and counts > 100
    assert truth.elements == (STOP,) and truth.discard_periods == 1
    modes = LINEAR.linear_modes()
    np.testing.assert_allclose(truth.modal.frequencies, modes.frequencies)
    assert run(LINEAR)[1].exceedances == {}


def test_outputs_subset_progress_and_cancel():
    calls = []
    measurement, truth = run(NONLINEAR, outputs=["b"], periods=2, discard_periods=1,
                             progress=lambda f, m: calls.append(f))
    assert measurement.output_names == ("b",) and truth.modal.shapes.shape == (2, 1)
    assert calls == [0.5, 1.0]
    assert measurement.input_names == ("F_a",)

    def cancel(fraction, message):
        raise RuntimeError("stop")
    with pytest.raises(RuntimeError, match="stop"):
        run(NONLINEAR, progress=cancel)


@pytest.mark.parametrize(("kwargs", "match"), [
    ({"fs": 1000.0}, "excitation is sampled"),
    ({"fs_int": 3100.0}, "integer multiple"),
    ({"outputs": ["z"]}, "unknown DOF"),
    ({"quantity": "jerk"}, "quantity"),
    ({"noise_reference": "z", "noise_percent": 1.0}, "not an output"),
    ({"noise_percent": -1.0}, "noise_percent"),
    ({"discard_periods": 4}, "discard_periods"),
    ({"periods": 0}, "periods"),
])
def test_bad_input_is_rejected(kwargs, match):
    with pytest.raises(ValueError, match=match):
        run(LINEAR, **kwargs)
