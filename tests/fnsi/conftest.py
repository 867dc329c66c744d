"""Shared truth data for the FNSI tests: small structures simulated with known parameters."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi.measurement import Measurement
from fnsi.newmark import newmark
from fnsi.smallsat import simulate_preset
from fnsi.structure import StructuralModel


def chain_model(n_dofs: int = 3, elements=(), *, k: float = 1e4, mass=1.0,
                couplings=None, grounds=None, alpha: float = 1.0, beta: float = 6e-4,
                extra_damper: float = 1.0) -> StructuralModel:
    """Spring-mass chain with DOFs a, b, c, ...; non-proportional damping.

    Springs ``couplings`` (n - 1) join neighbours and ``grounds`` (n) tie each DOF to the
    ground; by default k between neighbours and k to ground at both ends. Damping is
    alpha M + beta K plus one dashpot from DOF a to ground. With the defaults and three
    DOFs: 12.18, 22.51, 29.41 Hz, damping 3.0, 4.3, 5.8 %.
    """
    masses = np.broadcast_to(np.asarray(mass, dtype=float), (n_dofs,))
    couplings = np.full(n_dofs - 1, k) if couplings is None else np.asarray(couplings)
    if grounds is None:
        grounds = np.zeros(n_dofs)
        grounds[[0, -1]] = k
    K = np.diag(np.asarray(grounds, dtype=float))
    for j, kj in enumerate(couplings):
        K[j:j + 2, j:j + 2] += kj * np.array([[1.0, -1.0], [-1.0, 1.0]])
    M = np.diag(masses)
    C = alpha * M + beta * K
    C[0, 0] += extra_damper
    return StructuralModel(M, C, K, tuple("abcdefgh"[:n_dofs]), tuple(elements))


def multisine(n_inputs: int, period: int, fs: float, band: tuple[float, float], rms: float,
              rng: np.random.Generator, oversample: int = 1) -> np.ndarray:
    """Random-phase multisine, flat amplitude on the period's lines in ``band``.

    Returns one period sampled at ``oversample * fs``, shape (oversample * period, n_inputs),
    with RMS ``rms`` (the same band-limited signal at any rate).
    """
    f = np.fft.rfftfreq(period, 1.0 / fs)
    lines = (f >= band[0]) & (f <= band[1])
    spectrum = np.zeros((f.size, n_inputs), dtype=complex)
    spectrum[lines] = np.exp(2j * np.pi * rng.random((lines.sum(), n_inputs)))
    n = oversample * period
    full = np.zeros((n // 2 + 1, n_inputs), dtype=complex)
    full[: f.size - 1] = spectrum[:-1]
    u = np.fft.irfft(full, n=n, axis=0)
    return u * rms / u.std(axis=0)


def simulate(model: StructuralModel, force_dofs, *, fs: float = 200.0, period: int = 2000,
             periods: int = 4, band=(3.0, 45.0), rms=1.0, noise: float = 0.0,
             outputs=None, seed: int = 0, oversample: int = 16,
             noise_by_output=None) -> Measurement:
    """Periodic steady-state record of ``model`` by Newmark at ``oversample * fs``.

    The multisine excitation acts at ``force_dofs``; one realisation per value of ``rms``
    (force RMS [N], each with its own random phases). The displacement is decimated per
    period by keeping the DFT lines below fs / 2, which is exact anti-aliasing for the
    periodic steady state (the first, transient period is discarded by the tests).
    White output noise of ``noise`` times each channel's RMS is added
    (``noise_by_output`` gives one fraction per output instead).
    """
    rng = np.random.default_rng(seed)
    force_dofs = list(force_dofs)
    outputs = list(model.dof_names if outputs is None else outputs)
    levels = np.atleast_1d(np.asarray(rms, dtype=float))
    u_fine = np.stack([multisine(len(force_dofs), period, fs, band, level, rng, oversample)
                       for level in levels])
    p = np.zeros((levels.size, periods * u_fine.shape[1], model.n_dofs))
    for j, name in enumerate(force_dofs):
        p[:, :, model.dof_index(name)] = np.tile(u_fine[:, :, j], periods)
    q = newmark(model, p, 1.0 / (oversample * fs)).displacement
    q = q[:, :, [model.dof_index(n) for n in outputs]]
    q = q.reshape(levels.size, periods, oversample * period, len(outputs))
    spectrum = np.fft.rfft(q, axis=2)[:, :, : period // 2 + 1]
    spectrum[:, :, -1] = 0.0
    y = np.fft.irfft(spectrum, n=period, axis=2).reshape(levels.size, periods * period, -1)
    y /= oversample
    fractions = np.full(len(outputs), noise) if noise_by_output is None else np.asarray(
        noise_by_output)
    y = y + rng.standard_normal(y.shape) * fractions * y.std(axis=1, keepdims=True)
    u = np.tile(u_fine[:, ::oversample], (1, periods, 1))
    return Measurement.from_arrays(u, y, fs, input_names=force_dofs, output_names=outputs,
                                   periods=periods)


@pytest.fixture(scope="session")
def simulate_record():
    """The :func:`simulate` function (truth data by the project's Newmark integrator)."""
    return simulate


@pytest.fixture(scope="session")
def single():
    """SmallSat, paper IV.A: 100 N RMS at NC2w_Z, 8 x 30,000 samples (1.92 M Newmark
    steps), 0.5 % output noise: (measurement, truth)."""
    return simulate_preset("single")


@pytest.fixture(scope="session")
def chain():
    """The :func:`chain_model` factory."""
    return chain_model


@pytest.fixture(params=["modal", "whitened"])
def formation(request, monkeypatch):
    """Each way :func:`fnsi.subspace.input_matrices` forms its normal equations: in modal
    coordinates where well conditioned (the default), or always whitened."""
    if request.param == "whitened":
        monkeypatch.setattr("fnsi.subspace.MODAL_RCOND", np.inf)
    return request.param
