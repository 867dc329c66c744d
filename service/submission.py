"""Accepting jobs: checks that need the store, recording, handing over to the queue."""

from __future__ import annotations

from pydantic import BaseModel

from fnsi.distortion import check_periods
from fnsi.identification import check_settings
from fnsi.measurement import Layout
from service.deps import require_dataset
from service.problems import ProblemError
from service.queue import JobQueue
from service.schemas.analyses import AnalysisRequest
from service.schemas.identifications import IdentificationRequest
from service.store import JobRecord, Store
from worker.identifications import settings_of


def layout_of(summary: dict) -> Layout:
    """The shape of a dataset from its stored summary (the arrays are never loaded)."""
    return Layout(fs=summary["fs"], periods=summary["periods"],
                  period_length=summary["period_length"],
                  n_realisations=summary["realisations"],
                  input_names=tuple(summary["inputs"]), output_names=tuple(summary["outputs"]))


def check_dimensions(summary: dict, request: dict, memory_limit_mb: float) -> None:
    """The library's checks of an identification (request JSON) against the dataset's
    shape (:func:`fnsi.identification.check_settings`), made on the layout in the dataset
    summary so the API never loads the arrays (ValueError naming the fix)."""
    check_settings(layout_of(summary), settings_of(request, memory_limit_mb))


def check_analysis(store: Store, owner: str, request: AnalysisRequest, where: str) -> None:
    """The dataset exists, the outputs are its own (each once), two periods remain."""
    dataset = require_dataset(store, owner, request.dataset_id, f"{where}dataset_id")
    try:
        layout_of(dataset.summary).select(outputs=request.outputs)
        check_periods(dataset.summary["periods"], request.discard_periods)
    except ValueError as err:
        raise ProblemError(422, f"{where or 'request: '}{err}") from None


def check_request(store: Store, owner: str, kind: str, request: BaseModel,
                  memory_limit_mb: float, where: str = "") -> None:
    """Reject now (422) what would only fail later in the worker: unknown datasets or
    channels. ``where`` prefixes messages (e.g. ``jobs[3].request.``) in a batch."""
    if isinstance(request, AnalysisRequest):
        check_analysis(store, owner, request, where)
    if not isinstance(request, IdentificationRequest):
        return
    dataset = require_dataset(store, owner, request.dataset_id, f"{where}dataset_id")
    if request.validation_dataset_id is not None:
        require_dataset(store, owner, request.validation_dataset_id,
                        f"{where}validation_dataset_id")
    inputs, outputs = dataset.summary["inputs"], dataset.summary["outputs"]
    wanted = [(f"{where}inputs", n, inputs) for n in request.inputs or []]
    wanted += [(f"{where}outputs", n, outputs) for n in request.outputs or []]
    for k, (u, y) in enumerate(request.driving_points):
        wanted += [(f"{where}driving_points[{k}]", u, inputs),
                   (f"{where}driving_points[{k}]", y, outputs)]
    chosen = request.outputs or outputs
    for k, element in enumerate(request.elements):
        wanted += [(f"{where}elements[{k}].{field}", n, chosen)
                   for field, n in (("dof", element.dof), ("ref", element.ref)) if n]
    for field, name, valid in wanted:
        if name not in valid:
            raise ProblemError(422, f"{field}: dataset {dataset.id} has no channel {name!r} "
                               f"there; valid names are {valid}")
    try:
        check_dimensions(dataset.summary, request.model_dump(mode="json"), memory_limit_mb)
    except ValueError as err:
        raise ProblemError(422, f"{where or 'request: '}{err}") from None


def submit(store: Store, queue: JobQueue, owner: str, kind: str, request: BaseModel,
           memory_limit_mb: float) -> JobRecord:
    """Check, record and enqueue one job."""
    check_request(store, owner, kind, request, memory_limit_mb)
    record = store.create_job(owner, kind, request.model_dump(mode="json"))
    queue.submit(record.id)
    return record
