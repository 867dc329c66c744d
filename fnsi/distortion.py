"""Nonlinear distortion analysis, before any model is chosen.

From a periodic record of P periods and R realisations, per output and DFT line of one
period: the best linear approximation (BLA) G(k), the noise level (period to period) and
the level of the stochastic nonlinear distortions (realisation to realisation), after
Pintelon and Schoukens' nonparametric method (System Identification: a Frequency Domain
Approach, 2nd ed., Wiley 2012, ch. 3-4). On the lines the input does not excite (the
detection lines of a random-odd multisine, and the lines above the band) the output holds
only noise and nonlinear distortion; with an odd multisine, odd laws (cubic springs,
symmetric stops, friction) put energy on the odd lines only and even laws (quadratic
springs, one-sided or asymmetric stops) on the even ones.

Every level is output-referred, in the output's unit (DFT of Eq. 6, scaled 1/sqrt(N)), so
noise, distortions and response compare on one axis. A group of lines is called above
the noise by an F test of the ratio of its output power to its noise power (the noise
from the period-to-period scatter), at 0.1 % false-alarm probability and at least 1 dB.

Array convention: per-line arrays are (lines, outputs); the excitation mask is
(realisations, lines).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from fnsi.measurement import Measurement
from fnsi.spectra import kept_record

#: False-alarm probability of the F test that calls a group of lines above the noise.
FALSE_ALARM = 1e-3
#: Smallest level [dB] over the noise worth a word: below it a model gains nothing.
MIN_LEVEL_DB = 1.0
#: Smallest power gap [dB] that separates excited lines from lines the input leaves out.
EXCITATION_GAP_DB = 10.0
#: Out-of-band lines examined: up to this multiple of the highest excited frequency.
HARMONICS = 3


@dataclass(frozen=True)
class LineGroup:
    """Output power against noise power over a group of lines of one output.

    Attributes
    ----------
    lines : int
        Lines in the group (0: the excitation leaves no such line).
    level_db : float
        10 log10(output power / noise power) [dB]; 0 dB is noise alone. NaN when empty.
    p_value : float
        Probability of a level this high from noise alone (F test). NaN when empty.
    """

    lines: int
    level_db: float
    p_value: float

    @property
    def above_noise(self) -> bool:
        """Significant (p below :data:`FALSE_ALARM`) and at least :data:`MIN_LEVEL_DB`."""
        return bool(self.lines and self.p_value < FALSE_ALARM
                    and self.level_db >= MIN_LEVEL_DB)


@dataclass(frozen=True)
class ChannelDistortion:
    """The distortion levels of one output.

    Attributes
    ----------
    name : str
        Output channel.
    excited : LineGroup
        Excited lines in the band: total scatter of the BLA over realisations against
        its noise scatter (needs R >= 2 and one input; else empty).
    odd, even : LineGroup
        Non-excited odd and even lines in the band. With an excitation that excites
        even lines too, both hold odd and even distortions alike.
    above_band : LineGroup
        Lines above the band, up to :data:`HARMONICS` times its upper edge (harmonics).
    """

    name: str
    excited: LineGroup
    odd: LineGroup
    even: LineGroup
    above_band: LineGroup


@dataclass(frozen=True)
class DistortionAnalysis:
    """Nonparametric BLA and distortion levels of a periodic measurement.

    Attributes
    ----------
    frequencies : ndarray, shape (K,)
        Frequencies of the analysed lines of one period [Hz] (line 1 up to
        :data:`HARMONICS` times the band's upper edge, below Nyquist).
    excited : ndarray of bool, shape (R, K)
        Line k carries the input in realisation r.
    band : (float, float)
        Lowest and highest excited frequency [Hz].
    odd_design : bool
        Only odd lines are excited, so odd and even distortions can be told apart.
    output : ndarray, shape (K, l)
        RMS over realisations of the period-averaged output spectrum [output unit].
    noise : ndarray, shape (K, l)
        Standard deviation of the period-averaged output spectrum due to noise
        [output unit], from the period-to-period scatter.
    distortion : ndarray, shape (K, l)
        Standard deviation of the stochastic nonlinear distortions of the output of one
        realisation [output unit] on the excited lines; NaN elsewhere, or everywhere
        when R < 2 or the record has several inputs.
    bla : ndarray, shape (K, l), complex, or None
        Best linear approximation [output unit per input unit] on the excited lines
        (NaN elsewhere); None with several inputs (it then needs one experiment per
        input per realisation).
    channels : tuple of ChannelDistortion
        The per-output summary.
    realisations, periods : int
        R and the periods kept.
    output_names : tuple of str
    unit : str
        Unit of the outputs, which every level is referred to (:mod:`fnsi.units`).
    """

    frequencies: np.ndarray
    excited: np.ndarray
    band: tuple[float, float]
    odd_design: bool
    output: np.ndarray
    noise: np.ndarray
    distortion: np.ndarray
    bla: np.ndarray | None
    channels: tuple[ChannelDistortion, ...]
    realisations: int
    periods: int
    output_names: tuple[str, ...]
    unit: str = "output unit"

    @property
    def verdict(self) -> str:
        """One paragraph with the numbers: how nonlinear, which class, what can be told."""
        return _verdict(self)

    def to_json(self) -> dict:
        """The summary as JSON: band [Hz], design, levels [dB] and p-values per output and
        group of lines, and the verdict (the per-line levels stay in the arrays)."""
        def group(g: LineGroup) -> dict:
            finite = g.lines > 0
            return {"lines": g.lines, "level_db": round(g.level_db, 2) if finite else None,
                    "p_value": float(f"{g.p_value:.3g}") if finite else None,
                    "above_noise": g.above_noise}

        return {"band_hz": list(self.band), "odd_design": self.odd_design, "unit": self.unit,
                "realisations": self.realisations, "periods": self.periods,
                "channels": [{"name": c.name, "excited": group(c.excited),
                              "odd": group(c.odd), "even": group(c.even),
                              "above_band": group(c.above_band)} for c in self.channels],
                "verdict": self.verdict}


def analyse_distortion(measurement: Measurement, *, discard_periods: int = 1,
                       excited: np.ndarray | None = None) -> DistortionAnalysis:
    """Nonparametric BLA, noise and nonlinear distortion levels of a periodic record.

    Parameters
    ----------
    measurement : Measurement
        P periods of R realisations; at least two periods must remain after
        ``discard_periods``.
    discard_periods : int
        Leading transient periods left out.
    excited : ndarray of bool, shape (R, N // 2 + 1), optional
        Which lines of one period the excitation drives in each realisation; default
        found from the input spectra (the lines above the largest gap of at least
        :data:`EXCITATION_GAP_DB` in their sorted power).

    Returns
    -------
    DistortionAnalysis

    Raises
    ------
    ValueError
        Fewer than two periods kept, or no excited line.

    Examples
    --------
    >>> from fnsi.excitation import multisine
    >>> u = np.tile(multisine(256, 256.0, (2.0, 40.0), 1.0, lines="odd", detection=4)[0], 4)
    >>> noise = 1e-3 * np.random.default_rng(0).standard_normal((u.size, 2))
    >>> y = np.column_stack([u + 0.1 * u**3, u]) + noise   # a cubic and a linear output
    >>> m = Measurement.from_arrays(u, y, 256.0, periods=4)
    >>> a = analyse_distortion(m, discard_periods=0)
    >>> [c.odd.above_noise for c in a.channels], a.channels[0].even.above_noise
    ([True, False], False)
    """
    kept = check_periods(measurement.periods, discard_periods)
    N = measurement.period_length
    U = _period_spectra(kept_record(measurement.u, measurement.periods, discard_periods), kept)
    Y = _period_spectra(kept_record(measurement.y, measurement.periods, discard_periods), kept)
    driven = _excited_lines(U) if excited is None else _checked_mask(excited, U.shape)
    frequencies = np.arange(U.shape[2]) * measurement.fs / N
    lines = _analysed_lines(driven, frequencies, measurement.fs)
    U, Y, driven, frequencies = U[:, :, lines], Y[:, :, lines], driven[:, lines], \
        frequencies[lines]
    return _analysis(measurement, U, Y, driven, frequencies, lines)


def check_periods(periods: int, discard_periods: int) -> int:
    """Periods kept after ``discard_periods``; ValueError unless at least two (the noise
    comes from their scatter)."""
    if discard_periods < 0:
        raise ValueError(f"discard_periods must be >= 0; got {discard_periods}")
    kept = periods - discard_periods
    if kept < 2:
        raise ValueError(f"the distortion analysis needs at least two periods after the "
                         f"{discard_periods} discarded; the record has {periods}: measure "
                         "more periods (the noise comes from their scatter) or discard fewer")
    return kept


def _period_spectra(x: np.ndarray, periods: int) -> np.ndarray:
    """DFT of each period (Eq. 6 scaling): (R, P, N // 2 + 1, channels)."""
    R, n, c = x.shape
    N = n // periods
    return np.fft.rfft(x.reshape(R, periods, N, c), axis=2) / np.sqrt(N)


def _excited_lines(U: np.ndarray) -> np.ndarray:
    """Lines above the largest power gap (>= EXCITATION_GAP_DB) of the input spectra."""
    power = np.sum(np.abs(U.mean(axis=1)) ** 2, axis=-1)  # (R, lines)
    power[:, 0] = 0.0  # the mean is never an excitation line
    # Exact zeros and rounding residue (~1e-30 of the excited power) all sit at -200 dB.
    level = 10 * np.log10(np.maximum(power, 1e-20 * power.max()))
    ordered = np.sort(level.ravel())
    gaps = np.diff(ordered)
    if gaps.size == 0 or gaps.max() < EXCITATION_GAP_DB:
        raise ValueError("cannot tell the excited lines from the others: the input's line "
                         "powers show no gap of 10 dB; is the input a periodic multisine "
                         "measured over whole periods?")
    threshold = ordered[np.argmax(gaps) + 1]
    return level >= threshold


def excited_band(measurement: Measurement, discard_periods: int = 1) -> tuple[float, float]:
    """Lowest and highest frequency the input excites [Hz]: the default analysis band.

    Parameters
    ----------
    measurement : Measurement
        Periodic record; its input lines above the largest power gap of 10 dB are the
        excited ones (:func:`_excited_lines`).
    discard_periods : int
        Leading transient periods left out (none when the record has only that many).

    Raises
    ------
    ValueError
        When the input shows no such gap (not a periodic multisine over whole periods),
        saying to give the band.
    """
    drop = discard_periods if measurement.periods > discard_periods else 0
    kept = measurement.periods - drop
    U = _period_spectra(kept_record(measurement.u, measurement.periods, drop), kept)
    try:
        driven = _excited_lines(U).any(axis=0)
    except ValueError as error:
        raise ValueError(f"{error} Give the analysis band explicitly (--band LOW HIGH).") \
            from None
    frequencies = np.fft.rfftfreq(measurement.period_length, d=1.0 / measurement.fs)
    return float(frequencies[driven].min()), float(frequencies[driven].max())


def _checked_mask(excited: np.ndarray, shape: tuple[int, ...]) -> np.ndarray:
    mask = np.asarray(excited, dtype=bool)
    if mask.ndim == 1:
        mask = np.broadcast_to(mask, (shape[0], mask.size))
    if mask.shape != (shape[0], shape[2]):
        raise ValueError(f"excited must have shape (realisations, lines of one period) = "
                         f"{(shape[0], shape[2])}; got {mask.shape}")
    return mask


def _analysed_lines(driven: np.ndarray, frequencies: np.ndarray, fs: float) -> np.ndarray:
    """Line 1 up to HARMONICS times the highest excited line, below Nyquist."""
    if not driven.any():
        raise ValueError("no line of the input is excited")
    top = frequencies[driven.any(axis=0)].max()
    keep = (frequencies > 0) & (frequencies <= HARMONICS * top) & (frequencies < fs / 2)
    return np.flatnonzero(keep)


def _analysis(measurement: Measurement, U: np.ndarray, Y: np.ndarray, driven: np.ndarray,
              frequencies: np.ndarray, lines: np.ndarray) -> DistortionAnalysis:
    R, P = Y.shape[:2]
    Ybar = Y.mean(axis=1)                                              # (R, K, l)
    noise_var = np.sum(np.abs(Y - Ybar[:, None]) ** 2, axis=1) / (P * (P - 1))
    in_band = driven.any(axis=0)
    low, high = frequencies[in_band].min(), frequencies[in_band].max()
    odd_design = bool(np.all(lines[in_band] % 2 == 1))
    bla, total_var, bla_noise_var = _bla(U.mean(axis=1), Ybar, noise_var, driven)
    distortion = np.full(Ybar.shape[1:], np.nan)
    if total_var is not None:
        u_power = np.mean(np.abs(U.mean(axis=1)[..., 0]) ** 2, axis=0)[:, None]
        distortion = np.sqrt(np.maximum(R * (total_var - bla_noise_var), 0.0) * u_power)
    groups = _groups(lines, driven, frequencies, low, high, odd_design)
    channels = tuple(
        ChannelDistortion(
            name=name,
            excited=_excited_group(total_var, bla_noise_var, in_band & groups["band"], j, R, P),
            odd=_detection_group(Ybar, noise_var, groups["odd"], j, P),
            even=_detection_group(Ybar, noise_var, groups["even"], j, P),
            above_band=_detection_group(Ybar, noise_var, groups["above"], j, P))
        for j, name in enumerate(measurement.output_names))
    return DistortionAnalysis(
        frequencies=frequencies, excited=driven, band=(float(low), float(high)),
        odd_design=odd_design, output=np.sqrt(np.mean(np.abs(Ybar) ** 2, axis=0)),
        noise=np.sqrt(noise_var.mean(axis=0)), distortion=distortion, bla=bla,
        channels=channels, realisations=R, periods=P, output_names=measurement.output_names,
        unit=measurement.units.output)


def _bla(Ubar: np.ndarray, Ybar: np.ndarray, noise_var: np.ndarray, driven: np.ndarray):
    """BLA and its total and noise variances on lines excited in every realisation.

    G_r = Ybar_r / Ubar_r; BLA = mean over r; total variance of the mean from the
    scatter over r (needs R >= 2); noise variance from each G_r's period scatter.
    Single input only (None, None, None otherwise).
    """
    if Ubar.shape[-1] != 1:
        return None, None, None
    R = Ubar.shape[0]
    every = driven.all(axis=0)
    with np.errstate(divide="ignore", invalid="ignore"):
        G = np.where(driven[..., None], Ybar / Ubar, np.nan)
        G_noise = np.where(driven[..., None], noise_var / np.abs(Ubar) ** 2, np.nan)
    bla = np.where(every[:, None], G.mean(axis=0), np.nan)
    if R < 2:
        return bla, None, None
    total = np.sum(np.abs(G - bla) ** 2, axis=0) / (R * (R - 1))
    noise = G_noise.sum(axis=0) / R**2
    return bla, np.where(every[:, None], total, np.nan), np.where(every[:, None], noise, np.nan)


def _groups(lines, driven, frequencies, low, high, odd_design) -> dict[str, np.ndarray]:
    """Masks (R, K) of the non-excited odd and even lines in the band and of the lines
    above it, and (K,) of the band."""
    band = (frequencies >= low) & (frequencies <= high)
    quiet = ~driven
    return {"band": band,
            "odd": quiet & band & (lines % 2 == 1),
            "even": quiet & band & (lines % 2 == 0),
            "above": quiet & (frequencies > high)}


def _f_group(lines: int, power: float, noise: float, dof_signal: int,
             dof_noise: int) -> LineGroup:
    """Level and F-test p-value of ``power`` (dof_signal) against ``noise`` (dof_noise)."""
    ratio = power / noise if noise > 0 else np.inf
    return LineGroup(lines=lines, level_db=float(10 * np.log10(ratio)),
                     p_value=float(stats.f.sf(ratio, dof_signal, dof_noise)))


def _detection_group(Ybar, noise_var, mask, j: int, P: int) -> LineGroup:
    """Output power over noise power on the masked (R, K) lines of output j.

    Under noise alone |Ybar|^2 is sigma^2/2 chi2(2) per line and the period-scatter
    estimate sigma^2/(2(P-1)) chi2(2(P-1)), so their ratio of sums is F(2n, 2n(P-1)).
    """
    n = int(mask.sum())
    if n == 0:
        return LineGroup(0, float("nan"), float("nan"))
    power = float(np.sum(np.abs(Ybar[..., j][mask]) ** 2))
    noise = float(np.sum(noise_var[..., j][mask]))
    return _f_group(n, power, noise, 2 * n, 2 * n * (P - 1))


def _excited_group(total_var, noise_var, mask, j: int, R: int, P: int) -> LineGroup:
    """Total over noise variance of the BLA on the excited lines of output j: F(2n(R-1),
    2nR(P-1)) under noise alone."""
    if total_var is None:
        return LineGroup(0, float("nan"), float("nan"))
    keep = mask & np.isfinite(total_var[:, j])
    n = int(keep.sum())
    if n == 0:
        return LineGroup(0, float("nan"), float("nan"))
    return _f_group(n, float(total_var[keep, j].sum()), float(noise_var[keep, j].sum()),
                    2 * n * (R - 1), 2 * n * R * (P - 1))


def _strongest(analysis: DistortionAnalysis, group: str) -> ChannelDistortion | None:
    found = [c for c in analysis.channels if getattr(c, group).above_noise]
    return max(found, key=lambda c: getattr(c, group).level_db) if found else None


def _names(analysis: DistortionAnalysis, group: str) -> str:
    names = [c.name for c in analysis.channels if getattr(c, group).above_noise]
    return ", ".join(names[:6]) + (f" and {len(names) - 6} more" if len(names) > 6 else "")


def _verdict(analysis: DistortionAnalysis) -> str:
    low, high = analysis.band
    span = f"between {low:.3g} and {high:.3g} Hz"
    words = []
    if analysis.odd_design:
        odd, even = _strongest(analysis, "odd"), _strongest(analysis, "even")
        for kind, best, group in (("odd", odd, "odd"), ("even", even, "even")):
            if best is None:
                continue
            level = getattr(best, group).level_db
            words.append(f"{kind} nonlinear distortions up to {level:.0f} dB above the noise "
                         f"{span} ({_names(analysis, group)}): a nonlinear model can gain up "
                         f"to about {level:.0f} dB there")
        if odd and not even:
            words.append("no even distortions above the noise: the law looks symmetric "
                         "(cubic stiffness, symmetric clearance, friction)")
        elif even:
            words.append("even distortions above the noise: an asymmetric law acts "
                         "(quadratic stiffness, one-sided or asymmetric stop)")
    else:
        for group, where in (("odd", "non-excited"), ("even", "non-excited")):
            best = _strongest(analysis, group)
            if best is not None:
                words.append(f"nonlinear distortions up to {getattr(best, group).level_db:.0f}"
                             f" dB above the noise on {where} lines {span}")
                break
        words.append("the input excites even lines too, so odd and even laws cannot be "
                     "told apart; an odd random-phase multisine with detection lines "
                     "(fnsi.excitation.multisine(lines='odd', detection=4)) tells them apart")
    best = _strongest(analysis, "excited")
    if best is not None:
        words.append(f"on the excited lines the BLA scatters {best.excited.level_db:.0f} dB "
                     f"above its noise over the {analysis.realisations} realisations "
                     f"({_names(analysis, 'excited')})")
    elif analysis.realisations < 2:
        words.append("with one realisation the distortions on the excited lines cannot be "
                     "told from the BLA: measure several random-phase realisations")
    above = _strongest(analysis, "above_band")
    if above is not None:
        words.append(f"harmonics above the band up to {above.above_band.level_db:.0f} dB "
                     f"above the noise ({_names(analysis, 'above_band')})")
    groups = ("excited", "odd", "even", "above_band")
    if not any(getattr(c, g).lines for c in analysis.channels for g in groups):
        words.insert(0, _unexamined_words(analysis, span))
    elif not any(getattr(c, g).above_noise for c in analysis.channels for g in groups):
        words.insert(0, f"no nonlinear distortion above the noise {span}: a linear model "
                        "explains these data to the noise")
    return "; ".join(words) + "."


def _unexamined_words(analysis: DistortionAnalysis, span: str) -> str:
    """The verdict's words when no line could show a distortion: every analysed line is
    excited (no detection line, nothing above the band below Nyquist) and the BLA's
    scatter over realisations cannot be measured (one realisation, or several inputs).
    Such data say nothing either way: "a linear model explains them" would be false (the
    hidden benchmark's seed 35 case 4, 2 realisations of 2 inputs, a stop leaving the
    linear model 33 % off, was told so)."""
    if analysis.realisations < 2:
        why = "one realisation"
    else:
        why = (f"{analysis.realisations} realisations of several inputs (it needs several "
               f"realisations of each input driving alone)")
    return (f"no line {span} can show a nonlinear distortion: the input excites every "
            f"one, and the scatter of the best linear approximation cannot be measured "
            f"with {why}; these data cannot tell a linear structure from a nonlinear one")
