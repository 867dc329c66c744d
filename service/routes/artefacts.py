"""Artefacts of a job: plots (PNG), JSON results, models (NPZ), one-page reports (HTML)."""

from __future__ import annotations

import mimetypes
from typing import Annotated

from fastapi import APIRouter, Path
from fastapi.responses import Response

from service.deps import OwnJobDep, StoreDep
from service.downloads import file_download
from service.problems import ERROR_RESPONSES, ProblemError
from service.schemas.jobs import Artefact

router = APIRouter(prefix="/v1/jobs/{job_id}/artefacts", tags=["artefacts"],
                   responses=ERROR_RESPONSES)

_MEDIA_TYPES = {".png": "image/png", ".json": "application/json",
                ".npz": "application/octet-stream", ".csv": "text/csv",
                ".html": "text/html", ".uff": "application/octet-stream",
                ".mat": "application/octet-stream"}


def _media_type(name: str) -> str:
    suffix = name[name.rfind("."):] if "." in name else ""
    return _MEDIA_TYPES.get(suffix) or mimetypes.guess_type(name)[0] or "application/octet-stream"


@router.get("", response_model=list[Artefact], summary="List a job's artefacts")
def list_artefacts(job: OwnJobDep, store: StoreDep) -> list[Artefact]:
    """Files the job produced so far (complete once it succeeded)."""
    return [Artefact(name=name, media_type=_media_type(name), size_bytes=size,
                     url=f"/v1/jobs/{job.id}/artefacts/{name}")
            for name, size in store.list_artefacts(job.id)]


# Every artefact is a file, whatever its media type: declared binary in each (octet-stream
# first), so generated clients return its bytes instead of parsing a PNG as JSON.
_BINARY = {"schema": {"type": "string", "format": "binary"}}


@router.get("/{name}", summary="Download an artefact", response_class=Response,
            responses={200: {"description": "The artefact file.", "content": {
                media: _BINARY for media in ("application/octet-stream", "image/png",
                                             "application/json", "text/csv", "text/html")}}})
def get_artefact(job: OwnJobDep, store: StoreDep,
                 name: Annotated[str, Path(description="Artefact name, e.g. frf.png.")]
                 ) -> Response:
    """One artefact of a job, by the name given in its listing."""
    file = store.open_artefact(job.id, name)
    if file is None:
        known = [n for n, _ in store.list_artefacts(job.id)]
        raise ProblemError(404, f"job {job.id} has no artefact {name!r}; it has {known}")
    return file_download(file, _media_type(name), name)
