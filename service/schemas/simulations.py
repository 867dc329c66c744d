"""Schemas of simulation requests: SmallSat presets and generic structural models."""

from __future__ import annotations

from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    ConfigDict,
    Discriminator,
    Field,
    StrictFloat,
    StrictInt,
    Tag,
    model_validator,
)

from fnsi.acquisition import check_timing
from fnsi.excitation import excited_line_range
from fnsi.measurement import check_channels
from fnsi.nonlinear import NonlinearElement
from fnsi.smallsat import check_preset
from fnsi.structure import StructuralModel
from service.schemas.base import RequestModel
from service.schemas.identifications import NonlinearElementSpec

MAX_SAMPLES = 20_000_000
"""Most samples (periods x samples per period x realisations) one simulation may record;
the paper's records are 240,000."""
MAX_INTEGRATION_FACTOR = 64
"""Largest fs_int / fs."""


def _check_size(samples: int, fs: float, fs_int: float) -> None:
    if samples > MAX_SAMPLES:
        raise ValueError(f"{samples} samples requested; at most {MAX_SAMPLES} per "
                         "simulation: use fewer periods or samples per period")
    if fs_int / fs > MAX_INTEGRATION_FACTOR:
        raise ValueError(f"fs_int / fs = {fs_int / fs:g}; at most {MAX_INTEGRATION_FACTOR}")


class PresetSimulation(RequestModel):
    """Simulated test of the SmallSat reference structure (docs/design.md section 4).

    ``single``: 100 N RMS at NC2w_Z (paper Table 3); ``multi``: 200 N RMS at the wheel W
    along the X-Y diagonal (Table 8). The result is a new dataset; the truth (modes,
    nonlinear coefficients, contact counts) is the job artefact ``truth.json``.
    """

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"preset": "single", "periods": 3, "samples_per_period": 2500, "seed": 1}]})

    preset: Literal["single", "multi"] = Field(description="Excitation case of the paper.")
    periods: StrictInt = Field(8, ge=1, le=1000, description="Periods simulated; the first two "
                         "hold the transient and are left out of the noise reference and "
                         "the contact counts, so give at least 3.", examples=[8])
    samples_per_period: StrictInt = Field(30000, ge=16, le=10_000_000, description="Samples per "
                                    "period at the 2.5 kHz output rate.", examples=[30000])
    rms: StrictFloat | None = Field(None, gt=0, description="Excitation RMS [N]; default the "
                              "preset's (100 N single, 200 N multi).", examples=[100.0])
    seed: StrictInt = Field(0, ge=0, description="Seed of the random-phase multisine and noise.")
    noise_percent: StrictFloat = Field(0.5, ge=0, le=100, description="Measurement noise RMS in "
                                 "% of the RMS response at the bracket tip.", examples=[0.5])
    outputs: list[str] | None = Field(
        None, min_length=1, description="Measured DOFs of the SmallSat model, each once, "
        "e.g. NC2w_Z; default the 39 of the paper (13 nodes x X, Y, Z).",
        examples=[["NC2w_Z", "NC2b_Z", "W_Z"]])
    quantity: Literal["displacement", "velocity", "acceleration"] = Field(
        "displacement", description="What the outputs measure.")
    fs: StrictFloat = Field(2500.0, gt=0, description="Measurement sampling rate [Hz].")
    fs_int: StrictFloat = Field(20000.0, gt=0, description="Newmark integration rate [Hz], an "
                          "integer multiple of fs.")
    name: str | None = Field(None, max_length=200, description="Label of the new dataset.")

    @model_validator(mode="after")
    def _bounded(self) -> PresetSimulation:
        _check_size(self.periods * self.samples_per_period, self.fs, self.fs_int)
        return self

    @model_validator(mode="after")
    def _runnable(self) -> PresetSimulation:
        # The library owns the rules of a preset run (its transient periods, its channels,
        # the rates); its message says what to change.
        check_preset(self.preset, periods=self.periods,
                     samples_per_period=self.samples_per_period, outputs=self.outputs,
                     fs=self.fs, fs_int=self.fs_int)
        return self


class StructuralModelSpec(RequestModel):
    """Linear matrices and nonlinear elements of a structure (Eq. 1-2)."""

    M: list[list[StrictFloat]] = Field(description="Mass matrix (r x r) [kg].",
                                 examples=[[[1.0, 0.0], [0.0, 1.0]]])
    C: list[list[StrictFloat]] = Field(description="Viscous damping matrix (r x r) [N s/m]; may "
                                 "be non-proportional.", examples=[[[2.0, 0.0], [0.0, 2.0]]])
    K: list[list[StrictFloat]] = Field(description="Stiffness matrix (r x r) [N/m].",
                                 examples=[[[2.0e4, -1.0e4], [-1.0e4, 2.0e4]]])
    dof_names: list[str] = Field(description="Name of each DOF; also the output channel "
                                 "names.", examples=[["x1", "x2"]])
    elements: list[NonlinearElementSpec] = Field(
        default_factory=list, max_length=100,
        description="Nonlinear elements with their true coefficients.")

    @model_validator(mode="after")
    def _coefficients_given(self) -> StructuralModelSpec:
        missing = [k for k, e in enumerate(self.elements) if e.coefficients is None]
        if missing:
            raise ValueError(f"elements {missing} need coefficients (the true mu_j) to be "
                             "simulated")
        return self

    @model_validator(mode="after")
    def _valid_for_library(self) -> StructuralModelSpec:
        # The library owns the rules of a model (square finite matrices of one size, one
        # unique name per DOF, elements on known DOFs); its message says what to change.
        self.structural_model()
        return self

    def structural_model(self) -> StructuralModel:
        """The library's model of this spec."""
        return StructuralModel(
            np.array(self.M, dtype=float), np.array(self.C, dtype=float),
            np.array(self.K, dtype=float), tuple(self.dof_names),
            tuple(NonlinearElement.from_json(e.model_dump(mode="json")) for e in self.elements))


