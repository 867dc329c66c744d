"""Separability of the nonlinear elements: can the data tell their forces apart?

FNSI estimates one column of B^e and D^e per extended input (Eq. 11, 14) and absorbs any
linear force into the underlying linear model (A, B, C, D). When a combination of one
element's basis spectra is reproduced, on the analysis lines, by the other extended
inputs (another element's bases, the forces) or by a linear spring and dashpot at the
elements (which the linear model represents), the least squares can move force between
them at no cost in the fit: the data fix the sum, not the parts. The element's
coefficients and stiffness curve can then be off along that combination by the model's
relative error times 1 / u, with u the part of the combination that the others cannot
reproduce.

u is the sine of the smallest principal angle between the span of the element's basis
spectra and the span of the others (real and imaginary parts of every line and
realisation stacked): the other extended inputs, and the relative displacement x and
velocity j omega x of every element's DOFs (output spectra). 1 for bases that nothing
else resembles, 0 for bases repeated exactly. It needs no model and costs one Gram
matrix, so it is reported with every identification.

Typical causes: two stops on either side of a practically rigid part (their relative
displacements move together), the mirror-image motion of a symmetric structure driven
symmetrically (x_2 = -x_1, so any odd law at one stop repeats the other's), or a
flexible law (a spline) that bends like a linear spring over the measured range. A
known form (a clearance with its gap) resembles the others far less than a spline does.

On the SmallSat multi test (eight stops; benchmarks/results/paper.md and its variant
with an asymmetric bracket) the splines whose curves come out wrong (37-103 % of peak)
have u of 0.005-0.043 and those within 3-7 % 0.077-0.097; the single spline of the
paper's IV.B has 0.15 (curve within 1 %): :data:`SEPARABILITY_LIMIT` lies between. The
clearances (the true forms) have 0.026-0.089; those below the limit, the mirror-image
axial pairs, come within 2-3 % where the others come within 0.1-0.8 %: a known form has
little model error to amplify. u says nothing of how well the basis represents the law:
with 3 intervals the same splines are separable (u 0.12-0.21) and still 17-173 % off.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from fnsi.nonlinear import NonlinearElement
from fnsi.spectra import Spectra

SEPARABILITY_LIMIT = 0.05
"""u below which an element is reported as confounded: an error of the fitted response
becomes more than twenty times larger in the element's force."""

PARTNER_SHARE = 0.2
"""Smallest share of the reproduced combination for a group of columns to be named."""

LINEAR_STRUCTURE = "a linear spring and dashpot at the elements"
"""Name of the relative displacement and velocity columns among the partners."""


@dataclass(frozen=True)
class Separability:
    """How well the data separate one element's force from the other extended inputs
    and from a linear spring and dashpot at the elements.

    Attributes
    ----------
    element : int
        Index of the element in the identification's elements.
    name : str
        The element's name.
    unexplained : float
        u in [0, 1]: the smallest fraction of a combination of the element's basis
        spectra that the others cannot reproduce (sine of the smallest principal angle).
    partners : tuple of str
        What reproduces that combination, largest share first: element names,
        ``"input forces"``, :data:`LINEAR_STRUCTURE`, or ``"its other basis functions"``
        when the element's own bases repeat each other; empty when u is 1.
    """

    element: int
    name: str
    unexplained: float
    partners: tuple[str, ...]

    @property
    def confounded(self) -> bool:
        """u below :data:`SEPARABILITY_LIMIT`."""
        return self.unexplained < SEPARABILITY_LIMIT

    @property
    def concern(self) -> str | None:
        """What a confounded element means for its curve and what to change; None
        when separable."""
        if not self.confounded:
            return None
        others = " and ".join(self.partners) or "the other extended inputs"
        amplification = ("without bound" if self.unexplained == 0.0
                         else f"about {1.0 / self.unexplained:.0f} times")
        return (f"{self.name}: a combination of its basis functions is reproduced by "
                f"{others} to within {100.0 * self.unexplained:.1f} % on the analysis "
                f"lines, so FNSI can move force between them; its coefficients and curve "
                f"can be off by {amplification} the model's relative error. Elements "
                "whose relative displacements move together (a rigid part between two "
                "stops, the mirror-image motion of a symmetric structure) or a flexible "
                "law that bends like a linear spring do this: excite so that the "
                "connections move independently, give the element its known form (e.g. a "
                "clearance instead of a spline), or use fewer spline intervals")

    @property
    def caption(self) -> str | None:
        """Short warning for the figure panel of a confounded element; None when separable.

        Examples
        --------
        >>> Separability(0, "spline a", 0.007, ("spline b",)).caption
        'confounded with spline b (u = 0.007): not to be trusted'
        """
        if not self.confounded:
            return None
        return (f"confounded with {', '.join(self.partners) or 'the others'} "
                f"(u = {self.unexplained:.3f}): not to be trusted")

    def to_json(self) -> dict:
        """``{"element", "name", "unexplained", "partners", "confounded", "concern"}``."""
        return {"element": self.element, "name": self.name,
                "unexplained": self.unexplained, "partners": list(self.partners),
                "confounded": self.confounded, "concern": self.concern}


