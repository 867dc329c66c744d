"""Figures of a modelling study and its diagnoses, as PNG bytes.

Compare (measured vs simulated validation outputs), localise (residual spectra against
the noise floor with excited and non-excited lines apart; a residual map of channels by
frequency bands), diagnose (candidates, screening curves) and follow the error history.
Same conventions as :mod:`fnsi.plots`: an explicit Agg canvas per figure, no pyplot.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from fnsi.diagnosis import Diagnosis
from fnsi.plots import new_figure, panel_grid, png_bytes
from fnsi.study import Revision, Study

MAX_PANELS = 6
# A model that could not be simulated: a hatched bar up to the top of the chart, so a
# failure is seen at a glance and never mistaken for a missing bar.
FAILED_STYLE = {"facecolor": "#fbe3e3", "edgecolor": "#b2182b", "hatch": "//"}


def _failed_bars(ax, positions: Sequence[float], values: Sequence[float], reference: float,
                 *, horizontal: bool = False) -> None:
    """Draw the entries of ``values`` that are not finite as failed: a hatched bar of
    length ``reference`` labelled "failed"."""
    failed = [x for x, v in zip(positions, values, strict=True) if not np.isfinite(v)]
    if not failed:
        return
    label = "failed: could not be simulated"
    if horizontal:
        ax.barh(failed, reference, label=label, **FAILED_STYLE)
        for y in failed:
            ax.text(reference, y, " failed", va="center", ha="right", fontsize=8,
                    color=FAILED_STYLE["edgecolor"])
    else:
        ax.bar(failed, reference, label=label, **FAILED_STYLE)
        for x in failed:
            ax.text(x, reference, "failed", ha="center", va="top", fontsize=8,
                    color=FAILED_STYLE["edgecolor"])


def _failed_length(values: Sequence[float], *others: float) -> float:
    """Bar length of a failure: above every finite value shown (100 % if none)."""
    finite = [v for v in (*values, *others) if np.isfinite(v) and v > 0]
    return 2.0 * max(finite) if finite else 100.0


def _worst_channels(revision: Revision, count: int = MAX_PANELS) -> list[int]:
    """Indices of the channels with the largest NRMSE relative to their noise floor."""
    errors = _errors(revision)
    excess = errors.nrmse_percent / np.where(np.isfinite(errors.noise_floor_percent),
                                             errors.noise_floor_percent, 1.0)
    return [int(k) for k in np.argsort(-excess)[:count]]


def _errors(revision: Revision):
    if revision.errors is None:
        raise ValueError(f"revision {revision.number} could not be simulated "
                         f"({revision.failure}); it has no validation errors to plot")
    return revision.errors


def plot_comparison(study: Study, revision: int = -1, *, window_s: float | None = None,
                    channels: Sequence[str] | None = None) -> bytes:
    """Measured vs simulated validation outputs: a time window and the spectrum, both
    without the 0 Hz line (sensor offsets), as the revision was compared.

    Parameters
    ----------
    study : Study
    revision : int
        Revision index (default: the latest).
    window_s : float, optional
        Length of the time window [s]; default a fifth of a period (at most 2 s).
    channels : sequence of str, optional
        Channels to show (default: the worst against their noise floor, up to six).

    Returns
    -------
    bytes
        PNG content.
    """
    rev = study.revisions[revision]
    errors = _errors(rev)
    names = rev.model.output_names
    picks = ([names.index(c) for c in channels] if channels else _worst_channels(rev))
    validation = study.centred_validation.select(outputs=names)   # as it was compared
    unit = study.units.output
    n = validation.period_length
    measured = validation.y[0, -n:]
    simulated = rev.simulated[0]
    fs = validation.fs
    length = min(n, round((window_s or min(n / fs / 5, 2.0)) * fs))
    t = np.arange(length) / fs
    figure = new_figure(11.0, 2.6 * len(picks))
    axes = figure.subplots(len(picks), 2, squeeze=False)
    frequencies = np.fft.rfftfreq(n, 1 / fs)
    top = min(fs / 2, 3 * study.settings.band[1])
    shown = (frequencies > 0) & (frequencies <= top)
    for row, k in enumerate(picks):
        ax_t, ax_f = axes[row]
        ax_t.plot(t, measured[:length, k], color="k", lw=0.9, label="measured")
        ax_t.plot(t, simulated[:length, k], color="tab:red", lw=0.9, ls="--", label="model")
        ax_t.set_ylabel(f"{names[k]} [{unit}]")
        ax_f.set_ylabel(f"Amplitude [{unit}]")
        ax_t.set_title(f"{names[k]}: NRMSE {errors.nrmse_percent[k]:.3g} %", fontsize="medium")
        for data, colour, label in ((measured[:, k], "k", "measured"),
                                    (simulated[:, k], "tab:red", "model")):
            spectrum = np.abs(np.fft.rfft(data)) / math.sqrt(n)
            ax_f.semilogy(frequencies[shown], spectrum[shown], color=colour, lw=0.7,
                          label=label)
        ax_f.grid(True, which="both", alpha=0.3)
        ax_t.grid(True, alpha=0.3)
    axes[0, 0].legend(fontsize="small")
    axes[-1, 0].set_xlabel("Time [s]")
    axes[-1, 1].set_xlabel("Frequency [Hz]")
    figure.suptitle(f"Revision {rev.number} ({rev.note}): validation, measured vs model")
    return png_bytes(figure)


def plot_residual_spectra(study: Study, revision: int = -1,
                          channels: Sequence[str] | None = None) -> bytes:
    """Residual (measured - model) spectra per channel against the noise floor.

    Excited lines (where the validation input has power) and non-excited lines are drawn
    apart, so harmonics a missing nonlinearity creates stand out above the noise.
    """
    rev = study.revisions[revision]
    errors = _errors(rev)
    names = rev.model.output_names
    picks = ([names.index(c) for c in channels] if channels else _worst_channels(rev))
    rows, columns = panel_grid(len(picks))
    figure = new_figure(5.5 * columns, 3.4 * rows)
    axes = np.atleast_1d(figure.subplots(rows, columns, squeeze=False, sharex=True)).ravel()
    f = errors.frequencies
    excited = rev.excited
    for ax, k in zip(axes, picks, strict=False):
        ax.semilogy(f, errors.measured_spectrum[:, k], color="0.75", lw=0.6, label="measured")
        ax.semilogy(f[excited], errors.error_spectrum[excited, k], ".", ms=2.5,
                    color="tab:red", label="residual, excited lines")
        ax.semilogy(f[~excited], errors.error_spectrum[~excited, k], ".", ms=2.5,
                    color="tab:purple", label="residual, non-excited lines")
        ax.semilogy(f, errors.noise_spectrum[:, k], color="k", lw=0.8, label="noise floor")
        ax.set_title(f"{names[k]}: {errors.nrmse_percent[k]:.3g} % "
                     f"(floor {errors.noise_floor_percent[k]:.3g} %)", fontsize="medium")
        ax.grid(True, which="both", alpha=0.3)
        ax.set_xlabel("Frequency [Hz]")
        ax.set_ylabel(f"Amplitude [{study.units.output}]")
    axes[0].legend(fontsize="small", markerscale=3)
    for ax in axes[len(picks):]:
        ax.set_visible(False)
    figure.suptitle(f"Revision {rev.number}: residual spectra against the noise floor")
    return png_bytes(figure)


def residual_map(revision: Revision, bands: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Residual over noise, in dB, per channel and frequency band.

    Returns
    -------
    edges : ndarray, shape (bands + 1,)
        Band edges [Hz].
    excess_db : ndarray, shape (l, bands)
        10 log10 of residual power over noise power in each band (0 dB: at the floor).
    """
    errors = _errors(revision)
    f = errors.frequencies
    edges = np.linspace(f[0], f[-1], bands + 1)
    which = np.clip(np.searchsorted(edges, f, side="right") - 1, 0, bands - 1)
    residual = np.zeros((bands, errors.error_spectrum.shape[1]))
    noise = np.zeros_like(residual)
    np.add.at(residual, which, errors.error_spectrum**2)
    np.add.at(noise, which, np.nan_to_num(errors.noise_spectrum) ** 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        excess = 10 * np.log10(residual / noise)
    return edges, excess.T


def plot_residual_map(study: Study, revision: int = -1, bands: int = 12) -> bytes:
    """Map of residual power over noise (dB), channels x frequency bands: where the model
    fails."""
    rev = study.revisions[revision]
    edges, excess = residual_map(rev, bands)
    names = rev.model.output_names
    figure = new_figure(1.2 + 0.55 * bands, 1.4 + 0.22 * len(names))
    ax = figure.subplots()
    limit = max(float(np.nanmax(np.abs(excess[np.isfinite(excess)]), initial=1.0)), 1.0)
    image = ax.imshow(excess, aspect="auto", cmap="RdBu_r", vmin=-limit, vmax=limit,
                      interpolation="nearest")
    ax.set_yticks(range(len(names)), names, fontsize=7)
    centres = 0.5 * (edges[:-1] + edges[1:])
    ax.set_xticks(range(bands), [f"{c:.0f}" for c in centres], rotation=60, fontsize=7)
    ax.set_xlabel("Band centre [Hz]")
    figure.colorbar(image, ax=ax, label="residual / noise [dB]")
    ax.set_title(f"Revision {rev.number}: where the model fails")
    return png_bytes(figure)


def plot_history(study: Study) -> bytes:
    """Validation NRMSE revision by revision, with the noise floor; a revision whose
    model could not be simulated is drawn as failed."""
    rows = study.history()
    numbers = [r["number"] for r in rows]
    values = [r["nrmse_percent"] or np.nan for r in rows]
    floors = [r["noise_floor_percent"] or np.nan for r in rows]
    figure = new_figure(max(5.0, 1.0 + 1.1 * len(rows)), 4.0)
    ax = figure.subplots()
    ax.bar(numbers, values, color="tab:blue", label="validation NRMSE")
    _failed_bars(ax, numbers, values, _failed_length(values, *floors))
    ax.plot(numbers, floors, "k--", marker="_", ms=20, label="noise floor")
    ax.set_yscale("log")
    ax.set_xticks(numbers, [f"{r['number']}\n{r['note'][:18]}" for r in rows], fontsize=7)
    for x, v in zip(numbers, values, strict=True):
        if np.isfinite(v):
            ax.text(x, v, f"{v:.3g} %", ha="center", va="bottom", fontsize=8)
    ax.set_ylabel("NRMSE [%]")
    ax.set_title("Error history")
    ax.legend(fontsize="small")
    ax.grid(True, which="both", axis="y", alpha=0.3)
    return png_bytes(figure)


def plot_candidates(diagnosis: Diagnosis) -> bytes:
    """Validation NRMSE each candidate reaches, against the revision's and the floor; a
    candidate whose model could not be simulated is drawn as failed."""
    candidates = diagnosis.candidates
    if not candidates:
        raise ValueError("the diagnosis has no candidate to plot")
    labels = [c.effect.value + ("" if c.location is None else f"\n{c.location.label}")
              for c in candidates]
    values = [c.validation_nrmse_percent if math.isfinite(c.validation_nrmse_percent)
              else np.nan for c in candidates]
    figure = new_figure(7.0, 1.2 + 0.55 * len(candidates))
    ax = figure.subplots()
    y = np.arange(len(candidates))[::-1]
    groups = {("tab:green", "claimed"): [c.convincing for c in candidates],
              ("tab:orange", "passes the rule, implausible coefficient"):
                  [c.beats_noise_floor and not c.convincing for c in candidates],
              ("0.6", "not claimed (rule in the summary)"):
                  [not c.beats_noise_floor for c in candidates]}
    for (colour, verdict), members in groups.items():
        if any(members):
            ax.barh(y[members], np.asarray(values)[members], color=colour, label=verdict)
    _failed_bars(ax, y, values, _failed_length(values, diagnosis.nrmse_before_percent),
                 horizontal=True)
    ax.set_yticks(y, labels, fontsize=7)
    ax.axvline(diagnosis.nrmse_before_percent, color="tab:red", label="revision now")
    if math.isfinite(diagnosis.noise_floor_percent):
        ax.axvline(diagnosis.noise_floor_percent, color="k", ls="--", label="noise floor")
    ax.set_xscale("log")
    ax.set_xlabel("Validation NRMSE with the candidate [%]")
    ax.legend(fontsize="small")
    ax.set_title(f"Revision {diagnosis.revision}: candidate missing effects")
    return png_bytes(figure)


def plot_screening(diagnosis: Diagnosis, count: int = 4) -> bytes:
    """Nonparametric spline shapes at the best screened locations (scale arbitrary)."""
    scores = [s for s in diagnosis.locations if s.refined][:count]
    if not scores:
        raise ValueError("the diagnosis screened no location")
    rows, columns = panel_grid(len(scores))
    figure = new_figure(4.6 * columns, 3.3 * rows)
    axes = np.atleast_1d(figure.subplots(rows, columns, squeeze=False)).ravel()
    for ax, score in zip(axes, scores, strict=False):
        ax.plot(score.curve_x, score.curve_shape / max(np.max(np.abs(score.curve_shape)),
                                                       1e-300), color="tab:blue")
        ax.axhline(0, color="0.6", lw=0.6)
        ax.set_title(f"{score.location.label}: explains {100 * score.reduction:.1f} %",
                     fontsize="medium")
        ax.set_xlabel(f"Relative displacement [{diagnosis.units.length}]")
        ax.set_ylabel("Force shape [-]")
        ax.grid(True, alpha=0.3)
    for ax in axes[len(scores):]:
        ax.set_visible(False)
    figure.suptitle("Screening: spline restoring-force shapes (automatic knots)")
    return png_bytes(figure)


def study_figures(study: Study, revision: int = -1) -> dict[str, bytes]:
    """All figures of a revision plus the history, keyed by artefact file name."""
    number = study.revisions[revision].number
    figures = {"history.png": plot_history(study)}
    if study.revisions[revision].errors is not None:
        figures |= {
            f"revision-{number}-comparison.png": plot_comparison(study, revision),
            f"revision-{number}-residual-spectra.png": plot_residual_spectra(study, revision),
            f"revision-{number}-residual-map.png": plot_residual_map(study, revision),
        }
    return figures


def diagnosis_figures(diagnosis: Diagnosis) -> dict[str, bytes]:
    """Figures of a diagnosis keyed by artefact file name."""
    from fnsi.plots import plot_stiffness

    figures = {"screening.png": plot_screening(diagnosis)}
    if diagnosis.candidates:
        figures["candidates.png"] = plot_candidates(diagnosis)
    if diagnosis.curves:
        figures["stiffness.png"] = plot_stiffness(
            list(diagnosis.curves), title="Nonparametric stiffness at the top locations",
            units=diagnosis.units)
    return figures
