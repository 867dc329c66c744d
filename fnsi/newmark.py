"""Nonlinear Newmark integration of M q'' + C q' + K q + f(q, q') = p(t) (paper Eq. 1-2).

Implicit Newmark scheme (average acceleration by default: gamma = 1/2, beta = 1/4,
unconditionally stable and energy conserving for linear systems) in incremental form::

    K_eff dq = dp - B dw + M (v / (beta dt) + a / (2 beta))
                         + C (gamma / beta v + dt (gamma / (2 beta) - 1) a)
    K_eff = K + gamma / (beta dt) C + 1 / (beta dt^2) M

with dw the change of the nonlinear element forces w (Eq. 2: f = B w, B the influence
matrix of the elements). The nonlinear forces act on few DOFs, so K_eff is factorised once
and each step solves only the small problem in the s element coordinates x = B^T q::

    x - x_lin + G w(x, v(x)) = 0,    G = B^T K_eff^-1 B   (s x s)

by Newton-Raphson, before updating the full state once. The per-step cost is two r x r
matrix-vector products (O(r^2)) plus O(r s); realisations run in parallel threads.

Newton-Raphson: converged when max_e |residual_e| <= 1e-10 * max(|x|, |x_lin|, |x_n|)
(rounding level of the element equation), at most 50 iterations, each step halved up to
12 times until the residual decreases (guards against cycling across the kinks of
piecewise-linear laws). Non-convergence raises :class:`NewmarkConvergenceError` naming
the time and the element.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import numpy as np
import scipy.linalg
from numba import njit, prange

from fnsi.gauss import solve_small
from fnsi.nonlinear import element_force
from fnsi.structure import StructuralModel

Progress = Callable[[float, str], None]

NEWTON_TOLERANCE = 1e-10
NEWTON_MAX_ITERATIONS = 50
LINE_SEARCH_HALVINGS = 12
CHUNK_STEPS = 50_000


class NewmarkConvergenceError(ValueError):
    """Newton-Raphson on the nonlinear forces did not converge within a time step.

    Attributes
    ----------
    time : float
        Time [s] of the step that failed.
    element : str
        Name of the element with the largest residual.
    realisation : int
        Index of the load case.
    """

    def __init__(self, time: float, element: str, realisation: int):
        self.time, self.element, self.realisation = time, element, realisation
        super().__init__(
            f"Newton-Raphson did not converge at t = {time:.6g} s (realisation {realisation}) "
            f"on {element}: reduce the time step (raise the integration rate) or check that "
            "element's parameters (very stiff contacts need smaller steps)"
        )


class NewmarkResponse(NamedTuple):
    """Response of :func:`newmark`, each of shape (samples, r) or (realisations, samples, r)."""

    displacement: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


# -- compiled step loop -----------------------------------------------------------------------
@njit(cache=True, fastmath={"reassoc", "contract"})
def _linear_increment(H, z, Sd, du, SB, w, d):
    """d = H z + Sd du + SB w: the state increment with frozen element forces (O(r^2))."""
    for i in range(H.shape[0]):
        acc = 0.0
        for j in range(H.shape[1]):
            acc += H[i, j] * z[j]
        for j in range(du.shape[0]):
            acc += Sd[i, j] * du[j]
        for j in range(w.shape[0]):
            acc += SB[i, j] * w[j]
        d[i] = acc


@njit(cache=True)
def _element_residual(x, x_lin, x_n, v_pred, cv, G, kinds, params, p0, coefs, c0,
                      w, kx, residual):
    """Element forces w(x), total slopes kx = dw/dx + cv dw/dv and the residual; inf-norm."""
    s = x.shape[0]
    for e in range(s):
        v = cv * (x[e] - x_n[e]) + v_pred[e]
        f, fx, fv = element_force(kinds[e], params, p0[e], coefs, c0[e], c0[e + 1] - c0[e],
                                  x[e], v)
        w[e] = f
        kx[e] = fx + cv * fv
    norm = 0.0
    for e in range(s):
        acc = x[e] - x_lin[e]
        for j in range(s):
            acc += G[e, j] * w[j]
        residual[e] = acc
        norm = max(norm, abs(acc))
    return norm


@njit(cache=True)
def _newton(x, x_lin, x_n, v_pred, cv, G, kinds, params, p0, coefs, c0, w, work, J):
    """Solve x - x_lin + G w(x) = 0 in place; return -1 or the element with largest residual."""
    s = x.shape[0]
    kx, residual, step = work[0], work[1], work[2]
    x_try, w_try, kx_try, residual_try = work[3], work[4], work[5], work[6]
    scale = 0.0
    for e in range(s):
        scale = max(scale, abs(x_lin[e]), abs(x_n[e]))
    norm = _element_residual(x, x_lin, x_n, v_pred, cv, G, kinds, params, p0, coefs, c0,
                             w, kx, residual)
    for _ in range(NEWTON_MAX_ITERATIONS):
        size = scale
        for e in range(s):
            size = max(size, abs(x[e]))
        if norm <= NEWTON_TOLERANCE * size:
            return -1
        for e in range(s):
            for j in range(s):
                J[e, j] = G[e, j] * kx[j]
            J[e, e] += 1.0
            step[e] = -residual[e]
        solve_small(J, step)
        lam = 1.0
        for _halving in range(LINE_SEARCH_HALVINGS):
            for e in range(s):
                x_try[e] = x[e] + lam * step[e]
            norm_try = _element_residual(x_try, x_lin, x_n, v_pred, cv, G, kinds, params, p0,
                                         coefs, c0, w_try, kx_try, residual_try)
            if norm_try < norm:
                break
            lam *= 0.5
        x[:] = x_try
        w[:] = w_try
        kx[:] = kx_try
        residual[:] = residual_try
        norm = norm_try
    worst = 0
    for e in range(s):
        if abs(residual[e]) > abs(residual[worst]):
            worst = e
    return worst


@njit(cache=True)
def _integrate_realisation(rr, q, v, a, w, first, count, u, H, Sd, SB, G, dof, ref, kinds,
                           params, p0, coefs, c0, dt, gamma, beta, rec_q, rec_v, rec_a, out,
                           out_first, status):
    """Advance realisation rr over samples first .. first + count - 1 (0 = initial state).

    State q, v, a (R, r) and element forces w (R, s) are updated in place; samples are
    written to out[rr, k - out_first] as [q[rec_q], v[rec_v], a[rec_a]]. The input u
    (R, period, m) is read periodically (index k mod period). status[rr] = (sample, element)
    of a failed Newton solve, else stays -1.
    """
    r = q.shape[1]
    s = w.shape[1]
    period = u.shape[1]
    cv = gamma / (beta * dt)
    c_a = gamma / (2.0 * beta) - 1.0
    z = np.empty(2 * r)
    d = np.empty(r)
    du = np.empty(u.shape[2])
    x = np.empty(s)
    x_n = np.empty(s)
    x_lin = np.empty(s)
    v_pred = np.empty(s)
    work = np.empty((7, s))
    J = np.empty((s, s))
    for k in range(first, first + count):
        if k > 0:
            for i in range(r):
                z[i] = v[rr, i] / (beta * dt) + a[rr, i] / (2.0 * beta)
                z[r + i] = (gamma / beta) * v[rr, i] + dt * c_a * a[rr, i]
            for j in range(du.shape[0]):
                du[j] = u[rr, k % period, j] - u[rr, (k - 1) % period, j]
            _linear_increment(H, z, Sd, du, SB, w[rr], d)
            for e in range(s):
                i, o = dof[e], ref[e]
                x_n[e] = q[rr, i] - (q[rr, o] if o >= 0 else 0.0)
                dx = d[i] - (d[o] if o >= 0 else 0.0)
                vr = v[rr, i] - (v[rr, o] if o >= 0 else 0.0)
                ar = a[rr, i] - (a[rr, o] if o >= 0 else 0.0)
                x_lin[e] = x_n[e] + dx
                v_pred[e] = (1.0 - gamma / beta) * vr - dt * c_a * ar
            for e in range(s):  # predictor: element forces frozen at their last value
                acc = x_lin[e]
                for j in range(s):
                    acc -= G[e, j] * w[rr, j]
                x[e] = acc
            worst = _newton(x, x_lin, x_n, v_pred, cv, G, kinds, params, p0, coefs, c0,
                            w[rr], work, J) if s > 0 else -1
            if worst >= 0:
                status[rr, 0] = k
                status[rr, 1] = worst
                break
            for i in range(r):
                dq = d[i]
                for j in range(s):
                    dq -= SB[i, j] * w[rr, j]
                dv = cv * dq - (gamma / beta) * v[rr, i] - dt * c_a * a[rr, i]
                da = dq / (beta * dt * dt) - v[rr, i] / (beta * dt) - a[rr, i] / (2.0 * beta)
                q[rr, i] += dq
                v[rr, i] += dv
                a[rr, i] += da
        row = k - out_first
        for j in range(rec_q.shape[0]):
            out[rr, row, j] = q[rr, rec_q[j]]
        for j in range(rec_v.shape[0]):
            out[rr, row, rec_q.shape[0] + j] = v[rr, rec_v[j]]
        for j in range(rec_a.shape[0]):
            out[rr, row, rec_q.shape[0] + rec_v.shape[0] + j] = a[rr, rec_a[j]]


@njit(cache=True, parallel=True)
def _integrate_parallel(q, v, a, w, first, count, u, H, Sd, SB, G, dof, ref, kinds, params,
                        p0, coefs, c0, dt, gamma, beta, rec_q, rec_v, rec_a, out, out_first,
                        status):
    """:func:`_integrate_realisation` for every realisation, one thread each."""
    for rr in prange(q.shape[0]):
        if status[rr, 0] < 0:
            _integrate_realisation(rr, q, v, a, w, first, count, u, H, Sd, SB, G, dof, ref,
                                   kinds, params, p0, coefs, c0, dt, gamma, beta, rec_q, rec_v,
                                   rec_a, out, out_first, status)


# -- setup and public entry points ------------------------------------------------------------
class NewmarkIntegrator:
    """Newmark matrices of a model for one time step and load distribution, built once.

    Parameters
    ----------
    model : StructuralModel
        Linear matrices and nonlinear elements (with coefficients).
    dt : float
        Time step [s].
    loads : ndarray, shape (r, m)
        Distribution of the m input signals over the r DOFs: p(t) = loads @ u(t).
    gamma, beta : float
        Newmark parameters (1/2, 1/4: average acceleration, unconditionally stable).
    """

    def __init__(self, model: StructuralModel, dt: float, loads: np.ndarray, *,
                 gamma: float = 0.5, beta: float = 0.25):
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be a positive time step in seconds; got {dt}")
        if not (gamma >= 0.5 and 2 * beta >= gamma):
            raise ValueError(f"Newmark gamma={gamma}, beta={beta} is not unconditionally "
                             "stable; use 2 beta >= gamma >= 1/2 (default 1/2, 1/4)")
        loads = np.asarray(loads, dtype=np.float64)
        if loads.ndim != 2 or loads.shape[0] != model.n_dofs:
            raise ValueError(f"loads must be (r={model.n_dofs}, m); got {loads.shape}")
        self.model, self.dt, self.gamma, self.beta = model, float(dt), float(gamma), float(beta)
        self.loads = loads
        k_eff = model.K + gamma / (beta * dt) * model.C + model.M / (beta * dt**2)
        lu = scipy.linalg.lu_factor(k_eff)
        B = model.influence_matrix()
        self.H = np.ascontiguousarray(np.hstack([scipy.linalg.lu_solve(lu, model.M),
                                                 scipy.linalg.lu_solve(lu, model.C)]))
        self.Sd = np.ascontiguousarray(scipy.linalg.lu_solve(lu, loads))
        self.SB = np.ascontiguousarray(scipy.linalg.lu_solve(lu, B))
        self.G = np.ascontiguousarray(B.T @ self.SB)
        self.dof, self.ref = model.element_dofs()
        elements = model.elements
        self.kinds = np.array([e.kernel_kind for e in elements], dtype=np.int64)
        self.params = np.concatenate([e.kernel_parameters for e in elements] + [np.zeros(0)])
        self.p0 = np.cumsum([0] + [e.kernel_parameters.size for e in elements]).astype(np.int64)
        self.coefs = np.array([c for e in elements for c in e.coefficients], dtype=np.float64)
        self.c0 = np.cumsum([0] + [e.n_basis for e in elements]).astype(np.int64)

    def initial_state(self, u0: np.ndarray, q0: np.ndarray, v0: np.ndarray):
        """State (q, v, a, w) at t = 0 with a from equilibrium: M a = p - C v - K q - B w."""
        model = self.model
        b = model.influence_matrix()
        rel_q, rel_v = q0 @ b, v0 @ b
        w = np.zeros((q0.shape[0], len(model.elements)))
        for j, e in enumerate(model.elements):
            w[:, j] = e.force(rel_q[:, j], rel_v[:, j])
        p = u0 @ self.loads.T - v0 @ model.C.T - q0 @ model.K.T - w @ b.T
        a = scipy.linalg.solve(model.M, p.T).T
        # copies: the compiled loop updates the state in place
        return np.array(q0, dtype=np.float64), np.array(v0, dtype=np.float64), a.copy(), w

    def run(self, u: np.ndarray, n_samples: int, record: tuple[np.ndarray, np.ndarray, np.ndarray],
            *, q0=None, v0=None, out: np.ndarray | None = None, chunk: int = CHUNK_STEPS):
        """Integrate in chunks, yielding ``(first, block)`` after each chunk.

        Parameters
        ----------
        u : ndarray, shape (R, period, m)
            Input signals at the integration rate, read periodically (sample k uses
            u[:, k % period]); give the whole record for non-periodic loads.
        n_samples : int
            Samples to produce per realisation (sample 0 is the initial state).
        record : tuple of three int arrays
            DOF indices whose displacement, velocity and acceleration are recorded, in
            this order, as the columns of each block.
        q0, v0 : ndarray, shape (R, r), optional
            Initial displacement and velocity (rest by default).
        out : ndarray, shape (R, n_samples, n_recorded), optional
            Whole-record output; blocks are then views into it. By default one chunk
            buffer is reused, so a block is only valid until the next iteration.
        chunk : int
            Samples per chunk (the caller's progress and cancellation granularity).

        Yields
        ------
        first : int
            Index of the block's first sample.
        block : ndarray, shape (R, samples in chunk, n_recorded)

        Raises
        ------
        NewmarkConvergenceError
            When Newton-Raphson fails in a step.
        """
        # the compiled loop does not check bounds: check every shape here
        u = np.ascontiguousarray(u, dtype=np.float64)
        R, r = u.shape[0], self.model.n_dofs
        if u.ndim != 3 or u.shape[1] < 1 or u.shape[2] != self.loads.shape[1]:
            raise ValueError(f"u must be (realisations, samples, m={self.loads.shape[1]}); got "
                             f"{u.shape}")
        rest = np.zeros((R, r))
        q0, v0 = (rest if x is None else np.asarray(x, dtype=np.float64) for x in (q0, v0))
        if q0.shape != (R, r) or v0.shape != (R, r):
            raise ValueError(f"initial conditions must be (realisations={R}, r={r})")
        q, v, a, w = self.initial_state(u[:, 0], q0, v0)
        rec = tuple(np.ascontiguousarray(i, dtype=np.int64) for i in record)
        if any(np.any((i < 0) | (i >= r)) for i in rec):
            raise ValueError(f"recorded DOF indices must lie in 0..{r - 1}")
        n_rec = sum(i.size for i in rec)
        if out is not None and (out.shape != (R, n_samples, n_rec) or out.dtype != np.float64
                                or not out.flags.c_contiguous):
            raise ValueError(f"out must be a C-contiguous float64 array of shape "
                             f"{(R, n_samples, n_rec)}")
        buffer = out if out is not None else np.empty((R, min(chunk, n_samples), n_rec))
        status = np.full((R, 2), -1, dtype=np.int64)
        for first in range(0, n_samples, chunk):
            count = min(chunk, n_samples - first)
            out_first = 0 if out is not None else first
            _integrate_parallel(q, v, a, w, first, count, u, self.H, self.Sd, self.SB, self.G,
                                self.dof, self.ref, self.kinds, self.params, self.p0,
                                self.coefs, self.c0, self.dt, self.gamma, self.beta, *rec,
                                buffer, out_first, status)
            failed = np.flatnonzero(status[:, 0] >= 0)
            if failed.size:
                rr = int(failed[0])
                raise NewmarkConvergenceError(float(status[rr, 0] * self.dt),
                                              self.model.elements[status[rr, 1]].name, rr)
            yield first, buffer[:, first - out_first: first - out_first + count]


def newmark(model: StructuralModel, force, dt: float, *, gamma: float = 0.5,
            beta: float = 0.25, initial_displacement=None, initial_velocity=None,
            progress: Progress | None = None) -> NewmarkResponse:
    """Integrate M q'' + C q' + K q + f(q, q') = p(t) with the nonlinear Newmark scheme.

    Parameters
    ----------
    model : StructuralModel
        Structure with its nonlinear elements (Eq. 1-2).
    force : array_like, shape (samples, r) or (realisations, samples, r)
        External forces p at t = k dt [N]; realisations are independent load cases
        integrated together (in parallel).
    dt : float
        Time step [s].
    gamma, beta : float
        Newmark parameters; default average acceleration (1/2, 1/4).
    initial_displacement, initial_velocity : array_like, shape (r,) or (realisations, r)
        Initial conditions (rest by default).
    progress : callable(fraction, message), optional
        Called between chunks of steps; may raise to cancel.

    Returns
    -------
    NewmarkResponse
        displacement, velocity, acceleration with the leading shape of ``force``.

    Examples
    --------
    >>> m = StructuralModel(np.eye(1), np.zeros((1, 1)), np.eye(1), ("x",))
    >>> res = newmark(m, np.zeros((4, 1)), 0.1, initial_displacement=[1.0])
    >>> res.displacement.shape
    (4, 1)
    """
    force = np.asarray(force, dtype=np.float64)
    single = force.ndim == 2
    force3 = force[None] if single else force
    r = model.n_dofs
    if force3.ndim != 3 or force3.shape[2] != r or force3.shape[1] < 1:
        raise ValueError(f"force must be (samples, r={r}) or (realisations, samples, r={r}); "
                         f"got shape {force.shape}")
    if not np.all(np.isfinite(force3)):
        raise ValueError("force contains NaN or infinite values")
    R, n = force3.shape[:2]
    initial = []
    for name, value in (("initial_displacement", initial_displacement),
                        ("initial_velocity", initial_velocity)):
        value = np.zeros((R, r)) if value is None else np.asarray(value, dtype=np.float64)
        if value.shape not in ((r,), (R, r)):
            raise ValueError(f"{name} must be (r={r},) or (realisations={R}, r); got "
                             f"{value.shape}")
        initial.append(np.broadcast_to(value, (R, r)))
    loaded = np.flatnonzero(np.any(force3 != 0, axis=(0, 1)))  # p acts on few DOFs
    integrator = NewmarkIntegrator(model, dt, np.eye(r)[:, loaded], gamma=gamma, beta=beta)
    out = np.empty((R, n, 3 * r))
    every = np.arange(r)
    for first, block in integrator.run(force3[:, :, loaded], n, (every, every, every),
                                       q0=initial[0], v0=initial[1], out=out):
        if progress is not None:
            progress((first + block.shape[1]) / n, f"Newmark: {first + block.shape[1]} of "
                     f"{n} samples")
    parts = (out[..., :r], out[..., r:2 * r], out[..., 2 * r:])
    return NewmarkResponse(*(p[0] if single else p for p in parts))
