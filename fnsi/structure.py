"""Second-order structural model M q'' + C q' + K q + f(q, q') = p(t) (paper Eq. 1-2).

The model is the truth the simulator integrates (:mod:`fnsi.newmark`) and whose linear
modes (Eq. 3-4 state-space eigenproblem) are the reference for identification.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.linalg

from fnsi.modal import ModalTable
from fnsi.nonlinear import NonlinearElement


def _check_mass(M: np.ndarray) -> None:
    """ValueError unless the mass matrix is symmetric positive definite.

    Every DOF must carry inertia for M q'' = p - C q' - K q - f to give accelerations:
    the Newmark integration starts by solving it for q''(0), and the state-space form of
    Eq. 3-4 needs M^-1. A zero row, a negative mass or a singular M fail both. Symmetry is
    tested to 1e-12 of the largest entry (a matrix typed or exported with rounding
    passes); definiteness with numpy's rank tolerance, smallest eigenvalue above
    r eps times the largest (:func:`numpy.linalg.matrix_rank`).
    """
    scale = float(np.max(np.abs(M)))
    if np.max(np.abs(M - M.T)) > 1e-12 * scale:
        raise ValueError("the mass matrix M must be symmetric; M[i][j] and M[j][i] differ")
    eigenvalues = np.linalg.eigvalsh(M)
    if scale == 0 or eigenvalues[0] <= M.shape[0] * np.finfo(float).eps * eigenvalues[-1]:
        raise ValueError("the mass matrix M must be positive definite (every DOF with a "
                         f"positive mass); its smallest eigenvalue is {eigenvalues[0]:.3g} "
                         f"against a largest of {eigenvalues[-1]:.3g}, so M is singular or "
                         "indefinite: give each DOF its mass, or remove massless DOFs")


@dataclass(frozen=True)
class StructuralModel:
    """Linear matrices, DOF names and lumped nonlinear elements of a structure.

    Attributes
    ----------
    M, C, K : ndarray, shape (r, r)
        Mass, viscous damping and stiffness matrices (C may be non-proportional; M
        symmetric positive definite).
    dof_names : tuple of str
        Names of the r DOFs (also the output channel names of simulated measurements).
    elements : tuple of NonlinearElement
        Nonlinear elements between these DOFs, each with its coefficients (the truth).

    Examples
    --------
    >>> m = StructuralModel(np.eye(1), 0.1 * np.eye(1), 4 * np.pi**2 * np.eye(1), ("x",))
    >>> round(float(m.linear_modes().frequencies[0]), 6)
    1.0
    """

    M: np.ndarray
    C: np.ndarray
    K: np.ndarray
    dof_names: tuple[str, ...]
    elements: tuple[NonlinearElement, ...] = ()

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("M", "C", "K"):
            a = np.asarray(getattr(self, name), dtype=np.float64)
            set_(self, name, a)
        r = self.M.shape[0] if self.M.ndim == 2 else -1
        for name in ("M", "C", "K"):
            a = getattr(self, name)
            if a.shape != (r, r) or r < 1:
                raise ValueError(f"M, C and K must be square matrices of one size (r, r); got "
                                 f"M {self.M.shape}, C {self.C.shape}, K {self.K.shape}")
            if not np.all(np.isfinite(a)):
                raise ValueError(f"{name} contains NaN or infinite entries")
        _check_mass(self.M)
        names = tuple(str(n) for n in self.dof_names)
        if len(names) != r or len(set(names)) != r:
            raise ValueError(f"dof_names must be {r} unique names, one per DOF; got {len(names)}"
                             f" names ({len(set(names))} unique)")
        set_(self, "dof_names", names)
        set_(self, "elements", tuple(self.elements))
        for e in self.elements:
            for dof in (e.dof, e.ref):
                if dof is not None and dof not in names:
                    raise ValueError(f"{e.name} refers to unknown DOF {dof!r}; the model's "
                                     f"DOFs are {list(names)}")
            if e.coefficients is None:
                raise ValueError(f"{e.name} needs coefficients (the true mu_j) to be part of "
                                 "a structural model")
            e.kernel_parameters  # noqa: B018 - fails early for a spline without knots

    @property
    def n_dofs(self) -> int:
        """Number r of DOFs."""
        return self.M.shape[0]

    def dof_index(self, name: str) -> int:
        """Position of DOF ``name``; ValueError listing the valid names."""
        try:
            return self.dof_names.index(name)
        except ValueError:
            raise ValueError(f"unknown DOF {name!r}; the model's DOFs are "
                             f"{list(self.dof_names)}") from None

    def element_dofs(self) -> tuple[np.ndarray, np.ndarray]:
        """DOF indices (dof, ref) of each element, ref = -1 for ground; shapes (s,)."""
        dof = np.array([self.dof_index(e.dof) for e in self.elements], dtype=np.int64)
        ref = np.array([-1 if e.ref is None else self.dof_index(e.ref) for e in self.elements],
                       dtype=np.int64)
        return dof, ref

    def influence_matrix(self) -> np.ndarray:
        """Localisation b_j of each element force (Eq. 2): +1 at dof, -1 at ref; (r, s)."""
        b = np.zeros((self.n_dofs, len(self.elements)))
        dof, ref = self.element_dofs()
        b[dof, np.arange(dof.size)] = 1.0
        grounded = ref < 0
        b[ref[~grounded], np.flatnonzero(~grounded)] = -1.0
        return b

    def linear_modes(self) -> ModalTable:
        """Modes of the underlying linear structure from the state-space eigenproblem.

        The first-order form of Eq. 3-4 is solved as the generalised eigenproblem
        [[I, 0], [0, M]] x' = [[0, I], [-K, -C]] x, valid for non-proportional damping.
        Each oscillating pole pair lambda = -zeta w +- j w sqrt(1 - zeta^2) gives one mode
        with natural frequency |lambda| / (2 pi) [Hz] and damping ratio -Re(lambda)/|lambda|;
        overdamped (real) poles are not modes and are left out. Shapes are the displacement
        part of the eigenvectors, scaled so that their largest entry is 1 (real).

        Returns
        -------
        ModalTable
            Ascending frequencies, shapes (n_modes, r) at all DOFs, output_names = dof_names.
        """
        r = self.n_dofs
        eye, zero = np.eye(r), np.zeros((r, r))
        lhs = np.block([[eye, zero], [zero, self.M]])
        rhs = np.block([[zero, eye], [-self.K, -self.C]])
        poles, vectors = scipy.linalg.eig(rhs, lhs)
        keep = np.isfinite(poles) & (poles.imag > 0)
        poles, shapes = poles[keep], vectors[:r, keep].T
        order = np.argsort(np.abs(poles))
        poles, shapes = poles[order], shapes[order]
        peak = shapes[np.arange(shapes.shape[0]), np.argmax(np.abs(shapes), axis=1)]
        return ModalTable(
            frequencies=np.abs(poles) / (2 * np.pi),
            damping_ratios=-poles.real / np.abs(poles),
            shapes=shapes / peak[:, None],
            output_names=self.dof_names,
        )
