"""Modal parameters of the underlying linear structure (paper Section II.E, Eq. 15-16)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from fnsi.statespace import StateSpaceModel


@dataclass(frozen=True)
class ModalTable:
    """Natural frequencies, damping ratios and complex mode shapes.

    Attributes
    ----------
    frequencies : ndarray, shape (n_modes,)
        Undamped natural frequencies [Hz], ascending.
    damping_ratios : ndarray, shape (n_modes,)
        Viscous damping ratios [-].
    shapes : ndarray, shape (n_modes, l), complex
        Complex mode shapes at the output channels (one row per mode).
    output_names : tuple of str
        Names of the l output channels, the columns of ``shapes``.
    """

    frequencies: np.ndarray
    damping_ratios: np.ndarray
    shapes: np.ndarray
    output_names: tuple[str, ...]

    @property
    def n_modes(self) -> int:
        """Number of modes in the table."""
        return int(self.frequencies.shape[0])


#: Modes whose natural frequency lies further than this fraction of the band width outside
#: the analysis band are dropped: the data carry no information on them, and such poles
#: only absorb out-of-band residual dynamics.
BAND_MARGIN = 0.1


def continuous_poles(A: np.ndarray, fs: float) -> tuple[np.ndarray, np.ndarray]:
    """Continuous-time poles s = fs ln(lambda) of a discrete-time A and its eigenvectors.

    Parameters
    ----------
    A : ndarray, shape (n, n)
        Discrete-time state matrix (sample time 1 / fs).
    fs : float
        Sampling rate [Hz].

    Returns
    -------
    poles : ndarray, shape (n,), complex
        [rad/s]
    vectors : ndarray, shape (n, n), complex
        Right eigenvectors of A (columns).
    """
    lam, vectors = np.linalg.eig(A)
    with np.errstate(divide="ignore"):
        return np.log(lam.astype(complex)) * fs, vectors


def modal_table(A: np.ndarray, C: np.ndarray, fs: float, output_names: tuple[str, ...], *,
                band: tuple[float, float] | None = None) -> ModalTable:
    """Physical modes of a discrete-time state-space model (Section II.E).

    A pole pair s = -zeta w +- j w sqrt(1 - zeta^2) gives the natural frequency
    w / (2 pi) [Hz], the damping ratio zeta and the complex shape C v at the outputs
    (scaled so that its largest entry is 1). Non-physical poles are dropped: real poles
    (no oscillation, including poles on the negative real axis of z, i.e. at Nyquist),
    unstable ones (negative damping), and, when ``band`` is given, those further than
    :data:`BAND_MARGIN` times the band width outside the band.

    Parameters
    ----------
    A : ndarray, shape (n, n)
    C : ndarray, shape (l, n)
    fs : float
        Sampling rate [Hz].
    output_names : tuple of str
        Names of the l outputs.
    band : (float, float), optional
        Analysis band [Hz].

    Returns
    -------
    ModalTable

    Examples
    --------
    >>> s = -0.02 * 20 * np.pi + 20j * np.pi  # 10 Hz, 2 % damping (approximately)
    >>> lam = np.exp(s / 1000.0)
    >>> A = np.array([[lam.real, lam.imag], [-lam.imag, lam.real]])
    >>> t = modal_table(A, np.array([[1.0, 0.0]]), 1000.0, ("y",))
    >>> round(float(t.frequencies[0]), 3), round(float(t.damping_ratios[0]), 4)
    (10.002, 0.02)
    """
    poles, vectors = continuous_poles(A, fs)
    keep = np.isfinite(poles) & (poles.imag > 1e-9 * np.abs(poles)) & (poles.real < 0)
    keep &= np.abs(poles.imag) < np.pi * fs * (1 - 1e-9)
    freq = np.abs(poles) / (2 * np.pi)
    if band is not None:
        margin = BAND_MARGIN * (band[1] - band[0])
        keep &= (freq >= band[0] - margin) & (freq <= band[1] + margin)
    poles, shapes, freq = poles[keep], (C @ vectors[:, keep]).T, freq[keep]
    order = np.argsort(freq)
    shapes = shapes[order]
    if shapes.size:
        peak = shapes[np.arange(shapes.shape[0]), np.argmax(np.abs(shapes), axis=1)]
        shapes = shapes / np.where(peak == 0, 1.0, peak)[:, None]
    return ModalTable(freq[order], -poles.real[order] / np.abs(poles[order]), shapes,
                      tuple(output_names))


@dataclass(frozen=True)
class Coefficient:
    """Identified nonlinear coefficient mu_j(omega) of one basis function (Eq. 17-18).

    Attributes
    ----------
    name : str
        Basis function label (``NonlinearElement.basis_names``).
    element : int
        Index of the element in ``StateSpaceModel.elements``.
    basis : int
        Index of the basis function within its element.
    frequencies : ndarray, shape (N,)
        Frequencies [Hz] where mu_j is evaluated (the analysis lines).
    values : ndarray, shape (N,), complex, or None
        mu_j(omega), in force per basis unit (e.g. N/m for a clearance); None when not
        identifiable from the channels given (see ``reason``).
    method : str
        "driving point" (force at a DOF of the element, reciprocity of one measured FRF
        entry), "modal synthesis" (FRF columns at the element's DOFs synthesised from
        the identified modes scaled by the driving-point column) or "none".
    reason : str or None
        Why the coefficient is not identifiable, when ``values`` is None.
    """

    name: str
    element: int
    basis: int
    frequencies: np.ndarray
    values: np.ndarray | None
    method: str
    reason: str | None = None

    @property
    def identifiable(self) -> bool:
        """True when ``values`` holds an estimate."""
        return self.values is not None

    @property
    def mean_real(self) -> float:
        """Mean real part over the band: the coefficient estimate (nan if unidentifiable)."""
        return float(np.mean(self.values.real)) if self.identifiable else float("nan")

    @property
    def log10_real_imag(self) -> float:
        """Mean log10(|Re| / |Im|) over the band; 2 means |Im| is 1 % of |Re|."""
        if not self.identifiable:
            return float("nan")
        with np.errstate(divide="ignore"):
            return float(np.mean(np.log10(np.abs(self.values.real) / np.abs(self.values.imag))))

    @property
    def variation(self) -> float:
        """Coefficient of variation of Re over the band, std / |mean| (flatness)."""
        if not self.identifiable:
            return float("nan")
        return float(np.std(self.values.real) / abs(np.mean(self.values.real)))

    def to_json(self, *, spectrum: bool = False) -> dict:
        """JSON-ready summary; the mu_j(omega) curve ([re, im] per line) only when asked."""
        out = {"name": self.name, "element": self.element, "basis": self.basis,
               "method": self.method, "identifiable": self.identifiable,
               "reason": self.reason}
        if self.identifiable:
            out |= {"mean_real": self.mean_real, "log10_real_imag": self.log10_real_imag,
                    "variation": self.variation}
            if spectrum:
                out |= {"frequencies_hz": self.frequencies.tolist(),
                        "values": np.column_stack((self.values.real,
                                                   self.values.imag)).tolist()}
        return out


def _least_squares_ratio(h: np.ndarray, he: np.ndarray) -> np.ndarray:
    """mu(omega) = -(h^H he) / (h^H h) over the output rows, per line; (N, l) inputs."""
    return -np.sum(h.conj() * he, axis=1) / np.sum(np.abs(h) ** 2, axis=1)


def _synthesised_column(model: StateSpaceModel, frequencies: np.ndarray, input_col: int,
                        point: int, target: int) -> np.ndarray:
    """FRF column of a force at output ``target`` from the modes, shape (N, l).

    By reciprocity the residue of mode r is c_r phi phi^T, and the measured column of the
    force at driving point ``point`` gives c_r phi_r[point] phi (Section IV.C), hence
    column ``target`` = sum_r psi_r beta_r psi_r[target] / psi_r[point] / (z - lambda_r),
    with psi = C V and beta = (V^-1 B)[:, input]. Modes without motion at the driving point
    carry no information on their scaling and are left out; so is D (feedthrough).
    """
    lam, psi, participation = model.eigen_decomposition()
    at_point = psi[point]
    usable = np.abs(at_point) > 1e-8 * np.max(np.abs(at_point))
    scale = np.zeros_like(at_point)
    scale[usable] = participation[usable, input_col] * psi[target, usable] / at_point[usable]
    z = np.exp(2j * np.pi * frequencies / model.fs)
    return (psi * scale) @ (1.0 / (z[None, :] - lam[:, None]))  # (l, N)


def default_driving_points(input_names, output_names) -> dict[str, str]:
    """Driving points found by name: input ``"<dof>"`` or ``"F_<dof>"`` -> output ``"<dof>"``.

    The second form is the naming of :mod:`fnsi.excitation` (a force on one DOF).

    Examples
    --------
    >>> default_driving_points(("F_NC2w_Z", "u1"), ("NC2w_Z", "W_Z"))
    {'F_NC2w_Z': 'NC2w_Z'}
    """
    outputs = set(output_names)
    points = {}
    for u in input_names:
        if u in outputs:
            points[u] = u
        elif u.startswith("F_") and u[2:] in outputs:
            points[u] = u[2:]
    return points


def nonlinear_coefficients(model: StateSpaceModel, frequencies: np.ndarray,
                           driving_points: Mapping[str, str] | None = None,
                           ) -> tuple[Coefficient, ...]:
    """Nonlinear coefficients mu_j(omega) from the extended FRF (Eq. 17-18).

    The columns of H^e for basis j are -mu_j H b_j with b_j = +1 at the element's dof and
    -1 at its ref (Eq. 17). H b_j needs the FRF columns of forces at the element's DOFs:

    * driving point (paper IV.A): an input acts at the element's dof or ref. At the
      driving-point row, reciprocity gives H b_j = He[dof, input] - He[ref, input], both
      measured entries, so mu_j = -He[point, j] / (He[dof, input] - He[ref, input]). For an
      element to ground (ref None) the whole measured column is H b_j and mu_j is the
      least-squares ratio over all outputs.
    * modal synthesis (paper IV.C): the force acts elsewhere but its driving point is a
      measured output; the columns at dof and ref are synthesised from the identified
      modes (see :func:`_synthesised_column`) and mu_j is the least-squares ratio over all
      outputs.

    Otherwise mu_j is reported as not identifiable, with the reason.

    Parameters
    ----------
    model : StateSpaceModel
        Identified model with its ``elements``.
    frequencies : ndarray, shape (N,)
        Frequencies [Hz] (the analysis lines).
    driving_points : mapping of str to str, optional
        Input name -> output name measured at the point and direction of that force.
        Default: :func:`default_driving_points`.

    Returns
    -------
    tuple of Coefficient
        One per basis function, in the order of the extended-input columns.
    """
    frequencies = np.asarray(frequencies, dtype=float)
    outputs = {name: k for k, name in enumerate(model.output_names)}
    if driving_points is None:
        driving_points = default_driving_points(model.input_names, model.output_names)
    points = {model.input_names.index(u): outputs[p] for u, p in driving_points.items()
              if u in model.input_names and p in outputs}
    He = model.frequency_response(frequencies)
    m = model.n_inputs
    coefficients: list[Coefficient] = []
    column = m
    for index, element in enumerate(model.elements):
        cols = range(column, column + element.n_basis)
        column += element.n_basis
        mu, method, reason = _element_coefficients(model, frequencies, He, element, cols,
                                                   outputs, points)
        coefficients.extend(
            Coefficient(name, index, j, frequencies, None if mu is None else mu[j], method,
                        reason)
            for j, name in enumerate(element.basis_names))
    return tuple(coefficients)


def _element_coefficients(model, frequencies, He, element, cols, outputs, points):
    """(mu (n_basis, N) or None, method, reason) of one element; see nonlinear_coefficients."""
    dof = outputs.get(element.dof)
    ref = outputs.get(element.ref) if element.ref is not None else None
    if dof is None or (element.ref is not None and ref is None):
        return None, "none", (f"{element.name}: its DOFs are not all among the outputs "
                              f"{list(model.output_names)}")
    direct = [(a, p) for a, p in points.items() if p in (dof, ref)]
    if direct:
        a, p = direct[0]
        if ref is None:
            h = He[:, :, a]
            return [_least_squares_ratio(h, He[:, :, j]) for j in cols], "driving point", None
        denom = He[:, dof, a] - He[:, ref, a]
        return [-He[:, p, j] / denom for j in cols], "driving point", None
    if not points:
        return None, "none", (
            f"{element.name}: no force acts at its DOFs and no input has a measured driving "
            "point (an output named like the input, or driving_points), so the FRF columns "
            f"at {element.dof}" + (f" and {element.ref}" if element.ref else "")
            + " cannot be scaled; measure the response at the force location")
    a, p = next(iter(points.items()))
    h = _synthesised_column(model, frequencies, a, p, dof)
    if ref is not None:
        h = h - _synthesised_column(model, frequencies, a, p, ref)
    return ([_least_squares_ratio(h.T, He[:, :, j]) for j in cols], "modal synthesis", None)
