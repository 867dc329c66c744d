"""Schemas of batches: many jobs submitted in one request."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from service.schemas.base import RequestModel
from service.schemas.identifications import IdentificationRequest
from service.schemas.jobs import Job
from service.schemas.simulations import SimulationRequest


class SimulationItem(RequestModel):
    """A simulation job of a batch."""

    kind: Literal["simulation"] = Field(description="Job kind.")
    request: SimulationRequest = Field(description="As the body of POST /v1/simulations.")


class IdentificationItem(RequestModel):
    """An identification job of a batch."""

    kind: Literal["identification"] = Field(description="Job kind.")
    request: IdentificationRequest = Field(description="As the body of POST "
                                           "/v1/identifications.")


BatchItem = Annotated[SimulationItem | IdentificationItem, Field(discriminator="kind")]


class BatchRequest(RequestModel):
    """Jobs to submit together (at most 1000)."""

    model_config = ConfigDict(json_schema_extra={"examples": [{"jobs": [
        {"kind": "simulation", "request": {"preset": "single", "periods": 3,
                                           "samples_per_period": 2500, "seed": 1}},
        {"kind": "simulation", "request": {"preset": "single", "periods": 3,
                                           "samples_per_period": 2500, "seed": 2}}]}]})

    jobs: list[BatchItem] = Field(min_length=1, max_length=1000, description="The jobs.")


class Batch(BaseModel):
    """A submitted batch and the current state of its jobs."""

    id: str = Field(description="Batch id.", examples=["batch_0a1b2c3d4e5f60718293"])
    created_at: str = Field(description="Submission time, ISO 8601 UTC.")
    job_ids: list[str] = Field(description="Ids of the jobs, in request order.")
    counts: dict[str, int] = Field(description="Number of jobs per state.",
                                   examples=[{"queued": 1, "running": 1, "succeeded": 3}])
    jobs: list[Job] = Field(description="The jobs, in request order.")
