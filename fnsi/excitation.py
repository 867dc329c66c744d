"""Periodic excitation signals and where they act (paper Section IV: periodic noise in 5-50 Hz).

Signals are built on the DFT grid of one period (lines k fs / N), so they are exactly
periodic and exactly band-limited: no leakage once the transient has died out (Eq. 6).
A seed reproduces a signal bit for bit (numpy's PCG64 generator).

Array convention: one period, ``(realisations, samples)`` for a signal and
``(realisations, samples, m)`` for the m inputs of an :class:`Excitation`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

import numpy as np


def excited_line_range(samples: int, fs: float, band: tuple[float, float]) -> tuple[int, int]:
    """First and last DFT line k (frequency k fs / samples [Hz]) inside ``band``, DC and
    Nyquist excluded, found in a few steps whatever ``samples``: a request is checked
    with it without allocating its lines.

    The frequency k fs / samples never decreases with k (rounding is monotone), so the
    lines in the band, within 1e-9 fs, are every k from the first to the last.

    Parameters
    ----------
    samples : int
        Samples per period N.
    fs : float
        Sampling rate [Hz].
    band : (float, float)
        Lowest and highest excited frequency [Hz], inclusive.

    Returns
    -------
    (int, int)
        The first and the last line, first <= last.

    Examples
    --------
    >>> excited_line_range(100, 100.0, (5.0, 8.0))
    (5, 8)
    """
    if int(samples) != samples or samples < 4:
        raise ValueError(f"samples per period must be an integer >= 4; got {samples}")
    if not (np.isfinite(fs) and fs > 0):
        raise ValueError(f"fs must be a positive sampling rate in Hz; got {fs}")
    low, high = (float(b) for b in band)
    if not (0 <= low <= high <= fs / 2):
        raise ValueError(f"band must satisfy 0 <= low <= high <= fs/2 = {fs / 2} Hz; got {band}")
    samples = int(samples)
    top = (samples + 1) // 2 - 1  # below Nyquist: a Nyquist line has no phase
    lowest, highest = low - 1e-9 * fs, high + 1e-9 * fs

    def frequency(k: int) -> float:
        return float(np.float64(k) * fs / samples)

    # start from the rounded estimates, then step to the exact ends (a step or two)
    first = min(max(1, int(lowest * samples / fs)), top + 1)
    while first > 1 and frequency(first - 1) >= lowest:
        first -= 1
    while first <= top and frequency(first) < lowest:
        first += 1
    last = max(min(top, int(highest * samples / fs)), first - 1)
    while last < top and frequency(last + 1) <= highest:
        last += 1
    while last >= first and frequency(last) > highest:
        last -= 1
    if last < first:
        raise ValueError(f"no DFT line of resolution {fs / samples:g} Hz falls in band {band}; "
                         "widen the band or lengthen the period")
    return first, last


def excited_lines(samples: int, fs: float, band: tuple[float, float]) -> np.ndarray:
    """DFT lines k (frequency k fs / samples [Hz]) inside ``band``, DC and Nyquist excluded
    (:func:`excited_line_range`; parameters as there).

    Returns
    -------
    ndarray of int, shape (lines,)

    Examples
    --------
    >>> excited_lines(100, 100.0, (5.0, 8.0)).tolist()
    [5, 6, 7, 8]
    """
    first, last = excited_line_range(samples, fs, band)
    return np.arange(first, last + 1)


def _synthesise(spectrum: np.ndarray, samples: int, rms: float) -> np.ndarray:
    """Real periodic signals (realisations, samples) from half spectra, scaled to ``rms``."""
    if not (np.isfinite(rms) and rms > 0):
        raise ValueError(f"rms must be positive; got {rms}")
    x = np.fft.irfft(spectrum, n=samples, axis=-1)
    return x * (rms / np.sqrt(np.mean(x**2, axis=-1, keepdims=True)))


def _realisations(realisations: int) -> int:
    if int(realisations) != realisations or realisations < 1:
        raise ValueError(f"realisations must be a positive integer; got {realisations}")
    return int(realisations)


def periodic_noise(samples: int, fs: float, band: tuple[float, float], rms: float, *,
                   realisations: int = 1, seed: int = 0) -> np.ndarray:
    """Periodic Gaussian noise, band-limited by construction in the frequency domain.

    Every line in ``band`` gets an independent circular complex Gaussian amplitude (other
    lines are zero), so each time sample is Gaussian and the signal is exactly periodic;
    each realisation is then scaled to exactly ``rms``.

    Parameters
    ----------
    samples : int
        Samples per period N.
    fs : float
        Sampling rate [Hz].
    band : (float, float)
        Excited band [Hz].
    rms : float
        RMS value of each realisation (e.g. [N]).
    realisations : int
        Number of independent realisations.
    seed : int
        Seed of the random generator; the same seed gives the same signal bit for bit.

    Returns
    -------
    ndarray, shape (realisations, samples)

    Examples
    --------
    >>> x = periodic_noise(1000, 100.0, (5.0, 20.0), rms=2.0)
    >>> x.shape, round(float(x.std()), 12)
    ((1, 1000), 2.0)
    """
    lines = excited_lines(samples, fs, band)
    rng = np.random.default_rng(seed)
    spectrum = np.zeros((_realisations(realisations), samples // 2 + 1), dtype=complex)
    spectrum[:, lines] = rng.standard_normal((spectrum.shape[0], lines.size, 2)) @ [1.0, 1.0j]
    return _synthesise(spectrum, samples, rms)


def multisine(samples: int, fs: float, band: tuple[float, float], rms: float, *,
              lines: Literal["full", "odd"] = "full", detection: int | None = None,
              realisations: int = 1, seed: int = 0) -> np.ndarray:
    """Random-phase multisine: flat amplitude spectrum, independent uniform phases.

    Parameters
    ----------
    samples, fs, band, rms, realisations, seed :
        As in :func:`periodic_noise`.
    lines : {"full", "odd"}
        Excite every line in the band, or only odd lines (even lines then reveal even
        nonlinear distortions).
    detection : int, optional
        Leave out one randomly chosen line in every group of ``detection`` consecutive
        excited lines (random-odd multisine when lines="odd"), as detection lines for
        odd nonlinear distortions.

    Returns
    -------
    ndarray, shape (realisations, samples)

    Examples
    --------
    >>> x = multisine(64, 64.0, (1.0, 10.0), rms=1.0, lines="odd")
    >>> np.flatnonzero(np.abs(np.fft.rfft(x[0])) > 1e-9).tolist()
    [1, 3, 5, 7, 9]
    """
    if lines not in ("full", "odd"):
        raise ValueError(f"lines must be 'full' or 'odd'; got {lines!r}")
    excited = excited_lines(samples, fs, band)
    if lines == "odd":
        excited = excited[excited % 2 == 1]
        if excited.size == 0:
            raise ValueError(f"no odd DFT line falls in band {band}; widen the band")
    R = _realisations(realisations)
    rng = np.random.default_rng(seed)
    amplitude = np.zeros((R, samples // 2 + 1))
    amplitude[:, excited] = 1.0
    if detection is not None:
        if int(detection) != detection or not 2 <= detection <= excited.size:
            raise ValueError(f"detection must be an integer in 2..{excited.size} (lines per "
                             f"group with one left out); got {detection}")
        groups = excited.size // detection
        dropped = np.arange(groups) * detection + rng.integers(0, detection, (R, groups))
        np.put_along_axis(amplitude, excited[dropped], 0.0, axis=1)
    phases = rng.uniform(0.0, 2 * np.pi, amplitude.shape)
    return _synthesise(amplitude * np.exp(1j * phases), samples, rms)


@dataclass(frozen=True)
class Excitation:
    """One period of periodic input signals and the DOFs they act on.

    Input j is a force u_j(t) [N] along the unit direction ``directions[j]`` (DOF name to
    weight, normalised to unit Euclidean norm), so the DOF forces are
    p(t) = sum_j u_j(t) d_j.

    Attributes
    ----------
    u : ndarray, shape (realisations, samples, m)
        One period of each input at ``fs``.
    fs : float
        Sampling rate [Hz].
    directions : tuple of dict
        For each input, DOF name -> weight (unit norm).
    names : tuple of str
        Input channel names (distinct from the DOF / output names).

    Examples
    --------
    >>> signal = periodic_noise(1000, 2500.0, (5.0, 50.0), rms=200.0)
    >>> e = Excitation.along(signal, 2500.0, {"W_X": 1.0, "W_Y": 1.0}, name="F_W_XY")
    >>> round(e.directions[0]["W_X"], 6), e.u.shape
    (0.707107, (1, 1000, 1))
    """

    u: np.ndarray
    fs: float
    directions: tuple[dict[str, float], ...]
    names: tuple[str, ...]

    def __post_init__(self) -> None:
        u = np.asarray(self.u, dtype=np.float64)
        if u.ndim != 3 or u.shape[2] != len(self.directions) or len(self.names) != u.shape[2]:
            raise ValueError(f"u must be (realisations, samples, m) with one direction and one "
                             f"name per input; got u {u.shape}, {len(self.directions)} "
                             f"directions, {len(self.names)} names")
        if not np.all(np.isfinite(u)):
            raise ValueError("excitation signals contain NaN or infinite values")
        if not (np.isfinite(self.fs) and self.fs > 0):
            raise ValueError(f"fs must be a positive sampling rate in Hz; got {self.fs}")
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"input names must be unique; got {list(self.names)}")
        directions = []
        for direction in self.directions:
            weights = np.array([float(w) for w in direction.values()])
            norm = np.linalg.norm(weights)
            if not direction or not np.isfinite(norm) or norm == 0:
                raise ValueError(f"a direction needs finite weights, not all zero; got "
                                 f"{dict(direction)}")
            directions.append({str(k): float(w) / float(norm) for k, w in direction.items()})
        object.__setattr__(self, "u", u)
        object.__setattr__(self, "fs", float(self.fs))
        object.__setattr__(self, "directions", tuple(directions))
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    @classmethod
    def along(cls, signal, fs: float, direction: Mapping[str, float], *,
              name: str | None = None) -> Excitation:
        """Single input acting along ``direction`` (DOF name -> weight, normalised).

        Parameters
        ----------
        signal : array_like, shape (samples,) or (realisations, samples)
            One period of the force along the direction [N].
        fs : float
            Sampling rate [Hz].
        direction : mapping of str to float
            DOF weights, e.g. ``{"W_X": 1, "W_Y": 1}`` for the symmetric X-Y direction.
        name : str, optional
            Input channel name; default ``"F_" + "+".join(DOF names)``.
        """
        s = np.asarray(signal, dtype=np.float64)
        s = s[None] if s.ndim == 1 else s
        if s.ndim != 2:
            raise ValueError(f"signal must be (samples,) or (realisations, samples); got "
                             f"{np.shape(signal)}")
        return cls(s[:, :, None], fs, (dict(direction),),
                   (name or "F_" + "+".join(direction),))

    @classmethod
    def at_dof(cls, signal, fs: float, dof: str, *, name: str | None = None) -> Excitation:
        """Single input acting on one DOF (input name default ``"F_<dof>"``)."""
        return cls.along(signal, fs, {dof: 1.0}, name=name)

    @property
    def n_samples(self) -> int:
        """Samples per period."""
        return int(self.u.shape[1])

    @property
    def n_realisations(self) -> int:
        """Number of realisations."""
        return int(self.u.shape[0])

    def loads(self, dof_names: tuple[str, ...]) -> np.ndarray:
        """Load distribution matrix (r, m): column j is direction j over ``dof_names``."""
        out = np.zeros((len(dof_names), len(self.directions)))
        for j, direction in enumerate(self.directions):
            for dof, weight in direction.items():
                if dof not in dof_names:
                    raise ValueError(f"excitation acts on unknown DOF {dof!r}; the model's "
                                     f"DOFs are {list(dof_names)}")
                out[dof_names.index(dof), j] = weight
        return out
