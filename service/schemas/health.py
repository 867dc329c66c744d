"""Schema of the health route."""

from typing import Literal

from pydantic import BaseModel, Field


class Health(BaseModel):
    """The service is up; which queue runs its jobs."""

    status: Literal["ok"] = Field(description="Always \"ok\" when the API answers.")
    version: str = Field(description="Version of fnsi-service.", examples=["0.1.0"])
    queue: Literal["embedded", "celery"] = Field(
        description="\"embedded\": the API process runs jobs itself; \"celery\": jobs go to "
        "fnsi-worker processes through the broker.")
