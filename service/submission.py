"""Accepting jobs: checks that need the store, recording, handing over to the queue."""

from __future__ import annotations

from pydantic import BaseModel

from fnsi import subspace
from fnsi.nonlinear import NonlinearElement
from fnsi.spectra import band_lines, check_band
from service.deps import require_dataset
from service.problems import ProblemError
from service.queue import JobQueue
from service.schemas.identifications import IdentificationRequest
from service.store import JobRecord, Store


def check_dimensions(summary: dict, request: IdentificationRequest,
                     memory_limit_mb: float) -> None:
    """The library's checks of an identification against the dataset's shape, made from
    the dataset summary so the API never loads the arrays (ValueError naming the fix).

    Mirrors ``fnsi.identification`` validation: band within Nyquist, periods left after
    the transient, block rows (``"auto"`` resolved as the library does), enough lines
    for them and the order (harmonic lines for periodic data), working memory.
    """
    fs, periods, length = summary["fs"], summary["periods"], summary["period_length"]
    check_band(request.band, fs)
    kept = periods - request.discard_periods
    if kept < 1:
        raise ValueError(f"discard_periods={request.discard_periods} leaves no period of the "
                         f"{periods} measured; discard fewer")
    if request.weighting and kept < 2:
        raise ValueError(f"weighting needs two kept periods; {kept} kept ({periods} measured, "
                         f"{request.discard_periods} discarded)")
    record = kept * length if request.line_set == "all" else length
    n_lines = band_lines(record, fs, request.band).size
    if n_lines == 0:
        raise ValueError(f"no DFT line in the band {list(request.band)} Hz; widen it")
    signal = band_lines(length, fs, request.band).size
    realisations = summary["realisations"]
    n_outputs = len(request.outputs or summary["outputs"])
    n_extended = len(request.inputs or summary["inputs"]) + sum(
        NonlinearElement.from_json(e.model_dump(mode="json")).n_basis for e in request.elements)
    block_rows = (subspace.auto_block_rows(
        signal, realisations, n_extended, n_outputs,
        order=None if request.order == "auto" else request.order)
        if request.block_rows == "auto" else request.block_rows)
    dimensions = (n_lines, realisations, n_extended, n_outputs, block_rows)
    # as fnsi.identification: "auto" decomposes up to max_order capped at l (i - 1), so
    # only an explicit order can be too large for the block rows
    cap = n_outputs * (block_rows - 1)
    order = min(request.max_order, cap) if request.order == "auto" else request.order
    subspace.check_dimensions(*dimensions, order, signal_lines=signal)
    need = subspace.memory_estimate(*dimensions)
    if need > memory_limit_mb * 2**20:
        raise ValueError(f"FNSI would need about {need / 2**20:.0f} MiB, above the limit of "
                         f"{memory_limit_mb:.0f} MiB (FNSI_MEMORY_LIMIT_MB); reduce "
                         "block_rows, the band, the outputs or the basis functions")


def check_request(store: Store, owner: str, kind: str, request: BaseModel,
                  memory_limit_mb: float, where: str = "") -> None:
    """Reject now (422) what would only fail later in the worker: unknown datasets or
    channels. ``where`` prefixes messages (e.g. ``jobs[3].request.``) in a batch."""
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
        check_dimensions(dataset.summary, request, memory_limit_mb)
    except ValueError as err:
        raise ProblemError(422, f"{where or 'request: '}{err}") from None


def submit(store: Store, queue: JobQueue, owner: str, kind: str, request: BaseModel,
           memory_limit_mb: float) -> JobRecord:
    """Check, record and enqueue one job."""
    check_request(store, owner, kind, request, memory_limit_mb)
    record = store.create_job(owner, kind, request.model_dump(mode="json"))
    queue.submit(record.id)
    return record
