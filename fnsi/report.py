"""The artefacts of an identification (result document, model file, figures, report)
and of a distortion analysis.

One function builds what the service's identification jobs store and what
``fnsi identify`` writes to a folder, so both give the same files:

``result.json``
    :meth:`IdentificationResult.to_json` plus the model's errors on the estimation (and
    validation) data, NaN written as null (strict JSON). Its top-level ``warnings`` list
    says what makes the model unusable: the identification's (an unstable linear part)
    and a model that could not be simulated on the estimation or validation data, whose
    errors section then holds ``failure``, the reason, instead of errors. Each errors
    section holds the ``offsets`` removed from its data before the comparison
    (:mod:`fnsi.offsets`; 0 Hz is never compared).
``model.npz``
    :meth:`StateSpaceModel.to_npz`.
``frf.png``, ``stabilisation.png``, ``coefficients.png``, ``stiffness.png``, ``macx.png``
    Each when there is something to draw (no coefficients for a linear model, no FRF
    with fewer realisations than inputs). When the data were simulated, the truth
    (``Truth.to_json()``) is overlaid.
``errors.png``
    Where the model fails: measured spectrum, model error and noise floor per line for
    the six outputs with the most error energy, on the validation data when given (else
    the estimation data); absent when the model cannot be simulated.
``modes.uff``, ``result.mat``
    The modes as UFF 55 and the result as a MAT file (:func:`fnsi.export.export_files`).
``report.html``
    One self-contained page with the tables and every figure above
    (:func:`fnsi.html_report.identification_page`).

Likewise :func:`analysis_artefacts` for a distortion analysis (``fnsi analyse`` and the
service's analysis jobs): ``analysis.json``, ``distortion.png`` and ``report.html``.
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from fnsi import plots
from fnsi.distortion import DistortionAnalysis
from fnsi.errors import ModelErrors
from fnsi.export import export_files
from fnsi.html_report import REPORT_NAME, analysis_page, identification_page
from fnsi.identification import IdentificationResult, IdentificationSettings
from fnsi.measurement import Measurement
from fnsi.nonlinear import NonlinearElement
from fnsi.spectra import output_spectra
from fnsi.stabilisation import macx_matrix
from fnsi.validation import Comparison, compare_identified

Progress = Callable[[float, str], None]


@dataclass(frozen=True)
class Report:
    """What an identification leaves behind.

    Attributes
    ----------
    document : dict
        The content of ``result.json`` (strict JSON values).
    artefacts : dict of str to bytes
        File name to content, ``result.json`` and ``model.npz`` included.
    """

    document: dict[str, Any]
    artefacts: dict[str, bytes]


def strict_json(value: Any) -> Any:
    """``value`` with NaN and infinities as null (strict JSON, as HTTP clients expect)."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    return value


