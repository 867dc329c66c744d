"""Figures of an identification, as PNG bytes (paper Figures 5-12).

Every function builds a :class:`matplotlib.figure.Figure` on an explicit Agg canvas and
returns the PNG file content: no display, no pyplot, no global matplotlib state, so the
functions are safe in worker processes and threads. Figures are sized for 100 dpi.

Array conventions as everywhere in :mod:`fnsi`: FRF (lines, outputs, inputs), nonlinear
coefficients (lines, basis functions), frequencies in Hz.
"""

from __future__ import annotations

import io
import textwrap
from collections.abc import Sequence

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from fnsi.distortion import DistortionAnalysis
from fnsi.errors import ModelErrors
from fnsi.nonlinear import NonlinearElement, NonlinearityKind
from fnsi.stabilisation import PoleClass, StabilisationDiagram
from fnsi.stiffness import StiffnessCurve
from fnsi.units import ModelUnits

DPI = 100
#: Characters per line of a warning written in a 5-inch stiffness panel (small font).
WARNING_CHARACTERS = 60

#: Marker, colour, size and legend text of each class, after the paper's Figure 5.
_POLE_STYLE: dict[PoleClass, tuple[str, str, float, str]] = {
    PoleClass.NEW: (".", "0.55", 20, "new pole"),
    PoleClass.FREQUENCY: ("x", "tab:blue", 22, "stable frequency"),
    PoleClass.DAMPING: ("s", "tab:orange", 22, "+ damping"),
    PoleClass.SHAPE: ("o", "tab:green", 24, "+ MACX"),
    PoleClass.STABLE: ("^", "tab:red", 30, "fully stable"),
}


def new_figure(width: float, height: float) -> Figure:
    """A figure of ``width`` x ``height`` inches on its own Agg canvas."""
    figure = Figure(figsize=(width, height), dpi=DPI, layout="constrained")
    FigureCanvasAgg(figure)
    return figure


def png_bytes(figure: Figure) -> bytes:
    """PNG content of a figure."""
    buffer = io.BytesIO()
    figure.savefig(buffer, format="png", dpi=DPI)
    return buffer.getvalue()


