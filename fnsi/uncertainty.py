"""Uncertainty of an FNSI identification: standard deviations from the measurement noise.

What is propagated
------------------
The noise of the spectra, estimated per line from the period-to-period scatter of every
kept period of every realisation (:func:`fnsi.spectra.noise_factor`, pooled over the
realisations), jointly for the measured forces, the basis functions (computed from the
noisy outputs) and the outputs. It is propagated to first order through the
identification at the selected order, as Pintelon, Guillaume and Schoukens (2007) do for
frequency-domain subspace estimates:

1. Subspace (Eq. 12-14). The range of Gamma_i is that of the n dominant left singular
   vectors U_n of W = L^-1 Y_i Pi (Pi the projector onto the complement of the rows of
   E_i, L the noise weight or I). A perturbation (dE, dY) of the spectra changes W by
   L^-1 (dY_i - Theta dE_i) Pi + (a term whose products with W^T and U_n vanish),
   Theta = Y_i E_i^T (E_i E_i^T)^-1; with dM = dW W^T + W dW^T, column r of U_n moves by
   (s_r^2 I - M_perp)^-1 P_perp dM u_r, evaluated exactly on the k singular vectors the
   decomposition kept and as 1 / s_r^2 beyond them (their singular values are noise).
   Rotations inside the range do not change the poles and are left out.
2. Everything after it (A and C by the shift property, B^e and D^e by least squares with
   the perturbed spectra, poles, mode shapes, coefficients mu_j) is evaluated by the
   library's own functions at Gamma_n + h dGamma_n and the spectra + h (dE, dY), h =
   :data:`STEP`: a directional derivative, exact to O(h).

The derivatives are taken along noise directions (:func:`_directions`) whose mean
square is the noise covariance C, so that the mean square of the derivatives is the
first-order variance J C J^T without forming the Jacobian J (one row per data point:
millions) nor C. On the harmonic lines of the period a direction is one kept period's
deviation from the period average, on every line and channel at once: a whole period of
noise keeps how the noise of the basis functions (computed in time from the noisy
outputs, so spread over the lines by the nonlinear law) is correlated across lines and
with the outputs, which drawing each line on its own loses (the coefficient's std then
came out 30 % low on a cubic chain). There are R P directions (R realisations, P kept
periods), or :data:`DRAWS` random combinations of them when R P is larger, and the
variance they give has R (P - 1) degrees of freedom: each std is known to about
1 / sqrt(2 R (P - 1)) of itself (32 % for the paper's six kept periods). On the other
lines of ``line_set="all"`` (noise only) each direction draws the pooled covariance
line by line.

Why not a jackknife: re-running the decomposition for every deleted group of periods
costs a full decomposition each (85 % of an identification of the SmallSat single
record), so two groups already triple the time. The propagation costs thin products with
the data matrices (O(N (q + l) i n R P)), a Gram matrix of E_i and R P evaluations of
the least squares for B^e, D^e and of the coefficients: 15-50 % of an identification
(``benchmarks/uncertainty.py``).

What it does not see: errors from the model structure (an approximate basis, an order
that misses a mode, nonlinear distortions the bases do not model), which do not change
from period to period; the bias of the estimates (e.g. the attenuation of noisy bases);
and the noise of the weighting L itself (second order). With one kept period the noise
cannot be told from the signal, so no error bar is given (``note`` says why).

Reported quantities and units: natural frequency [Hz], damping ratio [-], mode shape
components normalised as in :func:`fnsi.modal.modal_table` (the largest component is 1,
so its own std is 0), std of the real and of the imaginary part separately [-],
coefficient mu_j [force per unit of basis function] (std of the band estimate's real part
and of Re and Im of mu_j(omega) per line).

References
----------
R. Pintelon, P. Guillaume, J. Schoukens, "Uncertainty calculation in (operational) modal
analysis", Mechanical Systems and Signal Processing 21(6), 2359-2373, 2007.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from fnsi.feedthrough import own_feedthrough_constraints, own_feedthrough_free
from fnsi.modal import Coefficient, ModalTable, continuous_poles, nonlinear_coefficients
from fnsi.stabilisation import reflect_unstable_poles
from fnsi.statespace import StateSpaceModel
from fnsi.subspace import SubspaceDecomposition, block_gram, input_matrices, noise_weight

#: Most noise directions (:func:`_directions`): beyond, random combinations of the periods
#: (each adds about 1 / sqrt(2 DRAWS) of scatter to the std, well below that of the
#: noise estimate itself when there are that many periods).
DRAWS = 24
#: Step h of the directional derivatives, in units of the noise directions (the noise
#: level): small enough for the poles and coefficients to be linear in it (O(h) error),
#: large enough for rounding (relative 1e-16 / (h x noise)) not to matter.
STEP = 1e-2
#: Directions of the row space of E_i whose Gram eigenvalue falls below this fraction of
#: the largest are taken as fixed by rounding, not by the data (:class:`_InputRows`).
RANK_TOLERANCE = 1e-12
#: Lines per chunk of the products with the data matrices (bounds memory).
CHUNK_LINES = 1024

NO_PERIODS_NOTE = ("no error bar: the noise is estimated from the scatter between periods, "
                   "and only one period was kept; measure (or keep) at least two periods")


@dataclass(frozen=True)
class Uncertainty:
    """Standard deviations of the identified quantities (first-order, from the noise).

    Attributes
    ----------
    frequencies : ndarray, shape (n_modes,), or None
        Std of the natural frequencies [Hz], in the order of the modal table.
    damping_ratios : ndarray, shape (n_modes,), or None
        Std of the damping ratios [-].
    shapes : ndarray, shape (n_modes, l, 2), or None
        Std of the real and imaginary parts of each mode-shape component [-] (shapes
        normalised with their largest component 1).
    coefficients : ndarray, shape (n_coefficients,), or None
        Std of each coefficient's band estimate (``Coefficient.mean_real``) [force per
        unit of basis function]; nan where not identifiable.
    coefficient_curves : ndarray, shape (n_coefficients, N, 2), or None
        Std of Re and Im of mu_j(omega) on each analysis line.
    draws : int
        Noise directions propagated (0 when no error bar could be given).
    note : str or None
        Why there is no error bar, when the arrays are None.
    """

    frequencies: np.ndarray | None = None
    damping_ratios: np.ndarray | None = None
    shapes: np.ndarray | None = None
    coefficients: np.ndarray | None = None
    coefficient_curves: np.ndarray | None = None
    draws: int = 0
    note: str | None = None

    @classmethod
    def unavailable(cls, note: str) -> Uncertainty:
        """No error bar, with the reason."""
        return cls(note=note)

    @property
    def available(self) -> bool:
        """Whether standard deviations were computed."""
        return self.frequencies is not None

    def to_json(self) -> dict:
        """Method, draws and note (the values sit beside each quantity in the result)."""
        return {"method": "first-order propagation of the period-to-period noise",
                "draws": self.draws, "note": self.note}


class _DataMatrix:
    """Products with the real data matrix X_i (i c x 2 K) of Eq. 9-11 without forming it.

    Column k (and K + k) holds the real (imaginary) part of [P_0(w_k) X(k); ...;
    P_(i-1)(w_k) X(k)], P_p the decomposition's row functions
    (:meth:`fnsi.subspace.SubspaceDecomposition.rows`).
    """

    def __init__(self, rows: np.ndarray):
        self.i = rows.shape[1]
        self._basis = np.ascontiguousarray(rows.T)   # P_p(w_k), (i, K)

    def basis(self, sl: slice) -> np.ndarray:
        """P_p(w_k) (i, lines of ``sl``)."""
        return self._basis[:, sl]

    def times(self, X: np.ndarray, V: np.ndarray) -> np.ndarray:
        """X_i V for X (K, c) or (B, K, c) complex and V (2K, r) or (B, 2K, r) real (one of
        them batched, or neither): (i c, r) or (B, i c, r)."""
        K, c = X.shape[-2:]
        v = V[..., :K, :] - 1j * V[..., K:, :]   # conjugated
        if X.ndim == 3:    # the batch joins the channels: one product for all of it
            B = X.shape[0]
            out = self._times(np.moveaxis(X, 0, 1).reshape(K, B * c), v)
            return np.moveaxis(out.reshape(self.i, B, c, -1), 1, 0).reshape(B, self.i * c, -1)
        if v.ndim == 3:    # the batch joins the columns
            B, r = v.shape[0], v.shape[2]
            out = self._times(X, np.moveaxis(v, 0, 1).reshape(K, B * r))
            return np.moveaxis(out.reshape(self.i * c, B, r), 1, 0)
        return self._times(X, v).reshape(self.i * c, -1)

    def _times(self, X: np.ndarray, v: np.ndarray) -> np.ndarray:
        """sum_k P_p(w_k) X(k) v(k)^T, (i, c, r), for X (K, c) and v (K, r) complex."""
        K, c = X.shape
        out = 0.0
        for start in range(0, K, CHUNK_LINES):
            sl = slice(start, start + CHUNK_LINES)
            G = (X[sl, :, None] * v[sl, None, :]).reshape(X[sl].shape[0], -1)
            out = out + (self.basis(sl) @ G).real
        return out.reshape(self.i, c, -1)

    def times_t(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """X_i^T U for X (..., K, c) complex and U (i c, r) real: (..., 2K, r)."""
        K, c = X.shape[-2:]
        Up = U.reshape(self.i, c * U.shape[1])
        out = np.empty((*X.shape[:-2], K, U.shape[1]), dtype=complex)
        for start in range(0, K, CHUNK_LINES):
            sl = slice(start, start + CHUNK_LINES)
            T = (self.basis(sl).T @ Up).reshape(-1, c, U.shape[1])  # (k, c, r)
            out[..., sl, :] = (X[..., sl, None, :] @ T)[..., 0, :]
        return np.concatenate([out.real, out.imag], axis=-2)


def propagate(decomposition: SubspaceDecomposition, model: StateSpaceModel, modal: ModalTable,
              coefficients: tuple[Coefficient, ...], *, driving_points: Mapping[str, str] | None,
              reflect: bool, draws: int = DRAWS, seed: int = 0) -> Uncertainty:
    """Standard deviations of an identification's modes and coefficients (module notes).

    Parameters
    ----------
    decomposition : SubspaceDecomposition
        The decomposition of the identification; its ``spectra.noise_factor`` is the noise.
    model : StateSpaceModel
        The identified model (order n = ``model.order``).
    modal : ModalTable
        The modes reported (physical poles of ``model``).
    coefficients : tuple of Coefficient
        The coefficients reported.
    driving_points : mapping of str to str or None
        As given to :func:`fnsi.modal.nonlinear_coefficients`.
    reflect : bool
        Whether the identification reflected unstable poles (automatic order).
    draws : int
        Most noise directions: the R P kept periods of every realisation when they are
        not more, else that many random combinations of them (:func:`_directions`).
    seed : int
        Seed of the random parts of the directions (the result is reproducible).

    Returns
    -------
    Uncertainty
    """
    factor = decomposition.spectra.noise_factor
    if factor is None:
        return Uncertainty.unavailable(NO_PERIODS_NOTE)
    scale = np.concatenate([decomposition.input_scale, np.ones(decomposition.n_outputs)])
    noise = _directions(factor / scale[None, :, None], decomposition.spectra.harmonic,
                        decomposition.spectra.inputs.shape[0], draws, seed)
    gamma = decomposition.observability[:, :model.order]
    dgamma = _subspace_derivatives(decomposition, model.order, noise)
    evaluate = _Evaluation(decomposition, model, driving_points, reflect)
    nominal = evaluate(gamma, np.zeros_like(noise[0]), _modal_poles(modal))
    rows = [_difference(evaluate(gamma + STEP * dgamma[d], STEP * noise[d], nominal.poles,
                                 nominal.peaks), nominal) / STEP for d in range(len(noise))]
    # the directions' mean square is the noise covariance: the derivatives' is the variance
    spread = np.sqrt(np.mean(np.square(rows), axis=0))
    return _unpack(spread, modal, coefficients, len(noise))


def _directions(factor: np.ndarray, harmonic: np.ndarray | None, realisations: int,
                most: int, seed: int) -> np.ndarray:
    """Noise directions (D, R, N, c) whose mean square is the noise covariance (module
    notes): the mean over D of J delta delta^H J^T is J C J^T for any linear J.

    ``factor`` F is (N, c, R P), its columns the period-to-period deviations of each
    realisation. On the harmonic lines the directions are whole periods: realisation r's
    deviation of period p, R sqrt(P) F[:, :, (r, p)], one direction each (D = R P), or,
    when R P exceeds ``most``, ``most`` random combinations sqrt(R) sum_p zeta_p F[:, :,
    (r, p)] of every realisation's periods (zeta standard normal). Periods keep how the
    noise of the basis functions (computed in time from the noisy outputs) is correlated
    across lines and with the outputs; drawn line by line, that correlation is lost and
    the coefficients' std came out 30 % low (cubic chain, 1 % noise). On the other lines
    of ``"all"`` (noise only) the lines are independent: the pooled covariance is drawn
    line by line.
    """
    rng = np.random.default_rng(seed)
    N, c, columns = factor.shape
    periods = columns // realisations
    own = factor.reshape(N, c, realisations, periods)
    if columns <= most:
        count = columns
        noise = np.zeros((count, realisations, N, c), dtype=complex)
        for r in range(realisations):
            picked = slice(r * periods, (r + 1) * periods)
            noise[picked, r] = np.moveaxis(own[:, :, r], -1, 0) * realisations * np.sqrt(periods)
    else:
        count = most
        zeta = rng.standard_normal((count, realisations, periods))
        noise = np.einsum("kcrp,drp->drkc", own, zeta) * np.sqrt(realisations)
    if harmonic is not None and not harmonic.all():
        quiet = ~harmonic
        shape = (count, realisations, int(quiet.sum()), columns)
        xi = (rng.standard_normal(shape) + 1j * rng.standard_normal(shape)) / np.sqrt(2)
        noise[:, :, quiet] = np.einsum("kcp,drkp->drkc", factor[quiet], xi)
    return noise


def _subspace_derivatives(decomposition: SubspaceDecomposition, order: int,
                          noise: np.ndarray) -> np.ndarray:
    """dGamma_n (D, l i, n) along each noise direction (D, R, N, q + l) (step 1 of the
    module notes)."""
    sp = decomposition.spectra
    R, N, q = sp.inputs.shape
    draws = noise.shape[0]
    basis = decomposition.rows()
    op = _DataMatrix(np.tile(basis, (R, 1)))
    E, Y = sp.inputs.reshape(R * N, q), sp.outputs.reshape(R * N, -1)
    dE = noise[..., :q].reshape(draws, R * N, q)
    dY = noise[..., q:].reshape(draws, R * N, -1)
    L = noise_weight(sp.noise_covariance, basis) if decomposition.weighted else None
    rows = _InputRows(E, op)
    U = decomposition.observability if L is None else scipy.linalg.solve_triangular(
        L, decomposition.observability, lower=True, check_finite=False)
    X = U[:, :order] if L is None else scipy.linalg.solve_triangular(
        L, U[:, :order], lower=True, trans="T", check_finite=False)
    YtX = op.times_t(Y, X)                       # Y_i^T L^-T U_n
    EtY = rows.coordinates(YtX)
    VS = YtX - rows.expand(EtY)                  # W^T U_n = Pi Y_i^T L^-T U_n = V_n S_n
    theta_t_x = rows.inverse @ EtY               # Theta^T L^-T U_n
    b = op.times(dY, VS) - op.times(Y, rows.expand(op.times(dE, VS)))
    Dt = op.times_t(dY, X) - op.times_t(dE, theta_t_x)
    b += op.times(Y, Dt - rows.expand(rows.coordinates(Dt)))
    if L is not None:
        b = _columns(lambda Z: scipy.linalg.solve_triangular(L, Z, lower=True,
                                                             check_finite=False), b)
    dU = _range_change(U, decomposition.singular_values ** 2, b, order)
    return dU if L is None else L @ dU


def _range_change(U: np.ndarray, lam: np.ndarray, b: np.ndarray, order: int) -> np.ndarray:
    """First-order change of the n = ``order`` dominant eigenvectors of M = W W^T outside
    their span, for changes dM u_r = b[..., r] (module notes, step 1).

    (lam_r I - M_perp)^-1 P_perp b_r on the k known eigenvectors U (l i, k) with
    eigenvalues ``lam`` (k,), and b_r / lam_r beyond them (M nearly 0 there).
    """
    coords = np.swapaxes(U, 0, 1) @ b              # (..., k, n)
    rest = b - U @ coords
    gap = lam[None, :order] - lam[order:, None]    # (k - n, n)
    return U[:, order:] @ (coords[..., order:, :] / gap) + rest / lam[:order]


class _InputRows:
    """The row space of E_i (q i x 2K) through its Gram matrix E_i E_i^T: the pseudo-inverse
    E_i^+ = E_i^T (E_i E_i^T)^+ and the projector Pi = I - E_i^+ E_i onto the complement,
    applied to thin matrices.

    The Gram matrix (:func:`fnsi.subspace.block_gram`) is taken by an eigendecomposition,
    which needs no pivoting should E_i be numerically rank-deficient (the paper's powers
    z^p on a narrow band, ``basis="powers"``: condition numbers of 1e17): directions whose
    eigenvalue falls below :data:`RANK_TOLERANCE` times the largest are dropped (fixed by
    rounding, not by the data). The kept ones carry a relative error of at most
    eps / RANK_TOLERANCE (1e-4), far below what a standard deviation needs.
    """

    def __init__(self, E: np.ndarray, op: _DataMatrix):
        self.E, self.op = E, op
        gram = block_gram(E[:, :, None] * E.conj()[:, None, :], op.basis(slice(None)).T)
        lam, V = np.linalg.eigh(gram)
        keep = lam > RANK_TOLERANCE * lam[-1]
        self.inverse = (V[:, keep] / lam[keep]) @ V[:, keep].T  # (E_i E_i^T)^+

    def coordinates(self, X: np.ndarray) -> np.ndarray:
        """E_i X for X (..., 2K, r): (..., q i, r)."""
        return self.op.times(self.E, X)

    def expand(self, C: np.ndarray) -> np.ndarray:
        """E_i^T (E_i E_i^T)^+ C for C (..., q i, r): E_i^+ C, (..., 2K, r); the projection
        of X onto the row space of E_i is expand(coordinates(X))."""
        return _columns(lambda Z: self.op.times_t(self.E, self.inverse @ Z), C)


def _columns(apply, X: np.ndarray) -> np.ndarray:
    """``apply`` (a matrix product from the left) on X (rows, r) or on every (rows, r) of
    X (B, rows, r) at once, the batch side by side as columns."""
    if X.ndim == 2:
        return apply(X)
    B, rows, r = X.shape
    out = apply(np.moveaxis(X, 0, 1).reshape(rows, B * r))
    return np.moveaxis(out.reshape(out.shape[0], B, r), 1, 0)


def _modal_poles(modal: ModalTable) -> np.ndarray:
    """Continuous-time poles s = -zeta w + j w sqrt(1 - zeta^2) [rad/s] of a modal table."""
    omega = 2 * np.pi * modal.frequencies
    zeta = modal.damping_ratios
    return omega * (-zeta + 1j * np.sqrt(1 - zeta**2))


@dataclass(frozen=True)
class _Point:
    """The quantities of one evaluation of the identification after the subspace step."""

    poles: np.ndarray     # (n_modes,) continuous-time [rad/s]
    peaks: np.ndarray     # (n_modes,) int, component normalised to 1 in each shape
    shapes: np.ndarray    # (n_modes, l) complex
    estimates: np.ndarray  # (n_coefficients,) Re of the band estimates
    curves: np.ndarray    # (n_coefficients, N) complex mu_j(omega)


class _Evaluation:
    """Step 2 of the module notes: from Gamma_n and the spectra to the reported quantities,
    with the library's own functions (as :func:`fnsi.identification.identify` calls them)."""

    def __init__(self, decomposition: SubspaceDecomposition, model: StateSpaceModel,
                 driving_points: Mapping[str, str] | None, reflect: bool):
        self.decomposition = decomposition
        self.model = model
        self.points = driving_points
        self.reflect = reflect
        self.repaired = own_feedthrough_free(model)

    def __call__(self, gamma: np.ndarray, noise: np.ndarray, poles: np.ndarray,
                 peaks: np.ndarray | None = None) -> _Point:
        """The quantities at observability basis ``gamma`` (l i, n) and spectra moved by
        ``noise`` (R, N, q + l, scaled units), for the modes nearest ``poles``; shapes
        normalised at ``peaks`` (default: their largest component)."""
        dec, order = self.decomposition, self.model.order
        A, C = dataclasses.replace(dec, observability=gamma, max_order=order, shift_r=None,
                                   shift_rhs=None).state_matrices(order)
        if self.reflect:
            A = reflect_unstable_poles(A)[0]
        found, vectors = continuous_poles(A, self.model.fs)
        nearest = np.argmin(np.abs(found[None, :] - poles[:, None]), axis=1)
        shapes = (C @ vectors[:, nearest]).T
        if peaks is None:
            peaks = np.argmax(np.abs(shapes), axis=1)
        shapes = shapes / shapes[np.arange(len(peaks)), peaks][:, None]
        estimates, curves = self._coefficients(A, C, noise)
        return _Point(found[nearest], peaks, shapes, estimates, curves)

    def _coefficients(self, A: np.ndarray, C: np.ndarray, noise: np.ndarray
                      ) -> tuple[np.ndarray, np.ndarray]:
        """Band estimates (s,) and mu_j(omega) (s, N) of the model with B^e, D^e fitted to
        the moved spectra (nothing to fit for a linear model: B, D leave the modes alone),
        under the nominal fit's constraints: a repaired model's perturbations keep each
        element's own feed-through at zero (:mod:`fnsi.feedthrough`), so that the spread
        is that of the reported estimates, not of the unconstrained fit's."""
        dec, sp = self.decomposition, self.decomposition.spectra
        if not self.model.elements:
            return np.zeros(0), np.zeros((0, sp.n_lines))
        q = sp.inputs.shape[2]
        E, Y = sp.inputs + noise[..., :q], sp.outputs + noise[..., q:]
        constraints = own_feedthrough_constraints(
            C, self.model.elements, self.model.output_names,
            self.model.n_inputs) if self.repaired else None
        B, D = input_matrices(A, C, E, Y, sp.z, noise_covariance=sp.input_noise_covariance,
                              constraints=constraints)
        model = dataclasses.replace(self.model, A=A, B=B / dec.input_scale, C=C,
                                    D=D / dec.input_scale)
        power = np.mean(np.abs(E * dec.input_scale) ** 2, axis=0)
        coefficients = nonlinear_coefficients(model, sp.frequencies, self.points, power)
        return (np.array([c.mean_real for c in coefficients]),
                np.array([c.values if c.identifiable else np.full(sp.n_lines, np.nan)
                          for c in coefficients]).reshape(len(coefficients), sp.n_lines))


