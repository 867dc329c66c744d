"""RFC 9457 problem details: the one shape of every error response.

Every failure, including unknown routes, validation errors and oversized bodies, is
answered with ``application/problem+json`` and a ``detail`` telling the caller what to
change. Validation errors list the fields at fault without echoing the submitted values
(an upload's bytes never come back).
"""

from __future__ import annotations

import errno
import logging
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from fastapi.routing import iter_route_contexts
from pydantic import BaseModel, Field
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

MEDIA_TYPE = "application/problem+json"
log = logging.getLogger("fnsi.service")


INTERNAL_ERROR = ("internal error; the server log has the details. Retry later or report the "
                  "request to the operator")
DISK_FULL = ("the server is out of disk space; nothing stored earlier was lost. Retry later "
             "or ask the operator to free space under FNSI_DATA_DIR")


class FieldError(BaseModel):
    """One invalid field of a request."""

    loc: list[str | int] = Field(description="Path to the field, e.g. ['body', 'band', 0].",
                                 examples=[["body", "block_rows"]])
    msg: str = Field(description="What is wrong with it.",
                     examples=["Input should be greater than or equal to 2"])
    type: str = Field(description="Machine-readable error kind.", examples=["greater_than_equal"])


class Problem(BaseModel):
    """Error response (RFC 9457 problem details)."""

    type: str = Field("about:blank", description="URI identifying the problem type.")
    title: str = Field(description="Short summary of the problem type.", examples=["Not Found"])
    status: int = Field(description="HTTP status code.", examples=[404])
    detail: str = Field(description="What went wrong and what to change.",
                        examples=["dataset ds_0123 does not exist or belongs to another key"])
    instance: str | None = Field(None, description="Path of the request that failed.",
                                 examples=["/v1/datasets/ds_0123"])
    errors: list[FieldError] | None = Field(
        None, description="Invalid fields, for validation errors (422) only.")


class ProblemError(Exception):
    """Raise from a route or dependency to answer with a problem document."""

    def __init__(self, status: int, detail: str, headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.headers = headers


def problem_response(request: Request, status: int, detail: str, *,
                     errors: list[dict[str, Any]] | None = None,
                     headers: dict[str, str] | None = None) -> JSONResponse:
    """A problem+json response for ``request``."""
    body = Problem(title=HTTPStatus(status).phrase, status=status, detail=detail,
                   instance=request.url.path, errors=errors)
    return JSONResponse(body.model_dump(exclude_none=True), status_code=status,
                        media_type=MEDIA_TYPE, headers=headers)


def _allowed_methods(request: Request) -> list[str]:
    """Methods of every route of the app whose path matches the request's.

    Starlette's 405 names only the first route matching the path, while FastAPI declares
    one route per method (GET and DELETE of /v1/jobs/{id} are two routes).
    """
    methods: set[str] = set()
    for route in iter_route_contexts(request.app.routes):  # routes of included routers too
        if route.matches(request.scope)[0] != Match.NONE:
            methods |= route.methods or set()
    return sorted(methods)


def _http_detail(exc: StarletteHTTPException, request: Request) -> str:
    if exc.status_code == 404 and exc.detail == "Not Found":
        return f"no route {request.url.path}; see /docs for the routes of this API"
    if exc.status_code == 405:
        return (f"{request.method} is not allowed on {request.url.path}; use "
                f"{' or '.join(_allowed_methods(request))} (see /docs)")
    if exc.status_code == 400 and str(exc.detail).startswith("Part exceeded maximum size"):
        # Starlette's form limit, on the upload's only non-file field
        return (f"the form field `meta` is too large ({exc.detail}, FNSI_MAX_META_BYTES); "
                "send a shorter meta JSON")
    return str(exc.detail)


def install(app: FastAPI) -> None:
    """Register the problem+json handlers on ``app``."""

    @app.exception_handler(ProblemError)
    async def _problem(request: Request, exc: ProblemError) -> JSONResponse:
        return problem_response(request, exc.status, exc.detail, headers=exc.headers)

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:
            headers = {**(headers or {}), "Allow": ", ".join(_allowed_methods(request))}
        return problem_response(request, exc.status_code, _http_detail(exc, request),
                                headers=headers)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        errors = [{"loc": [str(p) if not isinstance(p, int) else p for p in e["loc"]],
                   "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
        summary = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in errors[:5])
        media = request.headers.get("content-type", "").split(";")[0].strip().lower()
        if any(e["loc"][:1] == ["body"] for e in errors) and media not in (
                "application/json", "multipart/form-data"):
            summary += (f" (the body was sent as {media or 'no content type'}: send JSON "
                        "with Content-Type: application/json)")
        return problem_response(request, 422, f"invalid request: {summary}", errors=errors)

    @app.exception_handler(OSError)
    async def _os_error(request: Request, exc: OSError) -> JSONResponse:
        if exc.errno == errno.ENOSPC:
            return problem_response(request, 507, DISK_FULL)
        return _internal_error(request, exc)

    app.add_middleware(UnexpectedErrorMiddleware)


def _internal_error(request: Request, exc: BaseException) -> JSONResponse:
    log.error("unhandled error on %s %s", request.method, request.url.path, exc_info=exc)
    return problem_response(request, 500, INTERNAL_ERROR)


class UnexpectedErrorMiddleware:
    """Answer an exception no handler took with a complete problem+json 500.

    Starlette's own last-resort handler (``exception_handler(Exception)``) sends its
    response and then re-raises, and uvicorn closes a connection whose application
    raised: every unexpected error cost the client its keep-alive connection. This
    middleware, inside Starlette's, ends the request normally instead. An error after the
    response started cannot be answered: it is re-raised, and the connection closed is
    how the client learns that the body it got is incomplete.
    """

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracked_send(message: Message) -> None:
            nonlocal started
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, receive, tracked_send)
        except Exception as exc:
            if started:
                raise
            await _internal_error(Request(scope), exc)(scope, receive, send)


ERROR_RESPONSES: dict[int | str, dict[str, Any]] = {
    code: {"model": Problem, "description": HTTPStatus(code).phrase,
           "content": {MEDIA_TYPE: {"schema": {"$ref": "#/components/schemas/Problem"}}}}
    for code in (400, 401, 404, 413, 422, 507)
}
