"""Cursor pagination of the listing routes (jobs, datasets, studies), newest first.

A cursor is the opaque, URL-safe encoding of the position of the last item of a page
(``<kind>:<position>``); the next page holds the items strictly older than it, so a page
boundary does not move when new items are created between two requests.
"""

from __future__ import annotations

import base64
from collections.abc import Callable, Sequence
from typing import Annotated, TypeVar

from fastapi import Query
from pydantic import Field

from service.problems import ProblemError

NOT_OURS = "not one returned by this API; pass next_cursor from the previous page unchanged"
"""Why a cursor was refused (it was not produced by :func:`encode_cursor` for this list)."""

PageLimit = Annotated[int, Query(ge=1, le=200, description="Page size.")]
PageCursor = Annotated[str | None, Query(
    description="next_cursor of the previous page; absent or empty: the first page.")]
NextCursor = Annotated[str | None, Field(
    description="Pass as ?cursor= to get the next page; null on the last page.")]

# SQLite integers are signed 64-bit: a larger position would overflow in the query.
_ROWID_END = 2**63
T = TypeVar("T")
P = TypeVar("P")


def encode_cursor(kind: str, position: str) -> str:
    """Opaque cursor of the item of ``kind`` at ``position``."""
    return base64.urlsafe_b64encode(f"{kind}:{position}".encode()).decode().rstrip("=")


def decode_cursor(cursor: str, kind: str) -> str:
    """Position of a cursor from :func:`encode_cursor`; ValueError if malformed or of
    another kind of item."""
    try:
        text = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4)).decode()
        found, position = text.split(":", 1)
    except (ValueError, UnicodeDecodeError):
        found, position = "", ""
    if found != kind or not position:
        raise ValueError(NOT_OURS)
    return position


def cursor_position(cursor: str | None, kind: str,
                    parse: Callable[[str], P] = str) -> P | None:
    """Position of a request's ``cursor`` query parameter, converted by ``parse`` (None:
    first page, also for an empty ``cursor=``); a malformed cursor is a 422 problem."""
    if not cursor:
        return None
    try:
        return parse(decode_cursor(cursor, kind))
    except ValueError as err:
        raise ProblemError(422, f"cursor is {err}") from None


def sequence_number(position: str) -> int:
    """A cursor position that is a row's sequence number (a positive SQLite integer,
    below 2**63); ValueError otherwise."""
    if not (position.isascii() and position.isdigit()) or not 0 < int(position) < _ROWID_END:
        raise ValueError(NOT_OURS)
    return int(position)


def split_page(items: Sequence[T], limit: int, kind: str,
               position: Callable[[T], str]) -> tuple[Sequence[T], str | None]:
    """The first ``limit`` of ``items`` (fetched as ``limit + 1`` to know whether more
    follow) and the cursor of the next page, None on the last page."""
    page = items[:limit]
    more = len(items) > limit
    return page, encode_cursor(kind, position(page[-1])) if more else None
