"""Downloads of stored files that stay whole while the files are deleted.

A route opens the file first (404 if it is already gone) and answers with
:func:`file_download`, which streams from that open file: deleting a dataset or a job
removes the name, not the data still being sent, so a download is either a complete 200
or a 404, never a 500 or a truncated body. (Starlette's ``FileResponse`` opens the path
only once the response runs, after the route returned.)
"""

from __future__ import annotations

import os
from collections.abc import Iterator
from typing import BinaryIO
from urllib.parse import quote

from fastapi.responses import StreamingResponse

_CHUNK = 1024 * 1024


def _chunks(file: BinaryIO) -> Iterator[bytes]:
    with file:
        while chunk := file.read(_CHUNK):
            yield chunk


def file_download(file: BinaryIO, media_type: str, filename: str) -> StreamingResponse:
    """Stream an open ``file`` (closed when sent) as the attachment ``filename``."""
    quoted = quote(filename)
    disposition = (f'attachment; filename="{filename}"' if quoted == filename
                   else f"attachment; filename*=utf-8''{quoted}")
    size = os.fstat(file.fileno()).st_size
    return StreamingResponse(_chunks(file), media_type=media_type, headers={
        "Content-Length": str(size), "Content-Disposition": disposition})
