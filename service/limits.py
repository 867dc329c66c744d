"""Request body limits answered with problem+json: size (413) and JSON nesting (422).

FastAPI's own ``max_body_size`` answers oversized requests with a plain-text 413 when the
Content-Length is known; this middleware keeps every error in the API's problem format.
It also refuses JSON nested deeper than :data:`MAX_JSON_DEPTH` before anything parses
it: Python's parser gives up near its recursion limit (~1000 levels) with a generic
"error parsing the body", and depths below that reach validation and storage.
"""

from __future__ import annotations

import re
from email.message import Message as MediaType

import numpy as np
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service.problems import problem_response

DETAIL = ("request body too large: at most {limit} bytes here ({setting}); send less data "
          "or ask the operator to raise {setting}")

MAX_JSON_DEPTH = 32
"""Deepest nesting of arrays and objects in a JSON body (every request of the API needs
fewer than 10 levels)."""

# A JSON string (escapes included), unrolled so the regex engine runs without backtracking.
_JSON_STRING = re.compile(rb'"[^"\\]*(?:\\.[^"\\]*)*"', re.DOTALL)


class BodyTooLargeError(HTTPException):
    """Raised from ``receive`` once the streamed body passes the limit."""

    def __init__(self, limit: int, setting: str) -> None:
        super().__init__(413, DETAIL.format(limit=limit, setting=setting))


def json_depth(body: bytes) -> int:
    """Deepest nesting of arrays and objects in a JSON text, without parsing it.

    Brackets inside strings do not count. Linear time and constant stack: safe on any
    input, including text that is not JSON (its depth is then only an estimate, and the
    parser reports the syntax error).
    """
    skeleton = np.frombuffer(_JSON_STRING.sub(b"", body), dtype=np.uint8)
    steps = (np.isin(skeleton, (ord("["), ord("{"))).astype(np.int64)
             - np.isin(skeleton, (ord("]"), ord("}"))))
    return int(np.cumsum(steps).max(initial=0))


def _is_json(headers: Headers) -> bool:
    """Whether FastAPI would parse the body as JSON (no content type, or a JSON one)."""
    value = headers.get("content-type")
    if not value:
        return True
    media = MediaType()
    media["content-type"] = value
    subtype = media.get_content_subtype()
    return media.get_content_maintype() == "application" and (
        subtype == "json" or subtype.endswith("+json"))


class BodyLimitMiddleware:
    """Limit request bodies: ``uploads`` bytes on the given (method, path) pairs,
    ``default`` bytes everywhere else, and :data:`MAX_JSON_DEPTH` levels in JSON bodies."""

    def __init__(self, app: ASGIApp, *, default: int, uploads: int,
                 upload_routes: frozenset[tuple[str, str]]) -> None:
        self.app, self.default, self.uploads, self.upload_routes = (
            app, default, uploads, upload_routes)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        upload = (scope["method"], scope["path"].rstrip("/")) in self.upload_routes
        if upload:
            limit, setting = self.uploads, "FNSI_MAX_UPLOAD_BYTES"
        else:
            limit, setting = self.default, "FNSI_MAX_REQUEST_BYTES"
        headers = Headers(scope=scope)
        declared = headers.get("content-length")
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

        if upload or not _is_json(headers):
            await self.app(scope, limited_receive, send)
            return
        await self._json(scope, limited_receive, receive, send)

    async def _json(self, scope: Scope, limited_receive: Receive, receive: Receive,
                    send: Send) -> None:
        """Read a JSON body whole (it is small: FNSI_MAX_REQUEST_BYTES), refuse it if nested
        too deeply, else hand it to the app as one message."""
        chunks, more = [], True
        try:
            while more:
                message = await limited_receive()
                if message["type"] != "http.request":  # the client went away
                    return
                chunks.append(message.get("body", b""))
                more = message.get("more_body", False)
        except BodyTooLargeError as err:
            response = problem_response(Request(scope), 413, err.detail,
                                        headers={"Connection": "close"})
            await response(scope, receive, send)
            return
        body = b"".join(chunks)
        depth = json_depth(body)
        if depth > MAX_JSON_DEPTH:
            response = problem_response(Request(scope), 422, (
                f"the JSON body is nested too deeply: {depth} levels of arrays and objects, "
                f"at most {MAX_JSON_DEPTH} are accepted; send the flat request the schema "
                "describes (see /docs)"))
            await response(scope, receive, send)
            return
        replayed = False

        async def replay() -> Message:
            nonlocal replayed
            if replayed:
                return await receive()
            replayed = True
            return {"type": "http.request", "body": body, "more_body": False}

        await self.app(scope, replay, send)
