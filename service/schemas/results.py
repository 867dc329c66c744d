"""Schemas of job results, one per kind of job, told apart by ``kind``.

A result is the JSON document the worker stored; these models document its main fields
so that generated clients read them as typed attributes. They never reshape it: every
other key passes through unchanged, and a field missing from the document stays missing
in the response (it is not filled with its default). The one key added is ``kind``, the
job's kind (the OpenAPI discriminator of :data:`JobResult`).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field

from service.schemas.identifications import NonlinearElementSpec
from service.schemas.identified import (
    ChannelOffsets,
    ElementSeparability,
    ErrorSummary,
    IdentifiedCoefficient,
    RefinementSummary,
    StoredDocument,
)
from service.schemas.studies import Candidate, HistoryRow, RevisionRecord

_KIND = "The job's kind: tells the kinds of result apart."

class SimulationJobResult(StoredDocument):
    """Result of a simulation job: the dataset it produced (its truth is the artefact
    truth.json)."""

    kind: Literal["simulation"] = Field(description=_KIND)
    dataset_id: str = Field(description="The simulated dataset.",
                            examples=["ds_5f1c0e2a9b7d4c3e8a10"])


class IdentifiedMode(StoredDocument):
    """A physical mode of the identified underlying linear system."""

    frequency_hz: float = Field(description="Natural frequency [Hz].", examples=[13.7])
    damping_ratio: float = Field(description="Damping ratio [-].", examples=[0.012])
    shape: list[list[float]] = Field(description="Mode shape, one [re, im] pair per "
                                     "output (order of output_names).")
    confirmed: bool | None = Field(description="Stable at the next order of the "
                                   "stabilisation diagram and over at least four successive "
                                   "orders; null when none follows.")
    frequency_hz_std: float | None = Field(
        None, description="Standard deviation of frequency_hz from the measurement noise "
        "[Hz] (fnsi.uncertainty); null when no error bar can be given (one kept period, "
        "or uncertainty off): uncertainty.note says why.", examples=[0.004])
    damping_ratio_std: float | None = Field(
        None, description="Standard deviation of damping_ratio [-]; null as "
        "frequency_hz_std.", examples=[0.0003])
    shape_std: list[list[float]] | None = Field(
        None, description="Standard deviations of the real and the imaginary part of each "
        "shape component, one [re_std, im_std] pair per output [-] (shape normalised with "
        "its largest component 1, whose std is 0); null as frequency_hz_std.")




class IdentifiedStiffnessCurve(StoredDocument):
    """Force of an identified element against relative displacement (or velocity)."""

    element: NonlinearElementSpec = Field(description="The element with its identified "
                                       "coefficients (NonlinearElementSpec).")
    variable: str = Field(description="Abscissa: displacement or velocity.")
    x: list[float] = Field(description="Abscissae over the measured range.")
    force: list[float] = Field(description="Element force at x.")
    x_unit: str | None = Field(None, description="Unit of x.", examples=["mm"])
    force_unit: str | None = Field(None, description="Unit of force.", examples=["N"])


class DataUnits(StoredDocument):
    """Units of the identified channels and of the FRF (fnsi.units): the dataset's,
    'input unit' and 'output unit' where it gives none."""

    input: str = Field(description="Unit of the inputs (forces).", examples=["N"])
    output: str = Field(description="Unit of the outputs.", examples=["mm"])
    displacement: str = Field(description="Unit of displacements (the output unit, "
                              "integrated for velocities and accelerations).",
                              examples=["mm"])
    frf: str = Field(description="Unit of an FRF: output per input unit.", examples=["mm/N"])




class IdentificationErrors(StoredDocument):
    """Simulation errors on the estimation data and, if given, the validation data."""

    estimation: ErrorSummary = Field(description="On the estimation dataset.")
    validation: ErrorSummary | None = Field(None, description="On the validation dataset "
                                            "(present when one was given).")


class UsedSettings(StoredDocument):
    """The settings an identification ran with (fnsi.identification.IdentificationSettings):
    the request's, "auto" left as asked, spline knots resolved."""

    band: list[float] = Field(description="Analysis band [Hz].", examples=[[5.0, 50.0]])
    block_rows: int | str = Field(description="Block rows i, or \"auto\".")
    order: int | str = Field(description="Requested model order, or \"auto\".")
    max_order: int = Field(description="Highest order of the stabilisation diagram.")
    inputs: list[str] | None = Field(description="Input channels used; null: all.")
    outputs: list[str] | None = Field(description="Output channels used; null: all.")
    line_set: str = Field(description="all or excited.")
    discard_periods: int = Field(description="Leading periods dropped.")
    elements: list[NonlinearElementSpec] = Field(description="Nonlinear elements, spline knots "
                                              "resolved.")
    weighting: bool = Field(description="Noise-covariance weighting.")
    driving_points: list[list[str]] = Field(description="(input, output) driving points.")
    frequency_warping: bool = Field(description="Warped frequency variable.")
    refine: bool = Field(description="Output-error refinement asked.")
    uncertainty: bool = Field(True, description="Standard deviations asked (the *_std "
                              "fields).")
    remove_offsets: bool = Field(False, description="Sensor offsets removed before the "
                                 "estimation.")
    harmonic_band: bool = Field(
        False, description="With elements, the lines up to 3 times the band's upper edge "
        "fitted too (studies).")
    order_rule: Literal["modes", "simulation"] = Field(
        "modes", description="How order \"auto\" was chosen: modes (the stabilisation "
        "diagram's physical modes) or simulation (the order that simulates the estimation "
        "data best; studies).")


