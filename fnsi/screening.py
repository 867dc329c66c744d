"""Cheap screening of candidate nonlinear forces with the poles of a model held fixed.

A model revision (A, B^e, C, D^e) identified by FNSI explains the measured output spectra
Y(k) through Eq. 8. A physical effect it lacks acts as one more feedback force
f = sum_j mu_j g_j(x, v) at some location, i.e. as extra columns of the extended input E
(Eq. 5, 17). Because the extended FRF shares the poles of the underlying linear system
(Eq. 18), the output response to a candidate basis spectrum G_c(k) is
C (z_k I - A)^{-1} b_c G_c(k) with A and C unchanged: given (A, C), the input matrix of
every column of E follows by *linear* least squares, exactly the B^e step of FNSI
(Section II.D). Screening a candidate is therefore one small linear least-squares
problem, and all of them share the same line-wise products

    M_k = W_k^H W_k,  W_k = S C (z_k I - A)^{-1},

where S weights each output channel by the inverse of its noise level, in state
coordinates the band's lines see orthonormally (:mod:`fnsi.whitening`: the normal equations
square the conditioning of FNSI's own basis). The reduction of the weighted residual
when a candidate's columns are added, relative to the same fit without them, ranks
locations and kinds before any expensive identification. The base (inputs and the
revision's own bases) is eliminated once (Schur complement), so a candidate costs the
products of its own columns only.

Basis functions are evaluated on measured outputs, whose noise would be "explained" by
fitting them to the same periods (errors in variables): they are evaluated on the first
half of the kept periods and fitted to the average of the other half.

Conventions: spectra are ``(realisations, lines, channels)``; time records of one
averaged period ``(realisations, period_length, channels)``.
"""

from __future__ import annotations

import contextlib
import copy
from dataclasses import dataclass

import numpy as np
import scipy.linalg

from fnsi.measurement import Measurement
from fnsi.nonlinear import NonlinearElement
from fnsi.reciprocity import force_columns, location_column
from fnsi.spectra import displacement_velocity, kept_record, without_quiet_low_lines
from fnsi.statespace import StateSpaceModel
from fnsi.subspace import transfer_rows
from fnsi.whitening import whitening


@dataclass(frozen=True)
class MotionRecord:
    """Displacements and velocities of one averaged steady-state period.

    Attributes
    ----------
    x, v : ndarray, shape (realisations, period_length, l)
        Displacement and velocity at the outputs, in the measurement's length unit.
    output_names : tuple of str
        The l output channels.
    """

    x: np.ndarray
    v: np.ndarray
    output_names: tuple[str, ...]

    def relative(self, dof: str, ref: str | None) -> tuple[np.ndarray, np.ndarray]:
        """Relative displacement and velocity ``dof - ref`` (ref None: ground), flattened."""
        i = self.output_names.index(dof)
        x, v = self.x[..., i], self.v[..., i]
        if ref is not None:
            j = self.output_names.index(ref)
            x, v = x - self.x[..., j], v - self.v[..., j]
        return x.ravel(), v.ravel()


