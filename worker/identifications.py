"""Identification jobs: FNSI on a stored dataset; the result JSON, plots and the model.

Artefacts: ``result.json`` (everything), ``model.npz`` (the state-space model),
``stabilisation.png``, ``frf.png``, ``coefficients.png``, ``stiffness.png``, ``macx.png``
(each plot only when there is something to draw, e.g. no coefficients for a linear model).
"""

from __future__ import annotations

import io
import json
from typing import Any

import numpy as np

from fnsi import plots
from fnsi.errors import ModelErrors, model_errors
from fnsi.identification import IdentificationResult, IdentificationSettings, identify
from fnsi.measurement import Measurement
from fnsi.nonlinear import NonlinearElement
from fnsi.simulation import simulate_periodic
from fnsi.spectra import integrate_periodic, kept_record, output_spectra
from fnsi.stabilisation import macx_matrix
from fnsi.statespace import StateSpaceModel
from service.store import Store
from worker.runner import JobContext

_INTEGRATIONS = {"displacement": 0, "velocity": 1, "acceleration": 2}
# Error spectra reach this multiple of the band's upper edge (nonlinear harmonics).
_ERROR_BAND_FACTOR = 3.0
# Parts of the result kept out of the job record (they stay in result.json).
_HEAVY = ("model", "stabilisation", "singular_values")


def settings_of(request: dict[str, Any], memory_limit_mb: float) -> IdentificationSettings:
    """Library settings from a validated identification request."""
    return IdentificationSettings(
        memory_limit_mb=memory_limit_mb,
        band=tuple(request["band"]), block_rows=request["block_rows"], order=request["order"],
        max_order=request["max_order"], line_set=request["line_set"],
        discard_periods=request["discard_periods"], weighting=request["weighting"],
        inputs=request["inputs"], outputs=request["outputs"],
        driving_points=tuple(tuple(p) for p in request["driving_points"]),
        elements=tuple(NonlinearElement.from_json(e) for e in request["elements"]))


def model_errors_on(model: StateSpaceModel, measurement: Measurement,
                    settings: IdentificationSettings) -> ModelErrors:
    """Run the model to steady state with the measured input; NRMSE per channel against
    the noise floor, in the measured quantity (paper Section II, step 7)."""
    data = measurement.select(model.input_names, model.output_names)
    kept = data.periods - settings.discard_periods
    measured = kept_record(data.y, data.periods, settings.discard_periods)
    u = data.u[:, -data.period_length:]
    periods = [simulate_periodic(model, u[r]).y for r in range(data.n_realisations)]
    simulated = integrate_periodic(np.stack(periods), data.fs, -_INTEGRATIONS[data.quantity])
    high = min(data.fs / 2, _ERROR_BAND_FACTOR * settings.band[1])
    return model_errors(measured, simulated, data.fs, periods=kept,
                        output_names=data.output_names, band=(0.0, high))


def _errors_json(model: StateSpaceModel, measurement: Measurement,
                 settings: IdentificationSettings) -> dict[str, Any]:
    try:
        return model_errors_on(model, measurement, settings).to_json()
    except ValueError as err:  # e.g. an unstable model cannot be simulated
        return {"failure": str(err)}


