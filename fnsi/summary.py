"""What a measurement contains: channels, periods, RMS and SNR per channel.

The service computes it once, when a dataset enters its store; `fnsi info` prints it.
"""

from __future__ import annotations

import numpy as np

from fnsi.measurement import Measurement

# Period-to-period deviation of the input below this fraction of its RMS means the input
# repeats: measured forces carry a few percent of noise at most, while two periods of a
# random-phase multisine differ by about sqrt(2) times the RMS.
_PERIODIC_TOLERANCE = 0.1


def detect_periods(u: np.ndarray, max_periods: int = 1024) -> int:
    """Largest number of identical periods found in an input record.

    Parameters
    ----------
    u : ndarray, shape (realisations, samples, m)
        Input forces [N].
    max_periods : int
        Largest period count tried.

    Returns
    -------
    int
        The largest P dividing ``samples`` such that every period deviates from the mean
        period by less than 10 % of the input RMS; 1 when the input does not repeat.
    """
    n = u.shape[1]
    rms = float(np.sqrt(np.mean(u**2)))
    if rms == 0.0:
        return 1
    for periods in range(min(max_periods, n // 2), 1, -1):
        if n % periods:
            continue
        blocks = u.reshape(u.shape[0], periods, n // periods, u.shape[2])
        deviation = np.sqrt(np.mean((blocks - blocks.mean(axis=1, keepdims=True)) ** 2))
        if deviation < _PERIODIC_TOLERANCE * rms:
            return periods
    return 1


def snr_db(x: np.ndarray, periods: int) -> np.ndarray | None:
    """Signal-to-noise ratio per channel from the period-to-period variation [dB].

    Parameters
    ----------
    x : ndarray, shape (realisations, samples, channels)
        Periodic record.
    periods : int
        Periods per realisation.

    Returns
    -------
    ndarray, shape (channels,) or None
        10 log10(signal power / noise power), where the noise is the deviation of each
        period from the mean period (unbiased, P - 1 degrees of freedom) and the signal is
        the mean period with the noise share removed. The first period is left out as a
        transient when P >= 3. None with fewer than two usable periods.
    """
    blocks = x.reshape(x.shape[0], periods, x.shape[1] // periods, x.shape[2])
    if periods >= 3:
        blocks = blocks[:, 1:]
    p = blocks.shape[1]
    if p < 2:
        return None
    mean = blocks.mean(axis=1)
    noise = np.sum((blocks - mean[:, None]) ** 2, axis=(0, 1, 2)) / (
        (p - 1) * blocks.shape[0] * blocks.shape[2]
    )
    signal = np.mean(mean**2, axis=(0, 1)) - noise / p
    with np.errstate(divide="ignore", invalid="ignore"):  # silent and constant channels
        ratio = 10.0 * np.log10(np.maximum(signal, 0.0) / noise)
    return ratio


def channel_rms(x: np.ndarray) -> np.ndarray:
    """Root mean square of each channel, finite for every finite record.

    Parameters
    ----------
    x : ndarray, shape (realisations, samples, channels)

    Returns
    -------
    ndarray, shape (channels,)
        sqrt(mean(x^2)), computed as peak * sqrt(mean((x / peak)^2)) so that squares of
        samples beyond 1e154 do not overflow to infinity.
    """
    peak = np.max(np.abs(x), axis=(0, 1))
    scale = np.where(peak > 0, peak, 1.0)
    return scale * np.sqrt(np.mean((x / scale) ** 2, axis=(0, 1)))


def summarize(measurement: Measurement, periods_source: str) -> dict:
    """JSON summary of a measurement, as returned by the dataset routes.

    Parameters
    ----------
    measurement : Measurement
        The validated record.
    periods_source : {"declared", "detected"}
        Whether ``measurement.periods`` came from the file or meta, or from
        :func:`detect_periods`.
    """
    channels = []
    for role, x, names, units, quantity in (
        ("input", measurement.u, measurement.input_names, measurement.input_units, "force"),
        ("output", measurement.y, measurement.output_names, measurement.output_units,
         measurement.quantity),
    ):
        rms = channel_rms(x)
        snr = snr_db(x, measurement.periods)
        for k, name in enumerate(names):
            value = None if snr is None or not np.isfinite(snr[k]) else round(float(snr[k]), 2)
            channels.append({"name": name, "role": role, "quantity": quantity,
                             "unit": units[k] or None, "rms": float(rms[k]), "snr_db": value})
    return {
        "fs": measurement.fs,
        "samples": measurement.n_samples,
        "realisations": measurement.n_realisations,
        "periods": measurement.periods,
        "periods_source": periods_source,
        "period_length": measurement.period_length,
        "quantity": measurement.quantity,
        "inputs": list(measurement.input_names),
        "outputs": list(measurement.output_names),
        "channels": channels,
    }