def _averaged_spectra(record: np.ndarray, periods: int) -> tuple[np.ndarray, np.ndarray]:
    """Mean-period spectrum (R, lines, c) and the noise variance of one period's spectrum
    (R, lines, c), from the period-to-period spread (NaN for one period).

    ``record`` holds ``periods`` kept steady-state periods; numpy's unscaled DFT.
    """
    r, samples, c = record.shape
    spectra = np.fft.rfft(record.reshape(r, periods, samples // periods, c), axis=2)
    mean = spectra.mean(axis=1)
    if periods > 1:
        variance = np.sum(np.abs(spectra - mean[:, None]) ** 2, axis=1) / (periods - 1)
    else:
        variance = np.full(mean.shape, np.nan)
    return mean, variance


CANCELLATION = 1e-6
"""A fit whose cost from the normal equations falls below this fraction of the base
residual (or below zero, or above the base) is costed from its residual instead
(:meth:`ScreeningProblem._residual_cost`)."""


class ScreeningProblem:
    """Fixed-pole least-squares fits of candidate forces on estimation spectra.

    Parameters
    ----------
    measurement : Measurement
        Estimation data (the data the revision was identified on).
    model : StateSpaceModel
        The revision's identified model; its outputs, inputs and elements define the
        channels and the existing extended-input columns.
    band : (float, float)
        Analysed frequency band [Hz] (the identification band).
    discard_periods : int
        Transient periods dropped at the start of each realisation.

    Notes
    -----
    Unknowns are the real columns b_a (r,) of B^e, in the r <= n whitened state
    coordinates (:mod:`fnsi.whitening`, ``order``), for every extended input e_a (inputs,
    existing bases, candidate bases): the normal equations read
    sum_b Re(sum_k conj(e_a) e_b M_k) b_b = Re(sum_k conj(e_a) W_k^H S Y_k). D^e is left
    out: it carries no dynamics and would multiply the unknowns by l / n.
    """

    def __init__(self, measurement: Measurement, model: StateSpaceModel,
                 band: tuple[float, float], discard_periods: int,
                 driving_point: tuple[str, str] | None = None) -> None:
        data = measurement.select(inputs=model.input_names, outputs=model.output_names)
        # where a force at each measured DOF enters (fnsi.reciprocity), with a driving point
        # and modes that separate (else the free columns alone screen)
        self.force_columns = None
        if driving_point is not None:
            with contextlib.suppress(ValueError):
                self.force_columns = force_columns(model, driving_point)
        kept = data.periods - discard_periods
        periods = without_quiet_low_lines(kept_record(data.y, data.periods, discard_periods),
                                          kept, data.fs, data.quantity, band[0])
        # Regressors built from measured outputs carry their noise; fitted to the same
        # periods they would "explain" that noise (errors in variables). The bases are
        # therefore evaluated on the first half of the kept periods and fitted to the
        # average of the other half, whose noise is independent (needs 2 kept periods).
        split = kept // 2 if kept >= 2 else 0
        cut = split * data.period_length
        y_mean = _averaged_spectra(periods[:, cut:], kept - split)[0]
        x_mean = _averaged_spectra(periods[:, :cut], split)[0] if split else y_mean
        # Noise of the mean of the last kept - split periods, from all kept periods.
        y_var = _averaged_spectra(periods, kept)[1] / (kept - split)
        u_mean, _ = _averaged_spectra(kept_record(data.u, data.periods, discard_periods), kept)
        self.period_length = data.period_length
        self.fs = data.fs
        frequencies = np.fft.rfftfreq(self.period_length, d=1.0 / data.fs)
        self.lines = np.flatnonzero((frequencies >= band[0]) & (frequencies <= band[1])
                                    & (frequencies > 0))
        if self.lines.size < 2:
            raise ValueError(f"band {band} Hz holds fewer than two DFT lines at resolution "
                             f"{data.fs / self.period_length:.4g} Hz; widen the band")
        self.frequencies = frequencies[self.lines]
        # Bases are evaluated on the averaged period's displacement and velocity (exact
        # periodic integration), every line kept as the identification keeps it
        # (fnsi.spectra.without_quiet_low_lines): the candidates' parameters found here
        # are identified and simulated on that motion.
        mean_period = np.fft.irfft(x_mean, n=self.period_length, axis=1)
        x, v = displacement_velocity(mean_period, data.fs, data.quantity, True)
        self.motion = MotionRecord(x, v, data.output_names)
        # FNSI models predict displacements: fit displacement spectra (exact division by
        # (j omega)^p on the band's lines for velocity or acceleration data).
        power = {"displacement": 0, "velocity": 1, "acceleration": 2}[data.quantity]
        jw = (2j * np.pi * self.frequencies)[None, :, None] ** power
        y_lines = y_mean[:, self.lines] / jw
        noise = np.nanmean(y_var[:, self.lines] / np.abs(jw) ** 2, axis=(0, 1))
        if not np.all(np.isfinite(noise) & (noise > 0)):
            # One period: no noise estimate, weight channels by their own level instead.
            noise = np.mean(np.abs(y_lines) ** 2, axis=(0, 1)) * 1e-4
        self.weights = 1.0 / np.sqrt(noise)                                    # S, (l,)
        y = y_lines * self.weights                                             # S Y, (R, N, l)
        # the model's own rate: a refined revision may run at a multiple of fs
        z = np.exp(2j * np.pi * self.frequencies / model.fs)
        transfer = transfer_rows(model.A, model.C * self.weights[:, None], z)  # S C (zI - A)^-1
        self._transfer = transfer                                              # (N, l, states)
        w = transfer @ whitening(transfer)                                     # (N, l, r)
        n = w.shape[2]   # the unknowns of a column of B^e from here on: r whitened states
        self._w, self._y = w, y
        self._gram_lines = np.einsum("kli,klj->kij", w.conj(), w).reshape(z.size, n * n)
        # M_k is Hermitian (its (j, i) entry the exact conjugate of its (i, j) entry):
        # its upper triangle holds it, half the memory each Gram block streams through
        self._upper = np.triu_indices(n)
        upper = self._gram_lines.reshape(z.size, n, n)[:, *self._upper]
        self._gram_real = np.ascontiguousarray(upper.real)
        self._gram_imag = np.ascontiguousarray(upper.imag)
        self._projected = np.einsum("kli,rkl->rki", w.conj(), y)              # (R, N, n)
        self.output_energy = float(np.sum(np.abs(y) ** 2))
        self.order = n
        self._linear: dict[tuple[str, str | None], np.ndarray] = {}
        self._springs: dict[tuple[str, str | None], ScreeningProblem] = {}
        # Base columns: the inputs and the revision's own bases.
        base = [u_mean[:, self.lines]]
        base += [self.basis_spectra(element) for element in model.elements]
        self._set_base(np.concatenate(base, axis=2))

    def _set_base(self, base: np.ndarray) -> None:
        """Take ``base`` (R, N, p) as the regressors every candidate is fitted with."""
        self._base = base
        self._base_rhs = self._rhs(base)
        self._base_inverse = _pseudo_inverse(self._gram(base, base))
        self._base_solution = self._base_inverse @ self._base_rhs
        self.base_cost = float(self.output_energy - self._base_solution @ self._base_rhs)
        self._base_residual: np.ndarray | None = None

    def with_spring(self, dof: str, ref: str | None) -> ScreeningProblem:
        """The problem with a linear spring at ``dof - ref`` added to the base (once per
        location): a candidate fitted with it costs what it would fitted together with
        the spring, at about half the work, since the spring's blocks of the normal
        equations are eliminated once instead of at every trial (a clearance's gap
        search fits some 300 trials). Its ``base_cost`` is the spring's alone; reductions
        are taken against this problem's (:meth:`reduction`)."""
        key = (dof, ref)
        if key not in self._springs:
            spring = copy.copy(self)
            spring._springs = {}
            column = self.linear_spectrum(dof, ref)
            spring._set_base(np.concatenate([self._base, column], axis=2))
            spring.base_cost = self.fit(column)[0]   # guarded against cancellation
            self._springs[key] = spring
        return self._springs[key]

    # -- building blocks -------------------------------------------------------------------
    def basis_spectra(self, element: NonlinearElement) -> np.ndarray:
        """Spectra of the element's basis functions at the analysed lines, (R, N, s)."""
        x, v = self.motion.relative(element.dof, element.ref)
        g = element.basis(x, v)
        g = g.reshape(self.motion.x.shape[0], self.period_length, -1)
        return np.fft.rfft(g, axis=1)[:, self.lines]

    def linear_spectrum(self, dof: str, ref: str | None) -> np.ndarray:
        """Spectrum of the relative displacement ``dof - ref`` at the analysed lines,
        (R, N, 1): the basis of a linear spring there (computed once per location)."""
        key = (dof, ref)
        if key not in self._linear:
            x, _ = self.motion.relative(dof, ref)
            x = x.reshape(self.motion.x.shape[0], self.period_length)
            self._linear[key] = np.fft.rfft(x, axis=1)[:, self.lines, None]
        return self._linear[key]

    def _gram(self, ea: np.ndarray, eb: np.ndarray) -> np.ndarray:
        """Re sum_k conj(e_a) e_b M_k arranged as (pa * n, pb * n)."""
        pa, pb, n = ea.shape[2], eb.shape[2], self.order
        products = np.einsum("rka,rkb->abk", ea.conj(), eb).reshape(pa * pb, -1)
        # einsum's own loops, not BLAS: these products are many and small, and threaded
        # BLAS spends more time synchronising than computing on them.
        real = np.einsum("ak,kx->ax", products.real, self._gram_real)
        imag = np.einsum("ak,kx->ax", products.imag, self._gram_imag)
        # entry (i, j) is Re p M_ij = real - imag; (j, i), with M_ji = conj(M_ij),
        # is real + imag
        gram = np.empty((pa * pb, n, n))
        gram[:, self._upper[1], self._upper[0]] = real + imag
        gram[:, *self._upper] = real - imag
        return gram.reshape(pa, pb, n, n).transpose(0, 2, 1, 3).reshape(pa * n, pb * n)

    def _rhs(self, e: np.ndarray) -> np.ndarray:
        """Re sum_k conj(e_a) W_k^H S Y_k, flattened as (p * n,)."""
        return np.einsum("rka,rki->ai", e.conj(), self._projected).real.ravel()

    def _added(self, cross: np.ndarray, own: np.ndarray,
               rhs: np.ndarray) -> tuple[float, np.ndarray]:
        """Cost and unknowns of added regressors, the base eliminated (Schur complement).

        ``cross`` (base unknowns x added), ``own`` (added x added) and ``rhs`` (added,)
        are the added blocks of the normal equations.
        """
        t = self._base_inverse @ cross
        schur = own - cross.T @ t
        d = rhs - t.T @ self._base_rhs
        theta = _solve_normal(schur, d)
        return float(self.base_cost - theta @ d), theta

    # -- candidates --------------------------------------------------------------------------
    def fit(self, columns: np.ndarray) -> tuple[float, np.ndarray]:
        """Fit candidate basis spectra ``columns`` (R, N, s), each with its own B^e column.

        Returns
        -------
        cost : float
            Weighted residual energy with the candidate (compare with ``base_cost``).
        b_candidate : ndarray, shape (order, s)
            The candidate's columns of B^e, in the whitened state coordinates.
        """
        cross = self._gram(self._base, columns)
        cost, theta = self._added(cross, self._gram(columns, columns), self._rhs(columns))
        if not CANCELLATION * self.base_cost < cost <= self.base_cost:
            cost = self._residual_cost(columns, cross, theta)
        return cost, theta.reshape(-1, self.order).T

    def _residual_cost(self, columns: np.ndarray, cross: np.ndarray,
                       theta: np.ndarray) -> float:
        """The weighted residual energy of a fit computed from its residual, not as the
        energy less the explained part (which cancels when the normal equations are
        ill-conditioned, e.g. a revision of high order fitted on few lines: costs below
        zero, reductions of 20 times the residual)."""
        base = self._base_solution - self._base_inverse @ cross @ theta
        residual = self._residual(base, columns, theta)
        return float(np.sum(np.abs(residual) ** 2))

    def _residual(self, base: np.ndarray, columns: np.ndarray | None = None,
                  theta: np.ndarray | None = None) -> np.ndarray:
        """Weighted output residual (R, N, l) of the base regressors with unknowns
        ``base`` and, if given, ``columns`` with ``theta`` (flattened (p * order,))."""
        n = self.order
        force = np.einsum("rka,an->rkn", self._base, base.reshape(-1, n))
        if columns is not None:
            force = force + np.einsum("rka,an->rkn", columns, theta.reshape(-1, n))
        return self._y - np.einsum("kln,rkn->rkl", self._w, force)

    def directed_reduction(self, columns: np.ndarray, dof: str, ref: str | None) -> float:
        """Fraction of the base's residual that basis spectra ``columns`` (R, N, s)
        explain acting through the input column of a force between ``dof`` and ``ref``
        (None: ground) that reciprocity gives (:mod:`fnsi.reciprocity`), one real
        coefficient each, in [0, 1]; NaN without a driving point.

        Fitted to what the base leaves (its columns held): a score that ranks places by
        how well a force *there* explains the residual, not by how much n free unknowns
        per column can absorb (:meth:`fit`)."""
        if self.force_columns is None:
            return np.nan
        direction = location_column(self.force_columns, dof, ref)
        if self._base_residual is None:
            self._base_residual = self._residual(self._base_solution)
        response = self._transfer @ direction                                  # (N, l)
        regressors = (response[None, :, :, None] * columns[:, :, None, :]).reshape(
            -1, columns.shape[2])
        target = self._base_residual.ravel()
        stacked = np.concatenate([regressors.real, regressors.imag])
        rhs = np.concatenate([target.real, target.imag])
        coefficients = np.linalg.lstsq(stacked, rhs, rcond=None)[0]
        left = float(np.sum((rhs - stacked @ coefficients) ** 2))
        energy = float(rhs @ rhs)
        return min(max(0.0, 1.0 - left / energy), 1.0) if energy > 0.0 else 0.0

    def fit_rank_one(self, columns: np.ndarray, iterations: int = 6
                     ) -> tuple[float, np.ndarray]:
        """Fit basis functions acting through one force: B_c = b0 mu^T (Eq. 2, 4).

        All basis functions of one location move the structure through the same force
        direction b = e_dof - e_ref, so their B^e columns are proportional. Alternating
        least squares on b0 (``order``) and mu (s), started from the leading right
        singular vector of the unconstrained fit (``iterations=0``: that projection
        only).

        Returns
        -------
        cost : float
            Weighted residual energy.
        mu : ndarray, shape (s,)
            Combination of the basis functions (scale and sign arbitrary).
        """
        cost, b = self.fit(columns)
        if columns.shape[2] == 1:
            return cost, np.ones(1)
        mu = np.linalg.svd(b, full_matrices=False)[2][0]
        cost, b = self.fit(columns @ mu[:, None].astype(columns.dtype))
        n = self.order
        for _ in range(iterations):
            b0 = b[:, 0]
            # mu-step: regressors G_j(k) W_k b0; blocks of the normal equations via q_k = M_k b0.
            q = (self._gram_lines.reshape(-1, n, n) @ b0)                       # (N, n)
            h2 = np.real(np.einsum("i,ki->k", b0, q))                            # |W_k b0|^2
            own = np.einsum("rkj,rki,k->ji", columns.conj(), columns, h2).real
            cross = np.einsum("rka,rkj,ki->aij", self._base.conj(), columns, q).real
            cross = cross.reshape(-1, columns.shape[2])
            rhs = np.einsum("rkj,rki,i->j", columns.conj(), self._projected, b0).real
            mu = self._added(cross, own, rhs)[1]
            # b-step: one combined column g = G mu with its own B^e column.
            new_cost, b = self.fit(columns @ mu[:, None].astype(columns.dtype))
            converged = cost - new_cost < 1e-4 * (self.base_cost - new_cost)
            cost = new_cost
            if converged:
                break
        return cost, mu

    def model_residual(self, model: StateSpaceModel) -> np.ndarray:
        """Weighted residual of a whole model on these data, its own B^e and D^e kept:
        S (Y_k - H^e(z_k) E_k) on the lines (Eq. 8, 18), with E the inputs and the bases
        of ``model.elements`` on the motion, shape (R, N, l). The weights make the noise
        of each term about unit variance, so its squared norm compares with another
        model's (not with :meth:`fit`'s costs, whose poles are held and whose input
        matrices are fitted here)."""
        inputs = self._base[:, :, :model.n_inputs]
        extended = np.concatenate([inputs, *map(self.basis_spectra, model.elements)], axis=2)
        response = model.frequency_response(self.frequencies)                 # (N, l, m + s)
        return self._y - np.einsum("klq,rkq->rkl", response, extended) * self.weights

    def reduction(self, cost: float) -> float:
        """Fraction of the base residual a candidate explains, in [0, 1]."""
        return min(max(0.0, (self.base_cost - cost) / self.base_cost), 1.0)


def _solve_normal(gram: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Solve small normal equations by Cholesky after equilibration, falling back to the
    pseudo-inverse when collinear basis functions make them singular."""
    diagonal = np.diag(gram)
    scale = np.sqrt(np.where(diagonal > 0, diagonal, 1.0))
    try:
        factor = scipy.linalg.cho_factor(gram / np.outer(scale, scale), check_finite=False)
        if np.min(np.abs(np.diag(factor[0]))) < 1e-7:
            raise np.linalg.LinAlgError("nearly singular")
        return scipy.linalg.cho_solve(factor, rhs / scale, check_finite=False) / scale
    except np.linalg.LinAlgError:
        return _pseudo_inverse(gram) @ rhs


def _pseudo_inverse(gram: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of symmetric positive semidefinite normal equations, equilibrated
    (collinear basis functions make them rank deficient)."""
    diagonal = np.diag(gram)
    scale = np.sqrt(np.where(diagonal > 0, diagonal, 1.0))
    values, vectors = np.linalg.eigh(gram / np.outer(scale, scale))
    keep = values > 1e-12 * values.max()
    inverse = (vectors[:, keep] / values[keep]) @ vectors[:, keep].T
    return inverse / np.outer(scale, scale)
