"""Jobs: list with filters and cursor pagination, status, cancel."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from service.deps import ApiKeyDep, OwnJobDep, StoreDep
from service.problems import ERROR_RESPONSES, ProblemError
from service.schemas.jobs import Job, JobKind, JobPage
from service.store import JobState, decode_cursor, encode_cursor

router = APIRouter(prefix="/v1/jobs", tags=["jobs"], responses=ERROR_RESPONSES)


@router.get("", response_model=JobPage, summary="List jobs")
def list_jobs(
    store: StoreDep, owner: ApiKeyDep,
    state: Annotated[JobState | None, Query(description="Only jobs in this state.")] = None,
    kind: Annotated[JobKind | None, Query(description="Only jobs of this kind.")] = None,
    limit: Annotated[int, Query(ge=1, le=200, description="Page size.")] = 50,
    cursor: Annotated[str | None, Query(description="next_cursor of the previous page.")] = None,
) -> JobPage:
    """The caller's jobs, newest first, one page at a time."""
    try:
        before = decode_cursor(cursor) if cursor else None
    except ValueError as err:
        raise ProblemError(422, str(err)) from None
    records = store.list_jobs(owner, state=state, kind=kind, before_seq=before, limit=limit + 1)
    page = records[:limit]
    next_cursor = encode_cursor(page[-1].seq) if len(records) > limit else None
    return JobPage(items=[Job.of(r) for r in page], next_cursor=next_cursor)


@router.get("/{job_id}", response_model=Job, summary="Get a job")
def get_job(job: OwnJobDep) -> Job:
    """State, progress, result or error of a job."""
    return Job.of(job)


@router.delete("/{job_id}", response_model=Job, status_code=202, summary="Cancel a job")
def cancel_job(job: OwnJobDep, store: StoreDep) -> Job:
    """Cancel a job: a queued job is cancelled at once, a running one stops within seconds
    (poll until its state is cancelled). A finished job is returned unchanged."""
    return Job.of(store.request_cancel(job.id))
