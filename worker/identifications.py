"""Identification jobs: FNSI on a stored dataset, then :mod:`fnsi.report`'s artefacts."""

from __future__ import annotations

import json
from typing import Any

import numpy as np

from fnsi.identification import IdentificationResult, IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.report import identification_report
from service.store import Store
from worker.runner import JobContext

# Parts of the result kept out of the job record (they stay in result.json).
_HEAVY = ("model", "stabilisation", "singular_values")


def settings_of(request: dict[str, Any], memory_limit_mb: float) -> IdentificationSettings:
    """Library settings from a validated identification request."""
    return IdentificationSettings(
        memory_limit_mb=memory_limit_mb,
        band=tuple(request["band"]), block_rows=request["block_rows"], order=request["order"],
        max_order=request["max_order"], line_set=request["line_set"],
        discard_periods=request["discard_periods"], weighting=request["weighting"],
        frequency_warping=request.get("frequency_warping", False),
        refine=request.get("refine", False), uncertainty=request.get("uncertainty", True),
        remove_offsets=request.get("remove_offsets", False),
        inputs=request["inputs"], outputs=request["outputs"],
        driving_points=tuple(tuple(p) for p in request["driving_points"]),
        elements=tuple(NonlinearElement.from_json(e) for e in request["elements"]))


def _truth(store: Store, dataset_id: str) -> dict[str, Any] | None:
    """truth.json of the simulation that produced a dataset, if it did."""
    record = store.get_dataset(dataset_id)
    path = None if record is None or record.source_job is None else store.artefact_path(
        record.source_job, "truth.json")
    return None if path is None else json.loads(path.read_text())


def nothing_identified(request: dict[str, Any], result: IdentificationResult,
                       document: dict[str, Any], peak: float) -> str | None:
    """Why an identification has nothing to show, so that its job must fail, or None.

    - Under the automatic order only the modes the next order confirms are kept: none
      kept means the identification did not find the structure (an explicit order
      returns every physical pole of the model asked for, even none in the band).
    - Non-finite model matrices or modes are no model.
    - Errors computed but null on every channel (not a model that cannot be simulated,
      whose errors hold its ``failure``) mean the comparison overflowed: the record's
      squares exceed double precision (values above about 1e154).

    ``peak`` is the largest magnitude of the estimation record, quoted in the reason.
    """
    modal, model = result.modal, result.model
    low, high = request["band"]
    if request["order"] == "auto" and modal.frequencies.size == 0:
        return (f"no mode found in {low:g}-{high:g} Hz at orders up to "
                f"{request['max_order']}: the automatic order ({result.order}) keeps only "
                "modes the next order confirms, and none was. Pick an order from "
                "stabilisation.png and give it as order, raise max_order, or change the band")
    arrays = (model.A, model.B, model.C, model.D, modal.frequencies, modal.damping_ratios)
    if not all(np.all(np.isfinite(a)) for a in arrays):
        return ("the identified model holds NaN or infinite numbers: the computation "
                f"overflowed on a record whose values reach {peak:.3g}; rescale the record "
                "(e.g. to units where it is of order 1)")
    errors = document["errors"]["estimation"]
    if "failure" not in errors and all(c["nrmse_percent"] is None for c in errors["channels"]):
        return (f"the model's errors are NaN on every channel: the record's values reach "
                f"{peak:.3g}, whose squares overflow double precision; rescale the record "
                "(e.g. to units where it is of order 1)")
    return None


def identify_job(context: JobContext) -> dict[str, Any]:
    """Identify a model from the job's dataset (see IdentificationRequest); the result
    JSON omits the model matrices and stabilisation data, kept in result.json."""
    store, job, progress = context.store, context.job, context.progress
    request = job.request
    settings = settings_of(request, context.settings.memory_limit_mb)
    estimation = store.load_measurement(request["dataset_id"])
    result = identify(estimation, settings, lambda f, m: progress(0.7 * f, m))
    validation_id = request["validation_dataset_id"]
    report = identification_report(
        result, settings, estimation,
        validation=store.load_measurement(validation_id) if validation_id else None,
        truth=_truth(store, request["dataset_id"]),
        progress=lambda f, m: progress(0.7 + 0.3 * f, m))
    for name, content in report.artefacts.items():
        store.write_artefact(job.id, name, content)
    # never a success without a result; the figures stay to show why
    peak = max(float(np.max(np.abs(estimation.u))), float(np.max(np.abs(estimation.y))))
    reason = nothing_identified(request, result, report.document, peak)
    if reason is not None:
        raise ValueError(reason)
    return {k: v for k, v in report.document.items() if k not in _HEAVY}
