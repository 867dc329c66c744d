"""Each element's own nonlinear feed-through, held at zero where it folds the simulation.

The first Markov parameters of the nonlinear inputs, D^e_nl and C B^e_nl, say how a
basis function moves the outputs within the sample it acts in. In the simulation
(:mod:`fnsi.simulation`) an element's relative displacement then solves
z = z_hat + P D^e_nl g(z) at every step (its relative velocity, for velocity bases, also
through P C B^e_nl fs / 2): monotone, with one solution, when the element's own
sensitivity pushes back, and folding, with no solution beyond some motion, when it has
the sign of a softening.

FNSI fits both parameters from the band (Eq. 13-14 of the paper; :func:`fnsi.subspace.
input_matrices`), where they stand for the residual flexibility of the modes the model
leaves out (D^e = 0 only for the complete structure, Eq. 4-5). Their physical part can
be large (SmallSat NC2-Z clearance, order 6: -5.9 mm of relative displacement per mm of
penetration, of the sign that pushes back). On a narrow band far below fs the data barely
fix them, and a stiff law turns their noise into a fold: Coulomb friction regularised
over 0.5 mm/s between two masses of a 3-DOF grid (band 11.6-21 Hz at 128 Hz, measured
displacement) gave P (C B^e_nl + D^e_nl) fs / 2 of 0.0011 and 0.0076 (m/s) per unit
basis at orders 2 and 6, 2.4 and 16 times what the law's slope of 2070 per (m/s) allows;
of orders 2-12 only order 4 could be simulated (16 % against the linear model's 17 %),
and no refinement could start.

Held at zero, the element's own feed-through (its relative motion's response to its own
bases within the sample) is that of a complete structure measured in displacement: the
element's own step can no longer fold, and the fit over the band changes only through
the parameters the band barely fixed. The same grid then refined from 18.7 % to 1.85 % of
simulation error (noise floor 0.80 %). The repair is used only where the unconstrained
model cannot be simulated (:func:`fnsi.identification.identify`, :func:`fnsi.
simulation_order.simulation_order`), so models whose feed-through is physical keep it.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from fnsi.nonlinear import NonlinearElement
from fnsi.simulation import element_incidence
from fnsi.statespace import StateSpaceModel

ROUNDING = 1e-9
"""Largest |L theta| of :func:`own_feedthrough_free`, relative to the sum of its terms'
magnitudes: a repaired model's is about 1e-15 (rounding of the null-space solve); a free
fit's is of order one."""


def own_feedthrough_constraints(C: np.ndarray, elements: Sequence[NonlinearElement],
                                output_names: Sequence[str], n_inputs: int) -> np.ndarray:
    """Linear equalities L theta = 0 that hold each element's own feed-through at zero.

    For element e with incidence row p_e (its relative displacement dof - ref, :func:`fnsi.
    simulation.element_incidence`) and each of its basis columns a: p_e D^e[:, a] = 0,
    and for velocity bases also p_e C B^e[:, a] = 0 (module docstring).

    Parameters
    ----------
    C : ndarray, shape (l, n)
        Output matrix of the model.
    elements : sequence of NonlinearElement
        The model's elements, whose bases are the extended inputs after the first
        ``n_inputs``, in order.
    output_names : sequence of str
        The model's outputs (the element ends must be among them).
    n_inputs : int
        Number m of measured inputs.

    Returns
    -------
    ndarray, shape (k, q (n + l))
        Rows on the unknowns theta of :func:`fnsi.subspace.input_matrices`, the columns
        of [B^e; D^e] stacked (column a occupies theta[a (n + l): (a + 1) (n + l)]),
        q = m + the elements' basis count.
    """
    P = element_incidence(tuple(elements), tuple(output_names))
    n_outputs, n = C.shape
    width = n + n_outputs
    q = n_inputs + sum(element.n_basis for element in elements)
    rows = []
    column = n_inputs
    for p, element in zip(P, elements, strict=True):
        for a in range(column, column + element.n_basis):
            row = np.zeros(q * width)
            row[a * width + n: (a + 1) * width] = p    # p D^e[:, a]
            rows.append(row)
            if element.needs_velocity:
                row = np.zeros(q * width)
                row[a * width: a * width + n] = p @ C    # p C B^e[:, a]
                rows.append(row)
        column += element.n_basis
    return np.array(rows).reshape(-1, q * width)


def own_feedthrough_free(model: StateSpaceModel) -> bool:
    """Whether each element's own feed-through of ``model`` is zero to rounding: a repaired
    model's, which the models derived from it keep (:func:`fnsi.oversampling.finer_model`,
    the noise perturbations of :mod:`fnsi.uncertainty`). False for a linear model."""
    if not model.elements:
        return False
    L = own_feedthrough_constraints(model.C, model.elements, model.output_names,
                                    model.n_inputs)
    theta = np.concatenate([model.B, model.D]).T.ravel()
    return bool(np.all(np.abs(L @ theta) <= ROUNDING * (np.abs(L) @ np.abs(theta))))
