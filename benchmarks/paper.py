"""Reproduce the paper's Section IV on our SmallSat model (docs/design.md section 5).

Four reference workloads, each identified with the library exactly as a user would
(:func:`fnsi.identification.identify`) from the simulated SmallSat tests of
:func:`fnsi.smallsat.simulate_preset`:

``single-39``
    100 N RMS at NC2w_Z, 39 outputs, i = 50, clearance basis at NC2-Z, automatic order
    (paper Tables 4, 5 first line, Figures 5, 6, 7a).
``single-3``
    same data, outputs NC2w_Z, NC2b_Z, W_Z, i = 100, the 540 harmonic lines averaged over
    the periods (Tables 5 second line, 6, Figures 7b, 8).
``spline-3``
    as single-3 with a cubic-spline basis at NC2-Z (Table 7, Figures 9, 10), twice: with the
    paper's uneven knots (13 intervals, 10 within +-10 % of the clearances) and with
    automatic knots (13 intervals) that use no knowledge of the clearances; automatic
    block rows (the paper's i = 100 on all lines is refused by the dimension rule for
    periodic data, shown in the sensitivity table).
``multi-18``
    200 N RMS at W along the X-Y diagonal, 18 outputs, eight 9-interval splines with
    automatic knots (Tables 8, 9, Figures 11, 12); automatic block rows (the paper's
    i = 50 is refused, with the reason in the report).

Simulated data are cached in ``benchmarks/cache/`` under a hash of the request (preset,
simulation settings, tuned model parameters and the source of the simulator), so only a
changed request is simulated again. The report goes to ``benchmarks/results/paper.md``
with its PNG figures beside it. Every number in the report is measured by this script,
except the paper's own values, which are quoted from its tables.

All identifications weight the SVD by the output noise covariance and choose the order
automatically (falling back to the paper's order when nothing stabilises, as reported).
Timings are single-threaded BLAS unless OPENBLAS_NUM_THREADS is set (see :data:`BLAS_THREADS`).

Identified modes are paired with the true modes of the model by a one-to-one assignment
that maximises MACX and penalises frequency distance (:func:`match_modes`); every mode
kept by the automatic order choice enters the acceptance maxima, so a spurious mode
(no true partner) fails the check rather than being hidden.

Last output line: one JSON object with the headline numbers of each workload.

Run: ``make bench-paper`` (or ``.venv/bin/python benchmarks/paper.py``).
"""

from __future__ import annotations

import hashlib
import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import scipy.linalg
import scipy.optimize

from fnsi.acquisition import NOISE_BAND, Truth, measurement_noise
from fnsi.identification import (
    IdentificationResult,
    IdentificationSettings,
    extended_spectra,
    identify,
)
from fnsi.measurement import Measurement
from fnsi.modal import ModalTable, modal_table
from fnsi.nonlinear import NonlinearElement
from fnsi.plots import (
    new_figure,
    plot_coefficients,
    plot_macx,
    plot_stabilisation,
    plot_stiffness,
    png_bytes,
)
from fnsi.separability import SEPARABILITY_LIMIT
from fnsi.smallsat import (
    AXIAL_ADDED,
    AXIAL_GAP,
    BRACKET_TIP,
    FORCE_UNIT,
    LENGTH_UNIT,
    TABLE_3,
    TABLE_8,
    simulate_preset,
    smallsat_model,
    tuned_parameters,
)
from fnsi.spectra import band_lines, kept_record, output_spectra, period_mean
from fnsi.stabilisation import macx_matrix, modal_contributions
from fnsi.stiffness import StiffnessCurve, curve_error_percent, stiffness_curve
from fnsi.subspace import band_warp, row_basis, stacked_rows, warp_lines
from fnsi.units import ModelUnits, per

HERE = Path(__file__).resolve().parent
CACHE = HERE / "cache"
RESULTS = HERE / "results"
FNSI = HERE.parent / "fnsi"

#: The paper's tests (Section IV.A and IV.C): 8 periods of 30,000 samples at 2.5 kHz.
SIMULATION = {"periods": 8, "samples_per_period": 30000, "seed": 0, "noise_percent": 0.5}
#: Source files whose change changes the simulated data (part of the cache key).
SIMULATOR_SOURCES = ("smallsat.py", "smallsat_parameters.json", "acquisition.py",
                     "newmark.py", "nonlinear.py", "excitation.py", "structure.py")
BAND = (5.0, 50.0)
DISCARD = 2
#: Axis units of the SmallSat curves: the model's own (fnsi.smallsat: length unit 1 mm,
#: force unit 20 N).
MODEL_UNITS = ModelUnits(FORCE_UNIT, LENGTH_UNIT, "displacement")
NC2 = ("NC2w_Z", "NC2b_Z")
THREE = ("NC2w_Z", "NC2b_Z", "W_Z")
#: Force and output at the driving point of the single test.
DRIVING_POINT = ("F_NC2w_Z", "NC2w_Z")
#: Outputs (None: all 39), block rows and line set of the clearance workloads (IV.A).
CLEARANCE_WORKLOADS = {"single-39": (None, 50, "all"), "single-3": (THREE, 100, "excited")}

#: Paper Table 4: mode -> (error on frequency %, error on damping %), order 18, 39 outputs.
PAPER_TABLE_4 = {1: (0.16, -0.01), 3: (0.03, -0.59), 5: (0.11, -0.37), 7: (-0.03, -2.68),
                 8: (0.03, 0.25), 9: (-6.05, -21.48), 10: (-0.13, 0.68), 11: (-0.28, -0.28)}
#: Paper Table 5: (mean Re mu, error %, log10(Re/Im), time s) with 39 and with 3 outputs.
PAPER_TABLE_5 = {"single-39": (100.03, 0.03, 3.21, 119.0), "single-3": (100.29, 0.29, 2.19, 1.8)}
#: Paper Tables 6, 7, 9: mode -> (error on frequency %, error on damping %, MACX).
PAPER_TABLE_6 = {1: (0.17, -0.04, 1.00), 3: (0.02, -0.35, 1.00), 5: (0.06, -3.10, 1.00),
                 8: (0.02, -7.34, 1.00)}
PAPER_TABLE_7 = {1: (0.02, -5.45, 1.00), 3: (-0.15, -5.62, 1.00), 5: (0.44, 3.00, 1.00),
                 8: (-3.70, -5.79, 1.00)}
PAPER_TABLE_9 = {1: (0.39, -1.35, 1.00), 2: (0.59, 0.01, 1.00), 3: (0.06, -2.73, 1.00),
                 4: (0.38, -0.87, 1.00), 5: (0.79, 4.43, 0.99)}
#: Runs of the timed single-39 and single-3 identifications; the best wall time counts.
TIMING_REPEATS = 3
#: Paper orders chosen from the stabilisation diagrams (Figures 5, 8, 9, 11).
PAPER_ORDER = {"single-39": 18, "single-3": 8, "spline-3": 8, "multi-18": 10}


# -- simulated data, cached -----------------------------------------------------------------
def _truth_from_json(data: dict) -> Truth:
    modal = data["modal"]
    shapes = np.asarray(modal["shapes_real"]) + 1j * np.asarray(modal["shapes_imag"])
    return Truth(
        ModalTable(np.asarray(modal["frequencies"]), np.asarray(modal["damping_ratios"]),
                   shapes, tuple(modal["output_names"])),
        tuple(NonlinearElement.from_json(e) for e in data["elements"]),
        {k: int(v) for k, v in data["exceedances"].items()},
        int(data["discard_periods"]),
    )


def simulated(preset: str, noise_percent: float = SIMULATION["noise_percent"], *,
              variant: dict[str, float] | None = None) -> tuple[Measurement, Truth, dict]:
    """Measurement and truth of a SmallSat preset, simulated once and cached on disk.

    The cache key is the SHA-256 of the request: preset name, simulation settings (with
    ``noise_percent``, 0 for the noise-free record), the model parameters and the source
    of the simulator (a retuned or changed model is simulated again). ``variant`` scales
    tuned parameters by the given factors (a variant of the structure).

    Returns
    -------
    Measurement, Truth, dict
        The dict holds ``cached`` (bool), ``simulation_s`` (wall time of the simulation
        when it ran) and ``key``.
    """
    sources = hashlib.sha256(b"".join((FNSI / f).read_bytes() for f in SIMULATOR_SOURCES))
    tuned = tuned_parameters()
    parameters = replace(tuned, **{k: getattr(tuned, k) * f for k, f in (variant or {}).items()})
    request = {"preset": preset, **SIMULATION, "noise_percent": noise_percent,
               "parameters": asdict(parameters), "simulator": sources.hexdigest()}
    key = hashlib.sha256(json.dumps(request, sort_keys=True).encode()).hexdigest()[:16]
    name = (preset if noise_percent == SIMULATION["noise_percent"]
            else f"{preset}-noise{noise_percent:g}") + ("-variant" if variant else "")
    data, meta = CACHE / f"{name}-{key}.npz", CACHE / f"{name}-{key}.json"
    if data.exists() and meta.exists():
        stored = json.loads(meta.read_text())
        return (Measurement.from_npz(data), _truth_from_json(stored["truth"]),
                {"cached": True, "simulation_s": stored["simulation_s"], "key": key})
    start = time.perf_counter()
    measurement, truth = simulate_preset(preset, parameters=parameters,
                                         **{**SIMULATION, "noise_percent": noise_percent})
    elapsed = time.perf_counter() - start
    CACHE.mkdir(parents=True, exist_ok=True)
    measurement.to_npz(data)
    meta.write_text(json.dumps({"request": request, "truth": truth.to_json(),
                                "simulation_s": elapsed}))
    return measurement, truth, {"cached": False, "simulation_s": elapsed, "key": key}


# -- comparison with the truth ----------------------------------------------------------------
@dataclass(frozen=True)
class ModeMatch:
    """An identified mode and its true partner.

    ``spurious`` marks a mode without a credible partner (MACX below
    :data:`MIN_PARTNER_MACX` or more than :data:`MAX_PARTNER_DISTANCE` away in frequency):
    its errors are then taken against the nearest true frequency, so that it still counts
    (and fails) in the acceptance maxima.
    """

    identified: int
    truth: int
    frequency_error_pct: float
    damping_error_pct: float
    macx: float
    spurious: bool


#: Smallest MACX, and largest relative frequency distance, of a credible true partner.
MIN_PARTNER_MACX = 0.5
MAX_PARTNER_DISTANCE = 0.05


def in_band(table: ModalTable, band: tuple[float, float] = BAND) -> ModalTable:
    """The modes of ``table`` whose natural frequency lies in ``band``."""
    keep = (table.frequencies >= band[0]) & (table.frequencies <= band[1])
    return ModalTable(table.frequencies[keep], table.damping_ratios[keep],
                      table.shapes[keep], table.output_names)