def panel_grid(count: int, columns: int = 2) -> tuple[int, int]:
    """Rows and columns of a panel grid for ``count`` panels."""
    columns = min(columns, count)
    return -(-count // columns), columns


def output_panels(names: Sequence[str], valid: Sequence[str], width: float,
                  height: float) -> tuple[Figure, np.ndarray]:
    """A figure with one ``width`` x ``height`` inch panel per output in ``names``.

    Raises
    ------
    ValueError
        ``names`` is empty or names a channel not in ``valid``.
    """
    unknown = [name for name in names if name not in valid]
    if unknown or not names:
        raise ValueError(f"unknown or no outputs {unknown}; choose among {list(valid)}")
    rows, columns = panel_grid(len(names))
    figure = new_figure(width * columns, height * rows)
    return figure, np.atleast_1d(figure.subplots(rows, columns, squeeze=False)).ravel()


def confirmed_points(diagram: StabilisationDiagram) -> np.ndarray:
    """(frequency [Hz], order) of every pole in the band that the following orders
    confirm (``modes.confirmed``, :func:`fnsi.stabilisation.confirmed_poles`), shape (k, 2)."""
    low, high = diagram.band
    points = [(f, p.order) for p in diagram.poles if p.modes.confirmed is not None
              for f, c in zip(p.modes.frequencies, p.modes.confirmed, strict=True)
              if c and low <= f <= high]
    return np.array(points, dtype=float).reshape(-1, 2)


def plot_stabilisation(
    diagram: StabilisationDiagram,
    *,
    frf: tuple[np.ndarray, np.ndarray] | None = None,
    singular_values: np.ndarray | None = None,
    order: int | None = None,
    title: str = "Stabilisation diagram",
    frf_unit: str = "output unit/input unit",
) -> bytes:
    """Stabilisation diagram: poles over frequency and model order (paper Figure 5).

    Symbols as in the paper, each pole against the order below: dot new pole, cross
    stable in frequency, square + damping, circle + MACX, triangle fully stable. A black
    ring marks the poles the orders above confirm (:func:`confirmed_points`, the
    result's ``confirmed``): at the chosen order a mode can be new against the order
    below and confirmed by the orders above. The chosen order is marked by a line.

    Parameters
    ----------
    diagram : StabilisationDiagram
        The diagram.
    frf : (ndarray, ndarray), optional
        Background curve: frequencies [Hz] (lines,) and a magnitude (lines,), e.g. the sum
        of the measured FRF magnitudes over outputs and inputs, on a log axis.
    singular_values : ndarray, shape (k,), optional
        Singular values of the decomposition (sigma_1 >= sigma_2 ...), shown beside the
        diagram against the order n = 1..k.
    order : int, optional
        Order to mark; default ``diagram.auto_order``.
    title : str
        Figure title.
    frf_unit : str
        Unit of the background FRF magnitude (:attr:`fnsi.units.ModelUnits.frf`).

    Returns
    -------
    bytes
        PNG content.
    """
    figure = new_figure(10.0 if singular_values is not None else 9.0, 6.0)
    if singular_values is not None:
        ax, ax_sv = figure.subplots(1, 2, sharey=True, width_ratios=(5, 1))
    else:
        ax, ax_sv = figure.subplots(), None
    low, high = diagram.band
    if frf is not None:
        frequencies, magnitude = (np.asarray(a, dtype=float) for a in frf)
        background = ax.twinx()
        background.semilogy(frequencies, magnitude, color="0.75", lw=1.0, zorder=0)
        background.set_ylabel(f"sum of FRF magnitudes [{frf_unit}]")
        ax.set_zorder(background.get_zorder() + 1)
        ax.patch.set_visible(False)
    for cls, (marker, colour, size, label) in _POLE_STYLE.items():
        points = [
            (f, p.order)
            for p in diagram.poles
            for f, c in zip(p.modes.frequencies, p.classes, strict=True)
            if c is cls and low <= f <= high
        ]
        if points:
            f, n = np.array(points).T
            if marker in ("o", "s", "^"):   # hollow, as in the paper
                style = {"facecolors": "none", "edgecolors": colour}
            else:
                style = {"color": colour}
            ax.scatter(f, n, marker=marker, s=size, linewidths=1.0, label=label, **style)
    confirmed = confirmed_points(diagram)
    if confirmed.size:
        ax.scatter(*confirmed.T, marker="o", s=110, facecolors="none", edgecolors="k",
                   linewidths=0.8, label="confirmed (by the orders above)")
    chosen = diagram.auto_order if order is None else order
    if chosen is not None:
        ax.axhline(chosen, color="k", lw=0.8, ls="--", label=f"chosen order {chosen}")
    ax.set_xlim(low, high)
    ax.set_ylim(0, max(diagram.orders) + 2)
    ax.set_xlabel("Frequency [Hz]")
    ax.set_ylabel("Model order n")
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:   # below the axes: poles fill the whole plane
        ax.legend(loc="upper center", bbox_to_anchor=(0.5, -0.09), ncols=4,
                  fontsize="small", frameon=False, title_fontsize="small",
                  title="symbols: each pole against the order below; ring: the result's "
                        "confirmed, stable over the orders above")
    ax.set_title(title)
    if ax_sv is not None:
        sv = np.asarray(singular_values, dtype=float)
        ax_sv.semilogx(sv / sv[0], np.arange(1, sv.size + 1), ".-", color="tab:purple",
                       ms=3)
        ax_sv.set_xlabel("sigma_n / sigma_1 [-]")
        ax_sv.set_title("Singular values")
        ax_sv.grid(True, alpha=0.3)
    return png_bytes(figure)


def plot_frf(
    frequencies: np.ndarray,
    measured: np.ndarray,
    model: np.ndarray,
    *,
    output_names: Sequence[str],
    input_names: Sequence[str],
    pairs: Sequence[tuple[str, str]] | None = None,
    unit: str = "output unit/input unit",
    title: str = "Measured and model FRF",
) -> bytes:
    """Magnitude and phase of measured and model FRFs, one column per (output, input) pair.

    Parameters
    ----------
    frequencies : ndarray, shape (lines,)
        Frequencies [Hz].
    measured, model : ndarray, shape (lines, l, m), complex
        Measured (e.g. nonparametric, averaged over periods) and model FRFs.
    output_names, input_names : sequence of str
        Names of the l outputs and m inputs.
    pairs : sequence of (output, input), optional
        Pairs to draw; default the first four.
    unit : str
        FRF unit for the axis label (:attr:`fnsi.units.ModelUnits.frf`).
    title : str
        Figure title.

    Returns
    -------
    bytes
        PNG content.
    """
    measured = np.asarray(measured)
    model = np.asarray(model)
    if measured.shape != model.shape or measured.ndim != 3:
        raise ValueError(f"measured and model FRFs must both be (lines, outputs, inputs); "
                         f"got {measured.shape} and {model.shape}")
    outputs, inputs = list(output_names), list(input_names)
    if pairs is None:
        pairs = [(o, i) for i in inputs for o in outputs][:4]
    unknown = [p for p in pairs if p[0] not in outputs or p[1] not in inputs]
    if unknown:
        raise ValueError(f"unknown (output, input) pairs {unknown}; outputs {outputs}, "
                         f"inputs {inputs}")
    figure = new_figure(max(4.5 * len(pairs), 6.0), 6.0)
    axes = figure.subplots(2, len(pairs), sharex=True, squeeze=False, height_ratios=(2, 1))
    for column, (out, inp) in enumerate(pairs):
        h_meas = measured[:, outputs.index(out), inputs.index(inp)]
        h_model = model[:, outputs.index(out), inputs.index(inp)]
        magnitude, phase = axes[0, column], axes[1, column]
        curves = (("measured", np.abs(h_meas), {"color": "k", "lw": 1.0}),
                  ("model", np.abs(h_model), {"color": "tab:blue", "lw": 1.2, "ls": "--"}),
                  ("difference", np.abs(h_meas - h_model),
                   {"color": "tab:red", "lw": 0.8, "alpha": 0.8}))
        magnitude.set_yscale("log")
        # a curve with no finite positive value (an overflowed record) has no log scale
        drawn = [magnitude.plot(frequencies, values, label=label, **style)
                 for label, values, style in curves if np.any(np.isfinite(values) & (values > 0))]
        if not drawn:
            magnitude.text(0.5, 0.5, "no finite FRF magnitude to draw", ha="center",
                           va="center", transform=magnitude.transAxes)
        magnitude.set_title(f"{out} / {inp}")
        magnitude.set_ylabel(f"|H| [{unit}]")
        magnitude.grid(True, which="both", alpha=0.3)
        phase.plot(frequencies, np.degrees(np.angle(h_meas)), color="k", lw=1.0)
        phase.plot(frequencies, np.degrees(np.angle(h_model)), color="tab:blue", lw=1.2,
                   ls="--")
        phase.set_ylabel("Phase [deg]")
        phase.set_xlabel("Frequency [Hz]")
        phase.set_yticks([-180, -90, 0, 90, 180])
        phase.grid(True, alpha=0.3)
    if axes[0, 0].get_legend_handles_labels()[0]:
        axes[0, 0].legend(fontsize="small")
    figure.suptitle(title)
    return png_bytes(figure)


def plot_coefficients(
    frequencies: np.ndarray,
    coefficients: np.ndarray,
    names: Sequence[str],
    *,
    truth: Sequence[float | None] | None = None,
    unit: str = "input unit per unit of g_j",
    title: str = "Nonlinear coefficients",
    std: np.ndarray | None = None,
) -> bytes:
    """Real and imaginary parts of the nonlinear coefficients mu_j(omega) (paper Figure 7).

    A good estimate has a flat real part and an imaginary part orders of magnitude smaller
    (Section II.E).

    Parameters
    ----------
    frequencies : ndarray, shape (lines,)
        Frequencies [Hz].
    coefficients : ndarray, shape (lines, s), complex
        mu_j(omega) of the s basis functions.
    names : sequence of str
        Label of each basis function.
    truth : sequence of float or None, optional
        True coefficient per basis function (None where unknown), drawn as a line.
    unit : str
        Unit of the coefficients for the axis labels (force per unit of basis function).
    title : str
        Figure title.
    std : ndarray, shape (lines, s, 2), optional
        Standard deviations of Re and Im mu_j on each line (:mod:`fnsi.uncertainty`),
        drawn as shaded +-1 std bands.

    Returns
    -------
    bytes
        PNG content.
    """
    mu = np.asarray(coefficients)
    if mu.ndim == 1:
        mu = mu[:, None]
    if mu.shape != (np.size(frequencies), len(names)):
        raise ValueError(f"coefficients must be (lines, {len(names)}) for the given names and "
                         f"{np.size(frequencies)} frequencies; got {mu.shape}")
    figure = new_figure(9.0, 6.0)
    real, imaginary = figure.subplots(2, 1, sharex=True)
    labelled = mu.shape[1] <= 12   # beyond that a legend hides the curves
    for j, name in enumerate(names):
        colour = f"C{j % 10}"
        real.plot(frequencies, mu[:, j].real, color=colour, lw=1.0,
                  label=name if labelled else None)
        imaginary.plot(frequencies, mu[:, j].imag, color=colour, lw=1.0)
        if std is not None:
            for ax, part, k in ((real, mu[:, j].real, 0), (imaginary, mu[:, j].imag, 1)):
                ax.fill_between(frequencies, part - std[:, j, k], part + std[:, j, k],
                                color=colour, alpha=0.25, lw=0)
        if truth is not None and truth[j] is not None:
            real.axhline(truth[j], color=colour, ls=":", lw=1.2)
    if truth is not None and any(t is not None for t in truth):
        real.plot([], [], color="k", ls=":", label="truth")
    if std is not None:
        real.fill_between([], [], [], color="k", alpha=0.25, lw=0, label="\u00b11 std (noise)")
    real.set_ylabel(f"Re mu_j [{unit}]")
    imaginary.set_ylabel(f"Im mu_j [{unit}]")
    imaginary.set_xlabel("Frequency [Hz]")
    for ax in (real, imaginary):
        ax.grid(True, alpha=0.3)
    if real.get_legend_handles_labels()[0]:
        real.legend(fontsize="small", ncols=2 if mu.shape[1] > 4 else 1)
    real.set_title("Real part")
    imaginary.set_title("Imaginary part")
    figure.suptitle(title)
    return png_bytes(figure)


def plot_stiffness(
    curves: Sequence[StiffnessCurve],
    *,
    truths: Sequence[NonlinearElement | None] | None = None,
    title: str = "Nonlinear restoring forces",
    units: ModelUnits | None = None,
    warnings: Sequence[str | None] | None = None,
) -> bytes:
    """Identified restoring-force curves, with the exact ones when known (Figures 10, 12).

    Parameters
    ----------
    curves : sequence of StiffnessCurve
        Identified curves, one panel each.
    truths : sequence of NonlinearElement or None, optional
        True element (with coefficients) per curve, drawn in black over the same range.
    title : str
        Figure title (wrapped to the figure width).
    units : ModelUnits, optional
        Units of the data, for the axis labels (:meth:`fnsi.units.ModelUnits.curve`;
        default: the placeholders of a displacement record without units).
    warnings : sequence of str or None, optional
        A short warning per curve (None for none), written in red in its panel, whose
        identified curve is then dashed: a curve not to be trusted (e.g. confounded).

    Returns
    -------
    bytes
        PNG content.
    """
    if not curves:
        raise ValueError("no stiffness curve to plot: pass at least one")
    for name, given in (("truth", truths), ("warning", warnings)):
        if given is not None and len(given) != len(curves):
            raise ValueError(f"give one {name} (or None) per curve: {len(given)} for "
                             f"{len(curves)} curves")
    rows, columns = panel_grid(len(curves))
    figure = new_figure(5.0 * columns, 3.8 * rows)
    axes = np.atleast_1d(figure.subplots(rows, columns, squeeze=False)).ravel()
    for k, curve in enumerate(curves):
        ax = axes[k]
        truth = truths[k] if truths is not None else None
        if truth is not None:
            zeros = np.zeros_like(curve.x)
            exact = (truth.force(zeros, curve.x) if truth.needs_velocity
                     else truth.force(curve.x, zeros))
            ax.plot(curve.x, exact, color="k", lw=1.6, label="exact")
        warning = warnings[k] if warnings is not None else None
        ax.plot(curve.x, curve.force, color="tab:blue", lw=1.2, label="identified",
                ls="--" if warning else "-")
        if warning:
            # wrapped to the panel by hand: matplotlib wraps to the figure, and constrained
            # layout then shrinks the axes to make room for the overflowing line
            ax.text(0.02, 0.02, textwrap.fill(warning, WARNING_CHARACTERS),
                    transform=ax.transAxes, color="tab:red", fontsize="small",
                    va="bottom", bbox={"facecolor": "white", "alpha": 0.8, "lw": 0},
                    in_layout=False)
        element = curve.element
        if element.kind is NonlinearityKind.SPLINE and element.knots:
            knots = np.asarray(element.knots)
            ax.plot(knots, element.basis(knots) @ np.asarray(element.coefficients), "o",
                    mfc="none", color="tab:blue", ms=5, label="knots")
        unit, force = (units or ModelUnits("", "", "displacement")).curve(curve.variable)
        ax.set_xlabel(f"Relative {curve.variable} [{unit}]")
        ax.set_ylabel(f"Restoring force [{force}]")
        ax.set_title(element.name)
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    for ax in axes[len(curves):]:
        ax.set_visible(False)
    figure.suptitle(title, wrap=True)
    return png_bytes(figure)


def plot_macx(
    macx: np.ndarray,
    frequencies_a: np.ndarray,
    frequencies_b: np.ndarray,
    *,
    label_a: str = "identified",
    label_b: str = "reference",
    title: str = "MACX matrix",
) -> bytes:
    """MACX matrix between two sets of modes as an annotated map (paper Figure 6).

    Parameters
    ----------
    macx : ndarray, shape (na, nb)
        Values from :func:`fnsi.stabilisation.macx_matrix`.
    frequencies_a, frequencies_b : ndarray, shapes (na,), (nb,)
        Natural frequencies [Hz] of the two sets, used as tick labels.
    label_a, label_b : str
        Names of the two sets (row and column axes).
    title : str
        Figure title.

    Returns
    -------
    bytes
        PNG content.

    Examples
    --------
    >>> import numpy as np
    >>> plot_macx(np.eye(2), np.array([10.7, 28.3]), np.array([10.7, 28.3]))[:4]
    b'\x89PNG'
    """
    values = np.asarray(macx, dtype=float)
    if values.shape != (np.size(frequencies_a), np.size(frequencies_b)):
        raise ValueError(f"macx must be ({np.size(frequencies_a)}, {np.size(frequencies_b)}) "
                         f"for the given frequencies; got {values.shape}")
    size = max(4.5, 0.55 * max(values.shape) + 2.5)
    figure = new_figure(size + 1.0, size)
    ax = figure.subplots()
    image = ax.imshow(values, vmin=0.0, vmax=1.0, cmap="Blues", origin="upper")
    if values.size <= 400:
        for (i, j), value in np.ndenumerate(values):
            ax.text(j, i, f"{value:.2f}", ha="center", va="center", fontsize=7,
                    color="white" if value > 0.6 else "black")
    ax.set_xticks(range(values.shape[1]), [f"{f:.2f}" for f in frequencies_b], rotation=60)
    ax.set_yticks(range(values.shape[0]), [f"{f:.2f}" for f in frequencies_a])
    ax.set_xlabel(f"{label_b} modes [Hz]")
    ax.set_ylabel(f"{label_a} modes [Hz]")
    figure.colorbar(image, ax=ax, label="MACX [-]", shrink=0.8)
    ax.set_title(title)
    return png_bytes(figure)


def plot_errors(errors: ModelErrors, *, outputs: Sequence[str] | None = None,
                unit: str = "output unit",
                title: str = "Model error against the noise floor") -> bytes:
    """Per-line spectra of measured output, model error and noise, one panel per channel.

    Parameters
    ----------
    errors : ModelErrors
        From :func:`fnsi.errors.model_errors`.
    outputs : sequence of str, optional
        Channels to draw; default the first six.
    unit : str
        Output unit for the axis label.
    title : str
        Figure title.

    Returns
    -------
    bytes
        PNG content.
    """
    names = list(errors.output_names[:6] if outputs is None else outputs)
    figure, axes = output_panels(names, errors.output_names, 5.0, 3.5)
    for ax, name in zip(axes, names, strict=False):
        k = errors.output_names.index(name)
        ax.semilogy(errors.frequencies, errors.measured_spectrum[:, k], color="k", lw=0.8,
                    label="measured")
        ax.semilogy(errors.frequencies, errors.error_spectrum[:, k], color="tab:red", lw=0.8,
                    label="model error")
        ax.semilogy(errors.frequencies, errors.noise_spectrum[:, k], color="0.6", lw=0.8,
                    label="noise floor")
        ax.set_title(f"{name}: NRMSE {errors.nrmse_percent[k]:.3g} % "
                     f"(floor {errors.noise_floor_percent[k]:.3g} %)", fontsize="medium")
        ax.set_xlabel("Frequency [Hz]")
        ax.set_ylabel(f"Amplitude [{unit}]")
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize="small")
    for ax in axes[len(names):]:
        ax.set_visible(False)
    figure.suptitle(title)
    return png_bytes(figure)


