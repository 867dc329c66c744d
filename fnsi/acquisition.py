"""Synthetic measurement of a structural model under periodic excitation (paper Section III).

The chain reproduces the paper's numerical experiments: nonlinear Newmark integration at
``fs_int`` (20 kHz, to resolve impacts), anti-aliased decimation to ``fs`` (2.5 kHz),
and filtered white measurement noise in 0-100 Hz at a percentage of the RMS response of
a reference channel.

Signal path:

1. The excitation (one period at ``fs``) is upsampled band-limited to ``fs_int`` by
   zero-padding its DFT; the fine force equals the given samples exactly at the ``fs``
   instants, and it is applied periodically for ``periods`` periods from rest.
2. Each period after the first is decimated exactly in the frequency domain: its DFT is
   truncated below fs/2 (an ideal anti-aliasing low-pass) and transformed back on the
   ``fs`` grid, exact for steady-state (periodic) periods. The first period holds the
   transient and is not periodic: it is filtered by a zero-phase FIR (:func:`transient_filter`)
   from rest (zero before t = 0) into the start of the second period, so that it has no
   circular-filter ringing at its edges.
3. Noise: independent Gaussian lines of the DFT of the whole record in ``noise_band``,
   so its spectrum is confined to that band and it varies from period to period, scaled
   per channel to exactly ``noise_percent`` % of the RMS of the noise-free reference
   channel over the kept periods. Only the outputs are noisy; the input is the applied
   force.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.fft
import scipy.signal

from fnsi.excitation import Excitation
from fnsi.measurement import QUANTITIES, Measurement
from fnsi.modal import ModalTable
from fnsi.newmark import NewmarkIntegrator, Progress
from fnsi.nonlinear import NonlinearElement, NonlinearityKind
from fnsi.structure import StructuralModel

#: Half-length of the first period's FIR decimation filter, in output samples.
FIR_HALF = 16


@dataclass(frozen=True)
class Truth:
    """What the simulated structure really is, to judge an identification against.

    Attributes
    ----------
    modal : ModalTable
        Modes of the underlying linear model, shapes at the measurement's outputs.
    elements : tuple of NonlinearElement
        The model's nonlinear elements with their true coefficients.
    exceedances : dict of str to int
        For each clearance element (key: element name), the number of samples at ``fs``
        in the kept periods (all but the first ``discard_periods``), summed over the
        realisations, where the simulated relative displacement lies beyond a gap
        (x > g+ or x < -g-), i.e. where the stop is in contact (paper Table 3). The
        displacement is the integrator's value at the ``fs`` instants (not filtered).
    discard_periods : int
        Leading periods left out of ``exceedances``.
    """

    modal: ModalTable
    elements: tuple[NonlinearElement, ...]
    exceedances: dict[str, int]
    discard_periods: int = 2

    def to_json(self) -> dict:
        """JSON object with the modal table, the elements and the exceedance counts."""
        return {
            "modal": {
                "frequencies": self.modal.frequencies.tolist(),
                "damping_ratios": self.modal.damping_ratios.tolist(),
                "shapes_real": self.modal.shapes.real.tolist(),
                "shapes_imag": self.modal.shapes.imag.tolist(),
                "output_names": list(self.modal.output_names),
            },
            "elements": [e.to_json() for e in self.elements],
            "exceedances": dict(self.exceedances),
            "discard_periods": self.discard_periods,
        }


#: Band of the measurement noise [Hz] (paper Section III: filtered white noise in 0-100 Hz).
NOISE_BAND = (0.0, 100.0)


def upsample(period: np.ndarray, factor: int) -> np.ndarray:
    """Band-limited periodic upsampling along axis 1 by an integer ``factor``.

    Parameters
    ----------
    period : ndarray, shape (realisations, samples, channels)
        One period at the low rate.
    factor : int
        Rate ratio D.

    Returns
    -------
    ndarray, shape (realisations, samples * factor, channels)
        Equal to ``period`` at every D-th sample (a Nyquist line is split evenly).
    """
    n = period.shape[1]
    spectrum = scipy.fft.rfft(period, axis=1, workers=-1) * factor
    if n % 2 == 0:
        spectrum[:, -1] /= 2
    return scipy.fft.irfft(spectrum, n=n * factor, axis=1, workers=-1)


def decimate(period: np.ndarray, factor: int) -> np.ndarray:
    """Exact decimation of one period by ideal low-pass below the new Nyquist frequency.

    Parameters
    ----------
    period : ndarray, shape (realisations, samples, channels)
        One period at the high rate; ``samples`` divisible by ``factor``.
    factor : int
        Rate ratio D.

    Returns
    -------
    ndarray, shape (realisations, samples // factor, channels)
    """
    n = period.shape[1] // factor
    spectrum = scipy.fft.rfft(period, axis=1, workers=-1)[:, : (n + 1) // 2]  # below fs/2
    return scipy.fft.irfft(spectrum / factor, n=n, axis=1, workers=-1)


def transient_filter(factor: int) -> np.ndarray:
    """Linear-phase anti-aliasing low-pass for the first period, at the integration rate.

    2 FIR_HALF factor + 1 taps, Kaiser window (beta 8: about 80 dB stopband), cutoff
    0.9 fs/2: flat to about 0.8 fs/2, far above any analysis band.
    """
    return scipy.signal.firwin(2 * FIR_HALF * factor + 1, 0.9 / factor, window=("kaiser", 8.0))


def fir_decimate(x: np.ndarray, factor: int, h: np.ndarray) -> np.ndarray:
    """Zero-phase FIR decimation along axis 1, taking ``x`` as zero outside the record.

    Parameters
    ----------
    x : ndarray, shape (realisations, samples, channels)
    factor : int
        Rate ratio D.
    h : ndarray, shape (2 FIR_HALF D + 1,)
        Symmetric filter (:func:`transient_filter`).

    Returns
    -------
    ndarray, shape (realisations, samples // factor, channels)
        Sample n is the filter centred on x[:, n factor].
    """
    filtered = scipy.signal.upfirdn(h, x, down=factor, axis=1)
    return filtered[:, FIR_HALF:FIR_HALF + x.shape[1] // factor]


def band_noise(shape: tuple[int, int, int], fs: float, band: tuple[float, float],
               rng: np.random.Generator) -> np.ndarray:
    """Gaussian noise (realisations, samples, channels) whose DFT is zero outside ``band`` [Hz].

    Every DFT line of the record in the band (DC excluded) gets an independent complex
    Gaussian amplitude; each channel is scaled to unit RMS.
    """
    R, n, channels = shape
    f = np.fft.rfftfreq(n, 1 / fs)
    lines = np.flatnonzero((f > 0) & (f >= band[0]) & (f <= band[1]) & (f < fs / 2))
    if lines.size == 0:
        raise ValueError(f"noise band {band} Hz holds no DFT line of the {n / fs:g} s record")
    spectrum = np.zeros((R, f.size, channels), dtype=complex)
    spectrum[:, lines] = rng.standard_normal((R, lines.size, channels, 2)) @ [1.0, 1.0j]
    noise = scipy.fft.irfft(spectrum, n=n, axis=1, workers=-1)
    return noise / np.sqrt(np.mean(noise**2, axis=1, keepdims=True))


def measurement_noise(y: np.ndarray, fs: float, noise_percent: float, reference: int,
                      kept: slice, band: tuple[float, float], seed: int) -> np.ndarray:
    """The output noise :func:`acquire` adds: band-limited white noise, step 3 above.

    Parameters
    ----------
    y : ndarray, shape (R, samples, l)
        Noise-free outputs.
    fs : float
        Sampling rate [Hz].
    noise_percent : float
        Noise RMS on every channel as a percentage of the RMS of channel ``reference``
        over the ``kept`` samples.
    reference : int
        Index of the reference output channel.
    kept : slice
        Samples after the transient periods.
    band : (float, float)
        Noise band [Hz].
    seed : int
        Seed of the noise (numpy's PCG64).

    Returns
    -------
    ndarray, shape of ``y``
        The noise, in the units of ``y``.
    """
    level = noise_percent / 100 * np.sqrt(np.mean(y[:, kept, reference] ** 2))
    return level * band_noise(y.shape, fs, band, np.random.default_rng(seed))


def _count_exceedances(element: NonlinearElement, x: np.ndarray) -> int:
    gap_negative, gap_positive = element.gaps
    return int(np.count_nonzero((x > gap_positive) | (x < -gap_negative)))


def check_timing(fs: float, fs_int: float, samples_per_period: int, periods: int,
                 discard_periods: int) -> int:
    """The integration factor of a simulated test, after the checks of its timing.

    Parameters
    ----------
    fs, fs_int : float
        Measurement and integration rates [Hz]; fs_int must be an integer multiple of fs
        (each period is integrated at fs_int and decimated exactly, step 2).
    samples_per_period : int
        Samples per period at fs; at least 2 FIR_HALF, the first period's filter.
    periods, discard_periods : int
        Periods simulated, and leading transient periods left out of the noise reference
        and the exceedance counts: at least one period must remain.

    Returns
    -------
    int
        The rate ratio D = fs_int / fs.

    Examples
    --------
    >>> check_timing(2500.0, 20000.0, samples_per_period=2500, periods=3, discard_periods=2)
    8
    """
    ratio = fs_int / fs
    factor = round(ratio) if np.isfinite(ratio) else 0
    if factor < 1 or abs(factor * fs - fs_int) > 1e-9 * fs_int:
        raise ValueError(f"fs_int={fs_int:g} Hz must be an integer multiple of fs={fs:g} Hz")
    if samples_per_period < 2 * FIR_HALF:
        raise ValueError(f"a period of {samples_per_period} samples is too short; give at "
                         f"least {2 * FIR_HALF}")
    if int(periods) != periods or periods < 1 or not 0 <= discard_periods < periods:
        raise ValueError(f"periods={periods} leaves no period after the {discard_periods} "
                         f"transient periods discarded (discard_periods={discard_periods}); give "
                         f"periods >= {discard_periods + 1}")
    return factor


def acquire(model: StructuralModel, excitation: Excitation, *, fs: float = 2500.0,
            fs_int: float = 20000.0, periods: int = 8, outputs=None,
            quantity: str = "displacement", noise_percent: float = 0.5,
            noise_reference: str | None = None, noise_band: tuple[float, float] = NOISE_BAND,
            discard_periods: int = 2, seed: int = 0,
            progress: Progress | None = None) -> tuple[Measurement, Truth]:
    """Simulate a periodic test of ``model`` and return the noisy measurement and the truth.

    Parameters
    ----------
    model : StructuralModel
        Structure with its nonlinear elements (Eq. 1-2).
    excitation : Excitation
        One period of the inputs at ``fs`` and the DOFs they act on.
    fs : float
        Measurement sampling rate [Hz]; must equal ``excitation.fs``.
    fs_int : float
        Integration rate [Hz], an integer multiple of ``fs``.
    periods : int
        Periods simulated from rest and recorded.
    outputs : sequence of str, optional
        DOFs measured (default all, in model order).
    quantity : {"displacement", "velocity", "acceleration"}
        What the outputs measure.
    noise_percent : float
        Noise RMS as a percentage of the reference channel's RMS response (0: no noise).
    noise_reference : str, optional
        Output channel whose RMS sets the noise level (paper: the bracket tip); default
        the output with the largest RMS response.
    noise_band : (float, float)
        Band of the measurement noise [Hz].
    discard_periods : int
        Transient periods left out of the noise reference RMS and the exceedance counts.
    seed : int
        Seed of the measurement noise.
    progress : callable(fraction, message), optional
        Called after every simulated period; may raise to cancel.

    Returns
    -------
    Measurement
        u (realisations, periods * samples, m), y (..., l) at ``fs``.
    Truth
        Linear modes, elements and clearance exceedance counts.
    """
    outputs = tuple(model.dof_names if outputs is None else outputs)
    out_idx = np.array([model.dof_index(name) for name in outputs], dtype=np.int64)
    if quantity not in QUANTITIES:
        raise ValueError(f"quantity must be one of {QUANTITIES}; got {quantity!r}")
    if excitation.fs != fs:
        raise ValueError(f"the excitation is sampled at {excitation.fs} Hz but fs={fs}; "
                         "generate it at the measurement rate")
    factor = check_timing(fs, fs_int, excitation.n_samples, periods, discard_periods)
    if not (np.isfinite(noise_percent) and noise_percent >= 0):
        raise ValueError(f"noise_percent must be >= 0; got {noise_percent}")
    if noise_reference is not None and noise_reference not in outputs:
        raise ValueError(f"noise_reference {noise_reference!r} is not an output; outputs are "
                         f"{list(outputs)}")

    y, x_elements = _simulate(model, excitation, factor, periods, out_idx, quantity, progress)
    kept = slice(discard_periods * excitation.n_samples, None)
    if noise_percent > 0:
        reference = (outputs.index(noise_reference) if noise_reference is not None
                     else int(np.argmax(np.sqrt(np.mean(y[:, kept] ** 2, axis=(0, 1))))))
        y += measurement_noise(y, fs, noise_percent, reference, kept, noise_band, seed)
    exceedances = {e.name: _count_exceedances(e, x_elements[:, kept, j])
                   for j, e in enumerate(model.elements)
                   if e.kind is NonlinearityKind.CLEARANCE}
    modal = model.linear_modes()
    truth = Truth(ModalTable(modal.frequencies, modal.damping_ratios, modal.shapes[:, out_idx],
                             outputs), model.elements, exceedances, discard_periods)
    u = np.tile(excitation.u, (1, periods, 1))
    measurement = Measurement(u, y, fs, excitation.names, outputs, periods, quantity)
    return measurement, truth


def _simulate(model: StructuralModel, excitation: Excitation, factor: int, periods: int,
              out_idx: np.ndarray, quantity: str, progress: Progress | None):
    """Integrate period by period at fs * factor and decimate (module steps 1-2).

    Returns
    -------
    y : ndarray, shape (R, periods * samples, l)
        Noise-free outputs at fs.
    x : ndarray, shape (R, periods * samples, s)
        Element relative displacements at the fs instants (not filtered).
    """
    n = excitation.n_samples
    integrator = NewmarkIntegrator(model, 1.0 / (factor * excitation.fs),
                                   excitation.loads(model.dof_names))
    dof, ref = model.element_dofs()
    element_idx = np.concatenate([dof, ref[ref >= 0]])
    n_el = element_idx.size
    # recorded columns: element DOF displacements, then the outputs in `quantity`
    empty = np.zeros(0, dtype=np.int64)
    record = {"displacement": (np.concatenate([element_idx, out_idx]), empty, empty),
              "velocity": (element_idx, out_idx, empty),
              "acceleration": (element_idx, empty, out_idx)}[quantity]
    y = np.empty((excitation.n_realisations, periods * n, out_idx.size))
    x = np.empty((excitation.n_realisations, periods * n, dof.size))
    blocks = integrator.run(upsample(excitation.u, factor), periods * n * factor, record,
                            chunk=n * factor)
    h, edge = transient_filter(factor), FIR_HALF * factor
    for p, (_, block) in enumerate(blocks):
        recorded = block[:, :, n_el:]
        if p == 0:  # last FIR_HALF samples wait for the start of period 2 (zeros if none)
            y[:, :n] = fir_decimate(recorded, factor, h)
            tail = recorded[:, -2 * edge:].copy()
        else:
            y[:, p * n:(p + 1) * n] = decimate(recorded, factor)
        if p == 1:
            joint = np.concatenate([tail, recorded[:, :edge]], axis=1)
            y[:, n - FIR_HALF:n] = fir_decimate(joint, factor, h)[:, FIR_HALF:2 * FIR_HALF]
        x[:, p * n:(p + 1) * n] = _relative(block[:, ::factor, :n_el], dof, ref)
        if progress is not None:
            progress((p + 1) / periods, f"simulated period {p + 1} of {periods}")
    return y, x


def _relative(q: np.ndarray, dof: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """Relative displacements (..., s) from recorded [dof of each element, ref of each
    element not grounded]."""
    s = dof.size
    x = q[..., :s].copy()
    x[..., ref >= 0] -= q[..., s:]
    return x
