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
spline              natural cubic spline with g(0) = g'(0) = 0 (Eq. 19-22), one     L - 1
                    basis per knot ordinate outside the interval holding x = 0
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

MAX_EXPONENT = 10.0
"""Largest polynomial exponent p. Polynomial restoring forces of structures use p from
about 0.5 (softening) through 1.5 (Hertz contact) and 3 (Duffing) to 7 (high-order
hardening). A displacement spanning one decade of amplitude gives a basis |x|^p spanning
p decades, so at p = 10 its least-squares coefficient (Eq. 13) is already set by a handful
of peak samples, and beyond it the basis of a record reaching |x| = 10^(308 / p) overflows
double precision (1e31 at p = 10, 1 at p = 1e9)."""


# -- compiled force laws ----------------------------------------------------------------------
# Each element's parameters sit in a float vector ``params`` from offset ``p`` on (built by
# NonlinearElement.kernel_parameters; the Newmark loop concatenates those of all elements):
#   polynomial        [exponent, signed (1.0 or 0.0)]
#   clearance         [g-, g+]   (inf for a side without stop)
#   piecewise_linear  [b_1, ..., b_n]
#   spline            [n, q_1..q_n, Y (n x (n-2)), S (n x (n-2))], row-major: knot ordinates
#                     Y and slopes S of each basis function (Eq. 20-22 solved once)
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
    m = n - 2  # basis functions
    q = p + 1  # knots at params[q : q + n]
    y = q + n  # ordinates Y at params[y : y + n * m], row k = knot k
    s = y + n * m  # slopes S, same layout
    if x <= params[q] or x >= params[q + n - 1]:
        # linear extrapolation with the end slope: g = g_k + (x - q_k) g'_k
        k = 0 if x <= params[q] else n - 1
        slope = params[s + k * m + j]
        return params[y + k * m + j] + (x - params[q + k]) * slope, slope
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
    g_k, g_k1 = params[y + k * m + j], params[y + (k + 1) * m + j]
    slope_k, slope_k1 = params[s + k * m + j], params[s + (k + 1) * m + j]
    # Eq. 19: Hermite functions of the ordinates (h00, h01) and of the slopes (h10, h11)
    g = ((2.0 * t3 - 3.0 * t2 + 1.0) * g_k + (3.0 * t2 - 2.0 * t3) * g_k1
         + h * ((t3 - 2.0 * t2 + t) * slope_k + (t3 - t2) * slope_k1))
    gx = ((6.0 * t2 - 6.0 * t) * (g_k - g_k1) / h
          + (3.0 * t2 - 4.0 * t + 1.0) * slope_k + (3.0 * t2 - 2.0 * t) * slope_k1)
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
def _basis_matrix(kind, params, n_basis, x, v, derivative):
    """g_j (derivative 0), dg_j/dx (1) or dg_j/dv (2) at every sample, (samples, n_basis)."""
    out = np.empty((x.shape[0], n_basis))
    for i in range(x.shape[0]):
        for j in range(n_basis):
            out[i, j] = basis_value(kind, params, 0, j, x[i], v[i])[derivative]
    return out


# -- spline basis: equilibrium-constrained natural cubic spline (Eq. 19-22) ------------------
def spline_central_interval(knots) -> int:
    """Index k of the spline interval [q_k, q_{k+1}) that holds the equilibrium x = 0."""
    return int(np.searchsorted(np.asarray(knots, dtype=float), 0.0, side="right")) - 1


