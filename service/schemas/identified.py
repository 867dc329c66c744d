"""Schemas of what an identification says about its model, shared by identification
results and study revisions: coefficients, errors per channel, offsets, refinement,
separability.

They describe JSON documents the workers stored (:class:`StoredDocument`): documented
fields are typed, every other key passes through unchanged.
"""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, model_serializer


class StoredDocument(BaseModel):
    """A stored JSON document: documented fields, every other key kept as is."""

    model_config = ConfigDict(extra="allow")

    @model_serializer(mode="wrap")
    def _keys_of_the_document(self, handler):
        # Defaults document optional fields; emitting them would add keys the worker
        # never wrote.
        return {k: v for k, v in handler(self).items() if k in self.model_fields_set}


class IdentifiedCoefficient(StoredDocument):
    """mu_j(omega) of one basis function of a nonlinear element, summarised over the
    band (paper Section II.E); the estimate only when identifiable."""

    name: str = Field(description="Element and basis function.")
    element: int = Field(description="Index of the element in settings.elements.")
    basis: int = Field(description="Index of the basis function in the element.")
    method: str = Field(description="How mu_j(omega) was computed.")
    identifiable: bool = Field(description="The data determine the coefficient.")
    reason: str | None = Field(description="Why it is not identifiable.")
    mean_real: float | None = Field(None, description="Estimate: weighted mean of Re mu "
                                    "over the band.")
    mean_imag: float | None = Field(None, description="Weighted mean of Im mu (ideally "
                                    "0).")
    log10_real_imag: float | None = Field(None, description="log10(|Re mu| / |Im mu|): "
                                          "large for a physical element.")
    variation: float | None = Field(None, description="Relative spread of Re mu over "
                                    "frequency [-].")
    unit: str | None = Field(None, description="Unit of mu: input unit per unit of the "
                             "basis function (fnsi.units; 'input unit', 'output unit' where "
                             "the dataset gives none).", examples=["N/mm^3"])
    mean_real_std: float | None = Field(
        None, description="Standard deviation of mean_real from the measurement noise, in "
        "the units of mean_real (unit); null when no error bar can be given.",
        examples=[1.2e6])


class ChannelError(StoredDocument):
    """Simulation error of one output channel against its noise floor."""

    output: str = Field(description="Output channel.", examples=["NC2w_Z"])
    nrmse_percent: float | None = Field(description="NRMSE of the simulated output [%]; "
                                        "null when not finite.", examples=[0.49])
    nrmse_db: float | None = Field(description="The same in dB.", examples=[-46.2])
    noise_floor_percent: float | None = Field(description="What a perfect model would "
                                              "reach [%].", examples=[0.36])
    noise_floor_db: float | None = Field(description="The same in dB.", examples=[-48.9])
    relative_to_noise_floor_db: float | None = Field(
        None, description="NRMSE over the noise floor [dB] (study revisions).",
        examples=[2.7])


class ChannelOffset(StoredDocument):
    """Mean of one channel over the kept periods: its sensor offset (fnsi.offsets)."""

    channel: str = Field(description="Channel name.", examples=["x1"])
    offset: float | None = Field(description="Mean over the realisations, in unit; null "
                                 "when not finite.", examples=[0.0012])
    per_realisation: list[float | None] = Field(description="Mean of each realisation, in "
                                                "unit.", examples=[[0.0011, 0.0013]])
    unit: str = Field(description="Unit of the channel (fnsi.units; 'input unit', 'output "
                      "unit' where the dataset gives none).", examples=["mm"])


class ChannelOffsets(StoredDocument):
    """Sensor offsets of a dataset's channels (fnsi.offsets). 0 Hz is never compared:
    every error leaves them out, and remove_offsets also removes them before the
    estimation."""

    inputs: list[ChannelOffset] = Field(description="One per input channel.")
    outputs: list[ChannelOffset] = Field(description="One per output channel.")
    removed: bool | None = Field(None, description="Removed before the estimation "
                                 "(remove_offsets); present on the estimation data's "
                                 "offsets of an identification.")


class ErrorSummary(StoredDocument):
    """Errors of the model simulated with the measured input, or why it could not be."""

    overall_nrmse_percent: float | None = Field(None, description="NRMSE over all "
                                                "outputs, weighted by power [%].")
    overall_nrmse_db: float | None = Field(None, description="The same in dB.")
    overall_noise_floor_percent: float | None = Field(None, description="What a perfect "
                                                      "model would reach [%].")
    overall_noise_floor_db: float | None = Field(None, description="The same in dB.")
    channels: list[ChannelError] | None = Field(None, description="Per output, in the "
                                                "order of the outputs.")
    overall_relative_to_noise_floor_db: float | None = Field(
        None, description="Overall NRMSE over the noise floor [dB] (study revisions).")
    failure: str | None = Field(None, description="Why the model could not be simulated.")
    offsets: ChannelOffsets | None = Field(None, description="Offsets of the compared "
                                           "data, left out of the errors.")


class RefinementSummary(StoredDocument):
    """How the output-error refinement changed the model's simulation error on the
    estimation data (requests with refine: true)."""

    initial_percent: float | None = Field(description="Simulation error of the FNSI model "
                                          "on the residual lines [%]; null when not refined.")
    final_percent: float | None = Field(description="The same after refinement [%].")
    iterations: int = Field(description="Accepted Levenberg-Marquardt steps.")
    evaluations: int = Field(description="Steady-state simulations run.")
    seconds: float = Field(description="Wall time [s].")
    message: str = Field(description="Why the minimisation stopped, or why the model was "
                         "not refined.")


class ElementSeparability(StoredDocument):
    """Whether the data tell one element's force apart from the other extended inputs
    and from a linear spring and dashpot at the elements (fnsi.separability)."""

    element: int = Field(description="Index of the element in settings.elements.")
    name: str = Field(description="The element.")
    unexplained: float = Field(description="Smallest fraction of a combination of its "
                               "basis functions that the others cannot reproduce on the "
                               "analysis lines [-]: 1 separable, 0 not.", examples=[0.65])
    partners: list[str] = Field(description="What reproduces that combination, largest "
                                "share first: elements, 'input forces' or the linear "
                                "structure.")
    confounded: bool = Field(description="unexplained below fnsi.separability."
                             "SEPARABILITY_LIMIT (0.05): the curve can be off by more than "
                             "twenty times the model's relative error.")
    concern: str | None = Field(description="What a confounded element means and what to "
                                "change; null when separable.")

