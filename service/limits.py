"""Request body limits answered with problem+json (413), checked while the body streams.

FastAPI's own ``max_body_size`` answers oversized requests with a plain-text 413 when the
Content-Length is known; this middleware keeps every error in the API's problem format.
"""

from __future__ import annotations

from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.problems import problem_response

DETAIL = ("request body too large: at most {limit} bytes here ({setting}); send less data "
          "or ask the operator to raise {setting}")


class BodyTooLargeError(HTTPException):
    """Raised from ``receive`` once the streamed body passes the limit."""

    def __init__(self, limit: int, setting: str) -> None:
        super().__init__(413, DETAIL.format(limit=limit, setting=setting))


class BodyLimitMiddleware:
    """Limit request bodies: ``uploads`` bytes on the given (method, path) pairs,
    ``default`` bytes everywhere else."""

    def __init__(self, app: ASGIApp, *, default: int, uploads: int,
                 upload_routes: frozenset[tuple[str, str]]) -> None:
        self.app, self.default, self.uploads, self.upload_routes = (
            app, default, uploads, upload_routes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        if (scope["method"], scope["path"].rstrip("/")) in self.upload_routes:
            limit, setting = self.uploads, "FNSI_MAX_UPLOAD_BYTES"
        else:
            limit, setting = self.default, "FNSI_MAX_REQUEST_BYTES"
        declared = Headers(scope=scope).get("content-length")
        if declared is not None and declared.isdigit() and int(declared) > limit:
            response = problem_response(Request(scope), 413,
                                        DETAIL.format(limit=limit, setting=setting),
                                        headers={"Connection": "close"})
            await response(scope, receive, send)
            return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > limit:
                    raise BodyTooLargeError(limit, setting)
            return message

        await self.app(scope, limited_receive, send)
