"""Frequency-domain nonlinear subspace identification, FNSI (paper Section II.C-D, Eq. 8-14).

Steps, for the extended input E (forces then basis functions) and the outputs Y on N
lines z_k = exp(j 2 pi f_k / fs) (several realisations add columns with the same z_k):

0. Optional frequency warping (``warp``; off by default, see
   :class:`fnsi.identification.IdentificationSettings`): the data matrices are built in
   w_k = (z_k - a) / (1 - a z_k) (:func:`band_warp`), a Moebius map of the unit circle
   onto itself that spreads the band over it. A model of order n in z is a model of
   order n in w with the same C and A_w = (A - a I)(I - a A)^-1, so the shift property
   gives A_w and A is mapped back exactly. It changes the model class (a discrete-time
   model only approximates a continuous-time structure, and warping amplifies that
   approximation error: 3-DOF chain, band 3-45 Hz at 200 Hz, i = 10: poles 1.5e-6 off
   in z, 6.5e-5 in w), and conditioning no longer needs it (step 1). Warping with a real
   pole a is the Laguerre construction of Wahlberg (1991). Below, w = z without it.
1. Data matrices Y_i (l i x N) and E_i ((m+s) i x N) of Eq. 9-11, real and imaginary
   parts side by side (2N real columns), since Gamma_i and Lambda_i of Eq. 14 are real.
   Block row p holds P_p(w_k) Y(k), with P_0 = 1, ..., P_(i-1) the real polynomials of
   :func:`band_polynomials`, orthonormal on the lines, in place of the paper's powers
   w_k^p. Both span the same row spaces (P_p is a real combination of w^0 ... w^p, an
   invertible block-triangular map of the rows), so Eq. 12-14 hold unchanged with
   Gamma_i of block rows C P_p(A). The monomials are numerically dependent on a narrow
   band: on the SmallSat single record (band 2 % of fs) E_i built from them has
   singular values over 17 decades, the elimination of Eq. 14 removed directions that
   rounding defined, and the clearance coefficient was 87.1 or 99.5 depending on the
   BLAS kernel (single-3, i = 20); in the orthonormal basis E_i's singular values lie
   within three decades and the kernels agree to 1e-12. The basis is also the natural
   weighting: for output noise white over lines and channels, the stacked noise of
   Y_i has covariance sigma^2 N I, so the unweighted SVD of step 4 is already whitened.
   It changes the unweighted truncation where the powers were well conditioned too (the
   weighted one is the same in any basis): the noise directions now yield poles inside
   the band, near weakly excited modes, where the powers put them elsewhere (2-DOF
   chain, 5-40 Hz at 500 Hz, i = 10: order 6 adds a pole at 16.8 Hz beside the 15.9 Hz
   mode and moves its damping from 0.94 to 0.77 %, so order 4 is not confirmed).
2. Elimination of Lambda_i E_i (Eq. 14) by the orthogonal complement of the row space of
   E_i, with QR factorisations and no projector matrix: the R_22 block of the LQ
   factorisation of [E_i; Y_i] when the extended inputs outnumber the outputs, otherwise
   Y_i - (Y_i Q_1) Q_1^T with Q_1 the thin QR factor of E_i^T (the same R_22 up to an
   orthogonal factor, at lower cost for few inputs and many outputs). With periodic
   data only the harmonic lines of the period carry signal, and E_i must leave room for
   the state there (rule 3 of :func:`check_dimensions`; :func:`auto_block_rows`).
3. Optional weighting by the noise covariance C_V of the stacked outputs: block (a, b)
   is Re sum_k P_a(w_k) conj(P_b(w_k)) C_Y(k) (block Toeplitz in the monomials).
   The SVD is taken of L^-1 Y_perp with C_V = L L^T and Gamma_i = L U_n, which makes the
   truncation statistically meaningful when channels have unequal noise.
4. Dominant left singular vectors U (li x k, k = max_order + 20): exact (QR + SVD) when
   the problem is small, otherwise randomised subspace iteration (Halko, Martinsson &
   Tropp 2011, four power iterations), which costs O(l i N k) instead of O(l^2 i^2 N).
5. A and C of any order n <= max_order from the shift property of Gamma_i = U[:, :n]
   (Section II.D), in the basis: block row r times A is C P_r(A) A = sum_s H[s, r]
   C P_s(A), H the recurrence of :func:`band_polynomials` (the shift matrix for powers).
   One QR of the shifted Gamma_i of the largest order serves every order
   (its leading n columns are the QR of the order-n problem), so each order costs a
   triangular solve: the stabilisation diagram relies on it.
6. B^e and D^e by linear least squares over all lines (Noel & Kerschen 2013):
   min sum_k ||Y(k) - (C (z_k I - A)^-1 B^e + D^e) E(k)||^2, linear in (B^e, D^e). The
   normal equations are formed through the eigendecomposition A = V diag(lambda) V^-1,
   at O(N q^2 n^2) cost, or where that squares an ill-conditioned fit, in the state
   coordinates the lines see orthonormally (:mod:`fnsi.whitening`), and solved by
   Cholesky after equilibration.

The extended-input columns are scaled to unit RMS for conditioning; the scaling is undone
in B^e and D^e.

References
----------
P. D. Brubeck, Y. Nakatsukasa and L. N. Trefethen, "Vandermonde with Arnoldi", SIAM
Review 63(2), 405-415, 2021.

B. Wahlberg, "System identification using Laguerre models", IEEE Transactions on
Automatic Control 36(5), 551-562, 1991.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import numpy as np
import scipy.linalg

from fnsi.feedthrough import own_feedthrough_constraints
from fnsi.spectra import Spectra
from fnsi.statespace import StateSpaceModel
from fnsi.whitening import whitening

#: Extra singular vectors kept beyond ``max_order`` (randomised range finder oversampling).
OVERSAMPLING = 20
#: Power iterations of the randomised subspace iteration.
POWER_ITERATIONS = 4
#: Lines per chunk when forming the B^e, D^e normal equations (bounds memory).
CHUNK_LINES = 512
#: Largest block-row count of :func:`auto_block_rows` (the paper's largest, i = 100 with
#: three outputs): the cost grows as i^2 while l (i - 1) already exceeds any useful order.
AUTO_MAX_BLOCK_ROWS = 100


def data_columns(n_lines: int, n_realisations: int) -> int:
    """Number of real columns 2 N R of the stacked data matrices."""
    return 2 * n_lines * n_realisations


def check_dimensions(n_lines: int, n_realisations: int, n_extended: int, n_outputs: int,
                     block_rows: int, max_order: int, *, signal_lines: int | None = None,
                     ) -> None:
    """Validate block rows and order against the data (rules in the messages).

    Rules, with q = m + s extended inputs, l outputs, i block rows, order n:

    1. The 2 N R real columns exceed the (q + l) i rows of [E_i; Y_i], so that E_i can be
       eliminated while leaving room for the outputs.
    2. 1 <= n <= l (i - 1), so that the shift equation of Gamma_i (l (i - 1) rows)
       determines A.
    3. Periodic data: only the N_s harmonic lines of the period carry the signal (2 N_s R
       real columns; the other lines of a multi-period record hold noise). The
       elimination of E_i (Eq. 14) removes q i of them, and the n-dimensional state must
       fit in the rest: q i + n <= 2 N_s R. Rule 1 implies it when every line carries
       signal (``line_set="excited"``); with all lines of the record it does not, and a
       violation leaves Y_i with noise only while the decomposition still runs.

    Parameters
    ----------
    n_lines : int
        Analysis lines N per realisation.
    n_realisations : int
        Realisations R.
    n_extended, n_outputs : int
        Extended inputs q = m + s and outputs l.
    block_rows : int
        Index i of Eq. 9.
    max_order : int
        Largest order n decomposed.
    signal_lines : int, optional
        Lines N_s per realisation that carry the periodic signal (default: all N).
    """
    if block_rows < 2:
        raise ValueError(f"block_rows must be at least 2; got {block_rows}")
    columns = data_columns(n_lines, n_realisations)
    rows = (n_extended + n_outputs) * block_rows
    if columns <= rows:
        most = max(columns - 1, 0) // (n_extended + n_outputs)
        raise ValueError(
            f"too many block rows for the data: (m + s + l) i = ({n_extended} + {n_outputs}) "
            f"x {block_rows} = {rows} rows need more than the {columns} real columns "
            f"(2 x {n_lines} lines x {n_realisations} realisations); use block_rows <= {most}, "
            "a wider band, more lines or fewer basis functions"
        )
    if not 1 <= max_order <= n_outputs * (block_rows - 1):
        raise ValueError(
            f"order {max_order} is too large for {block_rows} block rows and {n_outputs} "
            f"outputs: it must satisfy 1 <= n <= l (i - 1) = {n_outputs * (block_rows - 1)}; "
            "raise block_rows or lower the order"
        )
    harmonic = n_lines if signal_lines is None else signal_lines
    signal = data_columns(harmonic, n_realisations)
    removed = n_extended * block_rows
    if removed + max_order > signal:
        most = (signal - max_order) // max(n_extended, 1)
        fix = f"block_rows <= {most} (or 'auto'), " if most >= 2 else ""
        raise ValueError(
            f"too many block rows for the periodic signal: eliminating E_i (Eq. 14) removes "
            f"(m + s) i = {n_extended} x {block_rows} = {removed} of the {signal} real "
            f"columns that carry it (2 x {harmonic} harmonic lines x {n_realisations} "
            f"realisations) and leaves fewer than the largest order decomposed, {max_order}, "
            f"so the outputs keep noise only; use {fix}fewer basis functions, a lower "
            "max_order, a wider band or more realisations"
        )


def auto_block_rows(signal_lines: int, n_realisations: int, n_extended: int, n_outputs: int,
                    *, max_order: int, order: int | None = None) -> int:
    """Block rows i for periodic data: the smallest with l (i - 1) >= 2 n_max, and at most
    the largest with (q + l) i <= N_s R.

    The shift property (Section II.D) needs l (i - 1) >= n; twice that leaves every order
    of the stabilisation diagram a margin of observability without making the model class
    much richer than the orders sought. In the orthonormal band basis
    (:func:`band_polynomials`) every block row is numerically alive, so surplus rows give
    the truncation room to fit the noise, with poles in the band: on the blind
    generalisation benchmark (seed 20, 200 random structures) the automatic order is right
    on 84.5 % with this count and on 76.0 % with the largest count the lines allow; on the
    SmallSat single-nonlinearity record (three outputs, order 8, 5-50 Hz) i = 100 gives the
    linear model an unstable 30.7 Hz pole, i = 41 does not.

    [E_i; Y_i] takes at most half of the 2 N_s R real columns that carry the periodic
    signal, so the elimination of E_i (Eq. 14) keeps at least half of them for the state.
    On the SmallSat multi-nonlinearity data (18 outputs, a force and eight clearances, 540
    harmonic lines) the four excited modes come within 0.2 % in frequency and 0.8 % in
    damping for i from 10 to 39; as q i approaches 2 N_s R the damping error grows (3.5 %
    at q i = 0.83 x 2 N_s R) and a spurious mode appears (0.98 x 2 N_s R). The count is
    capped at :data:`AUTO_MAX_BLOCK_ROWS` and raised, for an explicit order, to the
    l (i - 1) >= n that the shift property needs; :func:`check_dimensions` still applies.

    Parameters
    ----------
    signal_lines : int
        Harmonic lines N_s of the period in the band (per realisation).
    n_realisations : int
        Realisations R.
    n_extended, n_outputs : int
        Extended inputs q = m + s and outputs l.
    max_order : int
        Largest order n_max of the stabilisation diagram (or the explicit order, if larger).
    order : int, optional
        Explicit model order n.

    Returns
    -------
    int
        Block rows i >= 2.

    Examples
    --------
    >>> auto_block_rows(540, 1, 9, 18, max_order=60)
    8
    >>> auto_block_rows(540, 1, 2, 3, max_order=60)
    41
    >>> auto_block_rows(60, 1, 2, 3, max_order=60)
    12
    """
    i = min(signal_lines * n_realisations // (n_extended + n_outputs), AUTO_MAX_BLOCK_ROWS,
            -(-2 * max_order // n_outputs) + 1)
    if order is not None:
        i = max(i, -(-order // n_outputs) + 1)
    return max(i, 2)


def memory_estimate(n_lines: int, n_realisations: int, n_extended: int, n_outputs: int,
                    block_rows: int) -> int:
    """Peak working memory of :func:`decompose` [bytes], before anything is allocated.

    Real stacked Y_i^T and E_i^T, the thin Q factor of E_i^T, and the complex
    intermediates of the largest data matrix.
    """
    cols = data_columns(n_lines, n_realisations)
    i, q, n_out = block_rows, n_extended, n_outputs
    real = 8 * cols * i * (n_out + 2 * q)
    complex_tmp = 16 * (cols // 2) * i * max(q, n_out)
    chunk = 16 * min(CHUNK_LINES, cols // 2) * q * q * 2
    return int(real + complex_tmp + chunk)


def band_polynomials(w: np.ndarray, block_rows: int) -> tuple[np.ndarray, np.ndarray]:
    """Polynomials P_0, ..., P_(i-1) orthonormal on the lines, and their recurrence.

    The rows of the data matrices of Eq. 9-11 hold w_k^p X(k), p < i. Any basis of the
    real-coefficient polynomials of degree < i spans the same row spaces, and the
    monomials are the worst one on a narrow band: there every w_k is near the same point
    of the circle and the vectors w_k^p are nearly parallel (SmallSat single-3, band 2 %
    of fs, i = 20: the singular values of E_i span 17 decades, so that rounding decides
    what the elimination of Eq. 14 removes). This basis is orthonormal for the real
    inner product <f, g> = Re mean_k f(w_k) conj(g(w_k)) on the N lines (the one of the
    real and imaginary columns of the data matrices) and is built by the Arnoldi
    iteration of Brubeck, Nakatsukasa and Trefethen (2021), which never forms a power:
    P_0 = 1 and w P_r(w) = sum_(s <= r + 1) H[s, r] P_s(w) with H real, (i, i - 1),
    upper Hessenberg. The same E_i then has singular values within 3 decades.

    Parameters
    ----------
    w : ndarray, shape (N,), complex
        The lines' variable (z_k, or w_k when warped), on the unit circle, distinct.
    block_rows : int
        Number i of polynomials.

    Returns
    -------
    P : ndarray, shape (N, i), complex
        P_p(w_k).
    H : ndarray, shape (i, i - 1)
        Recurrence coefficients.

    References
    ----------
    P. D. Brubeck, Y. Nakatsukasa and L. N. Trefethen, "Vandermonde with Arnoldi", SIAM
    Review 63(2), 405-415, 2021.

    Examples
    --------
    >>> w = np.exp(1j * np.linspace(0.1, 0.2, 30))
    >>> P, H = band_polynomials(w, 4)
    >>> np.allclose((P.conj().T @ P).real / 30, np.eye(4))
    True
    >>> np.allclose(w[:, None] * P[:, :3], P @ H)
    True
    """
    N = w.size
    if block_rows > 2 * N:
        raise ValueError(f"block_rows = {block_rows} exceeds twice the {N} distinct lines: "
                         "polynomials of that degree are not distinct on the lines; use "
                         f"block_rows <= {2 * N} or a wider band")
    P = np.empty((N, block_rows), dtype=complex)
    H = np.zeros((block_rows, block_rows - 1))
    P[:, 0] = 1.0
    for r in range(block_rows - 1):
        v = w * P[:, r]
        for _ in range(2):  # Gram-Schmidt twice leaves v orthogonal to rounding
            c = (P[:, :r + 1].conj().T @ v).real / N
            v -= P[:, :r + 1] @ c
            H[:r + 1, r] += c
        H[r + 1, r] = np.linalg.norm(v) / np.sqrt(N)
        P[:, r + 1] = v / H[r + 1, r]
    return P, H


def stacked_rows(X: np.ndarray, basis: np.ndarray, out: np.ndarray) -> None:
    """Write the transpose of the real data matrix of Eq. 9-11 into ``out`` (2 K, i c).

    Row k (and K + k for the imaginary part) holds [P_0 X(k), ..., P_(i-1) X(k)], with
    ``basis`` (K, i) the values P_p of :func:`band_polynomials` on each row's line.
    """
    K, c = X.shape
    for p in range(basis.shape[1]):
        block = basis[:, p, None] * X
        out[:K, p * c:(p + 1) * c] = block.real
        out[K:, p * c:(p + 1) * c] = block.imag


def _projected_outputs(E: np.ndarray, Y: np.ndarray, basis: np.ndarray,
                       *, r_only: bool) -> np.ndarray:
    """Z with Z^T Z = Y_i P Y_i^T, P the projector onto the complement of the rows of E_i.

    Two QR-based routes, the cheaper for the shape: the R factor only of [E_i; Y_i]^T and
    Z = R_22 (l i x l i), which avoids forming Q_1; or, with fewer extended inputs than
    outputs and a large l i (``r_only`` false), the thin Q_1 of E_i^T and
    Z = Y_i^T - Q_1 (Q_1^T Y_i^T) (2K x l i), whose (2K x l i) QR is never computed
    because the randomised SVD only multiplies by Z. ``basis`` (K, i): the values of
    :func:`band_polynomials` on each row's line.
    """
    K, q = E.shape
    n_out = Y.shape[1]
    block_rows = basis.shape[1]
    qi, li = q * block_rows, n_out * block_rows
    if q < n_out and not r_only:
        Et = np.empty((2 * K, qi))
        stacked_rows(E, basis, Et)
        Q1 = scipy.linalg.qr(Et, mode="economic", overwrite_a=True, check_finite=False)[0]
        del Et
        Z = np.empty((2 * K, li))
        stacked_rows(Y, basis, Z)
        Z -= Q1 @ (Q1.T @ Z)
        return Z
    data = np.empty((2 * K, qi + li))
    stacked_rows(E, basis, data[:, :qi])
    stacked_rows(Y, basis, data[:, qi:])
    R = scipy.linalg.qr(data, mode="r", overwrite_a=True, check_finite=False)[0]
    return np.triu(R[qi:qi + li, qi:])


def block_gram(products: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Real Gram matrix of a stacked data matrix from per-line products (i c x i c).

    Block (a, b) is Re sum_k P_a(w_k) conj(P_b(w_k)) G(k), ``basis`` (K, i) holding
    P_p(w_k) (:func:`band_polynomials`) and ``products`` (K, c, c) the Hermitian G(k): with
    G(k) = X(k) X(k)^H, the Gram matrix X_i X_i^T of the real and imaginary columns of the
    data matrix of Eq. 9-11; with G(k) the noise covariance of X(k), their covariance.
    Block (b, a) is the transpose of (a, b). Summed in real arithmetic, one block row at a
    time (memory K i c^2), at O(K i^2 c^2 / 2) cost: the Toeplitz structure of the powers,
    which needed only 2 i - 1 distinct blocks, is lost in this basis.
    """
    K, c, _ = products.shape
    block_rows = basis.shape[1]
    flat = products.reshape(K, c * c)
    gram = np.empty((block_rows, c, block_rows, c))
    for a in range(block_rows):
        pair = basis[:, a, None] * basis[:, a:].conj()   # P_a conj(P_b), b >= a
        blocks = (pair.real.T @ flat.real - pair.imag.T @ flat.imag).reshape(-1, c, c)
        gram[a, :, a:] = blocks.transpose(1, 0, 2)
        gram[a:, :, a] = blocks.transpose(0, 2, 1)
    return gram.reshape(block_rows * c, block_rows * c)