class UncertaintySummary(StoredDocument):
    """How the standard deviations (the *_std fields) were computed (fnsi.uncertainty)."""

    method: str = Field(description="First-order propagation of the period-to-period noise "
                        "through the identification at the chosen order.")
    draws: int = Field(description="Noise directions propagated (the kept periods times "
                       "the realisations, at most 24); 0 when no error bar was given.",
                       examples=[6])
    note: str | None = Field(description="Why no error bar could be given (e.g. a single "
                             "kept period); null when the std fields hold values.")


class SimulationOrderSummary(StoredDocument):
    """The automatic order of order_rule simulation (fnsi.simulation_order): the lowest
    order whose simulation of the estimation data is within 10 % of the best above the
    noise floor, passing over an order whose FRF is an outlier in the input directions
    those data do not excite."""

    order: int = Field(description="Chosen model order.", examples=[14])
    errors_percent: dict[str, float | None] = Field(
        description="Estimation-data NRMSE [%] of each order tried, keyed by order; null: "
        "the model could not be simulated.", examples=[{"12": 0.62, "14": 0.56}])
    noise_floor_percent: float | None = Field(
        description="Noise floor of the estimation data on the same lines [%].",
        examples=[0.43])
    repaired_orders: list[int] = Field(
        [], description="Orders whose model could be simulated only with each element's "
        "own nonlinear feed-through held at zero (fnsi.feedthrough); their errors are "
        "those of the repaired model.", examples=[[6]])
    unseen_outliers: list[int] = Field(
        [], description="Orders within the tolerance passed over because their FRF "
        "departs from the other such orders' in the input directions the estimation data "
        "do not excite (fewer realisations than inputs).", examples=[[24]])


class IdentificationJobResult(StoredDocument):
    """Result of an identification job: result.json without the model matrices,
    stabilisation diagram and singular values (download result.json or model.npz)."""

    kind: Literal["identification"] = Field(description=_KIND)
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
    units: DataUnits | None = Field(None, description="Units of the data identified from.")
    coefficients: list[IdentifiedCoefficient] = Field(
        description="Nonlinear coefficients with quality criteria.")
    stiffness: list[IdentifiedStiffnessCurve] = Field(description="One curve per element whose "
                                            "coefficients are all identifiable.")
    timings_s: dict[str, float] = Field(description="Wall time per stage [s].")
    settings: UsedSettings | None = Field(description="Identification settings used, "
                                          "spline knots resolved.")
    errors: IdentificationErrors = Field(description="Simulation errors of the model.")
    refinement: RefinementSummary | None = Field(
        None, description="Output-error refinement; null when not requested.")
    separability: list[ElementSeparability] | None = Field(
        None, description="One per nonlinear element: can the data separate its force "
        "from the others'?")
    uncertainty: UncertaintySummary | None = Field(
        None, description="How the *_std fields beside the modes and coefficients were "
        "computed; null when uncertainty was off in the settings.")
    offsets: ChannelOffsets | None = Field(
        None, description="Offsets of the estimation data, with whether they were removed "
        "before the estimation.")
    simulation_order: SimulationOrderSummary | None = Field(
        None, description="With order_rule simulation: the estimation data's simulation "
        "error of each order tried and the order chosen; null otherwise.")


