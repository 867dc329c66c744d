"""Identification jobs: FNSI on a stored dataset, then :mod:`fnsi.report`'s artefacts."""

from __future__ import annotations

import json
from typing import Any

from fnsi.identification import IdentificationSettings, identify
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
        refine=request.get("refine", False),
        inputs=request["inputs"], outputs=request["outputs"],
        driving_points=tuple(tuple(p) for p in request["driving_points"]),
        elements=tuple(NonlinearElement.from_json(e) for e in request["elements"]))


def _truth(store: Store, dataset_id: str) -> dict[str, Any] | None:
    """truth.json of the simulation that produced a dataset, if it did."""
    record = store.get_dataset(dataset_id)
    path = None if record is None or record.source_job is None else store.artefact_path(
        record.source_job, "truth.json")
    return None if path is None else json.loads(path.read_text())


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
    return {k: v for k, v in report.document.items() if k not in _HEAVY}