def measured_frf(measurement: Measurement, settings: IdentificationSettings
                 ) -> tuple[np.ndarray, np.ndarray] | None:
    """Nonparametric FRF on the excited lines, least squares over realisations.

    Returns (frequencies (lines,), H (lines, l, m)) or None with fewer realisations than
    inputs. H = S_yu S_uu^-1 per line, displacement over force.
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


def strict_json(value: Any) -> Any:
    """``value`` with NaN and infinities as null (strict JSON, as HTTP clients expect)."""
    if isinstance(value, float):
        return value if np.isfinite(value) else None
    if isinstance(value, dict):
        return {k: strict_json(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [strict_json(v) for v in value]
    return value


def _truth(store: Store, dataset_id: str) -> dict[str, Any] | None:
    """truth.json of the simulation that produced a dataset, if it did."""
    record = store.get_dataset(dataset_id)
    path = None if record is None or record.source_job is None else store.artefact_path(
        record.source_job, "truth.json")
    return None if path is None else json.loads(path.read_text())


def _true_element(truth: dict[str, Any] | None, element: NonlinearElement
                  ) -> NonlinearElement | None:
    for spec in (truth or {}).get("elements", []):
        true = NonlinearElement.from_json(spec)
        if (true.kind, true.dof, true.ref) == (element.kind, element.dof, element.ref):
            return true
    return None


def _model_npz(model: StateSpaceModel) -> bytes:
    buffer = io.BytesIO()
    np.savez(buffer, A=model.A, B=model.B, C=model.C, D=model.D, fs=np.float64(model.fs),
             input_names=np.array(model.input_names, dtype=str),
             output_names=np.array(model.output_names, dtype=str),
             elements=np.str_(json.dumps([e.to_json() for e in model.elements])))
    return buffer.getvalue()


def load_model_npz(file) -> StateSpaceModel:
    """Reload ``model.npz`` (never unpickling)."""
    with np.load(file, allow_pickle=False) as data:
        return StateSpaceModel(
            data["A"], data["B"], data["C"], data["D"], float(data["fs"]),
            tuple(data["input_names"].tolist()), tuple(data["output_names"].tolist()),
            tuple(NonlinearElement.from_json(e) for e in json.loads(str(data["elements"]))))


def _plots(result: IdentificationResult, measurement: Measurement,
           settings: IdentificationSettings, truth: dict[str, Any] | None) -> dict[str, bytes]:
    model = result.model
    out: dict[str, bytes] = {}
    frf = measured_frf(measurement, settings)
    if frf is not None:
        frequencies, H = frf
        fitted = model.frequency_response(frequencies)[:, :, :model.n_inputs]
        out["frf.png"] = plots.plot_frf(frequencies, H, fitted, output_names=model.output_names,
                                        input_names=model.input_names)
    if result.stabilisation is not None:
        background = None if frf is None else (frf[0], np.abs(frf[1]).sum(axis=(1, 2)))
        out["stabilisation.png"] = plots.plot_stabilisation(
            result.stabilisation, frf=background, singular_values=result.singular_values,
            order=result.order)
    known = [c for c in result.coefficients if c.identifiable]
    if known:
        trues = [_true_element(truth, model.elements[c.element]) for c in known]
        out["coefficients.png"] = plots.plot_coefficients(
            known[0].frequencies, np.column_stack([c.values for c in known]),
            [c.name for c in known],
            truth=[None if t is None or t.coefficients is None else t.coefficients[c.basis]
                   for t, c in zip(trues, known, strict=True)])
    if result.stiffness:
        out["stiffness.png"] = plots.plot_stiffness(
            result.stiffness, truths=[_true_element(truth, c.element) for c in result.stiffness])
    out["macx.png"] = _macx_plot(result, truth)
    return out


def _macx_plot(result: IdentificationResult, truth: dict[str, Any] | None) -> bytes:
    """Identified modes against the true ones when the data were simulated, else against
    themselves (how distinct the identified shapes are)."""
    modal = result.modal
    reference, label = modal.shapes, "identified"
    frequencies = modal.frequencies
    if truth is not None:
        names = truth["modal"]["output_names"]
        columns = [names.index(n) for n in modal.output_names]
        shapes = np.array(truth["modal"]["shapes_real"]) + 1j * np.array(
            truth["modal"]["shapes_imag"])
        reference, label = shapes[:, columns], "true"
        frequencies = np.array(truth["modal"]["frequencies"])
    return plots.plot_macx(macx_matrix(modal.shapes, reference), modal.frequencies,
                           frequencies, label_a="identified", label_b=label)


def identify_job(context: JobContext) -> dict[str, Any]:
    """Identify a model from the job's dataset (see IdentificationRequest); the result
    JSON omits the model matrices and stabilisation data, kept in result.json."""
    store, job, progress = context.store, context.job, context.progress
    request = job.request
    settings = settings_of(request, context.settings.memory_limit_mb)
    estimation = store.load_measurement(request["dataset_id"])
    result = identify(estimation, settings, lambda f, m: progress(0.7 * f, m))
    progress(0.7, "simulating the model on the estimation data")
    doc = result.to_json()
    doc["errors"] = {"estimation": _errors_json(result.model, estimation, settings)}
    if request["validation_dataset_id"]:
        progress(0.8, "simulating the model on the validation data")
        validation = store.load_measurement(request["validation_dataset_id"])
        doc["errors"]["validation"] = _errors_json(result.model, validation, settings)
    doc = strict_json(doc)
    progress(0.9, "drawing plots")
    artefacts = _plots(result, estimation, settings, _truth(store, request["dataset_id"]))
    artefacts["result.json"] = json.dumps(doc).encode()
    artefacts["model.npz"] = _model_npz(result.model)
    for name, content in artefacts.items():
        store.write_artefact(job.id, name, content)
    return {k: v for k, v in doc.items() if k not in _HEAVY}
