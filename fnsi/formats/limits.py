"""How much a file may decode to: checked from its headers, before any data are decoded.

A compressed upload can be small and still decode to gigabytes (zeros compress a
thousandfold; an HDF5 dataset of fill values needs no stored bytes at all), so every
reader computes the decoded size from the file's own metadata (array headers, MATLAB
dimensions, HDF5 shapes) and refuses it here before it allocates anything.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

FLOAT_BYTES = 8
"""Bytes per decoded sample: every record is held as float64, whatever its file type."""


class DecodeLimitError(ValueError):
    """A file decodes to more than a :class:`DecodeLimits` allows.

    Attributes
    ----------
    limit_name : str
        The :class:`DecodeLimits` field that refused it (``max_decoded_bytes`` or
        ``max_channels``).
    limit : int
        Its value.
    """

    def __init__(self, message: str, limit_name: str, limit: int) -> None:
        super().__init__(message)
        self.limit_name = limit_name
        self.limit = limit


class DecodedTooLargeError(DecodeLimitError):
    """The decoded arrays would exceed ``DecodeLimits.max_decoded_bytes``."""


class TooManyChannelsError(DecodeLimitError):
    """The record has more channels than ``DecodeLimits.max_channels``."""


@dataclass(frozen=True)
class DecodeLimits:
    """Largest record a reader decodes.

    Attributes
    ----------
    max_decoded_bytes : int
        Largest total size of the decoded arrays [bytes], counted as float64 for samples.
        512 MiB holds the paper's SmallSat record (40 channels x 240,000 samples, 77 MB)
        six times over; reading, summarising and writing a 500 MiB record as canonical
        NPZ peaked at 0.96 GiB of resident memory.
    max_channels : int
        Most input plus output channels of one record.
    """

    max_decoded_bytes: int = 512 * 1024**2
    max_channels: int = 1024

    def check_bytes(self, nbytes: int, what: str) -> None:
        """Refuse ``nbytes`` of decoded data from ``what`` (a phrase naming the source)."""
        if nbytes > self.max_decoded_bytes:
            raise DecodedTooLargeError(
                f"{what} decodes to {nbytes} bytes, more than the limit of "
                f"{self.max_decoded_bytes} bytes (max_decoded_bytes); send a shorter record, "
                "fewer channels or fewer realisations", "max_decoded_bytes",
                self.max_decoded_bytes)

    def check_channels(self, count: int, what: str, hint: str = "") -> None:
        """Refuse a record of ``count`` channels (inputs plus outputs); ``hint`` ends the
        message (e.g. that the arrays look transposed)."""
        if count > self.max_channels:
            raise TooManyChannelsError(
                f"{what} has {count} channels, more than the limit of {self.max_channels} "
                f"(max_channels); send only the channels the identification needs{hint}",
                "max_channels", self.max_channels)

    def check_records(self, shapes: dict[str, Sequence[int]], what: str) -> None:
        """Channel count and orientation of the record arrays (``u``, ``y``) from their
        header shapes: channels stored in rows (fewer samples than channels) are refused
        as transposed, and named in the message of a channel count beyond the limit."""
        flipped = [f"{name} has shape {tuple(int(n) for n in shape)}"
                   for name, shape in shapes.items() if looks_transposed(shape)]
        hint = (f" ({', '.join(flipped)}: fewer samples than channels, transposed? store "
                "one sample per row, samples x channels)") if flipped else ""
        self.check_channels(sum(channels_of(shape) for shape in shapes.values()), what, hint)
        if flipped:
            raise ValueError(f"{', '.join(flipped)}: fewer samples than channels, transposed? "
                             "store one sample per row (samples x channels), e.g. save u.T "
                             "and y.T; MATLAB iddata-style records are samples x channels too")


def array_bytes(shape: Sequence[int], itemsize: int) -> int:
    """Bytes of an array of ``shape`` (Python integers: no overflow for absurd shapes)."""
    return math.prod(int(n) for n in shape) * int(itemsize)


def channels_of(shape: Sequence[int]) -> int:
    """Channels of a record array laid out (samples,), (samples, channels) or
    (realisations, samples, channels)."""
    return int(shape[-1]) if len(shape) >= 2 else 1


def looks_transposed(shape: Sequence[int]) -> bool:
    """A 2-D (samples, channels) or 3-D (realisations, samples, channels) record with fewer
    samples than channels: a periodic record needs many samples per channel, so the
    channels were stored in rows (an empty record is refused as empty, not here)."""
    return len(shape) >= 2 and 0 < int(shape[-2]) < int(shape[-1])


NUMERIC_KINDS = "biuf"
"""numpy dtype kinds a record's samples may have: bool, integers, floats."""


def is_numeric(dtype: np.dtype) -> bool:
    """Plain (unstructured) boolean, integer or floating dtype."""
    return dtype.fields is None and dtype.kind in NUMERIC_KINDS
