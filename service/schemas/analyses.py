"""Schemas of distortion analyses: nonlinear distortion levels before any model."""

from __future__ import annotations

from pydantic import Field

from service.schemas.base import RequestModel


class AnalysisRequest(RequestModel):
    """A nonparametric distortion analysis of a dataset (:mod:`fnsi.distortion`): per
    output the best linear approximation, the noise level and the nonlinear distortion
    levels on the excited, the odd and even non-excited and the above-band lines, with a
    verdict. Needs at least two periods after the discarded ones; several random-phase
    realisations give the distortions on the excited lines too."""

    dataset_id: str = Field(description="The dataset to analyse.",
                            examples=["ds_5f1c0e2a9b7d4c3e8a10"])
    outputs: list[str] | None = Field(
        None, min_length=1, description="Output channels to analyse (default all), each "
        "once.", examples=[["NC2w_Z", "NC2b_Z"]])
    discard_periods: int = Field(1, ge=0, description="Leading transient periods left "
                                 "out.", examples=[1])