def spline_matrices(knots) -> tuple[np.ndarray, np.ndarray]:
    """Knot ordinates and slopes of the spline basis functions (Eq. 19-22, natural ends).

    The spline g is C2 at the interior knots (Eq. 20, L - 1 equations), meets the
    equilibrium constraints g(0) = 0 and g'(0) = 0 (Eq. 21-22) and has natural ends,
    g'' = 0 at q_1 and q_{L+1}, where it continues as the linear extrapolation used beyond
    the knots. That leaves L - 1 free parameters: the ordinates at the knots outside the
    interval holding 0, whose two end ordinates follow from Eq. 21-22. Basis function j
    has ordinate 1 at the j-th of those knots and 0 at the others.

    The paper solves Eq. 20-22 for the L + 1 slopes from all L + 1 ordinates, without
    end conditions. That is an initial-value problem from x = 0 outwards: the basis
    functions grow by about 2 + sqrt(3) per interval towards the ends (to thousands for
    13 intervals), the two end curvatures are free where data are sparsest, and the
    identified curve is sensitive to noise there. With natural ends every basis function
    stays of order one and the end slopes are set by the neighbouring ordinates.

    Parameters
    ----------
    knots : ndarray, shape (L + 1,)
        Strictly increasing abscissas q_k, L >= 2, with 0 strictly inside (q_1, q_{L+1})
        and not a knot.

    Returns
    -------
    ordinates, slopes : ndarray, shape (L + 1, L - 1)
        g(q_k) and g'(q_k) of basis function j in column j.
    """
    q = np.asarray(knots, dtype=float)
    n = q.shape[0]
    h = np.diff(q)
    # rows act on z = [g(q_1)..g(q_n), g'(q_1)..g'(q_n)]
    rows = np.zeros((n + 2, 2 * n))
    for k in range(1, n - 1):  # Eq. 20 at interior knot k
        rows[k - 1, n + k - 1: n + k + 2] = 1 / h[k - 1], 2 / h[k - 1] + 2 / h[k], 1 / h[k]
        rows[k - 1, k - 1: k + 2] = (3 / h[k - 1] ** 2, 3 / h[k] ** 2 - 3 / h[k - 1] ** 2,
                                     -3 / h[k] ** 2)
    # natural ends: g''(q_1) = 0 and g''(q_n) = 0 in Hermite form
    rows[n - 2, [0, 1, n, n + 1]] = 3 / h[0], -3 / h[0], 2.0, 1.0
    rows[n - 1, [n - 2, n - 1, 2 * n - 2, 2 * n - 1]] = 3 / h[-1], -3 / h[-1], 1.0, 2.0
    k = spline_central_interval(q)
    t = -q[k] / h[k]
    # Eq. 21: zero force at x = 0; Eq. 22: zero slope at x = 0 (Hermite functions at t0)
    rows[n, [k, k + 1, n + k, n + k + 1]] = (2 * t**3 - 3 * t**2 + 1, 3 * t**2 - 2 * t**3,
                                             (t**3 - 2 * t**2 + t) * h[k], (t**3 - t**2) * h[k])
    rows[n + 1, [k, k + 1, n + k, n + k + 1]] = (6 * (t**2 - t) / h[k], 6 * (t - t**2) / h[k],
                                                 3 * t**2 - 4 * t + 1, 3 * t**2 - 2 * t)
    free = np.array([i for i in range(n) if i not in (k, k + 1)], dtype=int)
    dependent = np.concatenate(([k, k + 1], np.arange(n, 2 * n)))
    try:
        solved = -np.linalg.solve(rows[:, dependent], rows[:, free])
    except np.linalg.LinAlgError:
        raise ValueError(f"spline knots {q.tolist()} give a singular system (Eq. 20-22); "
                         "move the knots") from None
    ordinates = np.zeros((n, n - 2))
    ordinates[free, np.arange(n - 2)] = 1.0
    ordinates[[k, k + 1]] = solved[:2]
    return ordinates, solved[2:]


def _kind(value) -> NonlinearityKind:
    """``value`` as a kind; ValueError listing the kinds."""
    try:
        return NonlinearityKind(value)
    except ValueError:
        raise ValueError(f"unknown nonlinearity kind {value!r}; use one of "
                         f"{[k.value for k in NonlinearityKind]}") from None


def _refuse_foreign(foreign, kind: NonlinearityKind) -> None:
    """ValueError when parameters of other kinds were given to a ``kind`` element."""
    if foreign:
        raise ValueError(f"{sorted(foreign)} are not parameters of a {kind} element; it takes "
                         f"{list(KIND_PARAMETERS[kind])}")


