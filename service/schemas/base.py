"""The base of every request model: what all request bodies refuse."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict


class RequestModel(BaseModel):
    """A request body or a part of one: unknown fields are refused (a misspelt parameter
    must not be silently ignored), and so are the JSON extensions ``NaN``, ``Infinity``
    and ``-Infinity`` in every number (422 naming the field). Python's JSON parser accepts
    them, but no computation can use them, and pydantic would serialise them as null,
    which the library then reads as a missing value."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