class RevisionSummary(StoredDocument, RevisionRecord):
    """A study revision: its model and validation errors, as the job stored it."""


class StudyJobResult(StoredDocument):
    """Result of a study or study_revision job: the revision it computed and the error
    history of the study."""

    kind: Literal["study", "study_revision"] = Field(description=_KIND)
    study_id: str = Field(description="The study.")
    revision: int = Field(description="Number of the revision computed.")
    revision_summary: RevisionSummary = Field(description="That revision.")
    history: list[HistoryRow] = Field(description="Error history, one row per revision.")
    warnings: list[str] = Field(
        [], description="What makes the revisions' results unusable in part, with what to "
        "change: e.g. elements without a driving point (no coefficient is identified; give "
        "driving_points).")


class UnexplainedGroup(StoredDocument):
    """A part of the excess validation error: one channel over one group of lines."""

    channel: str = Field(description="Output channel.", examples=["x3"])
    lines: str = Field(description="Lines: excited or not, below, in or above the band.",
                       examples=["excited lines in the band"])
    share: float = Field(description="Share of the error above the floor [-].",
                         examples=[0.62])
    over_noise_db: float | None = Field(description="Its level over the noise [dB].",
                                        examples=[18.0])


class UnexplainedError(StoredDocument):
    """Where a revision's validation error lies beyond the noise."""

    ratio_to_floor: float | None = Field(description="Validation error over the noise floor "
                                         "[-].", examples=[12.5])
    groups: list[UnexplainedGroup] = Field(description="Largest parts first.")


class DiagnosisJobResult(StoredDocument):
    """Result of a study_diagnosis job: ranked candidate missing effects."""

    kind: Literal["study_diagnosis"] = Field(description=_KIND)
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
    unexplained: UnexplainedError | None = Field(
        None, description="Where the revision's validation error lies beyond the noise "
        "(fnsi.claim.unexplained); null when within 3 times the floor.")
    claim_rule: str | None = Field(None, description="The rule a candidate must pass to "
                                   "be claimed, with its numbers.")


class LineGroupLevel(StoredDocument):
    """Output power against noise power over a group of lines of one output."""

    lines: int = Field(description="Lines in the group (0: the excitation leaves none).",
                       examples=[228])
    level_db: float | None = Field(description="10 log10(output power / noise power) "
                                   "[dB]; 0 dB is noise alone. Null when empty.",
                                   examples=[45.7])
    p_value: float | None = Field(description="Probability of this level from noise alone "
                                  "(F test). Null when empty.", examples=[2.1e-45])
    above_noise: bool = Field(description="p below 0.001 and at least 1 dB.")


class ChannelDistortionLevels(StoredDocument):
    """The distortion levels of one output."""

    name: str = Field(description="Output channel.", examples=["NC2w_Z"])
    excited: LineGroupLevel = Field(description="Excited lines: the BLA's scatter over "
                                    "realisations against its noise (R >= 2, one input).")
    odd: LineGroupLevel = Field(description="Non-excited odd lines in the band.")
    even: LineGroupLevel = Field(description="Non-excited even lines in the band.")
    above_band: LineGroupLevel = Field(description="Lines above the band, up to three "
                                       "times its upper edge.")


class AnalysisJobResult(StoredDocument):
    """Result of an analysis job: nonlinear distortion levels and the verdict."""

    kind: Literal["analysis"] = Field(description=_KIND)
    band_hz: list[float] = Field(description="Lowest and highest excited line [Hz].",
                                 examples=[[5.5, 49.5]])
    odd_design: bool = Field(description="Only odd lines are excited, so odd and even "
                             "distortions are told apart.")
    realisations: int = Field(description="Realisations analysed.", examples=[1])
    periods: int = Field(description="Periods kept.", examples=[2])
    channels: list[ChannelDistortionLevels] = Field(description="Levels per output.")
    unit: str | None = Field(None, description="Unit of the outputs the levels refer to.",
                             examples=["mm"])
    verdict: str = Field(description="How nonlinear, which law, what can be told, in "
                         "words with the numbers.")


JobResult = Annotated[SimulationJobResult | IdentificationJobResult | StudyJobResult
                      | DiagnosisJobResult | AnalysisJobResult, Field(discriminator="kind")]
"""The result of a job, by its ``kind``."""
