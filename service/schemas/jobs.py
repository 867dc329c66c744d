"""Schemas of jobs, their pages and their artefacts.

A job's ``request`` and ``result`` are served typed, each one schema per job kind: the
stored documents plus ``kind`` (the job's), which tells generated clients which schema
to read.
"""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Any, Literal

from pydantic import BaseModel, Discriminator, Field, Tag

from service.pagination import NextCursor
from service.schemas.analyses import AnalysisRequest
from service.schemas.identifications import IdentificationRequest
from service.schemas.results import JobResult
from service.schemas.simulations import ModelSimulation, PresetSimulation
from service.schemas.studies import DiagnosisRequest, RevisionRequest, StudyRequest
from service.store import JobRecord, JobState


class JobKind(StrEnum):
    """What a job computes."""

    SIMULATION = "simulation"
    IDENTIFICATION = "identification"
    STUDY = "study"
    STUDY_REVISION = "study_revision"
    STUDY_DIAGNOSIS = "study_diagnosis"
    ANALYSIS = "analysis"


_KIND = "The job's kind: tells the kinds of request apart."
_STUDY = Field(description="The study the job acts on.", examples=["study_0a1b2c3d4e5f60718293"])


class PresetSimulationJobRequest(PresetSimulation):
    """The request of a simulation job of a SmallSat preset."""

    kind: Literal["simulation"] = Field(description=_KIND)


class ModelSimulationJobRequest(ModelSimulation):
    """The request of a simulation job of a generic structure."""

    kind: Literal["simulation"] = Field(description=_KIND)


class IdentificationJobRequest(IdentificationRequest):
    """The request of an identification job."""

    kind: Literal["identification"] = Field(description=_KIND)


class AnalysisJobRequest(AnalysisRequest):
    """The request of a distortion analysis job."""

    kind: Literal["analysis"] = Field(description=_KIND)


class StudyJobRequest(StudyRequest):
    """The request of a study's creation job (revision 0)."""

    kind: Literal["study"] = Field(description=_KIND)
    study_id: str = _STUDY


class RevisionJobRequest(RevisionRequest):
    """The request of a study revision job."""

    kind: Literal["study_revision"] = Field(description=_KIND)
    study_id: str = _STUDY


class DiagnosisJobRequest(DiagnosisRequest):
    """The request of a study diagnosis job."""

    kind: Literal["study_diagnosis"] = Field(description=_KIND)
    study_id: str = _STUDY


def _request_tag(value: Any) -> str:
    """``kind``, and for a simulation which of its two shapes (``model`` or ``preset``)."""
    data = value if isinstance(value, dict) else value.model_dump()
    if data.get("kind") == "simulation":
        return "simulation-model" if "model" in data else "simulation-preset"
    return str(data.get("kind"))


JobRequest = Annotated[
    Annotated[PresetSimulationJobRequest, Tag("simulation-preset")]
    | Annotated[ModelSimulationJobRequest, Tag("simulation-model")]
    | Annotated[IdentificationJobRequest, Tag("identification")]
    | Annotated[AnalysisJobRequest, Tag("analysis")]
    | Annotated[StudyJobRequest, Tag("study")]
    | Annotated[RevisionJobRequest, Tag("study_revision")]
    | Annotated[DiagnosisJobRequest, Tag("study_diagnosis")],
    Discriminator(_request_tag)]
"""The request of a job, by its ``kind`` (a simulation: by ``preset`` or ``model``)."""


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
    # A document of no known shape (e.g. stored by an older version) is still served, as
    # a plain object, rather than failing the response.
    request: JobRequest | dict[str, Any] = Field(
        union_mode="left_to_right", description="The validated request, defaults filled "
        "in, with the job's kind.")
    result: JobResult | dict[str, Any] | None = Field(
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
                   batch_id=record.batch_id, request={**record.request, "kind": record.kind},
                   result=None if record.result is None else {**record.result,
                                                              "kind": record.kind},
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
