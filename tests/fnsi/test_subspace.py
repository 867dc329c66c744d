"""FNSI decomposition and B^e, D^e estimation on exact linear data (Eq. 8-14)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg

from fnsi.identification import IdentificationSettings, identify
from fnsi.measurement import Measurement
from fnsi.modal import modal_table
from fnsi.spectra import Spectra, output_spectra, transform
from fnsi.subspace import (
    COMPENSATION_KEEP,
    auto_block_rows,
    band_warp,
    compensation_scale,
    decompose,
    input_matrices,
    transfer_rows,
)

FS, PERIOD, BAND = 200.0, 2000, (3.0, 45.0)


def receptance(model, frequencies: np.ndarray) -> np.ndarray:
    """H(omega) = (K - omega^2 M + j omega C)^-1 (Eq. 15), shape (N, r, r)."""
    w = 2 * np.pi * np.asarray(frequencies)[:, None, None]
    return np.linalg.inv(model.K - w**2 * model.M + 1j * w * model.C)


def exact_record(model, *, periods: int = 3, realisations: int = 1, seed: int = 0,
                 noise=None) -> Measurement:
    """Exact periodic response Y = H U on the DFT lines (no integrator), force at DOF a."""
    rng = np.random.default_rng(seed)
    f = np.fft.rfftfreq(PERIOD, 1 / FS)
    lines = (f >= BAND[0]) & (f <= BAND[1])
    U = np.zeros((realisations, f.size), dtype=complex)
    U[:, lines] = np.exp(2j * np.pi * rng.random((realisations, lines.sum())))
    Y = receptance(model, f)[None, :, :, 0] * U[:, :, None]
    u = np.tile(np.fft.irfft(U, n=PERIOD, axis=1), (1, periods))[:, :, None]
    y = np.tile(np.fft.irfft(Y, n=PERIOD, axis=1), (1, periods, 1))
    if noise is not None:
        y = y + rng.standard_normal(y.shape) * np.asarray(noise) * y.std(axis=1, keepdims=True)
    return Measurement.from_arrays(u, y, FS, input_names=("a",), output_names=model.dof_names,
                                   periods=periods)


@pytest.fixture(scope="module")
def linear(chain):
    model = chain(3)
    return model, exact_record(model)


def modal_errors(model, A, C):
    truth = model.linear_modes()
    found = modal_table(A, C, FS, model.dof_names, band=BAND)
    assert found.n_modes == truth.n_modes
    return (np.abs(found.frequencies / truth.frequencies - 1),
            np.abs(found.damping_ratios / truth.damping_ratios - 1))


@pytest.mark.parametrize("block_rows", [10, 40])  # exact SVD, randomised range finder
def test_linear_modes_from_exact_data(linear, block_rows):
    model, data = linear
    spectra = output_spectra(data, BAND, discard_periods=1)
    decomposition = decompose(spectra, block_rows=block_rows, max_order=6)
    df, dz = modal_errors(model, *decomposition.state_matrices(6))
    # acceptance: 0.01 % and 0.5 %; the only error left is the discrete-time rational
    # approximation of a continuous-time FRF (observed below 1e-4 %, 0.03 %)
    assert df.max() < 1e-4
    assert dz.max() < 5e-3


@pytest.mark.parametrize("fs", [2500.0, 200.0])  # band 2 % of fs (the paper's), 25 %
def test_warped_decomposition_returns_the_z_model(fs):
    """Exact data of a discrete-time model (order 4, two outputs) on 5-50 Hz, i = 50:
    built in w, the poles mapped back to z are the true ones to rounding, as built in z
    (the ill-conditioning of the powers z^p at 2.5 kHz shows with noise, see
    test_identification; the cost of warping, with data of a continuous-time structure,
    in the module docstring)."""
    poles = np.exp(2 * np.pi * np.array([12.0, 31.0]) * (-0.03 + 1j) / fs)
    A = scipy.linalg.block_diag(*[[[p.real, p.imag], [-p.imag, p.real]] for p in poles])
    rng = np.random.default_rng(4)
    B, C, D = rng.standard_normal((4, 1)), rng.standard_normal((2, 4)), np.zeros((2, 1))
    f = np.linspace(5.0, 50.0, 400)
    z = np.exp(2j * np.pi * f / fs)
    U = np.exp(2j * np.pi * rng.random(f.size))
    H = np.einsum("ij,kjl,lm->kim", C, np.linalg.inv(z[:, None, None] * np.eye(4) - A), B) + D
    spectra = Spectra(f, fs, U[None, :, None], (H[:, :, 0] * U[:, None])[None], ("u",),
                      ("y1", "y2"))
    decomposition = decompose(spectra, block_rows=50, max_order=4, warp=True)
    assert decomposition.warp == pytest.approx(band_warp(z)) and decomposition.warp > 0
    np.testing.assert_allclose(np.sort_complex(np.linalg.eigvals(
        decomposition.state_matrices(4)[0])), np.sort_complex(np.linalg.eigvals(A)),
        rtol=1e-9)


@pytest.mark.parametrize("warp", [False, True])
def test_narrow_band_decomposition_is_fixed_by_the_data_not_by_rounding(warp):
    """Band 5-50 Hz at 2.5 kHz (2 % of fs, the paper's), three inputs, i = 50, 2 % output
    noise: with the powers z^p (``basis="powers"``) E_i is numerically rank-deficient and
    a relative perturbation of 1e-13 of the data moves the poles by 2e-5; in the
    orthonormal band basis they move by rounding only, in z and in w."""
    fs = 2500.0
    poles = np.exp(2 * np.pi * np.array([12.0, 31.0]) * (-0.03 + 1j) / fs)
    A = scipy.linalg.block_diag(*[[[p.real, p.imag], [-p.imag, p.real]] for p in poles])
    rng = np.random.default_rng(5)
    B, C = rng.standard_normal((4, 3)), rng.standard_normal((2, 4))
    f = np.linspace(5.0, 50.0, 400)
    z = np.exp(2j * np.pi * f / fs)
    U = np.exp(2j * np.pi * rng.random((f.size, 3)))
    Y = np.einsum("ij,kjl,lm,km->ki", C, np.linalg.inv(z[:, None, None] * np.eye(4) - A), B, U)
    Y += 0.02 * np.abs(Y).mean() * (rng.standard_normal(Y.shape)
                                    + 1j * rng.standard_normal(Y.shape))

    def eigenvalues(inputs, outputs, basis="orthonormal"):
        spectra = Spectra(f, fs, inputs[None], outputs[None], ("u1", "u2", "u3"),
                          ("y1", "y2"))
        A4 = decompose(spectra, block_rows=50, max_order=4, warp=warp,
                       basis=basis).state_matrices(4)[0]
        return np.sort_complex(np.linalg.eigvals(A4))

    perturbed = (U * (1 + 1e-13 * rng.standard_normal(U.shape)),
                 Y * (1 + 1e-13 * rng.standard_normal(Y.shape)))
    base = eigenvalues(U, Y)
    assert np.max(np.abs(eigenvalues(*perturbed) - base)) < 1e-10   # observed < 1e-15
    if not warp:  # what the orthonormal basis fixes
        assert np.max(np.abs(eigenvalues(*perturbed, "powers")
                             - eigenvalues(U, Y, "powers"))) > 1e-8
    # and the noisy model is still the structure's (2 % noise: 0.01 % in the poles)
    np.testing.assert_allclose(np.abs(np.log(base)), np.abs(np.log(np.sort_complex(
        np.linalg.eigvals(A)))), rtol=1e-2)


def test_identified_frf_matches_receptance(linear):
    model, data = linear
    spectra = output_spectra(data, BAND, discard_periods=1)
    fitted = decompose(spectra, block_rows=10, max_order=6).model(6)
    H = fitted.frequency_response(spectra.frequencies)[:, :, 0]
    exact = receptance(model, spectra.frequencies)[:, :, 0]
    # 0.1 % of the peak: order-6 discrete model of a continuous 3-DOF FRF (observed 0.013 %)
    assert np.abs(H - exact).max() < 1e-3 * np.abs(exact).max()


def test_realisations_and_non_equidistant_lines(chain):
    model = chain(3)
    data = exact_record(model, realisations=2, seed=3)
    spectra = output_spectra(data, BAND, discard_periods=1)
    keep = np.sort(np.random.default_rng(1).permutation(spectra.n_lines)[: spectra.n_lines // 2])
    thinned = Spectra(spectra.frequencies[keep], FS, spectra.inputs[:, keep],
                      spectra.outputs[:, keep], spectra.input_names, spectra.output_names)
    df, dz = modal_errors(model, *decompose(thinned, block_rows=10, max_order=6)
                          .state_matrices(6))
    assert df.max() < 1e-4 and dz.max() < 5e-3  # same targets as the full line set


def test_structured_least_squares_equals_dense_solution(formation):
    rng = np.random.default_rng(0)
    n, n_out, q, N, R = 4, 3, 5, 60, 2
    A = np.diag([0.9, 0.5, -0.3, 0.7]) + 0.05 * rng.standard_normal((n, n))
    C = rng.standard_normal((n_out, n))
    z = np.exp(2j * np.pi * np.sort(rng.random(N)) / 2)
    E = rng.standard_normal((R, N, q)) + 1j * rng.standard_normal((R, N, q))
    Y = rng.standard_normal((R, N, n_out)) + 1j * rng.standard_normal((R, N, n_out))
    B, D = input_matrices(A, C, E, Y, z)
    # dense regression over real unknowns vec([B; D]) (column-major)
    rows = []
    for k in range(N):
        M = np.hstack([C @ np.linalg.inv(z[k] * np.eye(n) - A), np.eye(n_out)])
        for r in range(R):
            rows.append(np.kron(E[r, k][None, :], M))
    Phi = np.vstack(rows)
    rhs = Y.transpose(1, 0, 2).reshape(-1)
    theta = np.linalg.lstsq(np.vstack([Phi.real, Phi.imag]),
                            np.concatenate([rhs.real, rhs.imag]), rcond=None)[0]
    dense = theta.reshape(q, n + n_out).T
    # rounding only: both solve the same well-conditioned least-squares problem
    np.testing.assert_allclose(np.vstack([B, D]), dense, rtol=1e-8, atol=1e-10)


def test_noise_weighting_improves_modes_with_unequal_channel_noise(chain):
    model = chain(3)
    # channels a, b nearly clean, channel c very noisy (30 % of its RMS)
    data = exact_record(model, periods=8, seed=2, noise=[0.002, 0.002, 0.3])
    errors = {}
    for weighting in (False, True):
        result = identify(data, IdentificationSettings(band=BAND, block_rows=10, order=6,
                                                       max_order=12, weighting=weighting))
        errors[weighting] = modal_errors(model, result.model.A, result.model.C)
    # weighting by the noise covariance lowers the worst frequency and damping errors
    # several-fold (observed about 0.8 % -> 0.01 % and 3 % -> 0.3 %)
    assert errors[True][0].max() < 0.2 * errors[False][0].max()
    assert errors[True][1].max() < 0.5 * errors[False][1].max()


def test_too_many_block_rows_and_too_high_order_are_refused(linear):
    spectra = output_spectra(linear[1], BAND, discard_periods=1)
    with pytest.raises(ValueError, match="too many block rows"):
        decompose(spectra, block_rows=2000, max_order=6)
    with pytest.raises(ValueError, match=r"n <= l \(i - 1\)"):
        decompose(spectra, block_rows=3, max_order=7)
    with pytest.raises(ValueError, match="MiB"):
        decompose(spectra, block_rows=10, max_order=6, memory_limit=1e5)
    with pytest.raises(ValueError, match="noise covariance"):
        decompose(spectra, block_rows=10, max_order=6, weighting=True)
    with pytest.raises(ValueError, match="max_order"):
        decompose(spectra, block_rows=10, max_order=6).state_matrices(8)


@pytest.fixture(scope="module")
def padded(chain):
    """Noisy linear record on all 840 lines of two kept periods (420 harmonic lines), with
    39 extra periodic extended inputs that do not act (true B^e columns zero): q = 40."""
    model = chain(3)
    spectra = output_spectra(exact_record(model, noise=0.01), BAND, discard_periods=1)
    g = np.tile(np.random.default_rng(1).standard_normal((1, PERIOD, 39)), (1, 2, 1))
    _, G = transform(g, 2, FS, BAND, "all")
    return model, dataclasses.replace(spectra, inputs=np.concatenate([spectra.inputs, G], 2))


def test_eliminating_every_signal_column_leaves_noise_only(padded):
    model, spectra = padded
    assert (spectra.n_lines, spectra.signal_lines) == (840, 420)
    blind = dataclasses.replace(spectra, signal_lines=None)  # the rule cannot see the periods
    i = auto_block_rows(spectra.signal_lines, 1, 40, 3, max_order=60)
    assert i == 9  # 420 // 43: the lines bind
    good = decompose(blind, block_rows=i, max_order=6)
    df, dz = modal_errors(model, *good.state_matrices(6))
    # 1 % output noise: observed 0.015 % and 0.43 %; targets of the noisy single-3 case
    assert df.max() < 2e-3 and dz.max() < 3e-2
    assert good.singular_values[5] > 10 * good.singular_values[6]  # order 6 stands out
    # q i = 40 x 21 = 840 = 2 N_s: E_i spans every signal column, no order stands out
    # (observed ratio 1.08 against 27 at i = 9) and the modes are lost
    lost = decompose(blind, block_rows=21, max_order=6)
    assert lost.singular_values[5] < 1.5 * lost.singular_values[6]
    with pytest.raises(ValueError, match=r"periodic signal.*use block_rows <= 20"):
        decompose(spectra, block_rows=21, max_order=6)


@pytest.mark.parametrize("quantity", ["velocity", "acceleration"])
def test_velocity_or_acceleration_records_give_the_same_modes(linear, quantity):
    model, data = linear
    times = {"velocity": 1, "acceleration": 2}[quantity]
    w = 2j * np.pi * np.fft.rfftfreq(data.n_samples, 1 / FS)
    derived = np.fft.irfft(np.fft.rfft(data.y, axis=1) * (w**times)[None, :, None],
                           n=data.n_samples, axis=1)
    measured = Measurement.from_arrays(data.u, derived, FS, input_names=data.input_names,
                                       output_names=data.output_names, periods=data.periods,
                                       quantity=quantity)
    result = identify(measured, IdentificationSettings(band=BAND, block_rows=10, order=6))
    df, dz = modal_errors(model, result.model.A, result.model.C)
    assert df.max() < 1e-4 and dz.max() < 5e-3  # same targets as displacement records


def test_compensated_least_squares_removes_input_noise_bias(formation):
    # errors in variables: the second extended input is measured with noise of a quarter of
    # its power, partly correlated with the output noise
    rng = np.random.default_rng(3)
    n, n_out, q, N = 2, 2, 2, 4000
    A = np.array([[0.9, 0.2], [-0.2, 0.9]])
    C = np.array([[1.0, 0.5], [0.3, -1.0]])
    B = np.array([[1.0, -0.5], [0.4, 0.8]])
    D = np.array([[0.1, 0.2], [0.0, -0.3]])
    z = np.exp(1j * np.linspace(0.05, 3.0, N))
    E0 = rng.standard_normal((1, N, q)) + 1j * rng.standard_normal((1, N, q))
    H = C @ np.linalg.inv(z[:, None, None] * np.eye(n) - A) @ B + D  # (N, l, q)
    s = 0.5  # dE variance 2 s^2 = 0.5, a quarter of the input power 2
    delta = s * (rng.standard_normal(N) + 1j * rng.standard_normal(N))
    kappa = np.array([0.3, -0.2j])
    noise = kappa * delta[:, None] + 0.05 * rng.standard_normal((N, n_out))
    Y = np.einsum("kiq,kq->ki", H, E0[0])[None] + noise[None]
    E = E0.copy()
    E[0, :, 1] += delta
    cov = np.zeros((N, q, q + n_out), dtype=complex)
    cov[:, 1, 1] = 2 * s**2  # E[dE dE^H]
    cov[:, 1, q:] = 2 * s**2 * kappa.conj()  # E[dE dY^H]
    H_hat = {}
    for name, c in (("plain", None), ("compensated", cov)):
        Bh, Dh = input_matrices(A, C, E, Y, z, noise_covariance=c)
        H_hat[name] = C @ np.linalg.inv(z[:, None, None] * np.eye(n) - A) @ Bh + Dh
    error = {k: np.linalg.norm(h[:, :, 1] - H[:, :, 1]) / np.linalg.norm(H[:, :, 1])
             for k, h in H_hat.items()}
    # the plain least squares attenuates the noisy column by 1 / (1 + 0.25) and adds the
    # correlated-noise term (about 19 % error); compensated, only the scatter is left
    assert error["plain"] > 0.15
    assert error["compensated"] < 0.05  # 3 %, scatter falling as 1 / sqrt(N)


def test_a_noise_estimate_above_the_basis_power_is_scaled_down_not_subtracted_whole(formation):
    """Few periods can estimate a basis' noise above its power: subtracted whole, the
    normal matrix stops being positive and the coefficients come out NaN (a cubic spring
    measured in acceleration with two kept periods did)."""
    rng = np.random.default_rng(5)
    G = np.cov(rng.standard_normal((6, 200)))
    N = 1.5 * G                                   # more noise than power in every direction
    alpha = compensation_scale(G, N)
    kept = scipy.linalg.eigh(G - alpha * N, G, eigvals_only=True)
    # what is left is COMPENSATION_KEEP of G in the worst direction, and no less
    assert kept.min() == pytest.approx(COMPENSATION_KEEP, rel=1e-6)
    assert compensation_scale(G, 0.5 * G) == 1.0   # a credible estimate is used in full
    n, q, N_lines = 2, 2, 400
    A = np.array([[0.9, 0.2], [-0.2, 0.9]])
    C = np.eye(2)
    z = np.exp(1j * np.linspace(0.05, 3.0, N_lines))
    E = rng.standard_normal((1, N_lines, q)) + 1j * rng.standard_normal((1, N_lines, q))
    Y = rng.standard_normal((1, N_lines, n)) + 0j
    cov = np.zeros((N_lines, q, q + n), dtype=complex)
    cov[:, 1, 1] = 5.0                            # the column's power is 2
    B, D = input_matrices(A, C, E, Y, z, noise_covariance=cov)
    assert np.all(np.isfinite(B)) and np.all(np.isfinite(D))



def test_input_matrices_at_the_largest_order_follow_the_data_not_rounding():
    """The generalisation benchmark's seed-22 case 1 at order 54, the largest its 19 block
    rows and 3 outputs allow (A, C and the spectra stored): its states are nearly
    collinear on the 96 lines (stacked map's condition number 2.4e9), and normal
    equations in FNSI's basis gave B^e, D^e out of their own rounding: a relative nudge
    of 1e-12 of A, C and the outputs moved the response between the lines by 11 %
    (:mod:`fnsi.whitening`)."""
    stored = np.load(Path(__file__).parent / "data" / "largest_order.npz")
    A, C, E, Y, z = (stored[k] for k in ("A", "C", "inputs", "outputs", "z"))
    rng = np.random.default_rng(0)
    nudged = [x * (1 + 1e-12 * rng.standard_normal(x.shape)) for x in (A, C, Y)]
    between = np.exp(1j * np.linspace(np.angle(z[0]), np.angle(z[-1]), 4000))

    def response(A: np.ndarray, C: np.ndarray, Y: np.ndarray) -> np.ndarray:
        B, D = input_matrices(A, C, E, Y, z)
        return np.array([C @ np.linalg.solve(w * np.eye(len(A)) - A, B) + D for w in between])

    reference = response(A, C, Y)
    # 1e-6: 15 times the 6.7e-8 observed under SkylakeX and Haswell, 1 and 2 threads
    # (directions the lines resolve to 1e-8, fnsi.whitening.RANK, amplify the nudge at
    # most 1e8-fold); the normal equations in FNSI's basis moved it by 0.11
    assert np.abs(response(*nudged) - reference).max() < 1e-6 * np.abs(reference).max()


def test_transfer_rows_from_the_eigenvectors_and_from_the_schur_form_agree():
    rng = np.random.default_rng(4)
    A = np.diag([0.9, 0.5, -0.3, 0.7]) + 0.05 * rng.standard_normal((4, 4))
    C = rng.standard_normal((3, 4))
    z = np.exp(1j * np.linspace(0.05, 3.0, 50))
    direct = np.array([C @ np.linalg.inv(w * np.eye(4) - A) for w in z])
    # rounding only: V's condition number here is below 10
    for rows in (transfer_rows(A, C, z), transfer_rows(A, C, z, eigen=np.linalg.eig(A))):
        np.testing.assert_allclose(rows, direct, rtol=1e-10, atol=1e-12 * np.abs(direct).max())
