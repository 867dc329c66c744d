"""POST /v1/analyses."""

from __future__ import annotations

from fastapi import APIRouter

from service.deps import ApiKeyDep, QueueDep, SettingsDep, StoreDep
from service.problems import ERROR_RESPONSES
from service.schemas.analyses import AnalysisRequest
from service.schemas.jobs import Job, JobKind
from service.submission import submit

router = APIRouter(prefix="/v1/analyses", tags=["analyses"], responses=ERROR_RESPONSES)


@router.post("", response_model=Job, status_code=202,
             summary="Analyse nonlinear distortions")
def create_analysis(request: AnalysisRequest, store: StoreDep, queue: QueueDep,
                    owner: ApiKeyDep, settings: SettingsDep) -> Job:
    """Queue a distortion analysis: is the structure nonlinear, how much, and of which
    law (odd or even), before any model. Its result holds the levels per output [dB over
    the noise] and the verdict; its artefacts analysis.json and distortion.png."""
    return Job.of(submit(store, queue, owner, JobKind.ANALYSIS, request,
                         settings.memory_limit_mb))
