"""Schemas of job results, one per kind of job.

A result is the JSON document the worker stored; these models document its main fields
so that generated clients read them as typed attributes. They never reshape it: every
other key passes through unchanged, and a field missing from the document stays missing
in the response (it is not filled with its default).
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_serializer

from service.schemas.studies import Candidate, HistoryRow, RevisionRecord


class _Document(BaseModel):
    """A stored JSON document: documented fields, every other key kept as is."""

    model_config = ConfigDict(extra="allow")

    @model_serializer(mode="wrap")
    def _keys_of_the_document(self, handler):
        # Defaults document optional fields; emitting them would add keys the worker
        # never wrote.
        return {k: v for k, v in handler(self).items() if k in self.model_fields_set}


class SimulationJobResult(_Document):
    """Result of a simulation job: the dataset it produced (its truth is the artefact
    truth.json)."""

    dataset_id: str = Field(description="The simulated dataset.",
                            examples=["ds_5f1c0e2a9b7d4c3e8a10"])


class IdentifiedMode(_Document):
    """A physical mode of the identified underlying linear system."""

    frequency_hz: float = Field(description="Natural frequency [Hz].", examples=[13.7])
    damping_ratio: float = Field(description="Damping ratio [-].", examples=[0.012])
    shape: list[list[float]] = Field(description="Mode shape, one [re, im] pair per "
                                     "output (order of output_names).")
    confirmed: bool | None = Field(description="Stable at the next order of the "
                                   "stabilisation diagram and over at least four successive "
                                   "orders; null when none follows.")


class IdentifiedCoefficient(_Document):
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


class IdentifiedStiffnessCurve(_Document):
    """Force of an identified element against relative displacement (or velocity)."""

    element: dict[str, Any] = Field(description="The element with its identified "
                                    "coefficients (JSON shape of NonlinearElementSpec).")
    variable: str = Field(description="Abscissa: displacement or velocity.")
    x: list[float] = Field(description="Abscissae over the measured range.")
    force: list[float] = Field(description="Element force at x.")


class ErrorSummary(_Document):
    """Errors of the model simulated with the measured input, or why it could not be."""

    overall_nrmse_percent: float | None = Field(None, description="NRMSE over all "
                                                "outputs, weighted by power [%].")
    overall_nrmse_db: float | None = Field(None, description="The same in dB.")
    overall_noise_floor_percent: float | None = Field(None, description="What a perfect "
                                                      "model would reach [%].")
    overall_noise_floor_db: float | None = Field(None, description="The same in dB.")
    channels: list[dict[str, Any]] | None = Field(None, description="Per output: "
                                                  "nrmse_percent, nrmse_db, noise floor.")
    failure: str | None = Field(None, description="Why the model could not be simulated.")


class IdentificationErrors(_Document):
    """Simulation errors on the estimation data and, if given, the validation data."""

    estimation: ErrorSummary = Field(description="On the estimation dataset.")
    validation: ErrorSummary | None = Field(None, description="On the validation dataset "
                                            "(present when one was given).")


class RefinementSummary(_Document):
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


class ElementSeparability(_Document):
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


class IdentificationJobResult(_Document):
    """Result of an identification job: result.json without the model matrices,
    stabilisation diagram and singular values (download result.json or model.npz)."""

    warnings: list[str] = Field(
        [], description="What makes the model unusable, with what to change; empty when "
        "all is well. A model whose linear part is unstable (an explicit order, or the "
        "automatic one when no order of the diagram is stable) cannot be simulated: the "
        "job still succeeds, since its modes and coefficients stand, but this list says so "
        "and each entry of errors then holds failure instead of errors.",
        examples=[["the linear part of the order-12 model is unstable (pole at 17.9 Hz, "
                   "|z| = 1.000400 >= 1): the model cannot be simulated, so it has no "
                   "simulation errors; orders of the stabilisation diagram whose linear part "
                   "is stable: [2, 4, 6, 8, 10]"]])
    order: int = Field(description="Model order n.", examples=[10])
    modes: list[IdentifiedMode] = Field(description="Physical modes in the band.")
    output_names: list[str] = Field(description="Output channels, order of mode shapes.")
    coefficients: list[IdentifiedCoefficient] = Field(
        description="Nonlinear coefficients with quality criteria.")
    stiffness: list[IdentifiedStiffnessCurve] = Field(description="One curve per element whose "
                                            "coefficients are all identifiable.")
    timings_s: dict[str, float] = Field(description="Wall time per stage [s].")
    settings: dict[str, Any] | None = Field(description="Identification settings used, "
                                            "spline knots resolved.")
    errors: IdentificationErrors = Field(description="Simulation errors of the model.")
    refinement: RefinementSummary | None = Field(
        None, description="Output-error refinement; null when not requested.")
    separability: list[ElementSeparability] | None = Field(
        None, description="One per nonlinear element: can the data separate its force "
        "from the others'?")


class RevisionSummary(_Document, RevisionRecord):
    """A study revision: its model and validation errors, as the job stored it."""


class StudyJobResult(_Document):
    """Result of a study or study_revision job: the revision it computed and the error
    history of the study."""

    study_id: str = Field(description="The study.")
    revision: int = Field(description="Number of the revision computed.")
    revision_summary: RevisionSummary = Field(description="That revision.")
    history: list[HistoryRow] = Field(description="Error history, one row per revision.")


class DiagnosisJobResult(_Document):
    """Result of a study_diagnosis job: ranked candidate missing effects."""

    study_id: str = Field(description="The study.")
    revision: int = Field(description="Diagnosed revision.")
    nrmse_before_percent: float | None = Field(description="Validation NRMSE of that "
                                               "revision [%].")
    noise_floor_percent: float | None = Field(description="Noise floor [%].")
    found: bool = Field(description="The best candidate passes the claim rule with a "
                        "physically plausible coefficient.")
    summary: str = Field(description="The verdict in words.")
    candidates: list[Candidate] = Field(description="Candidates, best first.")
    notes: list[str] = Field(description="Remarks on the diagnosis.")
    timings: dict[str, float] = Field(description="Wall time per stage [s].")
    unexplained: dict[str, Any] | None = Field(
        None, description="Where the revision's validation error lies beyond the noise: "
        "ratio_to_floor and groups (channel, lines: excited or not, below, in or above "
        "the band; share of the excess error; over_noise_db).")
    claim_rule: str | None = Field(None, description="The rule a candidate must pass to "
                                   "be claimed, with its numbers.")


# Exactly one kind matches a document: each has required fields the others lack. A
# document of none of these shapes (e.g. stored by an older worker) is still served, as a
# plain object, rather than failing the response.
class LineGroupLevel(_Document):
    """Output power against noise power over a group of lines of one output."""

    lines: int = Field(description="Lines in the group (0: the excitation leaves none).",
                       examples=[228])
    level_db: float | None = Field(description="10 log10(output power / noise power) "
                                   "[dB]; 0 dB is noise alone. Null when empty.",
                                   examples=[45.7])
    p_value: float | None = Field(description="Probability of this level from noise alone "
                                  "(F test). Null when empty.", examples=[2.1e-45])
    above_noise: bool = Field(description="p below 0.001 and at least 1 dB.")


class ChannelDistortionLevels(_Document):
    """The distortion levels of one output."""

    name: str = Field(description="Output channel.", examples=["NC2w_Z"])
    excited: LineGroupLevel = Field(description="Excited lines: the BLA's scatter over "
                                    "realisations against its noise (R >= 2, one input).")
    odd: LineGroupLevel = Field(description="Non-excited odd lines in the band.")
    even: LineGroupLevel = Field(description="Non-excited even lines in the band.")
    above_band: LineGroupLevel = Field(description="Lines above the band, up to three "
                                       "times its upper edge.")


class AnalysisJobResult(_Document):
    """Result of an analysis job: nonlinear distortion levels and the verdict."""

    band_hz: list[float] = Field(description="Lowest and highest excited line [Hz].",
                                 examples=[[5.5, 49.5]])
    odd_design: bool = Field(description="Only odd lines are excited, so odd and even "
                             "distortions are told apart.")
    realisations: int = Field(description="Realisations analysed.", examples=[1])
    periods: int = Field(description="Periods kept.", examples=[2])
    channels: list[ChannelDistortionLevels] = Field(description="Levels per output.")
    verdict: str = Field(description="How nonlinear, which law, what can be told, in "
                         "words with the numbers.")


JobResult = (SimulationJobResult | IdentificationJobResult | StudyJobResult
             | DiagnosisJobResult | AnalysisJobResult | dict[str, Any])
