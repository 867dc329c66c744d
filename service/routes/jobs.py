"""Jobs: list with filters and cursor pagination, status, cancel or delete."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Query, Response

from service.deps import ApiKeyDep, OwnJobDep, StoreDep
from service.pagination import (
    PageCursor,
    PageLimit,
    cursor_position,
    sequence_number,
    split_page,
)
from service.problems import ERROR_RESPONSES, ProblemError
from service.schema import STUDY_JOB_KINDS
from service.schemas.jobs import Job, JobKind, JobPage
from service.store import TERMINAL, JobState

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


@router.delete("/{job_id}", response_model=Job, status_code=202,
               summary="Cancel a job, or delete a finished one", responses={
                   204: {"description": "The finished job was deleted with its artefacts."},
                   409: ERROR_RESPONSES[422] | {"description": "Conflict"}})
def cancel_job(job: OwnJobDep, store: StoreDep) -> Job | Response:
    """Two meanings, by the job's state:

    * **queued or running**: cancel it (202, the job). A queued job is cancelled at once,
      a running one stops within seconds: poll until its state is `cancelled`.
    * **finished** (succeeded, failed or cancelled): delete its record and artefacts
      (204). Datasets it produced stay. Jobs of a study are kept with the study (409):
      their artefacts are the study's figures.

    So a second DELETE, once the cancelled job has stopped, deletes it.
    """
    if job.state not in TERMINAL:
        return Job.of(store.request_cancel(job.id))
    if job.kind in STUDY_JOB_KINDS:
        raise ProblemError(409, f"job {job.id} belongs to study {job.request.get('study_id')}: "
                           "its artefacts are the study's figures, so it is kept with the "
                           "study")
    if not store.delete_job(job.id):
        raise ProblemError(404, f"job {job.id} does not exist (deleted meanwhile)")
    return Response(status_code=204)
