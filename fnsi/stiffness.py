"""Nonlinear stiffness (and damping) curves of identified elements (paper Figures 10, 12).

The restoring force of an element is f = sum_j mu_j g_j (Eq. 2). With the identified
coefficients (the band average of the real part of mu_j(omega), Section II.E) it is drawn
against the relative displacement over the measured range: for a cubic-spline element the
coefficients are the knot ordinates outside the interval holding the equilibrium (Eq. 19-22,
:func:`fnsi.nonlinear.spline_matrices`), for a known form they scale its basis.
Elements that depend on velocity (Coulomb friction, quadratic damping) give the force
against the relative velocity instead.

Only the nonlinear part of the force is represented: the linear stiffness of the
connection belongs to the underlying linear structure identified with it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from fnsi.nonlinear import NonlinearElement
from fnsi.units import ModelUnits


@dataclass(frozen=True)
class StiffnessCurve:
    """Nonlinear restoring force of one element against its relative motion.

    Attributes
    ----------
    element : NonlinearElement
        The element, carrying the coefficients used.
    x : ndarray, shape (samples,)
        Relative displacement dof - ref [m] (relative velocity [m/s] when
        ``element.needs_velocity``), increasing.
    force : ndarray, shape (samples,)
        Nonlinear restoring force f(x) [N] acting on ``element.dof`` (Eq. 1-2).
    """

    element: NonlinearElement
    x: np.ndarray
    force: np.ndarray

    @property
    def variable(self) -> str:
        """``"velocity"`` for velocity-dependent elements, otherwise ``"displacement"``."""
        return "velocity" if self.element.needs_velocity else "displacement"

    def to_json(self, units: ModelUnits | None = None) -> dict:
        """JSON-ready curve: the element (with coefficients), abscissae and forces, and
        with ``units`` their units ``x_unit`` and ``force_unit``."""
        out = {
            "element": self.element.to_json(),
            "variable": self.variable,
            "x": self.x.tolist(),
            "force": self.force.tolist(),
        }
        if units is not None:
            out["x_unit"], out["force_unit"] = units.curve(self.variable)
        return out


def _abscissae(element: NonlinearElement, x: tuple[float, float] | np.ndarray | None,
               points: int) -> np.ndarray:
    """Increasing sample abscissae from a range, explicit samples or the spline knots."""
    if x is None:
        if not element.knots:
            motion = "velocity" if element.needs_velocity else "displacement"
            raise ValueError(
                f"give the measured range of relative {motion} of the {element.kind} element "
                f"at {element.dof} as x=(low, high); only spline elements carry it in their "
                f"knots"
            )
        x = (element.knots[0], element.knots[-1])
    values = np.asarray(x, dtype=float)
    if values.shape == (2,):
        low, high = values
        if not low < high:
            raise ValueError(f"range must be (low, high) with low < high; got {tuple(values)}")
        return np.linspace(low, high, points)
    if values.ndim != 1 or values.size < 2 or not np.all(np.isfinite(values)):
        raise ValueError("x must be a (low, high) range or a 1-D array of at least two "
                         f"finite samples; got shape {values.shape}")
    return np.sort(values)


def stiffness_curve(
    element: NonlinearElement,
    coefficients: np.ndarray | None = None,
    x: tuple[float, float] | np.ndarray | None = None,
    *,
    points: int = 501,
) -> StiffnessCurve:
    """Restoring force of an element over a range of relative displacement.

    Parameters
    ----------
    element : NonlinearElement
        The element; its ``basis`` gives g_j (Eq. 2, 19-22).
    coefficients : ndarray, shape (n_basis,), real, optional
        Identified mu_j: the band-averaged real parts of the nonlinear coefficients
        (for a spline, its ordinates at the knots outside the interval holding 0).
        Default: ``element.coefficients``.
    x : (float, float) or ndarray, optional
        Measured range (low, high) [m] sampled at ``points`` abscissae, or explicit
        abscissae (three or more). Default for splines: the range of their knots.
    points : int
        Number of abscissae when ``x`` is a range.

    Returns
    -------
    StiffnessCurve
        With ``element`` carrying the coefficients used.

    Examples
    --------
    >>> import numpy as np
    >>> stop = NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=1.5)
    >>> curve = stiffness_curve(stop, np.array([100.0]), (-2.0, 2.0), points=5)
    >>> curve.force.tolist()
    [-50.0, 0.0, 0.0, 0.0, 50.0]
    """
    if coefficients is None:
        if element.coefficients is None:
            raise ValueError(
                f"the {element.kind} element at {element.dof} has no coefficients; "
                f"pass the identified ones"
            )
        coefficients = np.asarray(element.coefficients)
    mu = np.asarray(coefficients)
    if np.iscomplexobj(mu):
        raise ValueError(
            "coefficients must be real: pass the band average of the real part of the "
            "identified mu_j(omega)"
        )
    mu = mu.astype(float).ravel()
    if mu.size != element.n_basis:
        raise ValueError(
            f"the {element.kind} element at {element.dof} has {element.n_basis} basis "
            f"functions; got {mu.size} coefficients"
        )
    if points < 2:
        raise ValueError(f"points must be at least 2; got {points}")
    samples = _abscissae(element, x, points)
    zeros = np.zeros_like(samples)
    basis = (element.basis(zeros, samples) if element.needs_velocity
             else element.basis(samples, zeros))
    return StiffnessCurve(
        element=replace(element, coefficients=tuple(mu.tolist())),
        x=samples,
        force=basis @ mu,
    )


def curve_error_percent(identified: StiffnessCurve, truth: NonlinearElement) -> float:
    """RMS error of an identified curve against the true force law, in % of its peak.

    error = 100 * RMS(f_identified - f_true) / max |f_true|, both on the abscissae of
    the identified curve (which should span the measured range).

    Parameters
    ----------
    identified : StiffnessCurve
        Identified curve.
    truth : NonlinearElement
        True element with its coefficients (e.g. from the simulator's truth record).

    Returns
    -------
    float
        Error [%].

    Examples
    --------
    >>> import numpy as np
    >>> truth = NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(2.0,))
    >>> curve = stiffness_curve(truth, np.array([2.2]), (-1.0, 1.0))  # 10 % too stiff
    >>> round(curve_error_percent(curve, truth), 1)  # 10 / sqrt(7) on a continuous range
    3.8
    """
    zeros = np.zeros_like(identified.x)
    exact = (truth.force(zeros, identified.x) if truth.needs_velocity
             else truth.force(identified.x, zeros))
    peak = np.max(np.abs(exact))
    if peak == 0.0:
        raise ValueError(
            "the true force is zero over the whole range of the curve (e.g. inside a "
            "clearance): widen the range to where the element is active"
        )
    return float(100.0 * np.sqrt(np.mean((identified.force - exact) ** 2)) / peak)
