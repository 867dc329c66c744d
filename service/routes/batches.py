"""Batches: many jobs in one request, idempotent with an Idempotency-Key header."""

from __future__ import annotations

from collections import Counter
from typing import Annotated

from fastapi import APIRouter, Header, Response

from service.deps import ApiKeyDep, OwnBatchDep, QueueDep, SettingsDep, StoreDep
from service.problems import ERROR_RESPONSES, ProblemError
from service.schemas.batches import Batch, BatchRequest
from service.schemas.jobs import Job
from service.store import BatchRecord, IdempotencyConflictError, Store
from service.submission import check_request

router = APIRouter(prefix="/v1/batches", tags=["batches"], responses=ERROR_RESPONSES)


def _view(store: Store, batch: BatchRecord) -> Batch:
    jobs = [Job.of(j) for j in store.jobs_of(batch.job_ids)]
    return Batch(id=batch.id, created_at=batch.created_at, job_ids=batch.job_ids,
                 counts=dict(Counter(j.state.value for j in jobs)), jobs=jobs)


@router.post("", response_model=Batch, status_code=202, summary="Submit a batch of jobs",
             responses={409: ERROR_RESPONSES[422] | {"description": "Conflict"}})
def create_batch(
    body: BatchRequest, store: StoreDep, queue: QueueDep, owner: ApiKeyDep,
    settings: SettingsDep, response: Response,
    idempotency_key: Annotated[str | None, Header(
        max_length=200, description="Any unique string; a retried request with the same key "
        "and body returns the first answer instead of submitting the jobs again.")] = None,
) -> Batch:
    """Queue every job of the batch, all or none (one invalid job rejects the batch)."""
    for k, item in enumerate(body.jobs):
        check_request(store, owner, item.kind, item.request, settings.memory_limit_mb,
                      f"jobs[{k}].request.")
    items = [(item.kind, item.request.model_dump(mode="json")) for item in body.jobs]
    try:
        batch, created = store.create_batch(owner, items, idempotency_key=idempotency_key)
    except IdempotencyConflictError as err:
        raise ProblemError(409, str(err)) from None
    if created:
        for job_id in batch.job_ids:
            queue.submit(job_id)
    else:
        response.headers["Idempotent-Replayed"] = "true"
    return _view(store, batch)


@router.get("/{batch_id}", response_model=Batch, summary="Get a batch")
def get_batch(batch: OwnBatchDep, store: StoreDep) -> Batch:
    """The batch's jobs and how many are in each state."""
    return _view(store, batch)
