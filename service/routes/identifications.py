"""POST /v1/identifications."""

from __future__ import annotations

from fastapi import APIRouter

from service.deps import ApiKeyDep, QueueDep, SettingsDep, StoreDep
from service.problems import ERROR_RESPONSES
from service.schemas.identifications import IdentificationRequest
from service.schemas.jobs import Job, JobKind
from service.submission import submit

router = APIRouter(prefix="/v1/identifications", tags=["identifications"],
                   responses=ERROR_RESPONSES)


@router.post("", response_model=Job, status_code=202, summary="Identify a model")
def create_identification(request: IdentificationRequest, store: StoreDep, queue: QueueDep,
                          owner: ApiKeyDep, settings: SettingsDep) -> Job:
    """Queue an FNSI identification. Its result holds the order, the modal table, the
    nonlinear coefficients with quality criteria, stiffness curves, errors and timings;
    its artefacts the plots (PNG), result.json and the model (model.npz)."""
    return Job.of(submit(store, queue, owner, JobKind.IDENTIFICATION, request,
                         settings.memory_limit_mb))