class InputSpec(RequestModel):
    """One excitation force along a direction of the DOFs."""

    name: str | None = Field(None, description="Input channel name; default F_<dofs>.",
                             examples=["F_x1"])
    direction: dict[str, StrictFloat] = Field(
        min_length=1, description="DOF name -> weight, normalised to unit length.",
        examples=[{"x1": 1.0}])
    rms: StrictFloat = Field(gt=0, description="RMS of the force [N].", examples=[10.0])


class ExcitationSpec(RequestModel):
    """Periodic excitation: a random-phase multisine or periodic noise per input."""

    signal: Literal["multisine", "periodic_noise"] = Field(
        "multisine", description="Flat-spectrum random-phase multisine, or periodic "
        "Gaussian noise.")
    band: tuple[StrictFloat, StrictFloat] = Field(description="Excited band [Hz].",
                                                  examples=[[5.0, 50.0]])
    samples_per_period: StrictInt = Field(ge=4, le=10_000_000, description="Samples per period "
                                    "at fs.", examples=[2500])
    realisations: StrictInt = Field(1, ge=1, le=100, description="Independent realisations.")
    lines: Literal["full", "odd"] = Field("full", description="multisine: every line in "
                                          "the band or only odd lines.")
    detection: StrictInt | None = Field(None, ge=2, description="multisine: leave out one random "
                                  "line per group of this many (detection lines).")
    seed: StrictInt = Field(0, ge=0, description="Seed of the signals (input j uses seed + j).")
    inputs: list[InputSpec] = Field(min_length=1, max_length=100, description="The forces.")


class ModelSimulation(RequestModel):
    """Simulated periodic test of any structure: Newmark integration at ``fs_int``,
    decimation to ``fs``, band-limited measurement noise."""

    model: StructuralModelSpec = Field(description="The structure.")
    excitation: ExcitationSpec = Field(description="The inputs.")
    fs: StrictFloat = Field(2500.0, gt=0, description="Measurement sampling rate [Hz].")
    fs_int: StrictFloat = Field(20000.0, gt=0, description="Integration rate [Hz], an integer "
                          "multiple of fs.")
    periods: StrictInt = Field(8, ge=1, le=1000, description="Periods simulated from rest.")
    outputs: list[str] | None = Field(None, min_length=1,
                                      description="DOFs measured; default all.")
    quantity: Literal["displacement", "velocity", "acceleration"] = Field(
        "displacement", description="What the outputs measure.")
    noise_percent: StrictFloat = Field(0.5, ge=0, le=100, description="Noise RMS in % of the "
                                 "reference output's RMS response.")
    noise_reference: str | None = Field(None, description="Output setting the noise level; "
                                        "default the one with the largest response.")
    noise_band: tuple[StrictFloat, StrictFloat] = Field((0.0, 100.0),
                                                        description="Noise band [Hz].")
    discard_periods: StrictInt = Field(2, ge=0, description="Transient periods left out of the "
                                 "noise reference and exceedance counts.")
    seed: StrictInt = Field(0, ge=0, description="Seed of the measurement noise.")
    name: str | None = Field(None, max_length=200, description="Label of the new dataset.")

    @model_validator(mode="after")
    def _bounded(self) -> ModelSimulation:
        e = self.excitation
        _check_size(self.periods * e.samples_per_period * e.realisations, self.fs,
                    self.fs_int)
        return self

    @model_validator(mode="after")
    def _runnable(self) -> ModelSimulation:
        """What fnsi.acquisition would refuse only after generating the excitation."""
        dofs = self.model.dof_names
        outputs = self.outputs or dofs
        named = [(f"excitation.inputs[{j}].direction", dof)
                 for j, force in enumerate(self.excitation.inputs) for dof in force.direction]
        for field, name in [*named, *(("outputs", n) for n in outputs)]:
            if name not in dofs:
                raise ValueError(f"{field}: the model has no DOF {name!r}; its DOFs are {dofs}")
        if self.noise_reference is not None and self.noise_reference not in outputs:
            raise ValueError(f"noise_reference: {self.noise_reference!r} is not measured; "
                             f"outputs are {outputs}")
        check_channels(outputs, tuple(dofs), "output")
        e = self.excitation
        check_timing(self.fs, self.fs_int, e.samples_per_period, self.periods,
                     self.discard_periods)
        try:
            excited_line_range(e.samples_per_period, self.fs, e.band)
        except ValueError as err:
            raise ValueError(f"excitation.band: {err}") from None
        return self


def _simulation_kind(value: Any) -> str:
    is_model = ("model" in value) if isinstance(value, dict) else isinstance(
        value, ModelSimulation)
    return "model" if is_model else "preset"


SimulationRequest = Annotated[
    Annotated[PresetSimulation, Tag("preset")] | Annotated[ModelSimulation, Tag("model")],
    Discriminator(_simulation_kind),
]
"""A SmallSat preset (field ``preset``) or a generic structure (field ``model``)."""