def _numbers(values, name: str) -> tuple[float, ...]:
    """``values`` as a tuple of floats; ValueError naming ``name`` when one is not a number."""
    try:
        return tuple(float(b) for b in values)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a list of numbers; got {values!r}") from None


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
        polynomial: g = |x|^exponent sign(x) if signed, else |x|^exponent
        (0 < exponent <= :data:`MAX_EXPONENT`).
    gap, gap_negative, gap_positive, side :
        clearance: contact beyond x > g+ and x < -g- [length]. ``gap`` sets both;
        ``gap_negative`` / ``gap_positive`` set them separately. ``side`` "positive" or
        "negative" keeps one stop only (one-sided stop).
    breakpoints :
        piecewise_linear: one hinge per breakpoint [length]; the hinge is
        max(x - b, 0) for b >= 0 and min(x - b, 0) for b < 0.
    knots, intervals :
        spline: L + 1 >= 3 strictly increasing knot abscissas [length] with 0 strictly
        inside an interval (Eq. 19-22, natural ends, :func:`spline_matrices`); or
        ``intervals`` L >= 2 for automatic knots placed by :meth:`resolve` from the
        measured displacement. The L - 1 coefficients are the force at the knots outside
        the interval holding 0.
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
        kind = _kind(self.kind)
        set_ = object.__setattr__
        set_(self, "kind", kind)
        if not isinstance(self.dof, str) or not self.dof:
            raise ValueError(f"dof must be a non-empty DOF / channel name; got {self.dof!r}")
        if self.ref is not None and (not isinstance(self.ref, str) or self.ref == self.dof):
            raise ValueError(f"ref must be another DOF name or None (ground); got {self.ref!r}")
        for name in ("breakpoints", "knots"):
            set_(self, name, _numbers(getattr(self, name), f"{kind} {name}"))
        defaults = {f.name: f.default for f in dataclasses.fields(self)}
        foreign = [name for name in defaults
                   if name not in ("kind", "dof", "ref", "coefficients")
                   and name not in KIND_PARAMETERS[kind]
                   and getattr(self, name) != defaults[name]]
        _refuse_foreign(foreign, kind)
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
        exponent = _positive(self.exponent, "exponent", "polynomial")
        if exponent > MAX_EXPONENT:
            raise ValueError(f"polynomial exponent must be at most {MAX_EXPONENT:g} (beyond it "
                             "|x|^exponent spans too many decades to identify, and overflows); "
                             f"got {self.exponent!r}")
        object.__setattr__(self, "exponent", exponent)
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
                                 "(automatic knots placed from the measured displacement)")
            return
        q = np.asarray(self.knots)
        if q.size < 3 or not np.all(np.isfinite(q)) or np.any(np.diff(q) <= 0):
            raise ValueError(f"spline knots must be at least 3 finite, strictly increasing "
                             f"values (2 intervals or more); got {list(self.knots)}")
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
            return len(self.knots) - 2 if self.knots else self.intervals - 1
        return 1

    @property
    def basis_names(self) -> list[str]:
        """One label per basis function, e.g. ``"clearance NC2w_Z-NC2b_Z"``."""
        if self.kind is NonlinearityKind.PIECEWISE_LINEAR:
            return [f"{self.name} b={b:g}" for b in self.breakpoints]
        if self.kind is NonlinearityKind.SPLINE:
            if not self.knots:
                return [f"{self.name} #{k}" for k in range(self.n_basis)]
            central = spline_central_interval(self.knots)
            return [f"{self.name} q={q:.6g}" for k, q in enumerate(self.knots)
                    if k not in (central, central + 1)]
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
            ordinates, slopes = spline_matrices(q)
            return np.concatenate(([q.size], q, ordinates.ravel(), slopes.ravel()))
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
        return _basis_matrix(self.kernel_kind, self.kernel_parameters, self.n_basis, x, v, 0)

    def basis_slopes(self, x, v=None) -> tuple[np.ndarray, np.ndarray]:
        """Derivatives of the basis functions with respect to the relative displacement
        and to the relative velocity, each of shape (samples, n_basis).

        Parameters are those of :meth:`basis`.

        Examples
        --------
        >>> e = NonlinearElement("clearance", "a", gap=1.0, side="positive")
        >>> dx, dv = e.basis_slopes(np.array([-3.0, 0.5, 3.0]))
        >>> dx[:, 0].tolist(), dv[:, 0].tolist()
        ([0.0, 0.0, 1.0], [0.0, 0.0, 0.0])
        """
        x, v = self._samples(x, v)
        kind, parameters = self.kernel_kind, self.kernel_parameters
        return (_basis_matrix(kind, parameters, self.n_basis, x, v, 1),
                _basis_matrix(kind, parameters, self.n_basis, x, v, 2))

    def force(self, x, v=None) -> np.ndarray:
        """Restoring force f = sum_j mu_j g_j(x, v) (Eq. 2), shape (samples,)."""
        if self.coefficients is None:
            raise ValueError(f"{self.name} has no coefficients: set coefficients "
                             f"(one per basis function {self.basis_names})")
        return self.basis(x, v) @ np.asarray(self.coefficients)

    def resolve(self, x) -> NonlinearElement:
        """Element with automatic spline knots placed from the measured displacement ``x``.

        For a spline given by ``intervals`` L only; other elements, and splines with
        explicit knots, are returned unchanged. No knowledge of the nonlinearity is used.
        With lo = min(x, 0) and hi = max(x, 0):

        - one central interval [lo / 2, hi / 2] holds the equilibrium: on the inner half
          of the measured excursion on each side the force is a single cubic
          a x^2 + b x^3 (Eq. 21-22). A spline with several short intervals there can
          imitate a linear spring g = x on the measured samples (to 5 % RMS with 13
          uniform intervals on the SmallSat data) and then trades off against the linear
          stiffness of the connection, which belongs to the underlying linear structure;
          the wide interval leaves it distinguishable (26 % RMS), as the paper's knots do.
        - the other L - 1 intervals split the outer halves [lo, lo / 2] and [hi / 2, hi],
          where large excursions reveal hardening, softening or contact, in proportion to
          their lengths (asymmetric ranges), each side uniformly. A side that gets no
          interval (a one-sided or very asymmetric record) is covered by the central
          interval, which then reaches -hi / 2 (or -lo / 2) beyond the data: its end
          ordinates are not coefficients, so no coefficient is left without data.
        - the end knots are the measured extremes, so every coefficient (an ordinate
          outside the central interval) is seen by data.

        A nonlinearity acting only within the inner half (e.g. a clearance smaller than
        half the excursion) is only approximated by the central cubic, whatever L: give
        explicit knots there once the curve has shown where it acts.

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
        tails = self.intervals - 1
        left = round(tails * -lo / (hi - lo))
        right = tails - left
        centre = (0.5 * lo if left else min(lo, -0.5 * hi),
                  0.5 * hi if right else max(hi, -0.5 * lo))
        knots = np.concatenate([np.linspace(lo, centre[0], left + 1)[:-1],
                                centre,
                                np.linspace(centre[1], hi, right + 1)[1:]])
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
    def check_keys(cls, d: dict) -> None:
        """ValueError naming the keys of the JSON object ``d`` (with a ``kind``) that are
        no field of an element, or that are parameters of another kind: given, they are
        refused even at their defaults, never silently ignored."""
        allowed = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(d) - allowed)
        if unknown:
            raise ValueError(f"unknown nonlinear element keys {unknown}; allowed: "
                             f"{sorted(allowed)}")
        kind = _kind(d["kind"])
        _refuse_foreign(set(d) - {"kind", "dof", "ref", "coefficients",
                                  *KIND_PARAMETERS[kind]}, kind)

    @classmethod
    def from_json(cls, d: dict) -> NonlinearElement:
        """Element from the JSON object of :meth:`to_json` (keys checked by
        :meth:`check_keys`)."""
        if not isinstance(d, dict) or "kind" not in d or "dof" not in d:
            raise ValueError("a nonlinear element needs at least {'kind': ..., 'dof': ...}")
        cls.check_keys(d)
        kwargs = dict(d)
        for name in ("breakpoints", "knots", "coefficients"):
            if kwargs.get(name) is not None:
                kwargs[name] = tuple(kwargs[name])
        return cls(**kwargs)
