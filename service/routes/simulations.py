"""POST /v1/simulations."""

from __future__ import annotations

from fastapi import APIRouter

from service.deps import ApiKeyDep, QueueDep, SettingsDep, StoreDep
from service.problems import ERROR_RESPONSES
from service.schemas.jobs import Job, JobKind
from service.schemas.simulations import SimulationRequest
from service.submission import submit

router = APIRouter(prefix="/v1/simulations", tags=["simulations"], responses=ERROR_RESPONSES)


@router.post("", response_model=Job, status_code=202, summary="Simulate a test")
def create_simulation(request: SimulationRequest, store: StoreDep, queue: QueueDep,
                      owner: ApiKeyDep, settings: SettingsDep) -> Job:
    """Queue a simulation; once it succeeds, ``result.dataset_id`` is the simulated
    measurement and the artefact ``truth.json`` holds the true modes and nonlinearities."""
    return Job.of(submit(store, queue, owner, JobKind.SIMULATION, request,
                         settings.memory_limit_mb))