def match_modes(identified: ModalTable, truth: ModalTable) -> list[ModeMatch]:
    """Pair identified and true modes one to one (MACX and frequency, Hungarian assignment).

    Cost of a pair: (1 - MACX) + 10 |f_id / f_true - 1|, so a 1 % frequency distance
    weighs like a MACX loss of 0.1: shapes decide between close modes (the 28.5 Hz pair),
    frequency between modes the outputs cannot tell apart.
    """
    if identified.n_modes == 0:
        return []
    macx = macx_matrix(identified.shapes, truth.shapes)
    distance = np.abs(identified.frequencies[:, None] / truth.frequencies[None, :] - 1)
    rows, cols = scipy.optimize.linear_sum_assignment((1 - macx) + 10 * distance)
    partner = dict(zip(rows.tolist(), cols.tolist(), strict=True))
    matches = []
    for k in range(identified.n_modes):
        j = partner.get(k)
        spurious = (j is None or macx[k, j] < MIN_PARTNER_MACX
                    or distance[k, j] > MAX_PARTNER_DISTANCE)
        if spurious:
            j = int(np.argmin(distance[k]))
        matches.append(ModeMatch(
            k, j, 100 * (identified.frequencies[k] / truth.frequencies[j] - 1),
            100 * (identified.damping_ratios[k] / truth.damping_ratios[j] - 1),
            float(macx[k, j]), spurious))
    return matches


def _max_abs(values) -> float:
    """Largest magnitude (nan when there is nothing to compare)."""
    values = [abs(v) for v in values]
    return float(max(values)) if values else math.nan


# -- one identification ---------------------------------------------------------------------
@dataclass
class Run:
    """One identification of a workload with everything the report needs."""

    name: str
    measurement: Measurement
    truth: Truth
    settings: IdentificationSettings
    repeats: int = 1
    result: IdentificationResult = field(init=False)
    time_s: float = field(init=False)
    truth_modes: ModalTable = field(init=False)
    matches: list[ModeMatch] = field(init=False)
    order_note: str = field(init=False)

    def __post_init__(self) -> None:
        self.time_s = math.inf
        self.order_note = "automatic"
        for _ in range(self.repeats):  # best of the repeats: other processes share the cores
            start = time.perf_counter()
            self._identify()
            self.time_s = min(self.time_s, time.perf_counter() - start)
        names = self.result.modal.output_names
        modal = self.truth.modal
        columns = [modal.output_names.index(n) for n in names]
        self.truth_modes = in_band(ModalTable(modal.frequencies, modal.damping_ratios,
                                              modal.shapes[:, columns], names))
        self.matches = match_modes(self.result.modal, self.truth_modes)

    def _identify(self) -> None:
        try:
            self.result = identify(self.measurement, self.settings)
        except ValueError as error:
            if self.settings.order != "auto" or "no model order stabilises" not in str(error):
                raise
            # nothing stabilises: take the order the paper read from its diagram
            self.order_note = ("automatic choice failed: no order has a fully stable "
                               "pole in the band; the paper's order is used")
            self.settings = replace(self.settings, order=PAPER_ORDER[self.name.split(" ")[0]])
            self.result = identify(self.measurement, self.settings)

    def stable_flags(self) -> list[bool]:
        """Whether each kept mode is confirmed by the next order of the diagram (fully
        stable in frequency, damping and MACX), as :func:`fnsi.identification.identify`
        flags it; with the automatic order every kept mode is."""
        confirmed = self.result.modal.confirmed
        if confirmed is None:
            return [False] * self.result.modal.n_modes
        return [bool(c) for c in confirmed]

    def stabilised_text(self) -> str:
        """Error maxima over the confirmed modes only (what a user would keep)."""
        kept = [m for m, ok in zip(self.matches, self.stable_flags(), strict=True) if ok]
        if not kept:
            return (f"none of the {len(self.matches)} kept modes is confirmed (fully stable) "
                    "by the next order of the diagram")
        return (f"{len(kept)} of the {len(self.matches)} kept modes are confirmed (fully "
                f"stable) by the next order of the diagram; over those only, max |err f| = "
                f"{_max_abs(m.frequency_error_pct for m in kept):.3f} % and max |err zeta| = "
                f"{_max_abs(m.damping_error_pct for m in kept):.2f} %")

    @property
    def max_frequency_error(self) -> float:
        return _max_abs(m.frequency_error_pct for m in self.matches)

    @property
    def max_damping_error(self) -> float:
        return _max_abs(m.damping_error_pct for m in self.matches)

    def order_text(self) -> str:
        s = self.result.settings
        chosen = "automatic choice" if self.order_note == "automatic" else self.order_note
        return (f"Settings: i = {s.block_rows}, {len(self.result.modal.output_names)} "
                f"outputs, {len(self.result.coefficients)} basis functions, {s.line_set} "
                f"lines, noise weighting {'on' if s.weighting else 'off'}. "
                f"Order: **{self.result.order}** ({chosen}; paper: "
                f"{PAPER_ORDER[self.name.split(' ')[0]]}); {self.result.modal.n_modes} modes kept")

    def timings_text(self) -> str:
        stages = ", ".join(f"{k} {v:.3f}" for k, v in self.result.timings.items())
        best = f", best of {self.repeats} runs" if self.repeats > 1 else ""
        return (f"identify() wall time {self.time_s:.3f} s{best} (stages of the last run: "
                f"{stages} s)")


def settings_for(outputs, block_rows: int, elements, driving_point: tuple[str, str], *,
                 line_set: str = "all", frequency_warping: bool = True,
                 ) -> IdentificationSettings:
    """The identification settings shared by the workloads (automatic order).

    The SVD is weighted by the output noise covariance estimated from the six kept
    periods (``weighting=True``): with few outputs, the unweighted truncation mixes the
    weakly excited modes with the noise (see the report). ``line_set="excited"`` keeps
    the 540 harmonic lines averaged over the periods instead of all 3,240 lines of the
    record (the other 2,700 carry only noise); it needs (m + s + l) i < 1,080. The
    single-record workloads warp the frequency variable (``frequency_warping``): built
    in z their results are fixed by rounding (the *Rounding* section); multi-18 is not,
    and :func:`stop_run` leaves it in z.
    """
    return IdentificationSettings(
        band=BAND, block_rows=block_rows, order="auto", max_order=60,
        outputs=None if outputs is None else tuple(outputs), discard_periods=DISCARD,
        elements=tuple(elements), driving_points=(driving_point,), weighting=True,
        line_set=line_set, frequency_warping=frequency_warping)


def clearance_settings(name: str, **changes) -> IdentificationSettings:
    """Settings of single-39 or single-3 (the NC2-Z clearance with its exact gap, IV.A),
    with ``changes`` to any field."""
    outputs, block_rows, line_set = CLEARANCE_WORKLOADS[name]
    return replace(settings_for(outputs, block_rows, [clearance_nc2()], DRIVING_POINT,
                                line_set=line_set), **changes)


# -- report helpers -----------------------------------------------------------------------
def _fmt(value: float, digits: int = 2) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "-"
    return f"{value:+.{digits}f}" if digits else f"{value:.0f}"


def _table(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(str(c) for c in row) + " |" for row in rows]
    return "\n".join(lines)


def _save(name: str, png: bytes) -> str:
    (RESULTS / name).write_bytes(png)
    return f"![{name}]({name})"


def _frf_background(run: Run) -> tuple[np.ndarray, np.ndarray]:
    """Sum over outputs of the measured FRF magnitude (H1 on the excited lines)."""
    data = run.measurement.select(outputs=run.settings.outputs)
    spectra = output_spectra(data, BAND, discard_periods=DISCARD, line_set="excited")
    H = spectra.outputs[0] / spectra.inputs[0, :, :1]
    return spectra.frequencies, np.sum(np.abs(H), axis=1)


def modal_rows(run: Run, paper: dict[int, tuple] | None) -> list[list[str]]:
    """Table rows: every true mode in the band with its identified partner, then the
    identified modes without a credible partner (errors against the nearest true mode)."""
    by_truth = {m.truth: m for m in run.matches if not m.spurious}
    table, t = run.result.modal, run.truth_modes
    stable = run.stable_flags()

    def identified(m: ModeMatch) -> list[str]:
        flag = "" if stable[m.identified] else " (not confirmed)"
        return [f"{table.frequencies[m.identified]:.3f}{flag}",
                f"{100 * table.damping_ratios[m.identified]:.2f}",
                _fmt(m.frequency_error_pct, 3), _fmt(m.damping_error_pct, 2),
                f"{m.macx:.3f}"]

    rows = []
    for j in range(t.n_modes):
        p = (paper or {}).get(j + 1)
        paper_cells = [_fmt(p[0]), _fmt(p[1])] if p else ["", ""]
        ours = identified(by_truth[j]) if j in by_truth else ["not identified", "", "", "",
                                                               ""]
        rows.append([str(j + 1), f"{t.frequencies[j]:.3f}",
                     f"{100 * t.damping_ratios[j]:.2f}", *ours, *paper_cells])
    for m in run.matches:
        if m.spurious:
            rows.append([f"spurious (nearest: {m.truth + 1})", "", "", *identified(m), "",
                         ""])
    return rows


#: Share of the band's response a mode must carry to be required of the automatic order
#: (issue 20: modes with 1 % of the response power recovered, none spurious).
RESPONSE_SHARE = 0.01


def response_shares(run: Run) -> np.ndarray:
    """Share of each true mode (``run.truth_modes``) in the response of the run's outputs
    to the force at NC2w_Z over the band, from the underlying linear model of our SmallSat
    (:func:`fnsi.stabilisation.modal_contributions` of its exact discrete-time model, zero-
    order hold at the record's rate, on the band's lines)."""
    structure = smallsat_model()
    fs, r = run.measurement.fs, structure.n_dofs
    names = run.result.modal.output_names
    Ac = np.block([[np.zeros((r, r)), np.eye(r)],
                   [-np.linalg.solve(structure.M, structure.K),
                    -np.linalg.solve(structure.M, structure.C)]])
    force = np.zeros((2 * r, 1))
    force[r:, 0] = np.linalg.solve(structure.M, np.eye(r)[:, structure.dof_index(NC2[0])])
    A = scipy.linalg.expm(Ac / fs)
    B = np.linalg.solve(Ac, (A - np.eye(2 * r)) @ force)
    C = np.eye(2 * r)[[structure.dof_index(n) for n in names]]
    modes = modal_table(A, C, fs, names, band=BAND)
    lines = band_lines(run.measurement.period_length, fs, BAND) * fs / (
        run.measurement.period_length)
    shares = modal_contributions(A, B, C, fs, lines, modes)
    truth = run.truth_modes.frequencies
    return np.array([shares[np.argmin(np.abs(modes.frequencies - f))] for f in truth])


def response_rows(run: Run, paper: dict[int, tuple]) -> tuple[list[list[str]], bool]:
    """One row per true mode that carries RESPONSE_SHARE of the response: kept or not, its
    errors and the paper's; and whether every such mode is kept, no kept mode is spurious,
    and the errors are within the acceptance targets (the paper's Table 4 level)."""
    by_truth = {m.truth: m for m in run.matches if not m.spurious}
    rows, ok = [], not any(m.spurious for m in run.matches)
    targets = TARGETS["single39"]
    for j, share in enumerate(response_shares(run)):
        if share < RESPONSE_SHARE:
            continue
        p = paper.get(j + 1)
        paper_cells = [_fmt(p[0]), _fmt(p[1])] if p else ["", ""]
        m = by_truth.get(j)
        if m is None:
            ok = False
            rows.append([str(j + 1), f"{100 * share:.1f}", "no", "", "", *paper_cells])
            continue
        ok &= (abs(m.frequency_error_pct) <= targets["max_freq_err_pct"]
               and abs(m.damping_error_pct) <= targets["max_damp_err_pct"])
        rows.append([str(j + 1), f"{100 * share:.1f}", "yes", _fmt(m.frequency_error_pct, 3),
                     _fmt(m.damping_error_pct, 2), *paper_cells])
    return rows, ok


