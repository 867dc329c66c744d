"""Lumped nonlinear elements and their basis functions g_j (paper Eq. 1-2, 19-22).

One definition of each force law serves both the simulator (the truth, through the
compiled kernels :func:`basis_value` and :func:`element_force` used by the Newmark loop)
and the identification (the bases evaluated on measured outputs, :meth:`NonlinearElement.basis`).

An element acts between DOF ``dof`` and DOF ``ref`` (ground when ``ref`` is None) through
the relative displacement x = q[dof] - q[ref] and relative velocity v = q'[dof] - q'[ref].
Its restoring force f(x, v) = sum_j mu_j g_j(x, v) acts +f on ``dof`` and -f on ``ref``
(Eq. 1-2 with b_j = e_dof - e_ref).

Kinds and basis functions (x in the model's length unit, v in length per second):

==================  ==============================================================  =======
kind                basis functions g_j                                             n_basis
==================  ==============================================================  =======
polynomial          |x|^p sign(x) (``signed``) or |x|^p                             1
clearance           x - g+ for x > g+, x + g- for x < -g-, 0 otherwise (dead zone)  1
piecewise_linear    one hinge per breakpoint b: max(x - b, 0) for b >= 0,           len(b)
                    min(x - b, 0) for b < 0 (zero around the equilibrium)
spline              cubic Hermite spline, one basis per knot ordinate (Eq. 19-22)   L + 1
coulomb_friction    tanh(v / width)                                                 1
quadratic_damping   v |v|                                                           1
==================  ==============================================================  =======
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from enum import StrEnum
from functools import cached_property

import numpy as np
from numba import njit


class NonlinearityKind(StrEnum):
    """Functional form of a nonlinear element (closed set, used in JSON and HTTP schemas)."""

    POLYNOMIAL = "polynomial"
    CLEARANCE = "clearance"
    PIECEWISE_LINEAR = "piecewise_linear"
    SPLINE = "spline"
    COULOMB_FRICTION = "coulomb_friction"
    QUADRATIC_DAMPING = "quadratic_damping"


#: Integer code of each kind in the compiled kernels.
KIND_CODES: dict[NonlinearityKind, int] = {kind: code for code, kind in enumerate(NonlinearityKind)}

#: Parameters (dataclass fields) that each kind uses; all others must keep their defaults.
KIND_PARAMETERS: dict[NonlinearityKind, tuple[str, ...]] = {
    NonlinearityKind.POLYNOMIAL: ("exponent", "signed"),
    NonlinearityKind.CLEARANCE: ("gap", "gap_negative", "gap_positive", "side"),
    NonlinearityKind.PIECEWISE_LINEAR: ("breakpoints",),
    NonlinearityKind.SPLINE: ("knots", "intervals"),
    NonlinearityKind.COULOMB_FRICTION: ("width",),
    NonlinearityKind.QUADRATIC_DAMPING: (),
}

CLEARANCE_SIDES = ("both", "positive", "negative")


# -- compiled force laws ----------------------------------------------------------------------
# Each element's parameters sit in a float vector ``params`` from offset ``p`` on (built by
# NonlinearElement.kernel_parameters; the Newmark loop concatenates those of all elements):
#   polynomial        [exponent, signed (1.0 or 0.0)]
#   clearance         [g-, g+]   (inf for a side without stop)
#   piecewise_linear  [b_1, ..., b_n]
#   spline            [n, q_1..q_n, D (n x n, row-major)] with g' = D g (Eq. 20-22 solved once)
#   coulomb_friction  [width]
#   quadratic_damping []
# The kernels return scalars (no buffers), which keeps a call at a few nanoseconds.


@njit(cache=True)
def _polynomial(params, p, x):
    exponent = params[p]
    ax = abs(x)
    # d|x|^p/d|x|; at x = 0 it is 1 for p = 1 and 0 otherwise (infinite for p < 1: not
    # usable by Newton, which only the simulation needs)
    slope = exponent * ax ** (exponent - 1.0) if ax > 0.0 else (1.0 if exponent == 1.0 else 0.0)
    if params[p + 1] != 0.0:
        return math.copysign(ax**exponent, x), slope
    return ax**exponent, slope * np.sign(x)


@njit(cache=True)
def _clearance(params, p, x):
    gap_negative, gap_positive = params[p], params[p + 1]
    if x > gap_positive:
        return x - gap_positive, 1.0
    if x < -gap_negative:
        return x + gap_negative, 1.0
    return 0.0, 0.0


@njit(cache=True)
def _hinge(params, p, j, x):
    b = params[p + j]
    if (b >= 0.0 and x > b) or (b < 0.0 and x < b):
        return x - b, 1.0
    return 0.0, 0.0


@njit(cache=True)
def _spline(params, p, j, x):
    n = int(params[p])
    q = p + 1  # knots at params[q : q + n]
    d = q + n  # slope matrix D at params[d : d + n * n], row-major
    if x <= params[q] or x >= params[q + n - 1]:
        # linear extrapolation with the end slope: g = g_k + (x - q_k) g'_k
        k = 0 if x <= params[q] else n - 1
        slope = params[d + k * n + j]
        return (x - params[q + k]) * slope + (1.0 if j == k else 0.0), slope
    k, hi = 0, n - 1  # bisection: q_k <= x < q_{k+1}
    while hi - k > 1:
        mid = (k + hi) // 2
        if params[q + mid] <= x:
            k = mid
        else:
            hi = mid
    h = params[q + k + 1] - params[q + k]
    t = (x - params[q + k]) / h
    t2 = t * t
    t3 = t2 * t
    slope_k, slope_k1 = params[d + k * n + j], params[d + (k + 1) * n + j]
    # Eq. 19: Hermite functions of the slopes (h10, h11) and of the ordinates (h00, h01)
    g = h * ((t3 - 2.0 * t2 + t) * slope_k + (t3 - t2) * slope_k1)
    gx = (3.0 * t2 - 4.0 * t + 1.0) * slope_k + (3.0 * t2 - 2.0 * t) * slope_k1
    if j == k:
        g += 2.0 * t3 - 3.0 * t2 + 1.0
        gx += (6.0 * t2 - 6.0 * t) / h
    elif j == k + 1:
        g += -2.0 * t3 + 3.0 * t2
        gx += (6.0 * t - 6.0 * t2) / h
    return g, gx


@njit(cache=True)
def basis_value(kind, params, p, j, x, v):
    """Basis function g_j(x, v) of one element and its derivatives, at one sample.

    Parameters
    ----------
    kind : int
        Kind code (:data:`KIND_CODES`).
    params : ndarray
        Parameter vector holding the element's kernel parameters from offset ``p``
        (:attr:`NonlinearElement.kernel_parameters`).
    p : int
        Offset of the element's parameters in ``params``.
    j : int
        Basis function index, 0 <= j < n_basis.
    x, v : float
        Relative displacement and velocity.

    Returns
    -------
    g, dg_dx, dg_dv : float
    """
    if kind == 0:
        g, gx = _polynomial(params, p, x)
    elif kind == 1:
        g, gx = _clearance(params, p, x)
    elif kind == 2:
        g, gx = _hinge(params, p, j, x)
    elif kind == 3:
        g, gx = _spline(params, p, j, x)
    elif kind == 4:
        th = math.tanh(v / params[p])
        return th, 0.0, (1.0 - th * th) / params[p]
    else:
        return v * abs(v), 0.0, 2.0 * abs(v)
    return g, gx, 0.0


@njit(cache=True)
def element_force(kind, params, p, coefficients, c, n_basis, x, v):
    """Restoring force f = sum_j mu_j g_j(x, v) of one element and its derivatives (Eq. 2).

    ``coefficients[c : c + n_basis]`` are the element's mu_j; other arguments as in
    :func:`basis_value`.

    Returns
    -------
    f, df_dx, df_dv : float
    """
    f = 0.0
    fx = 0.0
    fv = 0.0
    for j in range(n_basis):
        g, gx, gv = basis_value(kind, params, p, j, x, v)
        f += coefficients[c + j] * g
        fx += coefficients[c + j] * gx
        fv += coefficients[c + j] * gv
    return f, fx, fv


@njit(cache=True)
def _basis_matrix(kind, params, n_basis, x, v):
    out = np.empty((x.shape[0], n_basis))
    for i in range(x.shape[0]):
        for j in range(n_basis):
            out[i, j] = basis_value(kind, params, 0, j, x[i], v[i])[0]
    return out


# -- spline equilibrium-constrained slopes (Eq. 20-22) ---------------------------------------
def spline_slope_matrix(knots: np.ndarray) -> np.ndarray:
    """Matrix D mapping the knot ordinates to the knot slopes, g' = D g (Eq. 20-22).

    The L - 1 continuity equations (20) at the interior knots and the two equilibrium
    constraints (21)-(22) (zero force and zero slope at x = 0) are solved once.

    Parameters
    ----------
    knots : ndarray, shape (L + 1,)
        Strictly increasing abscissas q_k with 0 strictly inside (q_1, q_{L+1}) and not a knot.

    Returns
    -------
    ndarray, shape (L + 1, L + 1)
    """
    q = np.asarray(knots, dtype=float)
    n = q.shape[0]
    lhs = np.zeros((n, n))
    rhs = np.zeros((n, n))
    h = np.diff(q)
    for k in range(1, n - 1):  # Eq. 20, interior knot k
        lhs[k - 1, k - 1 : k + 2] = 1.0 / h[k - 1], 2.0 / h[k - 1] + 2.0 / h[k], 1.0 / h[k]
        rhs[k - 1, k - 1] = -3.0 / h[k - 1] ** 2
        rhs[k - 1, k] = 3.0 / h[k - 1] ** 2 - 3.0 / h[k] ** 2
        rhs[k - 1, k + 1] = 3.0 / h[k] ** 2
    k = int(np.searchsorted(q, 0.0, side="right")) - 1
    t0 = -q[k] / h[k]
    # Eq. 21: zero force at x = 0 in interval k
    lhs[n - 2, k : k + 2] = (t0**3 - 2 * t0**2 + t0) * h[k], (t0**3 - t0**2) * h[k]
    rhs[n - 2, k : k + 2] = -(2 * t0**3 - 3 * t0**2 + 1), -(-2 * t0**3 + 3 * t0**2)
    # Eq. 22: zero slope at x = 0
    lhs[n - 1, k : k + 2] = (3 * t0**2 - 4 * t0 + 1) * h[k], (3 * t0**2 - 2 * t0) * h[k]
    rhs[n - 1, k : k + 2] = 6 * (t0 - t0**2), -6 * (t0 - t0**2)
    return np.linalg.solve(lhs, rhs)


def _positive(value, name: str, kind: str) -> float | None:
    """``value`` as a float, None kept; ValueError unless positive and finite."""
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        raise ValueError(f"{kind} {name} must be a positive finite number; got {value!r}")
    return number


# -- the element ------------------------------------------------------------------------------
@dataclass(frozen=True)
class NonlinearElement:
    """A lumped nonlinear restoring force between two DOFs (or one DOF and ground), Eq. 2.

    Attributes
    ----------
    kind : NonlinearityKind
        Functional form (see the module table).
    dof : str
        DOF / output channel on which +f acts.
    ref : str or None
        DOF / output channel on which -f acts; None for ground.
    exponent, signed :
        polynomial: g = |x|^exponent sign(x) if signed, else |x|^exponent (exponent > 0).
    gap, gap_negative, gap_positive, side :
        clearance: contact beyond x > g+ and x < -g- [length]. ``gap`` sets both;
        ``gap_negative`` / ``gap_positive`` set them separately. ``side`` "positive" or
        "negative" keeps one stop only (one-sided stop).
    breakpoints :
        piecewise_linear: one hinge per breakpoint [length]; the hinge is
        max(x - b, 0) for b >= 0 and min(x - b, 0) for b < 0.
    knots, intervals :
        spline: strictly increasing knot abscissas [length] with 0 strictly inside an
        interval (Eq. 19-22); or ``intervals`` L >= 2 for automatic uniform knots chosen
        by :meth:`resolve` from the measured range.
    width :
        coulomb_friction: velocity smoothing width [length/s]; g = tanh(v / width), so the
        force reaches 76 % of its sliding value at |v| = width and 99.9 % at 3.8 width.
    coefficients : tuple of float or None
        mu_j, one per basis function (the truth for simulation; None for identification).

    Examples
    --------
    >>> e = NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=1.5, coefficients=(100.0,))
    >>> e.force(np.array([-2.0, 0.0, 2.0])).tolist()
    [-50.0, 0.0, 50.0]
    """

    kind: NonlinearityKind
    dof: str
    ref: str | None = None
    exponent: float = 3.0
    signed: bool = True
    gap: float | None = None
    gap_negative: float | None = None
    gap_positive: float | None = None
    side: str = "both"
    breakpoints: tuple[float, ...] = ()
    knots: tuple[float, ...] = ()
    intervals: int | None = None
    width: float | None = None
    coefficients: tuple[float, ...] | None = None

    def __post_init__(self) -> None:
        try:
            kind = NonlinearityKind(self.kind)
        except ValueError:
            raise ValueError(f"unknown nonlinearity kind {self.kind!r}; use one of "
                             f"{[k.value for k in NonlinearityKind]}") from None
        set_ = object.__setattr__
        set_(self, "kind", kind)
        if not isinstance(self.dof, str) or not self.dof:
            raise ValueError(f"dof must be a non-empty DOF / channel name; got {self.dof!r}")
        if self.ref is not None and (not isinstance(self.ref, str) or self.ref == self.dof):
            raise ValueError(f"ref must be another DOF name or None (ground); got {self.ref!r}")
        for name in ("breakpoints", "knots"):
            set_(self, name, tuple(float(b) for b in getattr(self, name)))
        defaults = {f.name: f.default for f in dataclasses.fields(self)}
        foreign = [name for name in defaults
                   if name not in ("kind", "dof", "ref", "coefficients")
                   and name not in KIND_PARAMETERS[kind]
                   and getattr(self, name) != defaults[name]]
        if foreign:
            raise ValueError(f"{foreign} are not parameters of a {kind} element; it takes "
                             f"{list(KIND_PARAMETERS[kind])}")
        getattr(self, f"_validate_{kind.value}")()
        if self.coefficients is not None:
            coefficients = tuple(float(c) for c in np.atleast_1d(self.coefficients))
            if len(coefficients) != self.n_basis or not np.all(np.isfinite(coefficients)):
                raise ValueError(f"{self.name} has {self.n_basis} basis functions "
                                 f"{self.basis_names}; give one finite coefficient each, "
                                 f"got {list(coefficients)}")
            set_(self, "coefficients", coefficients)

    # -- validation per kind ------------------------------------------------------------------
    def _validate_polynomial(self) -> None:
        object.__setattr__(self, "exponent", _positive(self.exponent, "exponent", "polynomial"))
        if not isinstance(self.signed, bool | np.bool_):
            raise ValueError(f"polynomial signed must be true or false; got {self.signed!r}")
        object.__setattr__(self, "signed", bool(self.signed))

    def _validate_clearance(self) -> None:
        for name in ("gap", "gap_negative", "gap_positive"):
            object.__setattr__(self, name, _positive(getattr(self, name), name, "clearance"))
        if self.side not in CLEARANCE_SIDES:
            raise ValueError(f"clearance side must be one of {CLEARANCE_SIDES}; got {self.side!r}")
        if self.gap is not None and (self.gap_negative is not None
                                     or self.gap_positive is not None):
            raise ValueError("give either gap (symmetric) or gap_negative / gap_positive, "
                             "not both")
        needed = {"both": ("negative", "positive"), "positive": ("positive",),
                  "negative": ("negative",)}[self.side]
        gaps = self.gaps
        missing = [s for s, g in zip(("negative", "positive"), gaps, strict=True)
                   if s in needed and not np.isfinite(g)]
        if missing:
            raise ValueError(f"clearance with side={self.side!r} needs a gap on the "
                             f"{' and '.join(missing)} side: set gap or gap_{missing[0]}")

    def _validate_piecewise_linear(self) -> None:
        b = np.asarray(self.breakpoints)
        if b.size == 0 or not np.all(np.isfinite(b)) or np.any(np.diff(b) <= 0):
            raise ValueError("piecewise_linear needs at least one finite breakpoint, strictly "
                             f"increasing; got {list(self.breakpoints)}")

    def _validate_spline(self) -> None:
        if self.intervals is not None:
            if int(self.intervals) != self.intervals or self.intervals < 2:
                raise ValueError(f"spline intervals must be an integer >= 2; got {self.intervals}")
            object.__setattr__(self, "intervals", int(self.intervals))
        if not self.knots:
            if self.intervals is None:
                raise ValueError("spline needs knots (increasing abscissas) or intervals "
                                 "(automatic uniform knots from the measured range)")
            return
        q = np.asarray(self.knots)
        if q.size < 2 or not np.all(np.isfinite(q)) or np.any(np.diff(q) <= 0):
            raise ValueError(f"spline knots must be at least 2 finite, strictly increasing "
                             f"values; got {list(self.knots)}")
        if not (q[0] < 0.0 < q[-1]) or np.any(q == 0.0):
            raise ValueError("the equilibrium x = 0 must lie strictly inside a spline interval "
                             f"(Eq. 21-22): it may not be a knot nor outside {list(self.knots)}")
        if self.intervals is not None and self.intervals != q.size - 1:
            raise ValueError(f"spline has {q.size} knots but intervals={self.intervals}; "
                             "give knots = intervals + 1 values or drop intervals")

    def _validate_coulomb_friction(self) -> None:
        if self.width is None:
            raise ValueError("coulomb_friction needs width, the velocity smoothing width in "
                             "g = tanh(v / width) [length/s]")
        object.__setattr__(self, "width", _positive(self.width, "width", "coulomb_friction"))

    def _validate_quadratic_damping(self) -> None:
        """No parameters."""

    # -- properties ---------------------------------------------------------------------------
    @property
    def name(self) -> str:
        """Label ``"<kind> <dof>-<ref>"`` (``"<kind> <dof>"`` to ground)."""
        where = self.dof if self.ref is None else f"{self.dof}-{self.ref}"
        return f"{self.kind.value} {where}"

    @property
    def gaps(self) -> tuple[float, float]:
        """Clearance (g-, g+), inf on a side without stop (clearance only)."""
        gn = self.gap_negative if self.gap_negative is not None else self.gap
        gp = self.gap_positive if self.gap_positive is not None else self.gap
        return (math.inf if gn is None or self.side == "positive" else float(gn),
                math.inf if gp is None or self.side == "negative" else float(gp))

    @property
    def n_basis(self) -> int:
        """Number of basis functions (= coefficients mu_j)."""
        if self.kind is NonlinearityKind.PIECEWISE_LINEAR:
            return len(self.breakpoints)
        if self.kind is NonlinearityKind.SPLINE:
            return len(self.knots) if self.knots else self.intervals + 1
        return 1

    @property
    def basis_names(self) -> list[str]:
        """One label per basis function, e.g. ``"clearance NC2w_Z-NC2b_Z"``."""
        if self.kind is NonlinearityKind.PIECEWISE_LINEAR:
            return [f"{self.name} b={b:g}" for b in self.breakpoints]
        if self.kind is NonlinearityKind.SPLINE:
            if not self.knots:
                return [f"{self.name} #{k}" for k in range(self.n_basis)]
            return [f"{self.name} q={q:.6g}" for q in self.knots]
        return [self.name]

    @property
    def needs_velocity(self) -> bool:
        """True when the basis depends on the relative velocity."""
        return self.kind in (NonlinearityKind.COULOMB_FRICTION,
                             NonlinearityKind.QUADRATIC_DAMPING)

    @property
    def kernel_kind(self) -> int:
        """Kind code for the compiled kernels."""
        return KIND_CODES[self.kind]

    @cached_property
    def kernel_parameters(self) -> np.ndarray:
        """Parameter vector for the compiled kernels (layout in the module source)."""
        kind = self.kind
        if kind is NonlinearityKind.POLYNOMIAL:
            return np.array([self.exponent, float(self.signed)])
        if kind is NonlinearityKind.CLEARANCE:
            return np.array(self.gaps)
        if kind is NonlinearityKind.PIECEWISE_LINEAR:
            return np.array(self.breakpoints)
        if kind is NonlinearityKind.SPLINE:
            self._require_knots()
            q = np.asarray(self.knots)
            return np.concatenate(([q.size], q, spline_slope_matrix(q).ravel()))
        if kind is NonlinearityKind.COULOMB_FRICTION:
            return np.array([self.width])
        return np.zeros(0)

    def _require_knots(self) -> None:
        if not self.knots:
            raise ValueError(f"{self.name} has no knots yet: call resolve(x) with the measured "
                             "relative displacement to place its uniform knots")

    # -- evaluation ---------------------------------------------------------------------------
    def _samples(self, x, v) -> tuple[np.ndarray, np.ndarray]:
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.ndim != 1:
            raise ValueError(f"x must be 1-D (samples,); got shape {x.shape}")
        if v is None:
            if self.needs_velocity:
                raise ValueError(f"{self.name} depends on the relative velocity: pass v")
            return x, np.zeros_like(x)
        v = np.ascontiguousarray(v, dtype=np.float64)
        if v.shape != x.shape:
            raise ValueError(f"v must have the shape of x {x.shape}; got {v.shape}")
        return x, v

    def basis(self, x, v=None) -> np.ndarray:
        """Basis functions g_j evaluated on samples (Eq. 2; Eq. 19 for splines).

        Parameters
        ----------
        x : array_like, shape (samples,)
            Relative displacement q[dof] - q[ref].
        v : array_like, shape (samples,), optional
            Relative velocity; required when :attr:`needs_velocity`.

        Returns
        -------
        ndarray, shape (samples, n_basis)

        Examples
        --------
        >>> e = NonlinearElement("clearance", "a", gap=1.0, side="positive")
        >>> e.basis(np.array([-3.0, 0.5, 3.0]))[:, 0].tolist()
        [0.0, 0.0, 2.0]
        """
        x, v = self._samples(x, v)
        return _basis_matrix(self.kernel_kind, self.kernel_parameters, self.n_basis, x, v)

    def force(self, x, v=None) -> np.ndarray:
        """Restoring force f = sum_j mu_j g_j(x, v) (Eq. 2), shape (samples,)."""
        if self.coefficients is None:
            raise ValueError(f"{self.name} has no coefficients: set coefficients "
                             f"(one per basis function {self.basis_names})")
        return self.basis(x, v) @ np.asarray(self.coefficients)

    def resolve(self, x) -> NonlinearElement:
        """Element with automatic spline knots placed from the measured displacement ``x``.

        For a spline given by ``intervals`` L only. The end knots are the measured
        extremes (range extended to include 0), so that every knot ordinate is seen by
        data: an end knot outside the measured range would leave its ordinate
        unidentifiable, and Eq. 20-22 would spread that error over the whole curve.
        Inside, a central interval of width h = range / L is centred on 0 (Eq. 21-22 are
        best conditioned with 0 mid-interval, and 0 is never a knot), and each side is
        split into near-h intervals. No knowledge of the nonlinearity is used. Other
        elements, and splines with explicit knots, are returned unchanged.

        Parameters
        ----------
        x : array_like, shape (samples,)
            Measured relative displacement.
        """
        if self.kind is not NonlinearityKind.SPLINE or self.knots:
            return self
        x = np.asarray(x, dtype=float)
        if x.size == 0 or not np.all(np.isfinite(x)):
            raise ValueError("resolve needs finite measured displacements to place spline knots")
        lo, hi = min(float(x.min()), 0.0), max(float(x.max()), 0.0)
        if hi <= lo:
            raise ValueError(f"{self.name}: the measured displacement is identically zero; "
                             "cannot place spline knots")
        h = (hi - lo) / self.intervals
        # intervals left of the central one, in proportion to the negative range
        left = min(max(round((-lo - 0.5 * h) / h), 0), self.intervals - 1)
        right = self.intervals - 1 - left
        centre = (max(lo, -0.5 * h) if left else lo - 0.5 * h,
                  min(hi, 0.5 * h) if right else hi + 0.5 * h)
        knots = np.concatenate([np.linspace(lo, centre[0], left + 1)[:-1] if left else [],
                                centre,
                                np.linspace(centre[1], hi, right + 1)[1:] if right else []])
        return dataclasses.replace(self, knots=tuple(knots.tolist()))

    # -- JSON ---------------------------------------------------------------------------------
    def to_json(self) -> dict:
        """JSON object ``{"kind", "dof", "ref", ...parameters of the kind, "coefficients"}``."""
        out: dict = {"kind": self.kind.value, "dof": self.dof, "ref": self.ref}
        defaults = {f.name: f.default for f in dataclasses.fields(self)}
        for name in KIND_PARAMETERS[self.kind]:
            value = getattr(self, name)
            if value is None or (name in ("gap_negative", "gap_positive", "knots")
                                 and value == defaults[name]):
                continue
            out[name] = list(value) if isinstance(value, tuple) else value
        if self.coefficients is not None:
            out["coefficients"] = list(self.coefficients)
        return out

    @classmethod
    def from_json(cls, d: dict) -> NonlinearElement:
        """Element from the JSON object of :meth:`to_json` (unknown keys are rejected)."""
        if not isinstance(d, dict) or "kind" not in d or "dof" not in d:
            raise ValueError("a nonlinear element needs at least {'kind': ..., 'dof': ...}")
        allowed = {"kind", "dof", "ref", "coefficients"} | {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - allowed)
        if unknown:
            raise ValueError(f"unknown nonlinear element keys {unknown}; allowed: "
                             f"{sorted(allowed)}")
        kwargs = dict(d)
        for name in ("breakpoints", "knots", "coefficients"):
            if kwargs.get(name) is not None:
                kwargs[name] = tuple(kwargs[name])
        return cls(**kwargs)