def measured_frf(measurement: Measurement, settings: IdentificationSettings
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """Nonparametric FRF on the excited lines, least squares over realisations.

    Returns
    -------
    (frequencies, H) or None
        frequencies (lines,) [Hz] and H (lines, l, m) = S_yu S_uu^-1 per line, output
        over force; None with fewer realisations than inputs.
    """
    data = measurement.select(settings.inputs, settings.outputs)
    if data.n_realisations < data.n_inputs:
        return None
    spectra = output_spectra(data, settings.band, discard_periods=settings.discard_periods,
                             line_set="excited")
    U, Y = spectra.inputs, spectra.outputs                       # (R, N, m), (R, N, l)
    s_uu = np.einsum("rki,rkj->kij", U, U.conj())
    s_yu = np.einsum("rkl,rkj->klj", Y, U.conj())
    H = np.linalg.solve(s_uu.transpose(0, 2, 1), s_yu.transpose(0, 2, 1)).transpose(0, 2, 1)
    return spectra.frequencies, H


def identification_report(result: IdentificationResult, settings: IdentificationSettings,
                          estimation: Measurement, *, validation: Measurement | None = None,
                          truth: dict[str, Any] | None = None,
                          progress: Progress | None = None) -> Report:
    """Errors, figures and files of an identification.

    Parameters
    ----------
    result : IdentificationResult
        What :func:`fnsi.identification.identify` returned for ``settings``.
    settings : IdentificationSettings
    estimation : Measurement
        The data the model was identified on.
    validation : Measurement, optional
        Separate data (another realisation or amplitude) to validate the model on.
    truth : dict, optional
        ``Truth.to_json()`` of simulated data: true modes and elements are overlaid.
    progress : callable(fraction, message), optional
        Called between stages; may raise to cancel.

    Returns
    -------
    Report
    """
    report = progress or (lambda fraction, message: None)
    document = result.to_json()
    report(0.0, "simulating the model on the estimation data")
    comparisons = {"estimation": _comparison(result, estimation)}
    if validation is not None:
        report(0.3, "simulating the model on the validation data")
        comparisons["validation"] = _comparison(result, validation)
    compared = {kind: c.errors if isinstance(c, Comparison) else c
                for kind, c in comparisons.items()}
    offsets = {kind: c.offsets for kind, c in comparisons.items() if isinstance(c, Comparison)}
    document["errors"] = {kind: errors.to_json() | {"offsets": offsets[kind].to_json()}
                          if isinstance(errors, ModelErrors) else errors
                          for kind, errors in compared.items()}
    document["warnings"] = list(result.warnings) + _simulation_warnings(result, compared)
    document = strict_json(document)
    report(0.6, "drawing figures")
    artefacts = _figures(result, settings, estimation, truth)
    # where the model fails: on the validation data when given
    kind, errors = list(compared.items())[-1]
    if isinstance(errors, ModelErrors):
        artefacts["errors.png"] = plots.plot_errors(
            errors, outputs=_worst_outputs(errors), unit=result.units.output,
            title=f"Model error on the {kind} data against the noise floor")
    artefacts[REPORT_NAME] = identification_page(document, artefacts)
    artefacts |= export_files(document)
    artefacts["result.json"] = json.dumps(document).encode()
    buffer = io.BytesIO()
    result.model.to_npz(buffer)
    artefacts["model.npz"] = buffer.getvalue()
    report(1.0, "report written")
    return Report(document, artefacts)


def analysis_artefacts(analysis: DistortionAnalysis) -> dict[str, bytes]:
    """File name to content of a distortion analysis: ``analysis.json``
    (:meth:`DistortionAnalysis.to_json`), ``distortion.png`` and ``report.html``."""
    document = analysis.to_json()
    figures = {"distortion.png": plots.plot_distortion(analysis)}
    return {"analysis.json": json.dumps(document, indent=2).encode(), **figures,
            REPORT_NAME: analysis_page(document, figures)}


def _comparison(result: IdentificationResult,
                measurement: Measurement) -> Comparison | dict[str, str]:
    """The model's errors and the sensor offsets on a measurement, or why it could not be
    simulated."""
    try:
        return compare_identified(result, measurement)
    except ValueError as err:  # e.g. an unstable model cannot be simulated
        return {"failure": str(err)}


def _simulation_warnings(result: IdentificationResult,
                         compared: dict[str, ModelErrors | dict[str, str]]) -> list[str]:
    """A warning per dataset the model could not be simulated on, unless the
    identification already warned that its linear part is unstable."""
    if np.max(np.abs(np.linalg.eigvals(result.model.A)), initial=0.0) >= 1.0:
        return []
    return [f"the model could not be simulated on the {kind} data ({errors['failure']}): it "
            "has no simulation errors there and errors.png is absent"
            for kind, errors in compared.items() if not isinstance(errors, ModelErrors)]


def _worst_outputs(errors: ModelErrors, count: int = 6) -> list[str]:
    """The ``count`` outputs with the most error energy (NRMSE squared times power)."""
    energy = (errors.nrmse_percent ** 2) * np.sum(errors.measured_spectrum ** 2, axis=0)
    order = np.argsort(-energy)[:count]
    return [errors.output_names[k] for k in sorted(order)]


def _true_element(truth: dict[str, Any] | None, element: NonlinearElement
                  ) -> NonlinearElement | None:
    for spec in (truth or {}).get("elements", []):
        true = NonlinearElement.from_json(spec)
        if (true.kind, true.dof, true.ref) == (element.kind, element.dof, element.ref):
            return true
    return None


def _figures(result: IdentificationResult, settings: IdentificationSettings,
             measurement: Measurement, truth: dict[str, Any] | None) -> dict[str, bytes]:
    model = result.model
    out: dict[str, bytes] = {}
    frf = measured_frf(measurement, settings)
    if frf is not None:
        frequencies, H = frf
        fitted = model.frequency_response(frequencies)[:, :, :model.n_inputs]
        out["frf.png"] = plots.plot_frf(frequencies, H, fitted, output_names=model.output_names,
                                        input_names=model.input_names, unit=result.units.frf)
    if result.stabilisation is not None:
        background = None if frf is None else (frf[0], np.abs(frf[1]).sum(axis=(1, 2)))
        out["stabilisation.png"] = plots.plot_stabilisation(
            result.stabilisation, frf=background, singular_values=result.singular_values,
            order=result.order, frf_unit=result.units.frf)
    known = [c for c in result.coefficients if c.identifiable]
    if known:
        trues = [_true_element(truth, model.elements[c.element]) for c in known]
        units = [result.coefficient_unit(c) for c in known]
        shared = len(set(units)) == 1   # else each curve's legend entry names its unit
        out["coefficients.png"] = plots.plot_coefficients(
            known[0].frequencies, np.column_stack([c.values for c in known]),
            [c.name if shared else f"{c.name} [{unit}]" for c, unit in zip(known, units,
                                                                           strict=True)],
            truth=[None if t is None or t.coefficients is None else t.coefficients[c.basis]
                   for t, c in zip(trues, known, strict=True)],
            unit=units[0] if shared else "unit in the legend", std=_curve_std(result))
    if result.stiffness:
        out["stiffness.png"] = plots.plot_stiffness(
            result.stiffness, truths=[_true_element(truth, c.element) for c in result.stiffness],
            units=result.units,
            warnings=[_confounding(result, c.element) for c in result.stiffness])
    out["macx.png"] = _macx_figure(result, truth)
    return out


def _curve_std(result: IdentificationResult) -> np.ndarray | None:
    """Std of Re and Im mu_j(omega) of the identifiable coefficients (lines, s, 2), or None
    when the identification gave no error bar."""
    u = result.uncertainty
    if u is None or not u.available:
        return None
    known = [j for j, c in enumerate(result.coefficients) if c.identifiable]
    return u.coefficient_curves[known].transpose(1, 0, 2)


def _confounding(result: IdentificationResult, element: NonlinearElement) -> str | None:
    """Short warning for the stiffness panel of a confounded element, else None."""
    return next((s.caption for s in result.separability if s.name == element.name), None)


def _macx_figure(result: IdentificationResult, truth: dict[str, Any] | None) -> bytes:
    """Identified modes against the true ones when the data were simulated, else against
    themselves (how distinct the identified shapes are)."""
    modal = result.modal
    reference, label, frequencies = modal.shapes, "identified", modal.frequencies
    if truth is not None:
        names = truth["modal"]["output_names"]
        columns = [names.index(n) for n in modal.output_names]
        shapes = np.array(truth["modal"]["shapes_real"]) + 1j * np.array(
            truth["modal"]["shapes_imag"])
        reference, label = shapes[:, columns], "true"
        frequencies = np.array(truth["modal"]["frequencies"])
    return plots.plot_macx(macx_matrix(modal.shapes, reference), modal.frequencies,
                           frequencies, label_a="identified", label_b=label)