MODAL_HEADER = ["true mode", "true f [Hz]", "true zeta [%]", "ident. f [Hz]",
                "ident. zeta [%]", "err f [%]", "err zeta [%]", "MACX",
                "paper err f [%]", "paper err zeta [%]"]


def coefficient_summary(run: Run, truth_mu: float) -> dict:
    """Mean Re mu over the band, its error, log10(Re/Im) and the time (Table 5)."""
    c = run.result.coefficients[0]
    return {"mean_mu": c.mean_real, "mu_err_pct": 100 * abs(c.mean_real / truth_mu - 1),
            "log10_re_im": c.log10_real_imag, "time_s": run.time_s}


def stabilisation_figure(run: Run, name: str, title: str) -> str:
    png = plot_stabilisation(run.result.stabilisation, frf=_frf_background(run),
                             singular_values=run.result.singular_values[:60],
                             order=run.result.order, title=title,
                             frf_unit=run.result.units.frf)
    return _save(name, png)


# -- evidence for the report ------------------------------------------------------------------
def _true_frf_terms(measurement: Measurement, settings: IdentificationSettings,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Lines f, the true driving-point FRF H (N, dofs) of a force at NC2w_Z, and the two
    sides a = (H_dof - H_ref) G, b = H_dof U - Y of Eq. 16-17 at NC2w_Z (so that a mu = b)
    on the excited lines of ``measurement``."""
    structure = smallsat_model()
    settings = replace(settings, line_set="excited")
    data = measurement.select(settings.inputs, settings.outputs)
    spectra, _, _ = extended_spectra(data, settings)
    f, U, G = spectra.frequencies, spectra.inputs[0, :, 0], spectra.inputs[0, :, 1]
    dof, ref = (structure.dof_index(n) for n in NC2)
    w = 2 * np.pi * f[:, None, None]
    H = np.linalg.solve(-w**2 * structure.M + 1j * w * structure.C + structure.K,
                        np.eye(structure.M.shape[0])[:, [dof]])[:, :, 0]
    y = spectra.outputs[0, :, data.output_index(NC2[0])]
    return f, H, (H[:, dof] - H[:, ref]) * G, H[:, dof] * U - y


def _log10_re_im(mu: complex) -> float:
    return float(np.log10(abs(mu.real / mu.imag)))


def frf_evidence(run: Run) -> dict:
    """Where the coefficient error comes from: the data or the identified model.

    On the excited lines, mu(omega) is computed twice from the same measured spectra
    (Eq. 16-17 at the driving point NC2w_Z): once with the true FRF of our structural
    model, once with the identified one. Also the median error of the identified
    driving-point FRF against the true one, and the true-FRF estimate from the
    noise-free record.
    """
    f, H, a, b = _true_frf_terms(run.measurement, run.result.settings)
    least_squares = np.vdot(a, b) / np.vdot(a, a)
    clean, _, _ = simulated("single", noise_percent=0.0)
    _, _, a0, b0 = _true_frf_terms(clean, run.result.settings)
    dof = smallsat_model().dof_index(NC2[0])
    He = run.result.model.frequency_response(f)[:, run.result.model.output_names.index(NC2[0]), 0]
    return {"mu_true_frf": float(np.mean((b / a).real)),
            "mu_true_frf_ls": float(least_squares.real),
            "log10_true_frf": _log10_re_im(least_squares),
            "log10_true_frf_clean": _log10_re_im(np.vdot(a0, b0) / np.vdot(a0, a0)),
            "frf_error_pct": float(100 * np.median(np.abs(He / H[:, dof] - 1))),
            "frf_error_max_pct": float(100 * np.max(np.abs(He / H[:, dof] - 1)))}


def best_curve_error(element: NonlinearElement, truth: NonlinearElement,
                     span: tuple[float, float]) -> float:
    """RMS error [% of peak] of the best least-squares spline ordinates for the true
    force over the measured range: what the knots allow at best."""
    x = np.linspace(*span, 2001)
    basis, force = element.basis(x), truth.force(x)
    ordinates = np.linalg.lstsq(basis, force, rcond=None)[0]
    return float(100 * np.sqrt(np.mean((basis @ ordinates - force) ** 2))
                 / np.max(np.abs(force)))


# -- workloads --------------------------------------------------------------------------------
def clearance_nc2() -> NonlinearElement:
    """The NC2-Z stop as identified in IV.A: known clearance, unknown coefficient."""
    return NonlinearElement("clearance", *NC2, gap=AXIAL_GAP)


def input_rank(run: Run) -> tuple[int, int, int]:
    """Numerical rank of the stacked extended inputs E_i (Eq. 10) of a run built from the
    paper's powers in z and in the warped variable w, and its row count (m + s) i.

    E_i as :func:`fnsi.subspace.decompose` forms it (columns scaled to unit RMS). The rank
    counts singular values above max(shape) x eps x the largest (numpy's ``matrix_rank``
    rule): the directions below are fixed by rounding, not by the data.
    """
    settings = run.result.settings
    spectra = extended_spectra(run.measurement.select(settings.inputs, settings.outputs),
                               settings)[0]
    e = spectra.inputs.reshape(-1, spectra.inputs.shape[2])
    e = e / np.sqrt(np.mean(np.abs(e) ** 2, axis=0))
    stacked = np.empty((2 * e.shape[0], e.shape[1] * settings.block_rows))
    ranks = []
    for a in (0.0, band_warp(spectra.z)):
        lines = np.tile(warp_lines(spectra.z, a), spectra.inputs.shape[0])
        stacked_rows(e, row_basis(lines, settings.block_rows, "powers")[0], stacked)
        ranks.append(int(np.linalg.matrix_rank(stacked)))
    return ranks[0], ranks[1], stacked.shape[1]


def single_workload(name: str, measurement: Measurement, truth: Truth, paper_modes: dict,
                    figures: dict[str, str]) -> tuple[Run, list[str], dict, dict]:
    """single-39 or single-3: clearance basis at NC2-Z with the exact gap (IV.A).

    Returns the run, the report lines, the acceptance summary and the
    :func:`frf_evidence` of the run (what bounds its coefficient)."""
    run = Run(name, measurement, truth, clearance_settings(name), repeats=TIMING_REPEATS)
    coef = coefficient_summary(run, AXIAL_ADDED)
    p = PAPER_TABLE_5[name]
    c = run.result.coefficients[0]
    evidence = frf_evidence(run)
    rank_z, rank_w, rows = input_rank(run)
    lines = [
        f"{run.order_text()}. {run.timings_text()}.",
        "",
        _table(MODAL_HEADER, modal_rows(run, paper_modes)),
        "",
        f"{run.stabilised_text()}.",
        "",
        *response_lines(run, paper_modes),
        _table(["", "mean Re mu", "error [%]", "log10(Re/Im)", "time [s]"], [
            ["paper", f"{p[0]:.2f}", f"{p[1]:.2f}", f"{p[2]:.2f}", f"{p[3]:.1f}"],
            ["ours", f"{coef['mean_mu']:.3f}", f"{coef['mu_err_pct']:.3f}",
             f"{coef['log10_re_im']:.2f}", f"{coef['time_s']:.2f}"],
            ["truth", f"{AXIAL_ADDED:.2f}", "0", "inf", ""]]),
        "",
        f"mu(omega) flatness: weighted spread of Re mu around the estimate / estimate = "
        f"{c.variation:.4f}; imaginary part of the estimate = {c.estimate.imag:.3f}.",
        "",
        f"Where the coefficient error comes from: from the same measured spectra (excited "
        f"lines), Eq. 16-17 at the driving point with the *true* FRF of our model give a "
        f"band-mean mu of {evidence['mu_true_frf']:.3f} (least squares over the lines: "
        f"{evidence['mu_true_frf_ls']:.3f}, log10(Re/Im) "
        f"{evidence['log10_true_frf']:.2f}, and {evidence['log10_true_frf_clean']:.2f} from "
        f"the noise-free record; the band mean of a per-line ratio is sensitive to "
        f"the noise at anti-resonances), while the identified model's "
        f"driving-point FRF differs from the true one by {evidence['frf_error_pct']:.2f} % "
        f"(median over the band; max {evidence['frf_error_max_pct']:.2f} %).",
        "",
        f"Numerical conditioning: the stacked extended inputs E_i (Eq. 10, rows z_k^p E(k), "
        f"p < i) have numerical rank {rank_z} of their {rows} rows when built in z. The band "
        f"is {BAND[1] / run.measurement.fs:.0%} of the sampling rate, so z_k stays near 1 and "
        f"the powers z_k^p are nearly dependent: the elimination of Eq. 14 would remove "
        f"{rows - rank_z} directions fixed by rounding. Built in the warped variable w "
        f"(`frequency_warping`, used here) E_i has rank {rank_w} (see *Rounding*).",
        "",
        stabilisation_figure(run, figures["stabilisation"],
                             f"{name}: stabilisation diagram (paper Fig. "
                             f"{figures['stabilisation_paper']})"),
        _save(figures["coefficient"], plot_coefficients(
            c.frequencies, c.values[:, None], [c.name], truth=[AXIAL_ADDED],
            unit=per(FORCE_UNIT, LENGTH_UNIT),
            title=f"{name}: NC2-Z coefficient mu(omega) "
                  f"(paper Fig. {figures['coefficient_paper']})")),
    ]
    summary = {"max_freq_err_pct": run.max_frequency_error,
               "max_damp_err_pct": run.max_damping_error,
               "mu_err_pct": coef["mu_err_pct"], "log10_re_im": coef["log10_re_im"],
               "time_s": run.time_s}
    return run, lines, summary, evidence


def response_lines(run: Run, paper_modes: dict) -> list[str]:
    """The modes that carry the response, as the automatic order kept them (issue 20)."""
    rows, ok = response_rows(run, paper_modes)
    return [
        f"Modes carrying at least {RESPONSE_SHARE:.0%} of the response of these outputs to "
        f"the force over the band (share of the true linear response), as the automatic "
        f"order kept them: {'all kept, no spurious mode, within' if ok else 'NOT all kept within'}"
        f" the targets (|err f| <= {TARGETS['single39']['max_freq_err_pct']} %, |err zeta| "
        f"<= {TARGETS['single39']['max_damp_err_pct']} %). The other true modes carry less "
        f"than {RESPONSE_SHARE:.0%} each.",
        "",
        _table(["true mode", "response share [%]", "kept", "err f [%]", "err zeta [%]",
                "paper err f [%]", "paper err zeta [%]"], rows),
        "",
    ]


def settings_comparison(measurement: Measurement, truth: Truth) -> list[str]:
    """What the weighting and the line set change for single-39 and single-3 (the
    settings the benchmark does not use, for comparison)."""
    cases = [("single-39", {"weighting": False}), ("single-3", {"weighting": False}),
             ("single-3", {"line_set": "all"}),
             ("single-3", {"line_set": "all", "weighting": False})]
    rows = []
    for name, changes in cases:
        run = Run(name, measurement, truth, clearance_settings(name, **changes))
        coef = coefficient_summary(run, AXIAL_ADDED)
        settings = run.result.settings
        rows.append([name, settings.line_set, "on" if settings.weighting else "off",
                     str(run.result.order),
                     f"{run.max_frequency_error:.3f}", f"{run.max_damping_error:.2f}",
                     f"{coef['mu_err_pct']:.3f}", f"{coef['log10_re_im']:.2f}",
                     f"{run.time_s:.2f}"])
    return [
        "#### Other settings tried (not used above)",
        "",
        _table(["workload", "lines", "weighting", "order", "max err f [%]",
                "max err zeta [%]", "mu err [%]", "log10(Re/Im)", "time [s]"], rows),
    ]


#: Explicit orders of the order sweep.
SWEEP_ORDERS = (6, 8, 10, 12, 14, 16, 18, 20, 24)


def order_sweep(measurement: Measurement, truth: Truth) -> list[str]:
    """The coefficient and the modes at explicit orders (every pole kept, flagged), for
    single-39 and single-3: whether another order than the automatic one would do better."""
    rows = []
    for name in CLEARANCE_WORKLOADS:
        for order in SWEEP_ORDERS:
            run = Run(name, measurement, truth, clearance_settings(name, order=order))
            coef = coefficient_summary(run, AXIAL_ADDED)
            rows.append([name, str(order), f"{coef['mu_err_pct']:.3f}",
                         f"{coef['log10_re_im']:.2f}", str(run.result.modal.n_modes),
                         str(sum(run.stable_flags())), f"{run.max_frequency_error:.3f}",
                         f"{run.max_damping_error:.2f}"])
    return [
        "#### Coefficient and modes at explicit orders",
        "",
        _table(["workload", "order", "mu err [%]", "log10(Re/Im)", "poles kept",
                "confirmed", "max err f [%] (all poles)", "max err zeta [%] (all poles)"],
               rows),
    ]


#: Noise realisations of the scatter study and the seed of the first.
NOISE_REALISATIONS, NOISE_SEED = 20, 1000


@dataclass(frozen=True)
class Scatter:
    """Coefficient errors [%] of one workload over the noise realisations."""

    errors: np.ndarray
    target: float

    @property
    def within(self) -> int:
        """Realisations whose |error| meets the target."""
        return int(np.sum(np.abs(self.errors) <= self.target))


def noise_scatter(truth: Truth) -> tuple[list[str], dict[str, Scatter]]:
    """How much of the single-39 / single-3 coefficient error is this realisation's noise.

    The noise-free single record is identified once (the method's own error), then
    :data:`NOISE_REALISATIONS` records made of the same response plus new measurement
    noise (0.5 % of the bracket-tip RMS in 0-100 Hz, as :func:`fnsi.acquisition.acquire`
    adds it), each identified with the benchmark's settings, without and with the
    compensation of the basis noise (``compensate_basis_noise``).

    Returns the report lines and, per workload, the :class:`Scatter` of the benchmark's
    own settings (no compensation).
    """
    clean, _, _ = simulated("single", noise_percent=0.0)
    kept = slice(DISCARD * clean.period_length, None)
    reference = clean.output_index(BRACKET_TIP)
    cases = {"single-39": TARGETS["single39"]["mu_err_pct"],
             "single-3": TARGETS["single3"]["mu_err_pct"]}

    def errors(measurement: Measurement, name: str, compensate: bool = False,
               ) -> tuple[float, float, float, float]:
        run = Run(name, measurement, truth,
                  clearance_settings(name, compensate_basis_noise=compensate))
        c = run.result.coefficients[0]
        return (100 * (c.mean_real / AXIAL_ADDED - 1), c.log10_real_imag,
                run.max_frequency_error, run.max_damping_error)

    exact = {name: errors(clean, name) for name in cases}
    noisy: dict[tuple[str, bool], list] = {(n, c): [] for n in cases for c in (False, True)}
    for k in range(NOISE_REALISATIONS):
        noise = measurement_noise(clean.y, clean.fs, SIMULATION["noise_percent"], reference,
                                  kept, NOISE_BAND, NOISE_SEED + k)
        record = replace(clean, y=clean.y + noise)
        for name, compensate in noisy:
            noisy[name, compensate].append(errors(record, name, compensate))
    rows, scatter = [], {}
    for (name, compensate), values in noisy.items():
        mu, log10, freq, damp = (np.array(v) for v in zip(*values, strict=True))
        spread = Scatter(mu, cases[name])
        if not compensate:
            scatter[name] = spread
        rows.append([name, "on" if compensate else "off",
                     f"{exact[name][0]:+.3f}", f"{exact[name][1]:.2f}",
                     f"{mu.mean():+.3f} ± {mu.std(ddof=1):.3f}",
                     f"{spread.within} of {mu.size} (<= {spread.target:g} %)",
                     f"{log10.mean():.2f}", f"{freq.max():.3f}", f"{damp.max():.2f}"])
    return [
        f"#### Noise scatter of the coefficient ({NOISE_REALISATIONS} noise realisations)",
        "",
        "The same response without noise, then with new measurement noise of the same "
        "level each time (same excitation, same settings as above):",
        "",
        _table(["workload", "basis-noise compensation", "mu err, no noise [%]",
                "log10, no noise",
                "mu err with noise [%] (mean ± std)", "realisations within the target",
                "mean log10(Re/Im)", "max err f [%]", "max err zeta [%]"], rows),
    ], scatter


def macx_figure(run: Run, name: str) -> str:
    macx = macx_matrix(run.result.modal.shapes, run.truth_modes.shapes)
    return _save(name, plot_macx(macx, run.result.modal.frequencies,
                                 run.truth_modes.frequencies, label_b="true",
                                 title=f"{run.name}: MACX identified vs true (paper Fig. 6)"))


def paper_knots(x_range: tuple[float, float], gap: float = AXIAL_GAP, *, near: int = 10,
                side: str = "both") -> tuple[float, ...]:
    """The paper's uneven knots: ``near`` equal intervals within +-10 % of the stops.

    IV.B: 13 intervals, 10 of them near the gaps; IV.C: 9 intervals, 6 near. A two-sided
    clearance (``side`` "both") splits ``near`` between its stops and adds one interval
    inside the clearance (holding the equilibrium) and one from each neighbourhood to the
    measured extreme. The paper does not say how IV.C placed them at a one-sided stop
    ("positive" or "negative"); here all ``near`` intervals go to that stop, one from it
    to the extreme beyond, and two cover the free side.
    """
    low, high = x_range
    signs = {"both": (-1, 1), "positive": (1,), "negative": (-1,)}[side]
    knots = {low, high}
    for sign in signs:
        if not (low < -1.1 * gap if sign < 0 else high > 1.1 * gap):
            raise ValueError(f"the measured range {x_range} does not pass the stop at "
                             f"{sign * gap:+g} by 10 %: the paper's knots need contact there")
        knots.update(sign * np.linspace(0.9 * gap, 1.1 * gap, near // len(signs) + 1))
    if len(signs) == 1:
        knots.add((low if signs[0] > 0 else high) / 2)
    return tuple(sorted(float(k) for k in knots))


def averaged_relative(data: Measurement, dof: str, ref: str) -> np.ndarray:
    """Relative displacement dof - ref averaged over the kept periods, (R, samples): what
    the identification's bases see (``average_bases``)."""
    y = period_mean(kept_record(data.y, data.periods, DISCARD), data.periods - DISCARD)
    return y[..., data.output_index(dof)] - y[..., data.output_index(ref)]


def measured_range(measurement: Measurement, dof: str, ref: str) -> tuple[float, float]:
    """Range of the period-averaged relative displacement the identification sees."""
    x = averaged_relative(measurement, dof, ref)
    return float(x.min()), float(x.max())


def curve_of(run: Run, index: int) -> StiffnessCurve:
    """The identified stiffness curve of element ``index`` (ValueError if unidentifiable)."""
    element = run.result.settings.elements[index]
    for curve in run.result.stiffness:
        if curve.element.dof == element.dof and curve.element.ref == element.ref:
            return curve
    raise ValueError(f"{element.name}: no stiffness curve (coefficients not identifiable)")


def spline_element(measurement: Measurement, knots_kind: str) -> NonlinearElement:
    """Spline at NC2-Z with the paper's knots or 13 intervals of automatic knots."""
    if knots_kind == "paper":
        return NonlinearElement("spline", *NC2,
                                knots=paper_knots(measured_range(measurement, *NC2)))
    return NonlinearElement("spline", *NC2, intervals=13)


def linear_mimicry(measurement: Measurement, element: NonlinearElement) -> float:
    """RMS residual [%] of the best imitation of a linear spring (g = x) by the spline
    basis, over the measured relative displacement: near 0 means the spline cannot be told
    apart from the linear stiffness of the connection (part of the underlying structure)."""
    x = averaged_relative(measurement, *NC2).ravel()
    basis = element.resolve(x).basis(x)
    fit = basis @ np.linalg.lstsq(basis, x, rcond=None)[0]
    return float(100 * np.sqrt(np.mean((fit - x) ** 2) / np.mean(x**2)))


def spline3_settings(element: NonlinearElement) -> IdentificationSettings:
    """Settings of spline-3: the three outputs, automatic block rows, excited lines."""
    return settings_for(THREE, "auto", [element], DRIVING_POINT, line_set="excited")


def spline_workload(measurement: Measurement, truth: Truth, knots_kind: str,
                    ) -> tuple[Run, list[str], float]:
    """spline-3: cubic splines at NC2-Z, paper knots or automatic knots (IV.B)."""
    element = spline_element(measurement, knots_kind)
    run = Run(f"spline-3 ({knots_kind} knots)", measurement, truth, spline3_settings(element))
    true_element = next(e for e in truth.elements if (e.dof, e.ref) == NC2)
    curve = curve_of(run, 0)
    error = curve_error_percent(curve, true_element)
    tag = knots_kind.replace(" ", "_")
    resolved = run.result.settings.elements[0]
    close = stiffness_curve(curve.element, np.asarray(curve.element.coefficients),
                            (1.0, curve.x[-1]))
    lines = [
        f"#### {knots_kind} knots",
        "",
        f"Knots: {', '.join(f'{q:.3f}' for q in resolved.knots)} (length units). "
        f"{run.order_text()}. {run.timings_text()}.",
        "",
        _table(MODAL_HEADER, modal_rows(run, PAPER_TABLE_7)),
        "",
        f"Stiffness-curve RMS error over the measured range [{curve.x[0]:.3f}, "
        f"{curve.x[-1]:.3f}]: **{error:.2f} %** of its peak (target <= 3 %). The best "
        f"least-squares ordinates for these knots would give "
        f"{best_curve_error(resolved, true_element, (curve.x[0], curve.x[-1])):.2f} %: the "
        f"knots can represent the stop; the gap is the identified ordinates. A linear "
        f"spring g = x is imitated by this spline basis to within "
        f"{linear_mimicry(measurement, element):.2f} % RMS over the measured displacement "
        f"(the smaller, the less the spline can be told apart from the connection's "
        f"linear stiffness, which belongs to the underlying linear structure).",
        "",
        stabilisation_figure(run, f"fig09_stabilisation_{tag}.png",
                             f"spline-3, {knots_kind} knots: stabilisation (paper Fig. 9)"),
        _save(f"fig10a_curve_{tag}.png", plot_stiffness(
            [curve], truths=[true_element],
            title=f"spline-3, {knots_kind} knots: NC2-Z restoring force (paper Fig. 10a)",
            units=MODEL_UNITS)),
        _save(f"fig10b_closeup_{tag}.png", plot_stiffness(
            [close], truths=[true_element],
            title=f"spline-3, {knots_kind} knots: positive discontinuity (paper Fig. 10b)",
            units=MODEL_UNITS)),
    ]
    return run, lines, error


def spline_diagnostic(measurement: Measurement, truth: Truth) -> list[str]:
    """Sensitivity of spline-3 to the block rows (the paper's i = 100 on all lines is
    refused for periodic data), and the same splines from all 39 outputs."""
    true_element = next(e for e in truth.elements if (e.dof, e.ref) == NC2)
    cases = [(THREE, i, "excited") for i in (20, 30, "auto", 50)]
    cases += [(THREE, 100, "all"), (None, "auto", "all")]
    rows = []
    for outputs, block_rows, line_set in cases:
        for kind in ("paper", "automatic"):
            settings = settings_for(outputs, block_rows, [spline_element(measurement, kind)],
                                    DRIVING_POINT, line_set=line_set)
            n_outputs = str(len(outputs) if outputs else measurement.n_outputs)
            try:
                run = Run(f"spline-3 diagnostic ({kind} knots)", measurement, truth, settings)
            except ValueError as refusal:
                rows.append([kind, n_outputs, str(block_rows), line_set,
                             f"refused: {refusal}", "", "", "", ""])
                continue
            rows.append([kind, n_outputs, str(run.result.settings.block_rows), line_set,
                         f"{run.result.order}",
                         f"{curve_error_percent(curve_of(run, 0), true_element):.2f}",
                         f"{run.max_frequency_error:.3f}", f"{run.max_damping_error:.2f}",
                         f"{run.time_s:.2f}"])
    return [
        "#### Sensitivity to the block rows, and all 39 outputs",
        "",
        _table(["knots", "outputs", "i", "lines", "order", "curve RMS error [%]",
                "max err f [%]", "max err zeta [%]", "time [s]"], rows),
    ]


#: multi-18 outputs: both sides of each NC in its stop's lateral axis and in Z, then the
#: wheel along the excitation direction and axially.
LATERAL = {"NC1": "X", "NC2": "X", "NC3": "Y", "NC4": "Y"}
W_DIAGONAL = "W_XY"


def multi_outputs() -> tuple[str, ...]:
    pairs = [(f"{nc}w_{a}", f"{nc}b_{a}") for nc, a in LATERAL.items()]
    pairs += [(f"{nc}w_Z", f"{nc}b_Z") for nc in LATERAL]
    return (*(n for p in pairs for n in p), W_DIAGONAL, "W_Z")


def with_diagonal(measurement: Measurement, truth: Truth) -> tuple[Measurement, Truth]:
    """Add the wheel displacement along the excitation direction, (W_X + W_Y) / sqrt 2,
    as an output channel (measured and true shapes), the driving point of the force."""
    ix, iy = measurement.output_index("W_X"), measurement.output_index("W_Y")
    diagonal = (measurement.y[..., ix] + measurement.y[..., iy]) / np.sqrt(2.0)
    data = replace(measurement, y=np.concatenate([measurement.y, diagonal[..., None]], axis=2),
                   output_names=(*measurement.output_names, W_DIAGONAL))
    modal = truth.modal
    jx, jy = modal.output_names.index("W_X"), modal.output_names.index("W_Y")
    shapes = np.concatenate(
        [modal.shapes, ((modal.shapes[:, jx] + modal.shapes[:, jy]) / np.sqrt(2.0))[:, None]],
        axis=1)
    return data, replace(truth, modal=replace(modal, shapes=shapes,
                                              output_names=(*modal.output_names, W_DIAGONAL)))


def multi_workload(measurement: Measurement, truth: Truth,
                   ) -> tuple[Run, list[str], dict, MultiEvidence]:
    """multi-18: eight splines with automatic knots, 9 intervals each (IV.C).

    Returns the run, the report lines, the acceptance summary and the
    :class:`MultiEvidence` of :func:`multi_evidence`."""
    data, truth = with_diagonal(measurement, truth)
    try:  # the paper's i = 50, for the record
        stop_run(data, truth, "", "spline", block_rows=50)
        paper_rows = "The paper's i = 50 was accepted."
    except ValueError as refusal:
        paper_rows = f"The paper's i = 50 is refused by `identify()`: {refusal}."
    run = stop_run(data, truth, "", "spline")
    curves, errors, rows = [], [], []
    for k, element in enumerate(truth.elements):
        curve = curve_of(run, k)
        curves.append(curve)
        errors.append(curve_error_percent(curve, element))
        rows.append([f"spline at the stop {element.dof}-{element.ref}",
                     f"[{curve.x[0]:.2f}, {curve.x[-1]:.2f}]",
                     f"{errors[-1]:.2f}"])
    exceedances = [
        [key.replace("_", "-"), f"{TABLE_3[key]:,}", f"{TABLE_8[key]:,}",
         f"{truth.exceedances[next(e.name for e in truth.elements if _stop_key(e) == key)]:,}"]
        for key in TABLE_8]
    lines = [
        "Table 8 analogue: clearance exceedances (samples in contact over the 6 kept periods).",
        "",
        _table(["stop", "paper Table 3 (single)", "paper Table 8 (multi)", "ours (multi)"],
               exceedances),
        "",
        f"{run.order_text()}. {run.timings_text()}. {paper_rows}",
        "",
        _table(MODAL_HEADER, modal_rows(run, PAPER_TABLE_9)),
        "",
        f"{run.stabilised_text()}.",
        "",
        "Stiffness curves (automatic knots, 9 intervals, no knowledge of the clearances):",
        "",
        _table(["element", "measured range", "RMS error [% of peak]"], rows),
        "",
        stabilisation_figure(run, "fig11_stabilisation_multi18.png",
                             "multi-18: stabilisation diagram (paper Fig. 11)"),
        _save("fig12_curves_multi18.png", plot_stiffness(
            curves, truths=list(truth.elements),
            title="multi-18: WEMS restoring forces (paper Fig. 12 a-f)", units=MODEL_UNITS,
            warnings=[s.caption for s in run.result.separability])),
    ]
    evidence_lines, evidence = multi_evidence(run, data, truth)
    lines += ["", *evidence_lines]
    summary = {"max_freq_err_pct": run.max_frequency_error,
               "max_damp_err_pct": run.max_damping_error,
               "max_curve_rms_pct": float(max(errors)), "time_s": run.time_s}
    return run, lines, summary, evidence


#: Variant of the structure for the separability study: the bracket tip node NC1b 2.5
#: times more flexible in Z than in the tuned model (the tip of a cantilever shelf).
ASYMMETRIC_BRACKET = {"bracket_tip_z": 0.4}


MIRROR_PAIRS = ((0, 1), (2, 3), (4, 5), (6, 7))
"""Indices of the mirror stops among the eight (NC1 and NC2, NC3 and NC4, lateral then
axial), the order of :func:`stop_elements`."""


def mirror_correlations(data: Measurement, elements) -> list[float]:
    """Correlation of each stop's relative displacement with its mirror stop's
    (:data:`MIRROR_PAIRS`, elements in the order of :func:`stop_elements`) over the
    period-averaged kept record."""
    relative = [averaged_relative(data, e.dof, e.ref)[0] for e in elements]
    correlations = [math.nan] * len(elements)
    for i, j in MIRROR_PAIRS:
        correlations[i] = correlations[j] = float(np.corrcoef(relative[i], relative[j])[0, 1])
    return correlations


@dataclass(frozen=True)
class PairLaw:
    """The force two stops exert together along the motion they share.

    With x_j = a x_i + c fitted over the record and q = x_i, virtual work gives the pair's
    force along q as f_i(q) + a f_j(a q + c): moving force from one stop to the other
    along that motion (what a confounded fit does freely) leaves it unchanged.
    """

    names: tuple[str, str]
    slope: float
    residual: float
    q: np.ndarray
    identified: np.ndarray
    exact: np.ndarray

    @property
    def error_pct(self) -> float:
        """RMS error in % of the exact pair force's peak, as :func:`curve_error_percent`."""
        return float(100 * np.sqrt(np.mean((self.identified - self.exact) ** 2))
                     / np.max(np.abs(self.exact)))


def pair_laws(run: Run, data: Measurement) -> list[PairLaw]:
    """:class:`PairLaw` of each mirror pair; ``residual`` is sqrt(1 - r^2), the RMS of
    x_j - a x_i - c over that of x_j, and q spans the part of x_i's measured range that
    a q + c maps into x_j's."""
    laws = []
    for i, j in MIRROR_PAIRS:
        ci, cj = curve_of(run, i), curve_of(run, j)
        xi, xj = (averaged_relative(data, c.element.dof, c.element.ref)[0] for c in (ci, cj))
        slope, offset = np.polyfit(xi, xj, 1)
        mapped = slope * ci.x + offset
        q = ci.x[(mapped >= cj.x[0]) & (mapped <= cj.x[-1])]
        laws.append(PairLaw(
            (_stop_key(ci.element), _stop_key(cj.element)), float(slope),
            float(np.sqrt(max(1.0 - np.corrcoef(xi, xj)[0, 1] ** 2, 0.0))), q,
            *(f_i.force(q) + slope * f_j.force(slope * q + offset)
              for f_i, f_j in ((ci.element, cj.element),
                               (run.truth.elements[i], run.truth.elements[j])))))
    return laws


def pair_figure(laws: list[PairLaw]) -> str:
    """Identified and exact pair forces, one panel per mirror pair."""
    figure = new_figure(4.2 * len(laws), 3.8)
    for ax, law in zip(figure.subplots(1, len(laws)), laws, strict=True):
        ax.plot(law.q, law.exact, color="k", lw=1.6, label="exact")
        ax.plot(law.q, law.identified, color="tab:blue", lw=1.2,
                label=f"identified ({law.error_pct:.1f} %)")
        ax.set_title(f"{law.names[0]} + {law.names[1]} (a = {law.slope:+.2f})")
        ax.set_xlabel(f"Relative displacement at {law.names[0]} [{MODEL_UNITS.length}]")
        ax.set_ylabel(f"Pair force [{MODEL_UNITS.force}]")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="small")
    figure.suptitle("multi-18: force of each mirror pair along its shared motion, "
                    "from the eight identified splines")
    return _save("fig12g_pair_forces_multi18.png", png_bytes(figure))


def pair_lines(laws: list[PairLaw], clean_laws: list[PairLaw], each: list[float],
               ) -> list[str]:
    """Table and figure of the :func:`pair_laws` of the measured and noise-free records;
    ``each`` holds the curve error of every stop of the measured record."""
    rows = [[f"{law.names[0]} + {law.names[1]}", f"{law.slope:+.3f}",
             f"{law.residual:.3f}", f"{each[i]:.1f}, {each[j]:.1f}",
             f"{law.error_pct:.1f}", f"{free.error_pct:.1f}"]
            for law, free, (i, j) in zip(laws, clean_laws, MIRROR_PAIRS, strict=True)]
    together = [k for k, law in enumerate(laws) if law.residual < PAIR_RESIDUAL]
    apart = [laws[k].residual for k in range(len(laws)) if k not in together]
    pair_errors = [laws[k].error_pct for k in together]
    stop_errors = [each[i] for k in together for i in MIRROR_PAIRS[k]]
    return [
        "What the data do fix for confounded stops is the force each mirror pair exerts "
        "along the motion it shares: with x_j = a x_i + c fitted over the record and q = "
        "x_i, virtual work gives f_i(q) + a f_j(a q + c), which does not change when the "
        "fit moves force from one stop to the other along that motion. From the same "
        "eight identified splines:",
        "",
        _table(["pair", "slope a", "residual of x_j = a x_i + c", "curve errors, each "
                "stop [%]", "pair force error [%]", "pair force error, noise-free [%]"],
               rows),
        "",
        f"Where the stops move together (residual below {PAIR_RESIDUAL}: "
        f"{', '.join(' + '.join(laws[k].names) for k in together)}) the pair forces are "
        f"within {min(pair_errors):.1f}-{max(pair_errors):.1f} % of peak while each stop's "
        f"curve is {min(stop_errors):.0f}-{max(stop_errors):.0f} % off: FNSI identifies "
        f"what the data determine, and the split between the stops is what the symmetry "
        f"hides. The other pairs move together only away from their stops (residual "
        f"{min(apart):.2f}-{max(apart):.2f}: where one stop engages, its mirror keeps "
        f"moving), so no pair law exists for them; the paper itself superimposes its "
        f"lateral curves, 'as they cannot be distinguished owing to the symmetry of the "
        f"WEMS device and of the external forcing' (Section IV.C, Figures 12 a-b).",
        "",
        pair_figure(laws),
    ]


#: Residual of x_j = a x_i + c below which a mirror pair moves together.
PAIR_RESIDUAL = 0.05


def stop_elements(data: Measurement, truth: Truth, form: str) -> list[NonlinearElement]:
    """The eight stops as splines of 9 intervals with automatic knots (``form``
    "spline") or with the paper's knots, 6 of them within +-10 % of the true clearances
    (IV.C, "paper"), or as clearances with their true gaps ("clearance")."""
    if form == "spline":
        return [NonlinearElement("spline", e.dof, e.ref, intervals=9) for e in truth.elements]
    if form == "paper":
        return [NonlinearElement("spline", e.dof, e.ref, knots=paper_knots(
                    measured_range(data, e.dof, e.ref),
                    e.gap or e.gap_positive or e.gap_negative, near=6, side=e.side))
                for e in truth.elements]
    return [replace(e, coefficients=None) for e in truth.elements]


def stop_run(data: Measurement, truth: Truth, name: str, form: str, *,
             block_rows: int | str = "auto", weighting: bool = True) -> Run:
    """multi-18 identified with the stops in ``form`` (:func:`stop_elements`), automatic
    order (noise weighting off for a noise-free record, which has no noise to weight by),
    in z: its results do not depend on rounding (the *Rounding* section)."""
    settings = settings_for(multi_outputs(), block_rows, stop_elements(data, truth, form),
                            (data.input_names[0], W_DIAGONAL), frequency_warping=False)
    return Run(f"multi-18 {name}".rstrip(), data, truth, replace(settings, weighting=weighting))


def curve_errors(run: Run) -> list[float]:
    return [curve_error_percent(curve_of(run, k), e) for k, e in enumerate(run.truth.elements)]


def _percents(values) -> str:
    return ", ".join(f"{v:.1f}" for v in values)


@dataclass(frozen=True)
class MultiEvidence:
    """What bounds the multi-18 spline results, as :func:`multi_evidence` measures it.

    Curve errors in % of peak, one per stop; damping errors in %; ``separability`` the
    u of each spline; ``pair_forces`` the error of each mirror pair that moves together;
    ``paper_knots_*`` the splines with the paper's knots, placed knowing the clearances.
    """

    separability: list[float]
    noise_free_curves: list[float]
    noise_free_damping: float
    paper_knots_curves: list[float]
    paper_knots_damping: float
    clearance_curves: list[float]
    clearance_damping: float
    pair_forces: list[float]


def multi_evidence(run: Run, data: Measurement, truth: Truth,
                   ) -> tuple[list[str], MultiEvidence]:
    """Why the spline configuration of IV.C fails on our model: a dimension count, the
    separability of the stops, the same data identified with the true clearance forms,
    the noise-free record and a variant of the structure without its mirror symmetry."""
    harmonic = band_lines(data.period_length, data.fs, BAND).size
    resolved = run.result.settings.elements
    q = data.n_inputs + sum(e.n_basis for e in resolved)
    diagnostic = stop_run(data, truth, "clearance diagnostic", "clearance")
    spans = [curve_of(run, k).x[[0, -1]] for k in range(len(resolved))]
    best = [best_curve_error(e, t, tuple(span))
            for e, t, span in zip(resolved, truth.elements, spans, strict=True)]
    correlations = mirror_correlations(data, truth.elements)
    errors, known_errors = curve_errors(run), curve_errors(diagnostic)
    rows = [[f"{s.name[len('spline '):]}", f"{s.unexplained:.3f}",
             ", ".join(p.split(" ", 1)[-1] for p in s.partners), f"{c.unexplained:.3f}",
             f"{r:+.3f}", f"{e:.1f}", f"{d:.1f}"]
            for s, c, r, e, d in zip(run.result.separability, diagnostic.result.separability,
                                     correlations, errors, known_errors, strict=True)]
    clean, clean_truth, _ = simulated("multi", 0.0)
    clean_data, clean_truth = with_diagonal(clean, clean_truth)
    clean_splines, clean_known = (stop_run(clean_data, clean_truth, "noise-free", form,
                                           weighting=False) for form in ("spline", "clearance"))
    variant, variant_truth, _ = simulated("multi", variant=ASYMMETRIC_BRACKET)
    variant_data, variant_truth = with_diagonal(variant, variant_truth)
    variant_splines, variant_known = (stop_run(variant_data, variant_truth, "variant", form)
                                      for form in ("spline", "clearance"))
    counts = [variant_truth.exceedances[e.name] for e in variant_truth.elements]
    clean_errors, laws = curve_errors(clean_splines), pair_laws(run, data)
    paper = stop_run(data, truth, "paper knots", "paper")
    paper_errors = curve_errors(paper)
    evidence = MultiEvidence(
        separability=[s.unexplained for s in run.result.separability],
        noise_free_curves=clean_errors, noise_free_damping=clean_splines.max_damping_error,
        paper_knots_curves=paper_errors, paper_knots_damping=paper.max_damping_error,
        clearance_curves=known_errors, clearance_damping=diagnostic.max_damping_error,
        pair_forces=[law.error_pct for law in laws if law.residual < PAIR_RESIDUAL])
    return [
        f"Dimension count: the excitation is periodic, so the signal lives on the "
        f"{harmonic} harmonic lines of the band, i.e. {2 * harmonic} real columns of the "
        f"data matrices (the other lines of the 6-period record carry noise only). With "
        f"{q} extended inputs, the paper's i = 50 makes E_i {q * 50} rows, more than "
        f"the signal columns: the projection of Eq. 14 would remove the signal from Y_i "
        f"and leave noise. The automatic count i = {run.result.settings.block_rows} gives "
        f"{q * run.result.settings.block_rows} rows.",
        "",
        f"Representation: the best least-squares ordinates of these automatic knots for the "
        f"true laws reach {_percents(best)} % of peak: the knots are not the limit.",
        "",
        "Separability (`IdentificationResult.separability`, `fnsi/separability.py`): u is "
        "the smallest fraction of a combination of an element's basis spectra that the "
        "other extended inputs and a linear spring and dashpot at the elements (which the "
        "underlying linear model holds) cannot reproduce on the analysis lines; an error "
        "of the fitted response grows by about 1 / u in that element's force, and below "
        f"{SEPARABILITY_LIMIT} the element is reported as confounded. The mirror "
        "correlation is that of the stop's relative displacement with the stop on the "
        "other side of the wheel (NC1 with NC2, NC3 with NC4).",
        "",
        _table(["stop", "u, splines", "reproduced by", "u, clearances",
                "mirror correlation", "curve error, splines [%]",
                "curve error, clearances [%]"], rows),
        "",
        f"The wheel and its cross are practically rigid and our model is symmetric, so the "
        f"axial stops on either side of the wheel move as mirror images (correlation "
        f"{correlations[4]:+.3f} and {correlations[6]:+.3f}) and the lateral ones together "
        f"({correlations[0]:+.3f}, {correlations[2]:+.3f}); the two-sided spline of one "
        f"stop then repeats its mirror's. The paper's structure is not symmetric: its "
        f"Table 8 counts {TABLE_8['NC1_Z']:,} and {TABLE_8['NC2_Z']:,} contacts at NC1-Z "
        f"and NC2-Z, ours {truth.exceedances[truth.elements[4].name]:,} and "
        f"{truth.exceedances[truth.elements[5].name]:,}. This is not noise: on the "
        f"noise-free record the spline curves are off by {_percents(clean_errors)} "
        f"% (clearances: {_percents(curve_errors(clean_known))} %) and the largest "
        f"damping error of its kept modes is {clean_splines.max_damping_error:.2f} % "
        f"(clearances: {clean_known.max_damping_error:.2f} %).",
        "",
        f"Nor is it where the knots are: with the paper's own knots for IV.C, placed "
        f"knowing the clearances (9 intervals, 6 of them within ±10 % of the stops; at a "
        f"one-sided lateral stop all six at that stop), the splines stay confounded "
        f"(separability u {_span([x.unexplained for x in paper.result.separability], 3)}), "
        f"their curves are off by {_percents(paper_errors)} % and the largest damping "
        f"error is {paper.max_damping_error:.2f} % (order {paper.result.order}).",
        "",
        *pair_lines(laws, pair_laws(clean_splines, clean_data), errors),
        "",
        f"Variant without the mirror symmetry in Z: the bracket tip node NC1b 2.5 times "
        f"more flexible axially (`ASYMMETRIC_BRACKET`), the same excitation. Contacts "
        f"{', '.join(f'{c:,}' for c in counts)} (order of the table above; paper Table 8: "
        f"{', '.join(f'{v:,}' for v in TABLE_8.values())}); mirror correlations "
        f"{_percents(100 * r for r in mirror_correlations(variant_data, variant_truth.elements))} "
        f"%. Spline curves: {_percents(curve_errors(variant_splines))} % (clearances: "
        f"{_percents(curve_errors(variant_known))} %); separability u of the splines "
        f"{', '.join(f'{s.unexplained:.3f}' for s in variant_splines.result.separability)}. "
        f"The axial curves come within a few percent once the structure separates them "
        f"(u above {SEPARABILITY_LIMIT}); the lateral ones do not: they stay confounded "
        f"with each other and with a linear spring at their connections (u below "
        f"{SEPARABILITY_LIMIT}), and the modes suffer with them (max damping error "
        f"{variant_splines.max_damping_error:.1f} % with splines, "
        f"{variant_known.max_damping_error:.2f} % with clearances), as expected if a basis "
        f"that imitates a linear spring also takes part of the linear response out of Y_i "
        f"with E_i (Eq. 14).",
        "",
        f"Diagnostic (not the paper's setting): the same data with the eight stops as "
        f"clearance bases with their true gaps (9 extended inputs, automatic block rows): "
        f"{diagnostic.order_text()}; max frequency error "
        f"{diagnostic.max_frequency_error:.2f} %, max damping error "
        f"{diagnostic.max_damping_error:.2f} %; {diagnostic.timings_text()}.",
        "",
        _table(MODAL_HEADER, modal_rows(diagnostic, PAPER_TABLE_9)),
    ], evidence


#: Relative size of the rounding-level perturbation of the outputs, and the perturbed
#: copies of each record, in the rounding study.
ROUNDING_SIZE, ROUNDING_COPIES = 1e-13, 3


def _perturbed(record: Measurement, copy: int) -> Measurement:
    """The record itself (copy 0) or its outputs times 1 + ROUNDING_SIZE x N(0, 1)."""
    if copy == 0:
        return record
    noise = np.random.default_rng(copy).standard_normal(record.y.shape)
    return replace(record, y=record.y * (1 + ROUNDING_SIZE * noise))


def _span(values: list[float], digits: int) -> str:
    """'smallest - largest' of ``values``."""
    return f"{min(values):.{digits}f} - {max(values):.{digits}f}"


def rounding_study(single: Measurement, single_truth: Truth, multi: Measurement,
                   multi_truth: Truth) -> list[str]:
    """Whether each workload's result is fixed by its data or by rounding.

    Each record is identified as is and after a perturbation of a few units in the last
    place of every output sample (:func:`_perturbed`), with the data matrices built in z
    (the paper's Eq. 9-11) and in the warped variable w (``frequency_warping``).
    """
    data, truth = with_diagonal(multi, multi_truth)
    nc2 = next(e for e in single_truth.elements if (e.dof, e.ref) == NC2)

    def mu_error(run: Run) -> float:
        return 100 * (run.result.coefficients[0].mean_real / AXIAL_ADDED - 1)

    cases = [
        ("single-39", single, single_truth, "mu error",
         lambda m: clearance_settings("single-39"), mu_error),
        ("single-3", single, single_truth, "mu error",
         lambda m: clearance_settings("single-3"), mu_error),
        ("spline-3, automatic knots", single, single_truth, "curve error",
         lambda m: spline3_settings(spline_element(m, "automatic")),
         lambda run: curve_error_percent(curve_of(run, 0), nc2)),
        ("multi-18", data, truth, "largest curve error",
         lambda m: settings_for(multi_outputs(), "auto", stop_elements(m, truth, "spline"),
                                (data.input_names[0], W_DIAGONAL)),
         lambda run: max(curve_errors(run))),
    ]
    rows = []
    for name, record, workload_truth, label, settings_of, metric in cases:
        runs: dict[bool, list[Run]] = {False: [], True: []}
        for copy in range(ROUNDING_COPIES + 1):
            copied = _perturbed(record, copy)
            for warp in runs:
                runs[warp].append(Run(name, copied, workload_truth,
                                      replace(settings_of(copied), frequency_warping=warp)))
        for warp, found in runs.items():
            values = [metric(r) for r in found]
            rows.append([name, "w" if warp else "z",
                         ", ".join(str(r.result.order) for r in found),
                         f"{label}: " + ", ".join(f"{v:+.3f}" for v in values),
                         _span([r.max_frequency_error for r in found], 3),
                         _span([r.max_damping_error for r in found], 2)])
    return [
        f"Each record identified as is and after multiplying every output sample by 1 + "
        f"{ROUNDING_SIZE:g} x N(0, 1) ({ROUNDING_COPIES} copies, a few units in the last "
        f"place: no measurement can tell them apart), with the data matrices of Eq. 9-11 "
        f"built in z, as the paper writes them, and in the warped variable w = (z - a) / "
        f"(1 - a z) (`IdentificationSettings.frequency_warping`, `fnsi.subspace."
        f"band_warp`), which spreads the band over the unit circle. A result that moves "
        f"is fixed by rounding, not by the data: it also moves with the BLAS build and its "
        f"thread count.",
        "",
        _table(["workload", "variable", "automatic order (as is, then the copies)",
                "result [%] (as is, then the copies)", "max err f [%]",
                "max err zeta [%]"], rows),
        "",
        "The single-record workloads (i = 33 to 100 on a band of 2 % of fs) use w in the "
        "sections above; multi-18 (i = 20, 81 extended inputs) does not depend on rounding "
        "and stays in z.",
    ]


def _stop_key(element: NonlinearElement) -> str:
    """Table 3 / 8 key (``NC2_Z``) of a WEMS stop element."""
    node, axis = element.dof.split("_")
    return f"{node[:-1]}_{axis}"


# -- report -----------------------------------------------------------------------------------
JSON_KEYS = {
    "single39": ("max_freq_err_pct", "max_damp_err_pct", "mu_err_pct", "log10_re_im", "time_s"),
    "single3": ("max_freq_err_pct", "max_damp_err_pct", "mu_err_pct", "log10_re_im", "time_s"),
    "spline3": ("curve_rms_pct_paper_knots", "curve_rms_pct_auto_knots"),
    "multi18": ("max_freq_err_pct", "max_damp_err_pct", "max_curve_rms_pct", "time_s"),
}
"""Keys of the last output line (None when a workload failed)."""

TARGETS = {
    "single39": {"max_freq_err_pct": 0.2, "max_damp_err_pct": 3.0, "mu_err_pct": 0.05,
                 "log10_re_im": -3.0, "time_s": 2.0},
    "single3": {"max_freq_err_pct": 0.2, "mu_err_pct": 0.1, "time_s": 0.2},
    "spline3": {"curve_rms_pct_paper_knots": 3.0, "curve_rms_pct_auto_knots": 3.0},
    "multi18": {"max_freq_err_pct": 0.5, "max_damp_err_pct": 3.0, "max_curve_rms_pct": 5.0,
                "time_s": 20.0},
}
"""Acceptance targets (issue 5): upper bounds; a negative bound -b means ">= b"."""


LIMITS = [
    "## What limits the results",
    "",
    "Numbers quoted here are measured in the sections below, except those marked "
    "*(development)*, measured with the same data and library while the changes were "
    "made (scripts not kept).",
    "",
    "- **Coefficient of single-39: the target is below the scatter of one realisation.** "
    "Over 20 noise realisations of the same response (the *Noise scatter* table) the "
    "estimate is unbiased to a few hundredths of a percent but scatters by about 0.3 % "
    "from one realisation to the next, so an error <= 0.05 % happens in a quarter of "
    "them: this record meets it, as the paper's single record did (0.03 %), and another "
    "realisation of the same noise may not. The scatter is the noise of the basis "
    "functions, which are computed from the noisy displacement: with basis noise alone "
    "the spread is 0.40 %, with output noise alone 0.02 % *(development)*; the nonlinear "
    "force is largely coherent with the input, so its noisy part is magnified. Averaging "
    "the bases over the periods (the library default), a bias-compensated least squares "
    "for B^e and D^e (`compensate_basis_noise`, in the table), a jackknife of the "
    "averaged bases and a Wiener filter of the displacement *(development)* do not "
    "reduce the scatter.",
    "- **Coefficient of single-3: model truncation.** Without noise the error is already "
    "the one in the table's first column (about -0.5 %): at the automatic order the "
    "three-output model leaves out the weakly excited 32.6 and 38.3 Hz modes, which still "
    "shape the driving-point FRF *(development)*; orders of 30 and more include them "
    "(-0.05 % without noise) but scatter by +-1 % with noise *(development)*. With noise "
    "the mean error is about -0.3 % and scatters by 0.3 %, and even the true FRF of our "
    "model misses the target on this record (the acceptance row). Without noise "
    "weighting this record happens to meet it (the *Other settings* table), but over the "
    "20 realisations every combination of line set and weighting keeps a mean of -0.17 "
    "to -0.29 % and a scatter of 0.28 %, at most 5 of 20 within 0.1 % *(development)*: "
    "choosing the setting that suits one record would be fitting its noise.",
    "- **log10(Re/Im): the identified FRF, not the data.** With the true FRF of our model "
    "the same measured spectra give the log10 of the single-39 evidence line (about 2.4 "
    "with this record's noise, about 4 without noise; over the 20 noise realisations 2.5 "
    "to 3.9, 14 of them at 3 or more *(development)*), while the identified models give "
    "about 2 at every explicit order (6 to 24 in the order table; up to 38, and without "
    "noise, *(development)*): the identified model's error (the evidence line's "
    "driving-point FRF error) goes into the imaginary part of mu, about 1 % of its real "
    "part. A second realisation of the excitation (seed 1) added to the record does not "
    "raise it for single-39 (1.95, warped or not), though it does for single-3 (3.5) "
    "*(development)*. Orders that add poles add spurious ones (errors of the "
    "unconfirmed poles in the order table).",
    "- **Rounding, and the frequency warping used for the single record.** The band is 2 "
    "% of the sampling rate, so z_k stays near 1, the rows z_k^p E(k) of E_i are nearly "
    "dependent and, built in z as the paper writes Eq. 9-11, E_i is numerically "
    "rank-deficient (the *Numerical conditioning* lines): the elimination of Eq. 14 "
    "removes directions that rounding, not the data, defines. The *Rounding* section "
    "measures it: a perturbation of a few units in the last place moves the single-39 "
    "order between 6 and 10 and its coefficient error between -0.07 and -0.26 %, and the "
    "spline-3 modes; one and two BLAS threads, or two numpy builds, do the same (earlier "
    "reports of this benchmark: single-39 at order 6 with 0.073 %, then at order 10 with "
    "0.293 %, on the same data). Built in the warped variable w = (z - a) / (1 - a z), "
    "which spreads the band over the unit circle and keeps the model order, the results "
    "no longer move (the *Rounding* table), so the single-record workloads use it "
    "(`frequency_warping=True`). It is not the library default: on the wide-band records "
    "of the test suite (band up to a quarter of fs) eleven tests failed with it, e.g. "
    "exact 3-DOF data at i = 10 gave damping errors of 0.11 % instead of 0.0006 %, and "
    "a noisy 3-DOF chain an automatic order of 8 instead of 4 *(development)*; "
    "multi-18 (i = 20, 81 extended inputs) does not depend on rounding in z, and in w "
    "its close pair at 28.2 Hz comes out as two modes, one 1.3 % off (the *Rounding* "
    "table), so it stays in z. Eliminating only the numerically determined directions of "
    "E_i (singular values above 1e-8 or 1e-6 of the largest) was deterministic too, but "
    "kept worse weakly excited modes *(development)*.",
    "- **Modes kept.** The automatic order keeps the physical poles of the lowest order "
    "that holds the most of them: fully stable at the next order, on a column of the "
    "diagram spanning four orders or more, and carrying 0.1 % or more of the fitted "
    "response over the band; a pole more damped than 20 % is never stable "
    "(`StabilisationTolerances.max_damping`; with warping, 2 of the 20 noise realisations"
    " otherwise kept a pole at 8.9 Hz with 44 % damping *(development)*). On single-39 "
    "the modes that carry the response of our model to the axial force (1, 3 and 5: 33, "
    "43 and 23 % of it) are kept, within the targets (the table under the modal table). "
    "The weakly excited modes the paper also lists (7-11) carry less than 0.01 % of the "
    "response of our model: orders 40-46 hold persistent poles, but none that carries "
    "0.1 % of the fitted response besides modes 1, 3 and 5, so the order choice stays at "
    "6; an explicit order returns every pole (the order table). Built in z, a "
    "rounding-level perturbation made the "
    "previous rule keep mode 8 with a 10 % damping error (the *Rounding* table).",
    "- **multi-18 splines: on our model the stops are confounded.** Frequencies and "
    "time meet the targets; the curves and the damping of mode 2 do not. Our reduced "
    "model is symmetric and its wheel cross practically rigid, so the axial stops on "
    "either side of the wheel move as mirror images and the lateral ones together (the "
    "*mirror correlation* column): a two-sided spline at one stop reproduces its "
    "mirror's, and FNSI, which fits one column of B^e and D^e per basis function, can "
    "move force between them at no cost in the fit. The *Separability* table measures "
    "it: u, the part of an element's bases that the others cannot reproduce, is below "
    "0.01 for the axial splines (an error of the fit grows a hundredfold in their "
    "curves) and below 0.05 for all eight, which `identify()` reports as confounded. It "
    "is not noise (the noise-free record gives curves as wrong) and not the "
    "knots (the best ordinates of the automatic knots are within a few percent, and the "
    "paper's own knots, placed knowing the clearances, give curves as wrong). What "
    "the data do determine, the force each axial mirror pair exerts along the motion it "
    "shares, the identified splines give within a few percent (the *pair force* table); "
    "the lateral pairs move apart exactly where their stops engage, and the paper itself "
    "superimposes its lateral curves because symmetry makes them indistinguishable. The "
    "paper's structure is not symmetric: its Table 8 counts unequal contacts at NC1-Z "
    "and NC2-Z, ours equal ones. In a variant of our structure with the bracket tip "
    "more flexible axially (the *Variant* line) the axial spline curves come within a "
    "few percent; the lateral ones do not, and stay confounded with each other and with "
    "a linear spring at their connections, and the modal damping stays off with them "
    "(presumably because a basis that imitates a linear spring also removes part of the "
    "linear response with E_i). With the same data the eight stops as "
    "clearance bases "
    "meet every target (the diagnostic table), damping of mode 2 included. We keep the "
    "reference structure as tuned (Table 1 modes, Table 3 and 8 regimes): retuning it to "
    "the paper's asymmetry would not meet these two targets either, since the variant's "
    "lateral curves and damping stay far off, and it would change the model that the "
    "other workloads and the tests are built on. The paper's i = 50 is refused: with "
    "periodic data it would eliminate every harmonic line.",
    "- **Time.** All identifications are within their targets; the decomposition "
    "dominates and scales with (lines x block rows x channels).",
]
"""Analysis of the misses; every number it refers to is measured in its section."""


def bounds(frf: dict[str, dict], scatter: dict[str, Scatter],
           multi: MultiEvidence | None) -> dict[tuple[str, str], str]:
    """What bounds each target that our model's data can miss, in numbers of this run.

    ``frf`` holds the :func:`frf_evidence` of single-39 and single-3, ``scatter`` the
    :func:`noise_scatter` of both, ``multi`` the :func:`multi_evidence` (None when a
    workload failed: its bounds are left out).
    """
    notes = {}
    for name, key in (("single-39", "single39"), ("single-3", "single3")):
        if name in frf:
            e = frf[name]
            notes[key, "log10_re_im"] = (
                f"the true FRF of our model gives {e['log10_true_frf']:.2f} on this record "
                f"({e['log10_true_frf_clean']:.2f} noise-free); the identified "
                f"driving-point FRF is {e['frf_error_pct']:.2f} % off (median)")
        if name in scatter:
            spread = scatter[name]
            notes[key, "mu_err_pct"] = (
                f"noise scatter: {spread.errors.mean():+.3f} ± "
                f"{spread.errors.std(ddof=1):.3f} % over {spread.errors.size} noise "
                f"realisations, {spread.within} within the target"
                + (f"; the true FRF of our model gives "
                   f"{100 * abs(frf[name]['mu_true_frf_ls'] / AXIAL_ADDED - 1):.3f} % on this "
                   f"record" if name in frf else ""))
    if multi is not None:
        confounded = f"splines confounded (separability u <= {max(multi.separability):.3f})"
        notes["multi18", "max_curve_rms_pct"] = (
            f"{confounded}: noise-free record {max(multi.noise_free_curves):.0f} %, the "
            f"paper's knots (clearances known) {max(multi.paper_knots_curves):.0f} %; the "
            f"same data with clearance bases {max(multi.clearance_curves):.1f} %; axial "
            f"mirror-pair forces {_percents(multi.pair_forces)} %")
        notes["multi18", "max_damp_err_pct"] = (
            f"{confounded}: noise-free record {multi.noise_free_damping:.2f} %, the "
            f"paper's knots {multi.paper_knots_damping:.2f} %; the same data with "
            f"clearance bases {multi.clearance_damping:.2f} %")
    return notes


def acceptance_rows(summary: dict, notes: dict[tuple[str, str], str]) -> list[list[str]]:
    """Rows of the acceptance table; a missed target carries its note from :func:`bounds`
    (or points to the analysis)."""
    rows = []
    for workload, targets in TARGETS.items():
        for key, bound in targets.items():
            value = summary[workload][key]
            if value is None:
                rows.append([workload, key, "failed", "", "**missed**", ""])
                continue
            ok = value >= -bound if bound < 0 else value <= bound
            rows.append([workload, key, f"{value:.4g}",
                         f">= {-bound:g}" if bound < 0 else f"<= {bound:g}",
                         "met" if ok else "**missed**",
                         "" if ok else notes.get((workload, key), "see *What limits the "
                                                                  "results*")])
    return rows


#: BLAS threads used when the caller does not set OPENBLAS_NUM_THREADS: on the shared
#: 2-core machine, OpenBLAS threads contending with other processes made a 300 x 300 SVD
#: take over a second (0.02 s single-threaded), so timings are taken single-threaded.
BLAS_THREADS = "1"


def main() -> None:
    if "OPENBLAS_NUM_THREADS" not in os.environ:
        # the thread count is read when numpy loads: run again with it set
        os.environ["OPENBLAS_NUM_THREADS"] = BLAS_THREADS
        os.execv(sys.executable, [sys.executable, *sys.argv])
    RESULTS.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    single, single_truth, single_info = simulated("single")
    multi, multi_truth, multi_info = simulated("multi")
    print(f"data ready in {time.perf_counter() - start:.1f} s "
          f"(single: {single_info}, multi: {multi_info})", flush=True)

    # what bounds the targets, gathered by the workloads for the acceptance table
    frf: dict[str, dict] = {}
    scatter: dict[str, Scatter] = {}
    multi_bounds: MultiEvidence | None = None

    def single39() -> tuple[list[str], dict]:
        run, lines, summary, frf["single-39"] = single_workload(
            "single-39", single, single_truth, PAPER_TABLE_4,
            {"stabilisation": "fig05_stabilisation_single39.png", "stabilisation_paper": "5",
             "coefficient": "fig07a_mu_single39.png", "coefficient_paper": "7a"})
        return [*lines, macx_figure(run, "fig06_macx_single39.png")], summary

    def single3() -> tuple[list[str], dict]:
        _, lines, summary, frf["single-3"] = single_workload(
            "single-3", single, single_truth, PAPER_TABLE_6,
            {"stabilisation": "fig08_stabilisation_single3.png", "stabilisation_paper": "8",
             "coefficient": "fig07b_mu_single3.png", "coefficient_paper": "7b"})
        scatter_lines, spreads = noise_scatter(single_truth)
        scatter.update(spreads)
        return [*lines, "", *settings_comparison(single, single_truth), "",
                *order_sweep(single, single_truth), "", *scatter_lines], summary

    def spline3() -> tuple[list[str], dict]:
        lines, errors = [], {}
        for kind in ("paper", "automatic"):
            _, part, errors[kind] = spline_workload(single, single_truth, kind)
            lines += [*part, ""]
        return ([*lines, *spline_diagnostic(single, single_truth)],
                {"curve_rms_pct_paper_knots": errors["paper"],
                 "curve_rms_pct_auto_knots": errors["automatic"]})

    def multi18() -> tuple[list[str], dict]:
        nonlocal multi_bounds
        _, lines, summary, multi_bounds = multi_workload(multi, multi_truth)
        return lines, summary

    summary: dict[str, dict] = {}
    sections: list[str] = []
    for key, title, workload in (
            ("single39", "single-39 (paper IV.A, Tables 4-5, Figures 5-7a)", single39),
            ("single3", "single-3 (paper IV.A, Tables 5-6, Figures 7b, 8)", single3),
            ("spline3", "spline-3 (paper IV.B, Table 7, Figures 9-10)", spline3),
            ("multi18", "multi-18 (paper IV.C, Tables 8-9, Figures 11-12)", multi18)):
        try:
            lines, summary[key] = workload()
        except Exception as error:  # report the failure, keep the other workloads
            lines = [f"**Failed**: {type(error).__name__}: {error}"]
            summary[key] = dict.fromkeys(JSON_KEYS[key])
        sections += [f"## {title}", "", *lines, ""]
        print(key, summary[key], flush=True)

    sections += ["## Rounding: which results the data fix", "",
                 *rounding_study(single, single_truth, multi, multi_truth), ""]
    write_report(sections, summary, bounds(frf, scatter, multi_bounds), single_info,
                 multi_info, single_truth)
    print(json.dumps(summary))


def write_report(sections: list[str], summary: dict, notes: dict[tuple[str, str], str],
                 single_info: dict, multi_info: dict, single_truth: Truth) -> None:
    rows = acceptance_rows(summary, notes)
    header = [
        "# Paper reproduction: FNSI on the SmallSat model (Section IV)",
        "",
        "Generated by `make bench-paper` (`benchmarks/paper.py`). Every number is measured "
        "by that script on our reduced SmallSat model (`fnsi/smallsat.py`), except the "
        "columns labelled *paper*, quoted from the paper's tables. Errors are relative: "
        "100 (identified / true - 1). Modes are paired with the true modes of our model "
        "(in the 5-50 Hz band, numbered by frequency) by MACX and frequency; our model's "
        "modes are not the paper's FE modes, so the paper columns are placed by mode number "
        "only as an indication.",
        "",
        f"Data: 8 periods x 30,000 samples at 2.5 kHz, 2 discarded, 0.5 % output noise; "
        f"simulation {single_info['simulation_s']:.1f} s (single), "
        f"{multi_info['simulation_s']:.1f} s (multi), "
        f"{'read from the cache' if single_info['cached'] else 'simulated in this run'} "
        f"(keys {single_info['key']}, {multi_info['key']}). NC2-Z exceedances in the single "
        f"test: {single_truth.exceedances['clearance NC2w_Z-NC2b_Z']:,} (paper Table 3: "
        f"{TABLE_3['NC2_Z']:,}); other stops: "
        f"{sum(v for k, v in single_truth.exceedances.items() if 'NC2w_Z' not in k)}.",
        "",
        f"Timings: wall time of `identify()` on the shared 2-core machine with "
        f"OPENBLAS_NUM_THREADS={os.environ.get('OPENBLAS_NUM_THREADS', 'default')}.",
        "",
        "## Acceptance",
        "",
        _table(["workload", "quantity", "ours", "target", "", "what bounds it (measured "
                "in the sections below)"], rows),
        "",
        f"{sum(row[4] == 'met' for row in rows)} of {len(rows)} targets are met. Each "
        "missed target's row gives, from this run, what bounds it on these records: an "
        "oracle that knows part of the truth (the true FRF of our model, the noise-free "
        "record, the stops' true forms) and what it reaches. *What limits the results* "
        "below explains each, and what was tried.",
        "",
        "Modal maxima run over every mode the automatic order keeps, as `identify()` "
        "returns them: the physical poles of that order in the band that the next order "
        "of the stabilisation diagram confirms (fully stable in frequency, damping and "
        "MACX). A kept mode without a credible true partner counts as spurious and enters "
        "the maxima. With an explicit order (the paper's, when nothing stabilises) every "
        "pole is kept and the unconfirmed ones are marked.",
        "",
        *LIMITS,
        "",
    ]
    (RESULTS / "paper.md").write_text("\n".join(header + sections) + "\n")


if __name__ == "__main__":
    sys.exit(main())
