"""Exact periodic steady state of a linear structure, synthesised in the frequency domain.

A random-phase multisine excites the DFT lines of one period in the band; on each line k
the response is Y(k) = (j w_k)^p H(j w_k) U(k), with H = (K - w^2 M + j w C)^-1 the
continuous-time receptance and p = 0, 1, 2 for displacement, velocity or acceleration.
The inverse DFT gives the steady state sampled exactly (the response of a band-limited
periodic input lives on the same lines): no integrator, no discretisation, no transient.
Written with numpy only, independently of ``fnsi``.

Arrays: one period of a record is ``(realisations, samples, channels)``; spectra on the
excited lines are ``(realisations, lines, channels)``; FRFs ``(lines, outputs, inputs)``.
"""

from __future__ import annotations

import numpy as np

from benchmarks.generalisation.structures import first_order

QUANTITIES = ("displacement", "velocity", "acceleration")


def excited_lines(samples: int, fs: float, band: tuple[float, float]) -> np.ndarray:
    """DFT lines k >= 1 of a period with low <= k fs / samples < high (half-open band),
    below Nyquist."""
    k = np.arange(1, (samples + 1) // 2)
    f = k * fs / samples
    return k[(f >= band[0]) & (f < band[1])]


def multisine(rng: np.random.Generator, realisations: int, samples: int, lines: np.ndarray,
              inputs: int) -> np.ndarray:
    """Half spectra of random-phase multisines of flat amplitude on ``lines``, 1 N RMS.

    Returns
    -------
    ndarray, shape (realisations, samples // 2 + 1, inputs), complex
        Independent phases per realisation and input; ``np.fft.irfft(.., n=samples,
        axis=1)`` gives the time signals.
    """
    spectrum = np.zeros((realisations, samples // 2 + 1, inputs), complex)
    phases = rng.uniform(0, 2 * np.pi, (realisations, lines.size, inputs))
    # Parseval: rms^2 = 2 sum |X_k|^2 / samples^2 for lines strictly inside (0, Nyquist)
    spectrum[:, lines] = np.exp(1j * phases) * samples / np.sqrt(2 * lines.size)
    return spectrum


def receptance(M: np.ndarray, C: np.ndarray, K: np.ndarray, frequencies: np.ndarray,
               ) -> np.ndarray:
    """H(j w) = (K - w^2 M + j w C)^-1 [m/N] on ``frequencies`` [Hz], shape (lines, n, n)."""
    s = 2j * np.pi * np.asarray(frequencies)[:, None, None]
    return np.linalg.inv(K[None] + s * C[None] + s**2 * M[None])


def modal_receptance(M: np.ndarray, C: np.ndarray, K: np.ndarray, frequencies: np.ndarray,
                     ) -> tuple[np.ndarray, np.ndarray]:
    """The receptance split into its modes: H = sum_r H_r, one term per conjugate pole pair.

    From the first-order form x' = A x + B f, x = [q; q'], A = V diag(lambda) V^-1, each
    pole contributes psi_r (w_r B) / (s - lambda_r), psi_r the displacement rows of
    column r of V and w_r row r of V^-1; no assumption on the damping (complex modes).

    Parameters
    ----------
    M, C, K : ndarray, shape (n, n)
    frequencies : ndarray, shape (lines,)
        [Hz]

    Returns
    -------
    poles : ndarray, shape (n,), complex
        Pole of each pair with positive imaginary part, by |pole| ascending.
    terms : ndarray, shape (n, lines, n, n), complex
        H_r on every line.
    """
    n = M.shape[0]
    A, B = first_order(M, C, K)
    values, V = np.linalg.eig(A)
    W = np.linalg.inv(V)
    s = 2j * np.pi * np.asarray(frequencies)
    residues = np.einsum("ir,rj->rij", V[:n], W @ B)  # (2n, n, n)
    single = residues[:, None] / (s[None, :, None, None] - values[:, None, None, None])
    upper = np.flatnonzero(values.imag > 0)
    upper = upper[np.argsort(np.abs(values[upper]))]
    # the conjugate partner of each upper pole
    partner = [int(np.argmin(np.abs(values - values[r].conj()))) for r in upper]
    return values[upper], single[upper] + single[partner]


def derivative(frequencies: np.ndarray, quantity: str) -> np.ndarray:
    """(j w)^p on ``frequencies`` [Hz] for the output ``quantity``, shape (lines,)."""
    return (2j * np.pi * np.asarray(frequencies)) ** QUANTITIES.index(quantity)


def power_shares(terms: np.ndarray, U: np.ndarray, factor: np.ndarray, sensors: np.ndarray,
                 inputs: np.ndarray) -> np.ndarray:
    """Each mode's share of the response power on the excited lines at the sensors.

    The power of mode r at sensor c is P_rc = sum over realisations and lines of
    |factor H_r U|^2; its share is the mean over sensors of P_rc / sum_r' P_r'c, so every
    sensor weighs alike (each carries noise in proportion to its own RMS).

    Parameters
    ----------
    terms : ndarray, shape (modes, lines, n, n)
        :func:`modal_receptance`'s H_r on the excited lines.
    U : ndarray, shape (realisations, lines, inputs)
        Input spectra on those lines.
    factor : ndarray, shape (lines,)
        :func:`derivative` of the output quantity.
    sensors, inputs : ndarray of int
        DOFs of the outputs and of the forces.

    Returns
    -------
    ndarray, shape (modes,)
        Shares, summing to 1.
    """
    H = terms[:, :, sensors][:, :, :, inputs]  # (modes, lines, l, m)
    Y = np.einsum("kloi,rli->krlo", H * factor[None, :, None, None], U)
    power = np.sum(np.abs(Y) ** 2, axis=(1, 2))  # (modes, l)
    return np.mean(power / power.sum(axis=0), axis=1)


def steady_state(M: np.ndarray, C: np.ndarray, K: np.ndarray, spectrum: np.ndarray,
                 samples: int, lines: np.ndarray, fs: float, sensors: np.ndarray,
                 inputs: np.ndarray, quantity: str) -> tuple[np.ndarray, np.ndarray]:
    """One period of the forces and of the sensors' steady-state response.

    Parameters
    ----------
    M, C, K : ndarray, shape (n, n)
    spectrum : ndarray, shape (realisations, samples // 2 + 1, m)
        :func:`multisine` half spectra of the forces.
    samples : int
        Samples per period.
    lines : ndarray of int
        Excited lines (the only non-zero ones of ``spectrum``).
    fs : float
        Sampling rate [Hz].
    sensors, inputs : ndarray of int
        DOFs measured, and DOFs where the m forces act.
    quantity : str
        One of :data:`QUANTITIES`.

    Returns
    -------
    u : ndarray, shape (realisations, samples, m)
        Forces [N].
    y : ndarray, shape (realisations, samples, l)
        Responses in ``quantity`` units.
    """
    f = lines * fs / samples
    H = receptance(M, C, K, f)[:, sensors][:, :, inputs] * derivative(f, quantity)[:, None, None]
    Y = np.zeros((*spectrum.shape[:2], sensors.size), complex)
    Y[:, lines] = np.einsum("koi,rki->rko", H, spectrum[:, lines])
    return (np.fft.irfft(spectrum, n=samples, axis=1), np.fft.irfft(Y, n=samples, axis=1))