def noise_weight(noise_covariance: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """Cholesky factor L of the stacked-output noise covariance C_V (:func:`block_gram` of
    the output noise covariance (N, l, l) with ``basis`` (N, i))."""
    cov = block_gram(noise_covariance, basis)
    # a channel without measured noise would get infinite weight: a relative ridge keeps
    # C_V positive definite and leaves such channels at the weight of the quietest one
    ridge = 1e-10 * np.trace(cov) / cov.shape[0]
    return np.linalg.cholesky(cov + ridge * np.eye(cov.shape[0]))


def row_basis(w: np.ndarray, block_rows: int, basis: str = "orthonormal"
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """Values (N, i) of the data matrices' row functions on the lines' variable ``w``,
    and their recurrence: :func:`band_polynomials` ("orthonormal"), or the paper's powers
    w^p ("powers", recurrence None: the shift)."""
    if basis == "orthonormal":
        return band_polynomials(w, block_rows)
    if basis == "powers":
        return w[:, None] ** np.arange(block_rows), None
    raise ValueError(f"basis must be 'orthonormal' or 'powers'; got {basis!r}")


def _exact_svd(rows: int, k: int) -> bool:
    """Whether k singular vectors of ``rows`` rows are computed exactly (else randomised)."""
    return rows <= 4 * k


def _dominant_subspace(Z: np.ndarray, k: int, L: np.ndarray | None = None,
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Leading k left singular vectors and values of W = L^-1 Z^T (Z^T when L is None).

    Z has shape (cols, rows); L, when given, is the lower Cholesky factor (rows, rows) of
    the output noise covariance. Exact when :func:`_exact_svd` (R of a thin QR of Z, then
    the SVD of L^-1 R^T, which has the left singular vectors of W), else randomised
    subspace iteration. L^-1 only ever multiplies thin (rows, k) blocks: forming
    L^-1 Z^T would cost rows^2 cols flops, the largest cost of a weighted decomposition
    with many outputs (39 outputs, i = 50, 3,240 lines: 2.5e10 flops).
    """
    cols, rows = Z.shape

    def weigh(X: np.ndarray, trans: str = "N") -> np.ndarray:
        if L is None:
            return X
        return scipy.linalg.solve_triangular(L, X, lower=True, trans=trans,
                                             check_finite=False)

    if _exact_svd(rows, k):
        R = scipy.linalg.qr(Z, mode="r", check_finite=False)[0][:rows]
        U, s, _ = scipy.linalg.svd(weigh(R.T), full_matrices=False, check_finite=False)
        return U[:, :k], s[:k]
    rng = np.random.default_rng(0)
    Q = np.linalg.qr(weigh(Z.T @ rng.standard_normal((cols, k))))[0]
    for _ in range(POWER_ITERATIONS):
        Q = np.linalg.qr(weigh(Z.T @ np.linalg.qr(Z @ weigh(Q, "T"))[0]))[0]
    _, s, Vh = np.linalg.svd(Z @ weigh(Q, "T"), full_matrices=False)
    return Q @ Vh.T, s


@dataclass(frozen=True)
class SubspaceDecomposition:
    """Result of the projection and SVD of FNSI, usable for any order up to max_order.

    Attributes
    ----------
    singular_values : ndarray, shape (k,)
        Leading singular values of the (weighted) projected output matrix, decreasing.
    observability : ndarray, shape (l i, k)
        Extended observability basis Gamma_i (Eq. 12) of the largest order in the basis
        of :func:`band_polynomials` (block row p: C P_p(A), so block row 0 is C), columns
        by decreasing singular value (weighting undone).
    spectra : Spectra
        The spectra used, extended inputs scaled to unit RMS.
    input_scale : ndarray, shape (q,)
        RMS of each extended-input column before scaling.
    block_rows : int
        Index i of Eq. 9.
    max_order : int
        Largest order available.
    n_inputs : int
        Number m of measured inputs among the q extended inputs.
    elements : tuple
        Nonlinear elements whose basis functions are the last q - m extended inputs.
    weighted : bool
        Whether the noise weighting was applied.
    shift_r, shift_rhs : ndarray, shape (k, k)
        R of the thin QR of Gamma_i without its last block row, and Q^T times the
        recurrence applied to Gamma_i (shift property, Section II.D).
    warp : float
        Pole a of the frequency warping w = (z - a) / (1 - a z) in which Gamma_i was
        built (0: none); :meth:`state_matrices` maps A back to z.
    recurrence : ndarray, shape (i, i - 1)
        H of :func:`band_polynomials`, w P_r(w) = sum_s H[s, r] P_s(w); None: the
        monomials P_p = w^p (H the shift matrix).
    """

    singular_values: np.ndarray
    observability: np.ndarray
    spectra: Spectra
    input_scale: np.ndarray
    block_rows: int
    max_order: int
    n_inputs: int
    elements: tuple = field(default=())
    weighted: bool = False
    shift_r: np.ndarray | None = field(default=None, repr=False)
    shift_rhs: np.ndarray | None = field(default=None, repr=False)
    warp: float = 0.0
    recurrence: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        if self.shift_r is None:
            # block row r of Gamma_i times A is C P_r(A) A = sum_s H[s, r] C P_s(A)
            n_out = self.n_outputs
            gamma = self.observability.reshape(self.block_rows, n_out, -1)
            H = (np.eye(self.block_rows, self.block_rows - 1, -1) if self.recurrence is None
                 else self.recurrence)
            shifted = np.einsum("sr,slk->rlk", H, gamma).reshape(-1, gamma.shape[2])
            Q, R = np.linalg.qr(self.observability[:-n_out])
            object.__setattr__(self, "shift_r", R)
            object.__setattr__(self, "shift_rhs", Q.T @ shifted)

    @property
    def n_outputs(self) -> int:
        """Number l of outputs."""
        return len(self.spectra.output_names)

    def _check_order(self, order: int) -> int:
        if int(order) != order or not 1 <= order <= self.max_order:
            raise ValueError(f"order must be an integer in [1, {self.max_order}] (the "
                             f"max_order of this decomposition); got {order}")
        return int(order)

    def state_matrices(self, order: int) -> tuple[np.ndarray, np.ndarray]:
        """A (n, n) and C (l, n) of order n from the shift property of Gamma_i, in z.

        Parameters
        ----------
        order : int
            Model order n <= max_order.
        """
        n = self._check_order(order)
        A = scipy.linalg.solve_triangular(self.shift_r[:n, :n], self.shift_rhs[:n, :n],
                                          check_finite=False)
        if self.warp:  # z = (w + a) / (1 + a w), so A = (A_w + a I)(I + a A_w)^-1
            identity = np.eye(n)
            A = np.linalg.solve((identity + self.warp * A).T, (A + self.warp * identity).T).T
        return A, self.observability[: self.n_outputs, :n].copy()

    def input_matrices(self, A: np.ndarray, C: np.ndarray, *, own_feedthrough: bool = True
                       ) -> tuple[np.ndarray, np.ndarray]:
        """B^e (n, q) and D^e (l, q) of the scaled extended inputs for A and C
        (:func:`input_matrices`, with the noise compensation of the spectra), each
        element's own feed-through held at zero unless ``own_feedthrough``."""
        sp = self.spectra
        constraints = None if own_feedthrough else own_feedthrough_constraints(
            C, self.elements, sp.output_names, self.n_inputs)
        return input_matrices(A, C, sp.inputs, sp.outputs, sp.z,
                              noise_covariance=sp.input_noise_covariance,
                              constraints=constraints)

    def rows(self) -> np.ndarray:
        """Values (N, i) of the row functions the data matrices were built with on the
        lines (:func:`row_basis`: the orthonormal polynomials, or the powers when
        ``recurrence`` is None)."""
        basis = "powers" if self.recurrence is None else "orthonormal"
        return row_basis(warp_lines(self.spectra.z, self.warp), self.block_rows, basis)[0]

    def model(self, order: int, *, own_feedthrough: bool = True) -> StateSpaceModel:
        """Identified model of order n with B^e, D^e from least squares over all lines.

        Parameters
        ----------
        order : int
            Model order n <= max_order.
        own_feedthrough : bool
            False: each element's own feed-through is held at zero (the repair of a
            model whose simulation folds, :mod:`fnsi.feedthrough`).

        Returns
        -------
        StateSpaceModel
            B and D columns: the m inputs, then the basis functions (scaling undone).
        """
        A, C = self.state_matrices(order)
        B, D = self.input_matrices(A, C, own_feedthrough=own_feedthrough)
        sp = self.spectra
        return StateSpaceModel(
            A=A, B=B / self.input_scale, C=C, D=D / self.input_scale, fs=sp.fs,
            input_names=sp.input_names[: self.n_inputs], output_names=sp.output_names,
            elements=tuple(self.elements),
        )


def decompose(spectra: Spectra, *, block_rows: int, max_order: int, weighting: bool = False,
              n_inputs: int | None = None, elements: tuple = (),
              memory_limit: float | None = None, warp: bool = False,
              basis: str = "orthonormal") -> SubspaceDecomposition:
    """Eliminate the extended input and take the SVD of FNSI (Eq. 9-14, Section II.D).

    Parameters
    ----------
    spectra : Spectra
        Extended input E (inputs (R, N, q): forces then basis functions) and outputs Y
        (R, N, l), displacement spectra.
    block_rows : int
        Index i of Eq. 9.
    max_order : int
        Largest model order needed (stabilisation diagram, chosen order).
    weighting : bool
        Weight by the output noise covariance (``spectra.noise_covariance`` required).
    n_inputs : int, optional
        Number m of measured forces among the q extended inputs (default q).
    elements : tuple of NonlinearElement
        Elements of the basis columns, carried to the model.
    memory_limit : float, optional
        Refuse, before allocating, when the estimate of :func:`memory_estimate` exceeds it
        [bytes].
    warp : bool
        Build the data matrices in the warped variable of :func:`band_warp` (step 0 of
        the module). False (default) builds them in z, as the paper writes Eq. 9-11.
    basis : {"orthonormal", "powers"}
        Rows of the data matrices: the polynomials of :func:`band_polynomials` (default,
        step 1 of the module), or the paper's powers w^p, which rounding makes dependent
        on a narrow band. Both span the same row spaces; the truncated SVD differs where
        the data are not an exact model of the order sought (the exact continuous-time
        response of a structure over a wide band, say), since each basis weighs the
        lines differently.

    Returns
    -------
    SubspaceDecomposition

    Examples
    --------
    >>> fs, z0 = 100.0, np.exp(-0.02 + 2j * np.pi * 0.1)  # one mode, 10 Hz, sampled at fs
    >>> f = np.arange(1, 50) * fs / 100
    >>> z = np.exp(2j * np.pi * f / fs)
    >>> H = 1 / ((z - z0) * (z - z0.conjugate()))
    >>> sp = Spectra(f, fs, np.ones((1, 49, 1)), H[None, :, None], ("u",), ("y",))
    >>> A, C = decompose(sp, block_rows=4, max_order=2).state_matrices(2)
    >>> np.round(np.sort_complex(np.linalg.eigvals(A)), 6) == np.round(np.sort_complex(
    ...     np.array([z0.conjugate(), z0])), 6)
    array([ True,  True])
    """
    E, Y = spectra.inputs, spectra.outputs
    R, N, q = E.shape
    n_out = Y.shape[2]
    check_dimensions(N, R, q, n_out, block_rows, max_order,
                     signal_lines=spectra.signal_lines)
    if memory_limit is not None:
        need = memory_estimate(N, R, q, n_out, block_rows)
        if need > memory_limit:
            raise ValueError(f"FNSI would need about {need / 2**20:.0f} MiB, above the limit "
                             f"of {memory_limit / 2**20:.0f} MiB; reduce block_rows, lines, "
                             "outputs or basis functions")
    if weighting and spectra.noise_covariance is None:
        raise ValueError("weighting needs the output noise covariance: compute the spectra "
                         "with noise statistics (two or more kept periods)")
    scale = np.sqrt(np.mean(np.abs(E) ** 2, axis=(0, 1)))
    if np.any(scale == 0):
        dead = [spectra.input_names[j] for j in np.flatnonzero(scale == 0)]
        raise ValueError(f"extended inputs {dead} are zero on every analysis line (an "
                         "element never activated, or an input without excitation in the "
                         "band); remove them")
    noise = spectra.input_noise_covariance
    if noise is not None:
        noise = noise / scale[None, :, None] / np.concatenate([scale, np.ones(n_out)])
    scaled = dataclasses.replace(spectra, inputs=E / scale, input_noise_covariance=noise)
    k = min(max_order + OVERSAMPLING, n_out * block_rows)
    a = band_warp(spectra.z) if warp else 0.0
    rows, recurrence = row_basis(warp_lines(spectra.z, a), block_rows, basis)
    Z = _projected_outputs((E / scale).reshape(R * N, q), Y.reshape(R * N, n_out),
                           np.tile(rows, (R, 1)), r_only=_exact_svd(n_out * block_rows, k))
    L = noise_weight(spectra.noise_covariance, rows) if weighting else None
    U, s = _dominant_subspace(Z, k, L)
    gamma = U if L is None else L @ U
    return SubspaceDecomposition(
        singular_values=s, observability=gamma, spectra=scaled, input_scale=scale,
        block_rows=block_rows, max_order=max_order, n_inputs=q if n_inputs is None else n_inputs,
        elements=tuple(elements), weighted=weighting, warp=a, recurrence=recurrence,
    )


def warp_lines(z: np.ndarray, a: float) -> np.ndarray:
    """Warped variable w = (z - a) / (1 - a z) of lines z (any shape; w = z for a = 0)."""
    return (z - a) / (1 - a * z)


def band_warp(z: np.ndarray) -> float:
    """Pole a of the warping w = (z - a) / (1 - a z) that centres the band on the circle.

    With z = exp(j theta), the map gives tan(phi / 2) = c tan(theta / 2), c = (1 + a) /
    (1 - a): a bilinear frequency warping that keeps 0 and Nyquist. c is chosen so that
    the geometric centre of the band's angles goes to phi = pi / 2, the band then
    spreads symmetrically about it (5-50 Hz at 2.5 kHz: phi from 0.61 to 2.53 rad).

    Parameters
    ----------
    z : ndarray, shape (N,), complex
        z_k of the lines, on the unit circle.

    Returns
    -------
    float
        a in (-1, 1); positive when the band's geometric centre lies below fs / 4.

    Examples
    --------
    >>> z = np.exp(2j * np.pi * np.array([5.0, 50.0]) / 2500.0)
    >>> a = band_warp(z)
    >>> np.round(np.angle(warp_lines(z, a)), 2)
    array([0.61, 2.53])
    """
    theta = np.abs(np.angle(z))
    # a DC line has no scale: the lowest other line sets the band's low end
    low = theta[theta > 0].min()
    c = 1.0 / np.tan(np.sqrt(low * theta.max()) / 2)
    return float((c - 1) / (c + 1))


def input_matrices(A: np.ndarray, C: np.ndarray, E: np.ndarray, Y: np.ndarray,
                   z: np.ndarray, *, noise_covariance: np.ndarray | None = None,
                   constraints: np.ndarray | None = None,
                   ) -> tuple[np.ndarray, np.ndarray]:
    """B^e and D^e minimising sum_k ||Y(k) - (C (z_k I - A)^-1 B^e + D^e) E(k)||^2.

    Real unknowns theta = vec([B; D]); column a acts on line k through X_k =
    [C (z_k I - A)^-1, I], and the normal equations Re(sum_k Phi_k^H Phi_k) theta =
    Re(sum_k Phi_k^H Y(k)), Phi_k = E(k)^T kron X_k, are formed by sums over the lines.
    In modal coordinates (A = V diag(lambda) V^-1) they cost O(N q^2 n^2), but they square
    the conditioning of the states on the lines: at a decomposition's largest orders,
    where the states beyond the band's modes look alike, B^e and D^e then came out of
    rounding (the generalisation benchmark's seed-22 case 1 at order 54: a relative
    perturbation of 1e-12 of the data moved the response between the lines by 18 % and
    the automatic order from 42 to 54). They are solved when V is well conditioned
    (:data:`MODAL_VECTOR_COND`) and their equilibrated reciprocal condition number is
    at least :data:`MODAL_RCOND` (220 of the 241 calls of a 5-DOF chain's diagnosis);
    otherwise formed again with the states in the coordinates the lines see
    orthonormally (:mod:`fnsi.whitening`), at O(N l n^2 + N q^2 (n + l)^2), where the fit
    is as well conditioned as the excitation allows. Either is solved by Cholesky after
    equilibration.

    Bias compensation (errors in variables): when E = E_0 + dE carries noise (basis
    functions of measured outputs), E[conj(E) E^T] = conj(E_0) E_0^T + conj(S_k), S_k =
    E[dE dE^H], inflates the normal matrix and attenuates the coefficients of the noisy
    columns (the nonlinear force is largely coherent with the input, so little of the
    basis power is its own). With ``noise_covariance`` the products E_a^* E_b are
    replaced by their noise-free expectations E_a^* E_b - conj(S_k)_ab, and E_a^* Y_i by
    E_a^* Y_i - conj(E[dE dY^H])_ai: the bias-compensated least squares of Stoica and
    Soderstrom (1982), consistent as the lines grow.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    C : ndarray, shape (l, n)
    E : ndarray, shape (R, N, q), complex
        Extended input spectra.
    Y : ndarray, shape (R, N, l), complex
        Output spectra.
    z : ndarray, shape (N,), complex
        z_k of the lines.
    noise_covariance : ndarray, shape (N, q, q + l), complex, optional
        Noise covariance of one realisation's E(k) with itself and with Y(k),
        [E[dE dE^H], E[dE dY^H]] (``Spectra.input_noise_covariance``); compensated when
        given.
    constraints : ndarray, shape (k, q (n + l)), optional
        Linear equalities L theta = 0 on the unknowns, theta the columns of [B^e; D^e]
        stacked (:func:`fnsi.feedthrough.own_feedthrough_constraints`); the normal
        equations are solved in the null space of L.

    Returns
    -------
    B : ndarray, shape (n, q)
    D : ndarray, shape (l, q)
    """
    n, q = A.shape[0], E.shape[2]
    lam, V = np.linalg.eig(A)
    modal = np.linalg.cond(V) <= MODAL_VECTOR_COND
    theta = (_solution(*_modal_normal_equations(lam, V, C, E, Y, z, noise_covariance), q,
                       constraints, MODAL_RCOND) if modal else None)
    if theta is None:
        x = transfer_rows(A, C, z, eigen=(lam, V) if modal else None)
        theta = _solution(*_whitened_normal_equations(x, E, Y, noise_covariance), q,
                          constraints, 0.0)
    return theta[:n], theta[n:]


MODAL_RCOND = 1e-10
"""Smallest reciprocal condition number of the equilibrated normal equations formed in
modal coordinates that :func:`input_matrices` solves: rounding of their sums, about the
machine epsilon (2.2e-16) of their size, then moves B^e and D^e by at most about 1e-6
of theirs, far below anything a study compares (its order search weighs errors to 10 %,
:data:`fnsi.simulation_order.TOLERANCE`). Below it the equations are formed again in
whitened coordinates, at about 20 times the cost (21 of the 241 calls of a 5-DOF chain's
diagnosis; 64 with 1e-8)."""

MODAL_VECTOR_COND = 1e3
"""Largest condition number of A's eigenvectors V for which :func:`input_matrices` forms
the normal equations, or the transfer rows, in modal coordinates (V^-1 multiplies every
sum; FNSI's models at the orders a diagnosis searches gave 17-40)."""


def _modal_normal_equations(lam: np.ndarray, V: np.ndarray, C: np.ndarray, E: np.ndarray,
                            Y: np.ndarray, z: np.ndarray, noise_covariance: np.ndarray | None,
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normal equations (G, g) of vec([B; D]) and the identity map to [B^e; D^e], formed
    through A = V diag(lambda) V^-1 at O(N q^2 n^2) cost: with Ct = C V, W = V^-1 and
    d_kr = 1 / (z_k - lambda_r), every block reduces to sums over the lines of products
    E_a^* E_b d_kr^* d_ks."""
    n, n_out, q = len(lam), C.shape[0], E.shape[2]
    W = np.linalg.inv(V)
    Ct = C @ V
    realisations = E.shape[0]
    E = E.reshape(-1, q)
    Y = Y.reshape(-1, n_out)
    zz = np.tile(z, realisations)
    # conjugated, as the products E^* E^T and E^* Y^T of the normal equations
    noise = (None if noise_covariance is None
             else np.tile(noise_covariance.conj(), (realisations, 1, 1)))
    signal = _GramSums(q, n)   # sums of E_a^* E_b d_r^* d_s, E_a^* E_b d_r^*, E_a^* E_b
    noise_sums = None if noise is None else _GramSums(q, n)
    gB = np.zeros((q, n), dtype=complex)
    gB_noise = np.zeros((q, n), dtype=complex)
    Zy = Y @ Ct.conj()  # Ct^H Y(k), (K, n)
    for start in range(0, E.shape[0], CHUNK_LINES):
        sl = slice(start, start + CHUNK_LINES)
        e, d = E[sl], 1.0 / (zz[sl, None] - lam[None, :])
        signal.add(e.conj()[:, :, None] * e[:, None, :], d)
        gB += e.conj().T @ (d.conj() * Zy[sl])
        if noise is not None:
            noise_sums.add(noise[sl, :, :q], d)
            gB_noise += np.einsum("kai,ir,kr->ar", noise[sl, :, q:], Ct.conj(), d.conj())
    m = n + n_out
    G = signal.normal_matrix(W, Ct)
    g = np.concatenate([gB @ W.conj(), E.conj().T @ Y], axis=1).real.reshape(q * m)
    if noise is not None:
        G_noise = noise_sums.normal_matrix(W, Ct)
        g_noise = np.concatenate([gB_noise @ W.conj(), noise[:, :, q:].sum(axis=0)],
                                 axis=1).real.reshape(q * m)
        alpha = compensation_scale(G, G_noise)
        G, g = G - alpha * G_noise, g - alpha * g_noise
    return G, g, np.eye(n + n_out)


def _whitened_normal_equations(x: np.ndarray, E: np.ndarray, Y: np.ndarray,
                               noise_covariance: np.ndarray | None,
                               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Normal equations (G, g) of the unknowns [beta_a; d_a] whose states are taken in the
    coordinates the lines see orthonormally (:mod:`fnsi.whitening`), and the map
    blockdiag(T, I) from them to the columns of [B^e; D^e]: Re(sum_k F_ab(k) M_k) summed
    over the lines, M_k = [X_k T, I]^H [X_k T, I], X_k = C (z_k I - A)^-1 the transfer
    rows ``x`` (N, l, n) and F_ab(k) = sum_r conj(E_ra(k)) E_rb(k) over the realisations
    r, at O(N l n^2 + N q^2 (n + l)^2) cost."""
    n_out, q = x.shape[1], E.shape[2]
    T = whitening(x)                                                      # (n, r)
    r = T.shape[1]
    sums = _LineSums(q, r, n_out)
    g = np.zeros((q, r + n_out))
    noise = None if noise_covariance is None else E.shape[0] * noise_covariance.conj()
    noise_sums, g_noise = _LineSums(q, r, n_out), np.zeros_like(g)
    for start in range(0, len(x), CHUNK_LINES):
        sl = slice(start, start + CHUNK_LINES)
        xw = x[sl] @ T                                                    # X_k T, (K, l, r)
        e = E[:, sl]
        # conjugated as the products E^* E^T and E^* Y^T
        sums.add(np.einsum("rka,rkb->abk", e.conj(), e), xw)
        g += _projections(xw, Y[:, sl], e.conj()).real
        if noise is not None:   # one realisation's noise covariance, R times
            noise_sums.add(np.moveaxis(noise[sl, :, :q], 0, 2), xw)
            g_noise += _projections(xw, noise[None, sl, :, q:], None).real
    G, g = sums.normal_matrix(), g.reshape(-1)
    if noise is not None:
        G_noise = noise_sums.normal_matrix()
        alpha = compensation_scale(G, G_noise)
        G, g = G - alpha * G_noise, g - alpha * g_noise.reshape(-1)
    return G, g, scipy.linalg.block_diag(T, np.eye(n_out))


def _solution(G: np.ndarray, g: np.ndarray, to_theta: np.ndarray, q: int,
              constraints: np.ndarray | None, min_rcond: float) -> np.ndarray | None:
    """[B^e; D^e] (n + l, q) from the normal equations G phi = g of the unknowns phi,
    theta_a = to_theta phi_a, in the null space of the ``constraints`` on theta; None when
    the equilibrated equations' reciprocal condition number is below ``min_rcond``."""
    N = None
    if constraints is not None and constraints.shape[0] > 0:
        N = scipy.linalg.null_space(constraints @ scipy.linalg.block_diag(*[to_theta] * q))
        G, g = N.T @ G @ N, N.T @ g
    phi = solve_normal_equations(G, g, min_rcond=min_rcond)
    if phi is None:
        return None
    phi = phi if N is None else N @ phi
    return to_theta @ phi.reshape(q, -1).T


def transfer_rows(A: np.ndarray, C: np.ndarray, z: np.ndarray,
                  eigen: tuple[np.ndarray, np.ndarray] | None = None) -> np.ndarray:
    """C (z_k I - A)^-1 (N, l, n) of every line.

    With A's eigendecomposition ``eigen`` = (lambda, V), well conditioned
    (:data:`MODAL_VECTOR_COND`): (C V) diag(1 / (z_k - lambda)) V^-1, one matrix product.
    Otherwise from the Schur form A = U S U^H (U unitary, S upper triangular): X U^H,
    where X (z I - S) = C U is solved column by column for all lines at once, O(N l n^2)
    against O(N n^3) for a solve per line and backward stable where eigenvectors are
    not (poles that nearly coincide).
    """
    if eigen is not None:
        lam, V = eigen
        d = 1.0 / (z[:, None] - lam[None, :])
        return ((C @ V)[None] * d[:, None, :]) @ np.linalg.inv(V)
    S, U = scipy.linalg.schur(A.astype(complex), output="complex", check_finite=False)
    rhs = C @ U                                                           # (l, n)
    x = np.empty((z.size, *rhs.shape), dtype=complex)
    for j in range(len(S)):
        # X[:, j] (z - S_jj) = (C U)[:, j] + sum_{i<j} X[:, i] S_ij, on every line
        x[:, :, j] = (rhs[:, j] + x[:, :, :j] @ S[:j, j]) / (z - S[j, j])[:, None]
    return x @ U.conj().T


class _GramSums:
    """Sums over the lines of the products F_ab(k) = E_a^* E_b (or their noise parts)
    weighted by d_r^* d_s, by d_r^* and by 1 (:func:`input_matrices`)."""

    def __init__(self, q: int, n: int) -> None:
        self.T = np.zeros((q, q, n, n), dtype=complex)
        self.S = np.zeros((q * q, n), dtype=complex)
        self.P = np.zeros(q * q, dtype=complex)

    def add(self, F: np.ndarray, d: np.ndarray) -> None:
        """Add the lines of a chunk: F (K, q, q), d (K, n)."""
        _add_weighted_grams(self.T, F, d)
        F = F.reshape(len(F), -1)
        self.S += F.T @ d.conj()
        self.P += F.sum(axis=0)

    def normal_matrix(self, W: np.ndarray, Ct: np.ndarray) -> np.ndarray:
        """The real normal matrix (q m, q m), m = n + l, of the unknowns vec([B; D])."""
        q, _, n, _ = self.T.shape
        n_out = Ct.shape[0]
        m = n + n_out
        T = self.T * (Ct.conj().T @ Ct)
        S = self.S.reshape(q, q, n)
        G = np.zeros((q, m, q, m), dtype=complex)
        G[:, :n, :, :n] = np.swapaxes(W.conj().T @ T @ W, 1, 2)
        BD = W.conj().T @ (S[..., None] * Ct.conj().T)  # blocks (a, b) of shape (n, n_out)
        G[:, :n, :, n:] = np.swapaxes(BD, 1, 2)
        G[:, n:, :, :n] = np.swapaxes(BD.transpose(1, 0, 3, 2).conj(), 1, 2)  # Hermitian
        G[:, n:, :, n:] = self.P.reshape(q, q)[:, None, :, None] * np.eye(n_out)[None, :, None, :]
        return G.real.reshape(q * m, q * m)


def _add_weighted_grams(T: np.ndarray, F: np.ndarray, d: np.ndarray) -> None:
    """T[a, b] += d^H diag(F[:, a, b]) d for the lines of a chunk, in place.

    T (q, q, n, n), F (K, q, q) Hermitian in (a, b), d (K, n). One (n, K) x (K, n) product
    per pair a <= b, T[b, a] being T[a, b]^H: the same arithmetic as one product with
    the (K, n^2) array of every d_r^* d_s, without forming it (at n = 40 and 940 lines,
    that array alone cost 5 times this whole sum)."""
    q = F.shape[1]
    dc = d.conj()
    for a in range(q):
        for b in range(a, q):
            block = (dc * F[:, a, b, None]).T @ d
            T[a, b] += block
            if b > a:
                T[b, a] += block.conj().T


class _LineSums:
    """Sums over the lines of F_ab(k) M_k, M_k = [X_k T, I]^H [X_k T, I], by block: the
    states' (X_k T)^H (X_k T), their cross terms (X_k T)^H with D^e, and F_ab(k) alone
    for D^e's identity, which is never multiplied out (:func:`input_matrices`)."""

    def __init__(self, q: int, r: int, n_out: int) -> None:
        self.shape = q, r, n_out
        self.states = np.zeros((q * q, r * r), dtype=complex)
        self.cross = np.zeros((q * q, r * n_out), dtype=complex)
        self.total = np.zeros(q * q, dtype=complex)

    def add(self, F: np.ndarray, xw: np.ndarray) -> None:
        """Add a chunk of lines: F (q, q, K), xw (K, l, r)."""
        F = F.reshape(-1, len(xw))
        xh = np.swapaxes(xw.conj(), 1, 2)                                # (K, r, l)
        self.states += F @ np.matmul(xh, xw).reshape(len(xw), -1)
        self.cross += F @ xh.reshape(len(xw), -1)
        self.total += F.sum(axis=1)

    def normal_matrix(self) -> np.ndarray:
        """The real normal matrix (q p, q p), p = r + l, of the unknowns [beta_a; d_a]."""
        q, r, n_out = self.shape
        p = r + n_out
        G = np.zeros((q, p, q, p))
        G[:, :r, :, :r] = self.states.real.reshape(q, q, r, r).transpose(0, 2, 1, 3)
        cross = self.cross.real.reshape(q, q, r, n_out)
        G[:, :r, :, r:] = cross.transpose(0, 2, 1, 3)
        # Re(F_ab (X T)) = Re(F_ba (X T)^H)^T, F being Hermitian in (a, b)
        G[:, r:, :, :r] = cross.transpose(1, 3, 0, 2)
        G[:, r:, :, r:] = (self.total.real.reshape(q, q)[:, None, :, None]
                           * np.eye(n_out)[None, :, None, :])
        return G.reshape(q * p, q * p)


def _projections(xw: np.ndarray, Y: np.ndarray, weights: np.ndarray | None) -> np.ndarray:
    """sum_k sum_r w_ra(k) [X_k T, I]^H Y_r(k) (q, r + l) for Y (R, K, l) and weights
    w (R, K, q); without weights, Y (R, K, q, l) holds each column's own right-hand side
    (the noise covariance of the bases with the outputs)."""
    if weights is not None:
        Y = weights[..., None] * Y[:, :, None, :]                          # (R, K, q, l)
    Y = Y.sum(axis=0)                                                     # (K, q, l)
    states = np.einsum("kli,kal->ai", xw.conj(), Y, optimize=True)
    return np.concatenate([states, Y.sum(axis=0)], axis=1)


COMPENSATION_KEEP = 0.1
"""Least share of the uncompensated normal matrix's power, in any direction of the
unknowns, that the bias compensation leaves (:func:`compensation_scale`): a noise
estimate from a few periods is itself uncertain by tens of percent, so a direction it
would leave with less than this is one the data no longer determine (a cubic spring
under 20 % output noise, compensated in full, kept 31 % and its coefficient error fell
from -26 % to -15 %)."""


def compensation_scale(G: np.ndarray, N: np.ndarray) -> float:
    """Scale alpha in (0, 1] of the subtracted noise part N so that G - alpha N keeps at
    least :data:`COMPENSATION_KEEP` of G in every direction.

    The noise covariance of the bases comes from the spread of a few periods: on a 5-DOF
    chain measured in acceleration, with two kept periods, it exceeded the power of the
    cubic spring's basis on some directions, and the compensated normal matrix, no longer
    positive, gave NaN coefficients. Where the estimate stays below 1 -
    :data:`COMPENSATION_KEEP` of the power (the usual case) alpha is 1 and the
    compensation is the full one.

    Parameters
    ----------
    G, N : ndarray, shape (p, p)
        Real symmetric normal matrix of the noisy regressors (positive semidefinite) and
        its expected noise part.
    """
    scale = np.sqrt(np.diag(G))
    scale[scale == 0] = 1.0
    Gs, Ns = G / np.outer(scale, scale), N / np.outer(scale, scale)
    # a unit diagonal: the ridge keeps collinear regressors' G positive definite
    top = scipy.linalg.eigh(Ns, Gs + 1e-10 * np.eye(len(Gs)), eigvals_only=True,
                            subset_by_index=[len(Gs) - 1, len(Gs) - 1])[0]
    return 1.0 if top <= 1.0 - COMPENSATION_KEEP else (1.0 - COMPENSATION_KEEP) / top


def solve_normal_equations(G: np.ndarray, g: np.ndarray, *, min_rcond: float = 0.0
                           ) -> np.ndarray | None:
    """x solving G x = g, G symmetric positive (semi)definite, by Cholesky after
    equilibration; the minimum-norm solution when G is singular. With ``min_rcond`` > 0,
    None instead when the equilibrated G's reciprocal condition number (LAPACK's estimate
    from the Cholesky factor) is below it, or G is singular."""
    diag = np.sqrt(np.diag(G))
    diag[diag == 0] = 1.0
    Gs = G / diag[:, None] / diag[None, :]
    try:
        factor = scipy.linalg.cho_factor(Gs, check_finite=False)
    except np.linalg.LinAlgError:
        if min_rcond > 0:
            return None
        # rank-deficient regression (e.g. collinear basis functions): minimum-norm solution
        return scipy.linalg.lstsq(Gs, g / diag, check_finite=False)[0] / diag
    if min_rcond > 0:
        rcond, _ = scipy.linalg.lapack.dpocon(factor[0], np.abs(Gs).sum(axis=0).max(),
                                              uplo="L" if factor[1] else "U")
        if not rcond >= min_rcond:
            return None
    return scipy.linalg.cho_solve(factor, g / diag, check_finite=False) / diag