def _db(x: np.ndarray) -> np.ndarray:
    with np.errstate(divide="ignore"):
        return 20 * np.log10(x)


def plot_distortion(analysis: DistortionAnalysis, *, outputs: Sequence[str] | None = None,
                    unit: str | None = None) -> bytes:
    """Output, noise and nonlinear distortion levels against frequency, one panel per output.

    The classic figure of the nonparametric distortion analysis: the output on the
    excited lines, the noise level, the stochastic distortion level on the excited lines
    (several realisations), and the output on the non-excited odd and even lines and
    above the band, all in dB of the output unit.

    Parameters
    ----------
    analysis : DistortionAnalysis
        From :func:`fnsi.distortion.analyse_distortion`.
    outputs : sequence of str, optional
        Channels to draw; default the six with the strongest odd or even distortions.
    unit : str, optional
        Output unit for the axis label; default ``analysis.unit``.

    Returns
    -------
    bytes
        PNG content.
    """
    names = list(outputs) if outputs is not None else _strongest_outputs(analysis, 6)
    figure, axes = output_panels(names, analysis.output_names, 5.5, 3.6)
    f = analysis.frequencies
    excited = analysis.excited.all(axis=0)
    quiet = ~analysis.excited.any(axis=0)
    odd = (np.round(f / f[0]).astype(int) % 2 == 1) if f.size else quiet
    low, high = analysis.band
    for ax, name in zip(axes, names, strict=False):
        j = analysis.output_names.index(name)
        level = _db(analysis.output[:, j])
        ax.plot(f[excited], level[excited], "k.", ms=3, label="output, excited lines")
        ax.plot(f[quiet & odd], level[quiet & odd], "x", color="tab:blue", ms=4,
                label="odd non-excited lines")
        ax.plot(f[quiet & ~odd], level[quiet & ~odd], "+", color="tab:green", ms=4,
                label="even non-excited lines")
        ax.plot(f[excited], _db(analysis.distortion[excited, j]), ".", color="tab:red",
                ms=3, label="nonlinear distortion")
        ax.plot(f, _db(analysis.noise[:, j]), color="0.55", lw=0.8, label="noise")
        ax.axvspan(low, high, color="0.93", zorder=0)
        channel = analysis.channels[j]
        ax.set_title(f"{name}: odd {_level_text(channel.odd)}, even "
                     f"{_level_text(channel.even)} over the noise", fontsize="medium")
        ax.set_xlabel("Frequency [Hz]")
        ax.set_ylabel(f"Level [dB re 1 {unit or analysis.unit}]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(fontsize="x-small", loc="lower left")
    for ax in axes[len(names):]:
        ax.set_visible(False)
    figure.suptitle(f"Nonlinear distortions ({analysis.realisations} realisation(s), "
                    f"{analysis.periods} periods; band shaded)")
    return png_bytes(figure)


def _level_text(group) -> str:
    return "-" if group.lines == 0 else f"{group.level_db:.0f} dB"


def _strongest_outputs(analysis: DistortionAnalysis, count: int) -> list[str]:
    def strength(c) -> float:
        levels = [g.level_db for g in (c.odd, c.even, c.excited) if g.lines]
        return max(levels, default=-np.inf)

    ranked = sorted(analysis.channels, key=strength, reverse=True)
    return [c.name for c in ranked[:count]]