def _gram(columns: np.ndarray) -> np.ndarray:
    """Gram matrix of complex spectra (R, N, c) as real columns of unit norm, (c, c).

    Real and imaginary parts of every line and realisation are the rows; zero columns
    stay zero.
    """
    e = columns.reshape(-1, columns.shape[2])
    gram = (e.conj().T @ e).real
    norms = np.sqrt(np.diag(gram))
    scale = 1.0 / np.where(norms > 0.0, norms, 1.0)
    return gram * np.outer(scale, scale)


def _linear_columns(spectra: Spectra, elements: tuple[NonlinearElement, ...]) -> np.ndarray:
    """Relative displacement x and velocity j omega x spectra at every element's DOFs
    (each pair once), (R, N, 2 pairs): the forces a linear spring and dashpot there
    would add, which the underlying linear model represents."""
    outputs = {name: k for k, name in enumerate(spectra.output_names)}
    pairs = dict.fromkeys((e.dof, e.ref) for e in elements
                          if e.dof in outputs and (e.ref is None or e.ref in outputs))
    j_omega = 2j * np.pi * spectra.frequencies
    columns = []
    for dof, ref in pairs:
        x = spectra.outputs[:, :, outputs[dof]]
        if ref is not None:
            x = x - spectra.outputs[:, :, outputs[ref]]
        columns += [x, j_omega * x]
    shape = spectra.inputs.shape[:2]
    return np.stack(columns, axis=2) if columns else np.zeros((*shape, 0), complex)


def _groups(n_inputs: int, elements: tuple[NonlinearElement, ...]) -> list[tuple[str, slice]]:
    """Name and column slice of the input forces and of each element's bases."""
    groups = [("input forces", slice(0, n_inputs))]
    start = n_inputs
    for element in elements:
        groups.append((element.name, slice(start, start + element.n_basis)))
        start += element.n_basis
    return groups


def _partners(gram: np.ndarray, groups: list[tuple[str, slice]], rest: np.ndarray,
              beta: np.ndarray) -> tuple[str, ...]:
    """Groups whose columns make up most of the reproduction sum_g C_g beta_g."""
    shares = []
    for name, cols in groups:
        mask = (rest >= cols.start) & (rest < cols.stop)
        if mask.any():
            b = beta[mask]
            shares.append((float(np.sqrt(max(b @ gram[np.ix_(rest[mask], rest[mask])] @ b,
                                             0.0))), name))
    total = sum(s for s, _ in shares)
    if total == 0.0:
        return ()
    return tuple(name for share, name in sorted(shares, reverse=True)
                 if share >= PARTNER_SHARE * total)


def _element_separability(gram: np.ndarray, groups: list[tuple[str, slice]], k: int,
                           ) -> Separability:
    """Separability of the element whose columns are ``groups[k]`` (k >= 1).

    With C_k the element's columns and C_r the others, the part of C_k a that C_r cannot
    reproduce has squared norm a^T S a, S = G_kk - G_kr G_rr^+ G_rk (Schur complement of
    the Gram matrix G); u^2 is the smallest eigenvalue of S a = lambda G_kk a.
    """
    name, cols = groups[k]
    own = np.arange(cols.start, cols.stop)
    rest = np.setdiff1d(np.arange(gram.shape[0]), own)
    g_kk = gram[np.ix_(own, own)]
    if np.linalg.eigvalsh(g_kk)[0] <= 1e-12 * len(own):
        # the element's own basis functions repeat each other on these lines: nothing
        # fixes the coefficients of that combination
        return Separability(k - 1, name, 0.0, ("its other basis functions",))
    g_kr = gram[np.ix_(own, rest)]
    pinv_rr = np.linalg.pinv(gram[np.ix_(rest, rest)], rcond=1e-12, hermitian=True)
    schur = g_kk - g_kr @ pinv_rr @ g_kr.T
    values, vectors = scipy.linalg.eigh((schur + schur.T) / 2.0, g_kk)
    unexplained = float(np.sqrt(np.clip(values[0], 0.0, 1.0)))
    if unexplained >= 1.0 - 1e-9:
        return Separability(k - 1, name, 1.0, ())
    beta = pinv_rr @ g_kr.T @ vectors[:, 0]
    return Separability(k - 1, name, unexplained, _partners(gram, groups, rest, beta))


def separability(spectra: Spectra, n_inputs: int,
                 elements: tuple[NonlinearElement, ...]) -> tuple[Separability, ...]:
    """Separability of every nonlinear element on the analysis lines.

    Parameters
    ----------
    spectra : Spectra
        Extended input spectra (inputs, shape (R, N, m + s)): the m forces, then the
        basis functions of ``elements`` in order; displacement output spectra (outputs)
        with the elements' DOFs among ``output_names``.
    n_inputs : int
        m, the number of input forces.
    elements : tuple of NonlinearElement
        The elements, whose ``n_basis`` give the column groups.

    Returns
    -------
    tuple of Separability
        One per element, in order.
    """
    groups = _groups(n_inputs, elements)
    q = spectra.inputs.shape[2]
    if groups[-1][1].stop != q:
        raise ValueError(f"the spectra hold {q} extended inputs; {n_inputs} forces and "
                         f"the elements' bases make {groups[-1][1].stop}")
    linear = _linear_columns(spectra, elements)
    gram = _gram(np.concatenate([spectra.inputs, linear], axis=2))
    groups.append((LINEAR_STRUCTURE, slice(q, q + linear.shape[2])))
    return tuple(_element_separability(gram, groups, k) for k in range(1, len(elements) + 1))