def _summary(point: _Point) -> np.ndarray:
    """Frequencies [Hz], damping ratios, shapes (Re, Im), estimates, curves (Re, Im), flat."""
    s = point.poles
    return np.concatenate([np.abs(s) / (2 * np.pi), -s.real / np.abs(s),
                           point.shapes.real.ravel(), point.shapes.imag.ravel(),
                           point.estimates, point.curves.real.ravel(),
                           point.curves.imag.ravel()])


def _difference(moved: _Point, nominal: _Point) -> np.ndarray:
    """Change of every reported quantity between two evaluations, flat."""
    return _summary(moved) - _summary(nominal)


def _unpack(spread: np.ndarray, modal: ModalTable, coefficients: tuple[Coefficient, ...],
            draws: int) -> Uncertainty:
    """The flat standard deviations of :func:`_summary` as an :class:`Uncertainty`."""
    modes, outputs = modal.shapes.shape if modal.n_modes else (0, len(modal.output_names))
    n_coef = len(coefficients)
    lines = (spread.size - 2 * modes - 2 * modes * outputs - n_coef) // max(2 * n_coef, 1)
    parts = np.split(spread, np.cumsum([modes, modes, modes * outputs, modes * outputs,
                                        n_coef, n_coef * lines]))
    return Uncertainty(
        frequencies=parts[0], damping_ratios=parts[1],
        shapes=np.stack([parts[2], parts[3]], axis=-1).reshape(modes, outputs, 2),
        coefficients=parts[4],
        coefficient_curves=np.stack([parts[5], parts[6]], axis=-1).reshape(n_coef, lines, 2),
        draws=draws)
