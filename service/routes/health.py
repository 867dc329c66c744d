"""GET /health."""

from importlib.metadata import PackageNotFoundError, version

from fastapi import APIRouter

from service.deps import QueueDep
from service.schemas.health import Health

router = APIRouter(tags=["health"])


def _version() -> str:
    try:
        return version("fnsi-service")
    except PackageNotFoundError:  # running from a source tree that was never installed
        return "0+unknown"


@router.get("/health", response_model=Health, summary="Service status")
def health(queue: QueueDep) -> Health:
    """Answer while the API is up, with its version and the kind of job queue in use."""
    return Health(status="ok", version=_version(), queue=queue.name)
