"""Discrete-time extended state-space model of a nonlinear structure (paper Eq. 8)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fnsi.nonlinear import NonlinearElement


@dataclass(frozen=True)
class StateSpaceModel:
    """Identified model x[k+1] = A x[k] + B^e e[k], y[k] = C x[k] + D^e e[k] (Eq. 8).

    The extended input e = [u; -mu g(y)] is represented by its columns: the m measured
    inputs first, then the basis functions of ``elements`` in order. Scaling used for
    conditioning during identification is already undone.

    Attributes
    ----------
    A : ndarray, shape (n, n)
        State matrix, sample time 1 / fs.
    B : ndarray, shape (n, m + s)
        Extended input matrix B^e.
    C : ndarray, shape (l, n)
        Output matrix.
    D : ndarray, shape (l, m + s)
        Extended direct feedthrough D^e.
    fs : float
        Sampling rate [Hz].
    input_names : tuple of str
        Names of the m measured inputs.
    output_names : tuple of str
        Names of the l outputs.
    elements : tuple of NonlinearElement
        Nonlinear elements whose basis functions form the last s extended inputs.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    fs: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    elements: tuple[NonlinearElement, ...] = ()

    @property
    def order(self) -> int:
        """Model order n (number of states)."""
        return int(self.A.shape[0])

    @property
    def n_inputs(self) -> int:
        """Number m of measured inputs."""
        return len(self.input_names)

    @property
    def n_outputs(self) -> int:
        """Number l of outputs."""
        return len(self.output_names)

    def eigen_decomposition(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Diagonal form of the model: A = V diag(lambda) V^-1.

        Returns
        -------
        lam : ndarray, shape (n,), complex
            Discrete-time poles.
        shapes : ndarray, shape (l, n), complex
            C V, the output shapes of the poles.
        participation : ndarray, shape (n, m + s), complex
            V^-1 B^e.
        """
        lam, V = np.linalg.eig(self.A)
        return lam, self.C @ V, np.linalg.solve(V, self.B)

    def frequency_response(self, frequencies: np.ndarray) -> np.ndarray:
        """Extended FRF H^e = C (z I - A)^-1 B^e + D^e, z = exp(j 2 pi f / fs) (Eq. 18).

        Parameters
        ----------
        frequencies : ndarray, shape (N,)
            Any frequencies [Hz] below fs / 2.

        Returns
        -------
        ndarray, shape (N, l, m + s), complex
            Lines x outputs x extended inputs: the first m columns are the underlying
            linear FRF H (receptance when the outputs are displacements), the others
            -mu_j H b_j (Eq. 17).

        Examples
        --------
        >>> m = StateSpaceModel(np.array([[0.5]]), np.array([[1.0]]), np.array([[1.0]]),
        ...                     np.array([[0.0]]), 1.0, ("u",), ("y",))
        >>> complex(m.frequency_response(np.array([0.0]))[0, 0, 0])
        (2+0j)
        """
        lam, shapes, participation = self.eigen_decomposition()
        z = np.exp(2j * np.pi * np.asarray(frequencies, dtype=float) / self.fs)
        d = 1.0 / (z[:, None] - lam[None, :])
        return np.einsum("lr,kr,rq->klq", shapes, d, participation) + self.D

    def to_json(self) -> dict:
        """JSON-ready matrices (nested lists), names, fs and elements."""
        return {
            "order": self.order,
            "fs": self.fs,
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
            "elements": [e.to_json() for e in self.elements],
            "A": self.A.tolist(), "B": self.B.tolist(),
            "C": self.C.tolist(), "D": self.D.tolist(),
        }
