"""Schemas of the dataset routes."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, StrictFloat, StrictInt, StringConstraints

from service.pagination import NextCursor
from service.schemas.base import RequestModel

Quantity = Literal["displacement", "velocity", "acceleration"]


class DatasetFormat(StrEnum):
    """File formats accepted by the upload."""

    NPZ = "npz"
    CSV = "csv"
    MAT = "mat"
    H5 = "h5"
    UFF = "uff"


class DownloadFormat(StrEnum):
    """File formats a dataset can be downloaded in."""

    NPZ = "npz"
    CSV = "csv"


class UploadMeta(RequestModel):
    """Optional JSON sent with an upload (form field ``meta``); overrides the file."""

    model_config = ConfigDict(json_schema_extra={
        "examples": [{"fs": 2500, "inputs": ["force"], "periods": 8,
                      "quantity": "displacement"}]})

    name: str | None = Field(None, max_length=200,
                             description="Label of the dataset; default the file name.")
    format: DatasetFormat | None = Field(
        None, description="File format; default from the extension (.npz .csv .mat .h5 "
        ".hdf5 .uff .unv).")
    fs: StrictFloat | None = Field(None, gt=0, description="Sampling rate [Hz]; required for "
                                   "a CSV without a time column.", examples=[2500.0])
    inputs: list[str] | None = Field(
        None, min_length=1, description="Names of the input (force) channels; required for "
        "CSV, optional elsewhere (selects channels).", examples=[["force"]])
    outputs: list[str] | None = Field(
        None, min_length=1, description="Names of the output channels to keep; default all "
        "non-input channels.", examples=[["NC2w_Z", "NC2b_Z"]])
    periods: StrictInt | None = Field(
        None, ge=1, description="Excitation periods per record; default from the file, else "
        "detected from the input.", examples=[8])
    quantity: Quantity | None = Field(None, description="What the outputs measure.")
    units: dict[str, Annotated[str, StringConstraints(max_length=40)]] | None = Field(
        None, max_length=4096, description="Channel name -> unit (\"N\", \"mm\", \"V\"), "
        "overriding the file's; figures and results are labelled in them (\"input unit\", "
        "\"output unit\" where none is given).", examples=[{"force": "N", "NC2w_Z": "mm"}])
    group: str | None = Field(
        None, max_length=1000, description="HDF5 / MATLAB v7.3: path of the group holding u "
        "and y; default the root, or the one group holding them.", examples=["run1"])


class ChannelSummary(BaseModel):
    """Statistics of one channel."""

    name: str = Field(description="Channel name.", examples=["NC2w_Z"])
    role: Literal["input", "output"] = Field(description="Input force or measured output.")
    quantity: Literal["force", "displacement", "velocity", "acceleration"] | None = Field(
        None, description="What the channel measures: force for inputs, the dataset "
        "quantity for outputs.", examples=["displacement"])
    unit: str | None = Field(None, description="Unit of the channel, from the file or the "
                             "upload's meta.units; null when not given.", examples=["mm"])
    rms: StrictFloat = Field(description="Root mean square over the whole record, in the "
                             "channel's unit.", examples=[0.0123])
    snr_db: StrictFloat | None = Field(
        description="Signal-to-noise ratio [dB] from the period-to-period variation (first "
        "period skipped as transient when there are >= 3); null with fewer than 2 periods or "
        "a noise-free channel.", examples=[46.2])


class DatasetListItem(BaseModel):
    """A stored dataset as listed: its shape, without its channels."""

    id: str = Field(description="Dataset id.", examples=["ds_5f1c0e2a9b7d4c3e8a10"])
    name: str = Field(description="Label (file name unless given).", examples=["run12.npz"])
    created_at: str = Field(description="Creation time, ISO 8601 UTC.")
    size_bytes: StrictInt = Field(description="Size of the canonical NPZ [bytes].")
    source_job: str | None = Field(None, description="Simulation job that produced it, if any.")
    fs: StrictFloat = Field(description="Sampling rate [Hz].", examples=[2500.0])
    samples: StrictInt = Field(description="Samples per realisation.", examples=[240000])
    realisations: StrictInt = Field(description="Independent realisations.", examples=[1])
    periods: StrictInt = Field(description="Excitation periods per realisation.", examples=[8])
    periods_source: Literal["declared", "detected"] = Field(
        description="Whether the number of periods was given or detected from the input.")
    period_length: StrictInt = Field(description="Samples per period.", examples=[30000])
    quantity: Quantity = Field(description="What the outputs measure.")
    n_inputs: StrictInt = Field(description="Number of input channels.", examples=[1])
    n_outputs: StrictInt = Field(description="Number of output channels.", examples=[39])


class Dataset(DatasetListItem):
    """A stored dataset and what it contains."""

    inputs: list[str] = Field(description="Input channel names.", examples=[["force"]])
    outputs: list[str] = Field(description="Output channel names.", examples=[["NC2w_Z"]])
    channels: list[ChannelSummary] = Field(description="Per-channel statistics.")


class DatasetPage(BaseModel):
    """One page of datasets, newest first."""

    items: list[DatasetListItem] = Field(
        description="Datasets of this page, with channel counts; GET one for its channels.")
    next_cursor: NextCursor = None
