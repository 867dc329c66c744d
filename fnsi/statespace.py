"""Discrete-time extended state-space model of a nonlinear structure (paper Eq. 8)."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, BinaryIO

import numpy as np

if TYPE_CHECKING:
    from fnsi.nonlinear import NonlinearElement


_NPZ_ARRAYS = ("A", "B", "C", "D", "fs", "input_names", "output_names", "elements")


@dataclass(frozen=True)
class StateSpaceModel:
    """Identified model x[k+1] = A x[k] + B^e e[k], y[k] = C x[k] + D^e e[k] (Eq. 8).

    The extended input is e = [u; g(y)]: the m measured inputs first, then the basis
    functions of ``elements`` in order; the coefficients -mu_j sit in the last s columns
    of B^e and D^e (Eq. 4-5). Scaling used for
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
    motion_offsets : ndarray, shape (E,), optional
        Constant added to each element's relative displacement when the model is
        simulated [output unit]: the one with which the elements see, on the estimation
        record, the mean they were identified on (:mod:`fnsi.offsets`). FNSI never
        identifies 0 Hz, so the model's own static response to the forces' mean is an
        extrapolation; with the offsets a record whose mean force differs still shifts
        the motion by the model's static response to the difference. None: the
        simulation finds the offsets on the record it simulates when told the mean
        (:func:`fnsi.simulation.simulate_periodic`), else uses none.
    """

    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    fs: float
    input_names: tuple[str, ...]
    output_names: tuple[str, ...]
    elements: tuple[NonlinearElement, ...] = ()
    motion_offsets: np.ndarray | None = None

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

    def to_npz(self, file: str | Path | BinaryIO) -> None:
        """Write the model as ``model.npz``: matrices, fs, names, elements as JSON text.

        Reload with :meth:`from_npz`; nothing in the file needs unpickling.
        """
        offsets = {} if self.motion_offsets is None else {"motion_offsets": self.motion_offsets}
        np.savez(file, A=self.A, B=self.B, C=self.C, D=self.D, fs=np.float64(self.fs),
                 input_names=np.array(self.input_names, dtype=str),
                 output_names=np.array(self.output_names, dtype=str),
                 elements=np.str_(json.dumps([e.to_json() for e in self.elements])),
                 **offsets)

    @classmethod
    def from_npz(cls, file: str | Path | BinaryIO) -> StateSpaceModel:
        """Read a model written by :meth:`to_npz` (``allow_pickle=False``).

        Raises
        ------
        ValueError
            If the file is not a model NPZ, naming the missing arrays.
        """
        from fnsi.nonlinear import NonlinearElement

        with np.load(file, allow_pickle=False) as data:
            missing = sorted(set(_NPZ_ARRAYS) - set(data.files))
            if missing:
                raise ValueError(f"not a model NPZ: arrays {missing} are missing; write it "
                                 "with StateSpaceModel.to_npz")
            return cls(data["A"], data["B"], data["C"], data["D"], float(data["fs"]),
                       tuple(data["input_names"].tolist()),
                       tuple(data["output_names"].tolist()),
                       tuple(NonlinearElement.from_json(e)
                             for e in json.loads(str(data["elements"]))),
                       data["motion_offsets"] if "motion_offsets" in data.files else None)

    def to_json(self) -> dict:
        """JSON-ready matrices (nested lists), names, fs and elements."""
        return {
            "order": self.order,
            "fs": self.fs,
            "input_names": list(self.input_names),
            "output_names": list(self.output_names),
            "elements": [e.to_json() for e in self.elements],
            "motion_offsets": (None if self.motion_offsets is None
                               else self.motion_offsets.tolist()),
            "A": self.A.tolist(), "B": self.B.tolist(),
            "C": self.C.tolist(), "D": self.D.tolist(),
        }
