"""Jobs: list with filters and cursor pagination, status, cancel."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query

from service.deps import ApiKeyDep, OwnJobDep, StoreDep
from service.pagination import (
    PageCursor,
    PageLimit,
    cursor_position,
    sequence_number,
    split_page,
)
from service.problems import ERROR_RESPONSES
from service.schemas.jobs import Job, JobKind, JobPage
from service.store import JobState

router = APIRouter(prefix="/v1/jobs", tags=["jobs"], responses=ERROR_RESPONSES)


@router.get("", response_model=JobPage, summary="List jobs")
def list_jobs(
    store: StoreDep, owner: ApiKeyDep,
    state: Annotated[JobState | None, Query(description="Only jobs in this state.")] = None,
    kind: Annotated[JobKind | None, Query(description="Only jobs of this kind.")] = None,
    limit: PageLimit = 50,
    cursor: PageCursor = None,
) -> JobPage:
    """The caller's jobs, newest first, one page at a time."""
    before = cursor_position(cursor, "job", sequence_number)
    records = store.list_jobs(owner, state=state, kind=kind, before_seq=before, limit=limit + 1)
    page, next_cursor = split_page(records, limit, "job", lambda r: str(r.seq))
    return JobPage(items=[Job.of(r) for r in page], next_cursor=next_cursor)


@router.get("/{job_id}", response_model=Job, summary="Get a job")
async def get_job(job: OwnJobDep) -> Job:
    """State, progress, result or error of a job."""
    return Job.of(job)


@router.delete("/{job_id}", response_model=Job, status_code=202, summary="Cancel a job")
def cancel_job(job: OwnJobDep, store: StoreDep) -> Job:
    """Cancel a job: a queued job is cancelled at once, a running one stops within seconds
    (poll until its state is cancelled). A finished job is returned unchanged."""
    return Job.of(store.request_cancel(job.id))
