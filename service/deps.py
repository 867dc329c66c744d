"""Route dependencies: the store, the caller's identity and the caller's own objects.

Ownership is checked here once: a dataset, job or batch of another API key is answered
exactly like an unknown id (404), so ids leak nothing.
"""

from __future__ import annotations

import hashlib
import secrets
from typing import Annotated, Protocol, TypeVar

from fastapi import Depends, Path, Request, Security
from fastapi.security import APIKeyHeader

from service.problems import ProblemError
from service.queue import JobQueue
from service.settings import Settings
from service.store import BatchRecord, DatasetRecord, JobRecord, Store

PUBLIC_OWNER = "public"

_api_key = APIKeyHeader(
    name="X-API-Key", auto_error=False, scheme_name="ApiKey",
    description="One of the keys in FNSI_API_KEYS; not needed when none are configured.")


async def get_settings(request: Request) -> Settings:
    """Settings of the running app.

    This and the other dependencies that do no I/O are coroutines, so FastAPI runs them
    on the event loop: a plain function goes to the thread pool, and each such hop waits
    for a CPU slice, which makes status polls slow while jobs compute beside the API."""
    return request.app.state.settings


async def get_store(request: Request) -> Store:
    """Store of the running app."""
    return request.app.state.store


async def get_queue(request: Request) -> JobQueue:
    """Queue that runs the app's jobs."""
    return request.app.state.queue


SettingsDep = Annotated[Settings, Depends(get_settings)]
StoreDep = Annotated[Store, Depends(get_store)]
QueueDep = Annotated[JobQueue, Depends(get_queue)]


def get_owner(settings: SettingsDep,
              key: Annotated[str | None, Security(_api_key)] = None) -> str:
    """Owner id of the caller: a hash of its API key, or one public owner without keys."""
    if not settings.api_keys:
        return PUBLIC_OWNER
    if key is None or not any(secrets.compare_digest(key.encode(), k.encode())
                              for k in settings.api_keys):
        raise ProblemError(401, "missing or unknown API key: send a valid key in the "
                           "X-API-Key header", headers={"WWW-Authenticate": "ApiKey"})
    return "key_" + hashlib.sha256(key.encode()).hexdigest()[:24]


ApiKeyDep = Annotated[str, Depends(get_owner)]


class _Owned(Protocol):
    owner: str


R = TypeVar("R", bound=_Owned)


def owned(record: R | None, owner: str, what: str, object_id: str) -> R:
    """``record`` if the caller owns it; else 404, the same answer as for an unknown id, so
    another key's objects are never confirmed to exist."""
    if record is None or record.owner != owner:
        raise ProblemError(404, f"{what} {object_id} does not exist (or belongs to another "
                           "API key); check the id returned when it was created")
    return record


def own_dataset(dataset_id: Annotated[str, Path(description="Dataset id.")],
                store: StoreDep, owner: ApiKeyDep) -> DatasetRecord:
    """The caller's dataset, or 404."""
    return owned(store.get_dataset(dataset_id), owner, "dataset", dataset_id)


def own_job(job_id: Annotated[str, Path(description="Job id.")],
            store: StoreDep, owner: ApiKeyDep) -> JobRecord:
    """The caller's job, or 404."""
    return owned(store.get_job(job_id), owner, "job", job_id)


def own_batch(batch_id: Annotated[str, Path(description="Batch id.")],
              store: StoreDep, owner: ApiKeyDep) -> BatchRecord:
    """The caller's batch, or 404."""
    return owned(store.get_batch(batch_id), owner, "batch", batch_id)


OwnDatasetDep = Annotated[DatasetRecord, Depends(own_dataset)]
OwnJobDep = Annotated[JobRecord, Depends(own_job)]
OwnBatchDep = Annotated[BatchRecord, Depends(own_batch)]


def require_dataset(store: Store, owner: str, dataset_id: str, field: str) -> DatasetRecord:
    """A dataset named in a request body, or 422 naming the field."""
    record = store.get_dataset(dataset_id)
    if record is None or record.owner != owner:
        raise ProblemError(422, f"{field}: dataset {dataset_id} does not exist (or belongs to "
                           "another API key); upload it first with POST /v1/datasets")
    return record
