"""Model-versus-measurement errors and the noise floor they should be judged against.

The identified model is simulated with the measured periodic input (see
:mod:`fnsi.simulation`) and compared with the measured outputs after averaging over the
steady-state periods, in the time domain (normalised RMS error per channel) and per
frequency line. Period-to-period variation of a periodic measurement is noise only, so it
gives the level a perfect model would reach: the noise floor, in the same units as each
error (docs/design.md section 3, step 7).

Conventions: records are ``(samples, channels)`` or ``(realisations, samples,
channels)`` with ``samples = periods * period_length``; spectra are ``(lines,
channels)`` with the DFT scaled by 1 / sqrt(period_length) as in Eq. 6 of the paper, so
that Parseval's theorem links the per-line values to the time-domain errors.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


def _decibel(percent: np.ndarray | float) -> np.ndarray:
    """Amplitude ratio in % expressed in dB (1 % is -40 dB)."""
    with np.errstate(divide="ignore"):
        return 20.0 * np.log10(np.asarray(percent, dtype=float) / 100.0)


def json_float(value: float | None) -> float | None:
    """A number for JSON: None, NaN and infinities (unknown values) become null."""
    return None if value is None or not np.isfinite(value) else float(value)


@dataclass(frozen=True)
class ModelErrors:
    """Errors of a model against a periodic measurement, with the noise floor.

    Attributes
    ----------
    output_names : tuple of str
        The l output channels.
    nrmse_percent : ndarray, shape (l,)
        Normalised RMS error per channel [%]: RMS(y_measured - y_model) / RMS(y_measured),
        both averaged over periods.
    noise_floor_percent : ndarray, shape (l,)
        The same quantity for a perfect model: RMS of the noise left on the period
        average, estimated from the period-to-period variation [%]. NaN for one period.
    frequencies : ndarray, shape (lines,)
        Frequencies of the analysed DFT lines [Hz].
    measured_spectrum : ndarray, shape (lines, l)
        Amplitude of the period-averaged measured output spectrum [output unit].
    error_spectrum : ndarray, shape (lines, l)
        Amplitude of the measured minus model spectrum [output unit].
    noise_spectrum : ndarray, shape (lines, l)
        Standard deviation of the noise on the period-averaged spectrum [output unit].
    """

    output_names: tuple[str, ...]
    nrmse_percent: np.ndarray
    noise_floor_percent: np.ndarray
    frequencies: np.ndarray
    measured_spectrum: np.ndarray
    error_spectrum: np.ndarray
    noise_spectrum: np.ndarray

    @property
    def overall_percent(self) -> float:
        """Overall NRMSE [%]: RMS over channels, so every channel counts whatever its unit."""
        return float(np.sqrt(np.mean(self.nrmse_percent**2)))

    @property
    def overall_noise_floor_percent(self) -> float:
        """Overall noise floor [%], combined over channels like :attr:`overall_percent`."""
        return float(np.sqrt(np.mean(self.noise_floor_percent**2)))

    @property
    def nrmse_db(self) -> np.ndarray:
        """Per-channel NRMSE in dB (20 log10 of the ratio), shape (l,)."""
        return _decibel(self.nrmse_percent)

    @property
    def noise_floor_db(self) -> np.ndarray:
        """Per-channel noise floor in dB, shape (l,)."""
        return _decibel(self.noise_floor_percent)

    def to_json(self, *, spectra: bool = False) -> dict:
        """JSON-ready summary; the per-line spectra (amplitudes in dB re 1 unit) on request."""
        channels = [
            {
                "output": name,
                "nrmse_percent": json_float(e),
                "nrmse_db": json_float(e_db),
                "noise_floor_percent": json_float(n),
                "noise_floor_db": json_float(n_db),
            }
            for name, e, e_db, n, n_db in zip(
                self.output_names, self.nrmse_percent, self.nrmse_db,
                self.noise_floor_percent, self.noise_floor_db, strict=True,
            )
        ]
        result = {
            "overall_nrmse_percent": json_float(self.overall_percent),
            "overall_nrmse_db": json_float(_decibel(self.overall_percent)),
            "overall_noise_floor_percent": json_float(self.overall_noise_floor_percent),
            "overall_noise_floor_db": json_float(_decibel(self.overall_noise_floor_percent)),
            "channels": channels,
        }
        if spectra:
            result["spectra"] = {
                "frequency_hz": self.frequencies.tolist(),
                **{
                    key: [[json_float(v) for v in row] for row in _decibel(100.0 * values)]
                    for key, values in (
                        ("measured_db", self.measured_spectrum),
                        ("error_db", self.error_spectrum),
                        ("noise_db", self.noise_spectrum),
                    )
                },
            }
        return result


def _periods_view(record: np.ndarray, periods: int, name: str) -> np.ndarray:
    """(realisations, periods, period_length, channels) view of a record."""
    y = np.asarray(record, dtype=float)
    if y.ndim == 2:
        y = y[None]
    if y.ndim != 3:
        raise ValueError(
            f"{name} must be (samples, channels) or (realisations, samples, channels); "
            f"got shape {np.shape(record)}"
        )
    if y.shape[1] % periods:
        raise ValueError(
            f"{name} has {y.shape[1]} samples, not a multiple of periods={periods}; "
            f"pass whole steady-state periods"
        )
    return y.reshape(y.shape[0], periods, y.shape[1] // periods, y.shape[2])


def left_out_nrmse(measured: np.ndarray, simulated: np.ndarray, *,
                   periods: int) -> np.ndarray:
    """Per-channel NRMSE [%] of :func:`model_errors` with each period left out in turn.

    The jackknife replicates of the NRMSE over the periods: their spread, times
    sqrt((P - 1)^2 / P) about their mean, is the standard deviation that the noise of the
    measurement gives the NRMSE of the P-period average (Efron's delete-one jackknife;
    the NRMSE is a smooth function of the period average).

    Parameters
    ----------
    measured : ndarray, shape (samples, l) or (realisations, samples, l)
        Steady-state measured outputs, ``periods`` (>= 2) whole periods.
    simulated : ndarray
        One period of the model outputs per realisation (or the same shape as
        ``measured``).
    periods : int
        Number of periods in ``measured``.

    Returns
    -------
    ndarray, shape (periods, l)
        Row p: the NRMSE of the average of every period but p.
    """
    if periods < 2:
        raise ValueError(f"leaving a period out needs at least two; got {periods}")
    y = _periods_view(measured, periods, "measured")
    sim = np.asarray(simulated, dtype=float)
    model = _periods_view(sim, periods if sim.shape[-2] == y.shape[1] * y.shape[2] else 1,
                          "simulated").mean(axis=1)
    others = (y.sum(axis=1, keepdims=True) - y) / (periods - 1)   # (R, P, N, l)
    error = np.mean((others - model[:, None]) ** 2, axis=(0, 2))
    return 100.0 * np.sqrt(error / np.mean(others**2, axis=(0, 2)))


def model_errors(
    measured: np.ndarray,
    simulated: np.ndarray,
    fs: float,
    *,
    periods: int,
    output_names: Sequence[str] | None = None,
    band: tuple[float, float] | None = None,
) -> ModelErrors:
    """Compare simulated with measured periodic outputs, against the noise floor.

    Parameters
    ----------
    measured : ndarray, shape (samples, l) or (realisations, samples, l)
        Steady-state measured outputs (transient periods already discarded),
        ``samples = periods * period_length``.
    simulated : ndarray
        Model outputs for the same input: the same shape as ``measured``, or one period
        per realisation, shape (period_length, l) or (realisations, period_length, l).
    fs : float
        Sampling rate [Hz].
    periods : int
        Number of periods in ``measured``; at least 2 for a noise floor (NaN otherwise).
    output_names : sequence of str, optional
        Channel names (default ``y0, y1, ...``).
    band : (float, float), optional
        Frequency band [Hz] of the reported spectra; default all lines but DC.

    Returns
    -------
    ModelErrors

    Notes
    -----
    With P periods y_p of the measurement, the noise variance per sample is
    sigma^2 = sum_p (y_p - mean_p y)^2 / (P - 1) and the noise on the period average
    has variance sigma^2 / P. The floor is that RMS relative to the RMS of the averaged
    measurement: the NRMSE of an exact model. Per line, the same holds for the spectra.

    Examples
    --------
    >>> import numpy as np
    >>> t = np.arange(400) / 400.0
    >>> y = np.sin(2 * np.pi * 5 * t)[:, None]
    >>> e = model_errors(np.tile(y, (2, 1)), 0.99 * y, fs=400.0, periods=2)
    >>> round(float(e.nrmse_percent[0]), 6), round(float(e.nrmse_db[0]), 1)
    (1.0, -40.0)
    """
    if periods < 1:
        raise ValueError(f"periods must be a positive integer; got {periods}")
    if fs <= 0:
        raise ValueError(f"sampling rate fs must be positive; got {fs} Hz")
    y = _periods_view(measured, periods, "measured")
    sim = np.asarray(simulated, dtype=float)
    sim_periods = periods if sim.shape[-2] == y.shape[1] * y.shape[2] else 1
    model = _periods_view(sim, sim_periods, "simulated")
    if model.shape[0] != y.shape[0] or model.shape[2:] != y.shape[2:]:
        raise ValueError(
            f"simulated outputs {sim.shape} do not match the measured record {np.shape(measured)}:"
            f" give the same shape or one period per realisation"
        )
    n_outputs = y.shape[3]
    names = tuple(output_names) if output_names is not None else tuple(
        f"y{k}" for k in range(n_outputs))
    if len(names) != n_outputs:
        raise ValueError(f"{len(names)} output names for {n_outputs} channels; give one each")

    mean = y.mean(axis=1)                    # (R, N, l)
    error = mean - model.mean(axis=1)
    signal_ms = np.mean(mean**2, axis=(0, 1))
    if np.any(signal_ms == 0.0):
        raise ValueError("a measured channel is identically zero; its NRMSE is undefined")
    nrmse = 100.0 * np.sqrt(np.mean(error**2, axis=(0, 1)) / signal_ms)
    if periods > 1:
        noise_var = np.sum((y - mean[:, None]) ** 2, axis=1) / (periods - 1)   # (R, N, l)
        floor = 100.0 * np.sqrt(np.mean(noise_var, axis=(0, 1)) / periods / signal_ms)
    else:
        floor = np.full(n_outputs, np.nan)

    period_length = y.shape[2]
    frequencies = np.fft.rfftfreq(period_length, d=1.0 / fs)
    low, high = (0.0, fs / 2.0) if band is None else band
    lines = (frequencies > 0.0) & (frequencies >= low) & (frequencies <= high)
    if not lines.any():
        raise ValueError(f"no DFT line in band {band} Hz at resolution {fs / period_length} Hz")
    scale = 1.0 / np.sqrt(period_length)     # Eq. 6
    spectra = np.fft.rfft(y, axis=2)[:, :, lines] * scale          # (R, P, lines, l)
    mean_spectrum = spectra.mean(axis=1)
    error_spectrum = mean_spectrum - np.fft.rfft(model.mean(axis=1), axis=1)[:, lines] * scale
    if periods > 1:
        line_var = np.sum(np.abs(spectra - mean_spectrum[:, None]) ** 2, axis=1) / (periods - 1)
        noise_spectrum = np.sqrt(np.mean(line_var, axis=0) / periods)
    else:
        noise_spectrum = np.full(mean_spectrum.shape[1:], np.nan)
    return ModelErrors(
        output_names=names,
        nrmse_percent=nrmse,
        noise_floor_percent=floor,
        frequencies=frequencies[lines],
        measured_spectrum=np.sqrt(np.mean(np.abs(mean_spectrum) ** 2, axis=0)),
        error_spectrum=np.sqrt(np.mean(np.abs(error_spectrum) ** 2, axis=0)),
        noise_spectrum=noise_spectrum,
    )
