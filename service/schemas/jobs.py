"""Schemas of jobs, their pages and their artefacts."""

from __future__ import annotations

from enum import StrEnum
from typing import Any

from pydantic import BaseModel, Field

from service.pagination import NextCursor
from service.schemas.results import JobResult
from service.store import JobRecord, JobState


class JobKind(StrEnum):
    """What a job computes."""

    SIMULATION = "simulation"
    IDENTIFICATION = "identification"
    STUDY = "study"
    STUDY_REVISION = "study_revision"
    STUDY_DIAGNOSIS = "study_diagnosis"
    ANALYSIS = "analysis"


class Job(BaseModel):
    """An asynchronous computation and its outcome."""

    id: str = Field(description="Job id.", examples=["job_7d0c5e1f2a3b4c5d6e7f"])
    kind: JobKind = Field(description="What the job computes.")
    state: JobState = Field(description="queued, running, succeeded, failed or cancelled.")
    progress: float = Field(ge=0, le=1, description="Fraction done, 0..1.", examples=[0.42])
    message: str = Field(description="What the job is doing now, or how it ended.",
                         examples=["Newmark integration, period 3 of 8"])
    created_at: str = Field(description="Submission time, ISO 8601 UTC.")
    started_at: str | None = Field(None, description="Start of the latest attempt.")
    finished_at: str | None = Field(None, description="End time, once terminal.")
    attempts: int = Field(description="Attempts started (a job whose worker died is re-run "
                          "up to FNSI_MAX_ATTEMPTS times).", examples=[1])
    batch_id: str | None = Field(None, description="Batch the job was submitted in.")
    request: dict[str, Any] = Field(description="The validated request, defaults filled in.")
    result: JobResult | None = Field(
        None, union_mode="left_to_right",
        description="Outcome once succeeded: {\"dataset_id\": ...} for a simulation, "
        "the identification result for an identification; for a study or study_revision "
        "the revision number and error history, for a study_diagnosis the ranked "
        "candidates, for an analysis the distortion levels and verdict.")
    error: str | None = Field(None, description="Why the job failed, and what to change.")
    warnings: list[str] = Field(
        [], description="The result's warnings: why a succeeded job's model cannot be used "
        "as is (e.g. it cannot be simulated), and what to change; empty when all is well.",
        examples=[[]])

    @classmethod
    def of(cls, record: JobRecord) -> Job:
        """Public view of a stored job."""
        return cls(id=record.id, kind=record.kind, state=record.state,
                   progress=min(max(record.progress, 0.0), 1.0), message=record.message,
                   created_at=record.created_at, started_at=record.started_at,
                   finished_at=record.finished_at, attempts=record.attempts,
                   batch_id=record.batch_id, request=record.request, result=record.result,
                   error=record.error, warnings=_warnings(record.result))


def _warnings(result: Any) -> list[str]:
    """The warnings a stored result carries (identification results have them)."""
    found = result.get("warnings") if isinstance(result, dict) else None
    return [str(w) for w in found] if isinstance(found, list) else []


class JobPage(BaseModel):
    """One page of jobs, newest first."""

    items: list[Job] = Field(description="Jobs of this page.")
    next_cursor: NextCursor = None


class Artefact(BaseModel):
    """A file produced by a job."""

    name: str = Field(description="File name, unique within the job.",
                      examples=["stabilisation.png"])
    media_type: str = Field(description="MIME type.", examples=["image/png"])
    size_bytes: int = Field(description="Size [bytes].", examples=[48213])
    url: str = Field(description="Path to download it.",
                     examples=["/v1/jobs/job_7d0c5e1f2a3b4c5d6e7f/artefacts/stabilisation.png"])
