"""State coordinates in which the band's lines see the unknowns of a fit orthonormally.

FNSI's input matrices (:func:`fnsi.subspace.input_matrices`, Section II.D) and the
screening of candidate forces (:mod:`fnsi.screening`) fit the real columns b of B^e,
which act on every line k at once through the transfer rows X_k = C (z_k I - A)^-1
(l, n). How well the data determine b is decided by the real map b -> (X_k b)_k,
stacked over the lines, real and imaginary parts. In FNSI's state basis its columns are
far from orthogonal and, for a model with more states than the band has modes, nearly
collinear: the states beyond the band's modes look alike on its lines. Normal equations
square that conditioning. On the generalisation benchmark's seed-22 case 1 (54 states,
the largest order of its decomposition, 3 outputs, 96 lines) the stacked map's condition
number was 2.4e9: B^e came out of rounding, and a relative perturbation of the data of
1e-12 moved the fitted response between the lines by 18 % and the automatic order from
42 to 54; on its case 25 (34 states, 4 outputs, 50 lines) the screening's costs were
wrong by more than the residual, and its ranking of locations was noise.

With X's columns equilibrated to unit norm (so that the cut measures collinearity, not
units) and T = diag(1/c) V_r diag(1/s_r) from the singular value decomposition of the
stacked map, X T has orthonormal columns over the band, and the directions below
:data:`RANK` of the largest singular value, which no fit in double precision resolves,
are dropped: b = T beta. Fits are unchanged up to those directions, and the normal
equations of beta are as well conditioned as the rest of the regression (the excitation
and the basis functions) allows.
"""

from __future__ import annotations

import numpy as np
import scipy.linalg

RANK = 1e-8
"""Smallest singular value, relative to the largest, of a direction the band's lines can
tell apart (a fit in double precision resolves about half of its 16 digits)."""


def whitening(x: np.ndarray) -> np.ndarray:
    """T (p, r), r <= p, such that the lines see x T orthonormally (module docstring).

    Parameters
    ----------
    x : ndarray, shape (N, l, p), complex
        The map X_k of p real unknowns (states) on each of the N lines' l outputs.

    Returns
    -------
    ndarray, shape (p, r)
        Real; the unknowns are b = T beta.
    """
    lines, outputs, p = x.shape
    # real and imaginary parts stacked, in the column-major order LAPACK factors in place
    stacked = np.empty((2 * lines * outputs, p), order="F")
    stacked[: lines * outputs] = x.real.reshape(-1, p)
    stacked[lines * outputs:] = x.imag.reshape(-1, p)
    norms = np.linalg.norm(stacked, axis=0)
    norms[norms == 0] = 1.0
    stacked /= norms
    # the triangular factor has the stacked map's singular values at a fraction of the cost
    # of an SVD of the tall matrix, whose left vectors are never needed
    factored, _, _, _ = scipy.linalg.lapack.dgeqrf(stacked, overwrite_a=True)
    _, values, vt = np.linalg.svd(np.triu(factored[:p]), full_matrices=False)
    keep = values > RANK * values[0]
    return (vt[keep].T / values[keep]) / norms[:, None]
