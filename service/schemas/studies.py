"""Schemas of modelling studies: creation, revisions, diagnoses and the error history."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, StrictInt, model_validator

from fnsi.diagnosis import Effect
from service.pagination import NextCursor
from service.schemas.base import RequestModel
from service.schemas.identifications import Auto, IdentificationRequest, NonlinearElementSpec
from service.schemas.identified import (
    ElementSeparability,
    ErrorSummary,
    IdentifiedCoefficient,
    RefinementSummary,
    StoredDocument,
)
from service.store import JobState

_CLEARANCE = {"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z", "gap": 1.5}


class StudyRequest(IdentificationRequest):
    """A modelling study (docs/design.md section 3, step 7): an estimation and a
    validation dataset of the same test set-up and a starting model (order, nonlinear
    elements), identified and validated as revision 0. Every later revision shares these
    identification settings (channels, band, block rows, lines, weighting) and changes
    only its order and elements."""

    model_config = ConfigDict(json_schema_extra={"examples": [{
        "dataset_id": "ds_5f1c0e2a9b7d4c3e8a10", "validation_dataset_id": "ds_93ab1c0e2a9b7d4c3e8a",
        "outputs": ["NC2w_Z", "NC2b_Z", "W_Z"], "band": [5.0, 50.0], "block_rows": 100,
        "order": "auto", "max_order": 40, "elements": [],
        "connections": [["NC2w_Z", "NC2b_Z"]], "name": "SmallSat NC2 axial"}]})

    dataset_id: str = Field(description="Estimation dataset: every revision is identified "
                            "on it.", examples=["ds_5f1c0e2a9b7d4c3e8a10"])
    validation_dataset_id: str = Field(
        description="Validation dataset (another realisation or level of the excitation, "
        "same channels, sampling rate and quantity): every revision is simulated with its "
        "input and judged on its outputs. Needs a kept period after discard_periods "
        "(two for a noise floor).", examples=["ds_93ab1c0e2a9b7d4c3e8a"])
    connections: list[tuple[str, str]] = Field(
        default_factory=list, max_length=1000,
        description="Pairs of output channels a physical element could join; the diagnosis "
        "screens them and every output to ground. Empty: pairs of channels on the same "
        "axis (names <node>_<axis>), or all pairs of up to 12 outputs.",
        examples=[[["NC2w_Z", "NC2b_Z"]]])
    name: str = Field("", max_length=200, description="Free label.",
                      examples=["SmallSat NC2 axial"])
    note: str = Field("starting model", max_length=500,
                      description="What revision 0 is, in your words.")

    @model_validator(mode="after")
    def _distinct_connections(self) -> StudyRequest:
        for k, (a, b) in enumerate(self.connections):
            if a == b:
                raise ValueError(f"connections[{k}] joins {a!r} to itself; a connection joins "
                                 "two different output channels")
        return self


class RevisionRequest(RequestModel):
    """A new revision derived from an earlier one: elements added or removed, order
    changed. It is identified on the estimation data and judged on the validation data;
    revisions of a study are computed one at a time, in the order requested."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"add": [_CLEARANCE], "note": "clearance at NC2 (diagnosis)"},
        {"remove": [0], "order": 24}]})

    add: list[NonlinearElementSpec] = Field(
        default_factory=list, max_length=100,
        description="Elements to add (their coefficients are identified; any given are "
        "ignored).", examples=[[_CLEARANCE]])
    remove: list[StrictInt | NonlinearElementSpec] = Field(
        default_factory=list, max_length=100,
        description="Elements of the base revision to remove: their index in its "
        "`elements`, or the element itself.", examples=[[0]])
    order: StrictInt | Auto | None = Field(
        None, description="New model order n, or \"auto\"; null keeps the base revision's "
        "identified order.", examples=[24])
    note: str | None = Field(None, max_length=500, description="What changed; default "
                             "generated from add, remove and order.")
    base: StrictInt | None = Field(
        None, ge=0, description="Revision number to start from; null: the latest when the "
        "revision runs (after every revision requested before it).")

    @model_validator(mode="after")
    def _order_positive(self) -> RevisionRequest:
        if isinstance(self.order, int) and self.order < 1:
            raise ValueError(f"order must be a positive model order or \"auto\"; got "
                             f"{self.order}")
        return self


class DiagnosisRequest(RequestModel):
    """Rank the candidate missing effects of a revision (fnsi.diagnosis): screen every
    location, compare kinds at the best, validate the best few by identification and
    simulation. The effort fields trade time for thoroughness."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {}, {"revision": 0, "validated_candidates": 3}]})

    revision: StrictInt | None = Field(
        None, ge=0, description="Revision number to diagnose; null: the latest when the "
        "diagnosis runs (after every revision requested before it).", examples=[0])
    screening_intervals: StrictInt = Field(8, ge=2, le=100, description="Spline intervals of "
                                           "the location screening.")
    top_locations: StrictInt = Field(3, ge=1, le=50, description="Best-screened locations "
                                     "whose kinds of effect are compared; the connections "
                                     "among the DOFs of near-tied locations are added.")
    validated_candidates: StrictInt = Field(
        4, ge=1, le=20, description="Most candidates identified and simulated on the "
        "validation data (each costs about one revision): the two best first, the others "
        "only when neither validates within twice the noise floor.")
    curve_locations: StrictInt = Field(1, ge=0, le=10, description="Locations of the best "
                                       "proposals whose nonparametric stiffness curve is "
                                       "identified.")
    curve_intervals: StrictInt = Field(12, ge=2, le=100, description="Spline intervals of "
                                       "those curves.")
    include_missing_mode: bool = Field(True, description="Also validate one more linear mode "
                                       "(order + 2).")


class Location(BaseModel):
    """Where a lumped element acts: between dof and ref (null: ground)."""

    dof: str = Field(description="Output channel.", examples=["NC2w_Z"])
    ref: str | None = Field(None, description="Other output channel; null for ground.",
                            examples=["NC2b_Z"])


class Partner(BaseModel):
    """The second effect a candidate is claimed together with."""

    effect: Effect = Field(description="Kind of the second effect.")
    location: Location = Field(description="Where it acts.")
    element: NonlinearElementSpec = Field(
        description="Element to add beside the candidate's, with the coefficients "
        "identified together with it.", examples=[{**_CLEARANCE, "coefficients": [98.5]}])


class Candidate(BaseModel):
    """A candidate missing effect, validated by identification and simulation."""

    effect: Effect = Field(description="Kind of missing effect.")
    element: NonlinearElementSpec | None = Field(
        None, description="Element to add (NonlinearElementSpec) with its identified "
        "coefficients: POST it as a revision's `add`. Null for a missing mode.",
        examples=[{**_CLEARANCE, "coefficients": [98.5]}])
    order: int = Field(description="Model order of the validated model.", examples=[10])
    location: Location | None = Field(None, description="Where it acts; null for a mode.")
    validation_nrmse_percent: float | None = Field(
        description="Overall validation NRMSE with the candidate added [%]; null if that "
        "model could not be simulated.", examples=[0.49])
    error_reduction_factor: float | None = Field(
        description="Validation NRMSE before / after [-].", examples=[51.0])
    beats_noise_floor: bool = Field(description="It passes the claim rule: its improvement "
                                    "is significant against the period-to-period noise "
                                    "and worth the parameters it adds (see claim).")
    screening_reduction: float | None = Field(
        None, description="Fraction of the fixed-pole residual it explains [-].")
    log10_real_imag: float | None = Field(
        None, description="log10(|Re mu| / |Im mu|) of the least-squares estimate of its "
        "coefficients over the band; large for a physical element (paper Section II.E).")
    flatness_percent: float | None = Field(
        None, description="Weighted spread of Re mu over frequency relative to the "
        "estimate [%].")
    explanation: str = Field(description="Why, in words.", examples=[
        "A clearance of about ±1.5 between NC2w_Z and NC2b_Z explains ..."])
    failure: str | None = Field(None, description="Why the validated model failed.")
    concern: str | None = Field(
        None, description="Why its identified coefficient contradicts the physics of the "
        "effect (a stop with negative contact stiffness, friction or damping that feeds "
        "energy in); such candidates rank after the convincing ones. Null when plausible.",
        examples=[None])
    claim: ClaimTestSummary | None = Field(
        None, description="The claim rule's test (fnsi.claim); null for candidates not "
        "validated.")
    repairs: list[str] = Field(default_factory=list, description=(
        "What was changed so that its model could be simulated."))
    partner: Partner | Location | None = Field(
        None, description="The second effect this candidate is claimed together with "
        "(neither was worth its parameters alone; claim then tests both added together): "
        "POST both elements as one revision's `add`. Null when judged alone. Diagnoses "
        "stored before 2026-12 give only its location: diagnose again for its element.")


class ClaimTestSummary(BaseModel):
    """The claim rule applied to one candidate (fnsi.claim): a one-sided z test of its
    improvement against the period-to-period noise, and a penalty per added parameter."""

    z: float | None = Field(description="Standardised improvement of the validation error "
                            "against the noise [-]; null when not finite.", examples=[412.0])
    z_critical: float | None = Field(description="Threshold of the test (family-wise level, "
                                     "Bonferroni over the candidates) [-].", examples=[3.5])
    significant: bool = Field(description="z above z_critical.")
    parameters: int = Field(description="Parameters the candidate adds.", examples=[1])
    removed_fraction: float | None = Field(description="Fraction of the error above the "
                                           "noise floor it removes [-].", examples=[0.93])
    required_fraction: float = Field(description="Fraction its parameters must remove [-].",
                                     examples=[0.1])
    worth_parameters: bool = Field(description="removed_fraction reaches required_fraction.")
    rule: str = Field(description="Why it is or is not claimed, in words.")


class StudyJob(BaseModel):
    """A job that acts on the study."""

    id: str = Field(description="Job id.", examples=["job_7d0c5e1f2a3b4c5d6e7f"])
    kind: Literal["study", "study_revision", "study_diagnosis"] = Field(
        description="study: creation (revision 0); study_revision; study_diagnosis.")
    state: JobState = Field(description="Job state.")
    message: str = Field(description="What it is doing now, or how it ended.")
    error: str | None = Field(None, description="Why it failed, and what to change.")
    url: str = Field(description="Path of the job.", examples=["/v1/jobs/job_7d0c5e1f2a3b"])


class RevisionArtefacts(BaseModel):
    """Figures of one revision (PNG), computed by the job that made it."""

    comparison: str | None = Field(None, description="Measured vs simulated validation "
                                   "outputs, time window and spectrum.")
    residual_spectra: str | None = Field(None, description="Residual spectra against the "
                                         "noise floor, excited and non-excited lines apart.")
    residual_map: str | None = Field(None, description="Residual over noise [dB], channels "
                                     "x frequency bands.")
    all: str = Field(description="Listing of every artefact of the job.")


class RevisionModes(StoredDocument):
    """Natural frequencies and damping ratios of a revision's underlying linear system,
    mode by mode (same length)."""

    frequency_hz: list[float] = Field(description="Natural frequencies [Hz].",
                                      examples=[[13.7, 21.2]])
    damping_ratio: list[float] = Field(description="Damping ratios [-].",
                                       examples=[[0.012, 0.009]])
    frequency_hz_std: list[float | None] | None = Field(
        None, description="Standard deviations of frequency_hz from the estimation record's "
        "noise [Hz]; null when no error bar can be given (one kept period).")
    damping_ratio_std: list[float | None] | None = Field(
        None, description="Standard deviations of damping_ratio [-]; null as "
        "frequency_hz_std.")


class RevisionRecord(BaseModel):
    """One model of the study and its validation errors, as the study stores it (also
    the ``revision_summary`` of a study job's result)."""

    number: int = Field(description="Position in the study (0: the starting model).")
    note: str = Field(description="What changed.", examples=["add clearance NC2w_Z-NC2b_Z"])
    order: int | str = Field(description="Requested order (or \"auto\").")
    identified_order: int = Field(description="Order of the identified model.")
    elements: list[NonlinearElementSpec] = Field(
        description="Requested nonlinear elements (no coefficients).",
        examples=[[_CLEARANCE]])
    coefficients: list[IdentifiedCoefficient] = Field(
        description="Identified coefficients per basis function with quality criteria.")
    modal: RevisionModes = Field(description="Modes of the underlying linear system.")
    nrmse_percent: float | None = Field(description="Overall validation NRMSE [%] (channels "
                                        "weighted by power); null: not simulated.")
    nrmse_std_percent: float | None = Field(
        None, description="Standard deviation of nrmse_percent from the noise of the "
        "validation record [%] (delete-one-period jackknife); null with one kept period, "
        "no simulation, or a revision computed before it existed.", examples=[0.02])
    noise_floor_percent: float | None = Field(description="Overall noise floor [%]: what a "
                                              "perfect model would reach.")
    validation: ErrorSummary | None = Field(
        description="Validation errors: per channel NRMSE [%] and [dB], noise floor, "
        "excess over the floor; null if the model could not be simulated.")
    failure: str | None = Field(None, description="Why the model could not be simulated.")
    model_elements: list[NonlinearElementSpec] | None = Field(
        None, description="The identified model's elements: spline knots resolved, "
        "clearance gaps refined when the study refines its revisions.")
    refinement: RefinementSummary | None = Field(
        None, description="How refinement changed the simulation error; null when the study "
        "does not refine.")
    separability: list[ElementSeparability] | None = Field(
        None, description="Per element: whether the data tell its force apart from the "
        "others' (unexplained, partners, confounded, concern; see the identification "
        "result's separability).")
    repairs: list[str] = Field(default_factory=list, description=(
        "What was changed so that the model could be simulated (reflected unstable poles, "
        "an explicit output equation), in words."))


class Revision(RevisionRecord):
    """One model of the study and its validation errors, with the job that computed it."""

    job_id: str = Field(description="Job that computed this revision.")
    artefacts: RevisionArtefacts = Field(description="Figures of this revision.")


class HistoryRow(BaseModel):
    """One row of the error history."""

    number: int = Field(description="Revision number.")
    note: str = Field(description="What changed.")
    order: int = Field(description="Identified model order.")
    elements: list[str] = Field(description="Names of the revision's elements.",
                                examples=[["clearance NC2w_Z-NC2b_Z"]])
    nrmse_percent: float | None = Field(description="Validation NRMSE [%].", examples=[0.49])
    nrmse_std_percent: float | None = Field(
        None, description="Standard deviation of nrmse_percent from the validation record's "
        "noise [%]; null when none can be given.", examples=[0.02])
    nrmse_db: float | None = Field(description="Validation NRMSE [dB].", examples=[-46.2])
    noise_floor_percent: float | None = Field(description="Noise floor [%].", examples=[0.36])
    failure: str | None = Field(None, description="Why the model could not be simulated.")
    repairs: list[str] = Field(default_factory=list, description=(
        "What was changed so that the model could be simulated (reflected unstable poles, "
        "an explicit output equation), in words."))


class StudyDiagnosis(BaseModel):
    """A diagnosis of the study and, once done, its ranked candidates."""

    job_id: str = Field(description="Diagnosis job.")
    state: JobState = Field(description="Job state.")
    revision: int | None = Field(None, description="Diagnosed revision (once known).")
    found: bool | None = Field(None, description="The best candidate passes the claim rule "
                               "with a physically plausible coefficient.")
    summary: str | None = Field(None, description="The verdict in words.")
    candidates: list[Candidate] = Field(default_factory=list,
                                        description="Candidates, best first.")
    artefacts: str = Field(description="Listing of its figures: stiffness curves at the top "
                           "locations, candidates, screening, error history.")


class Study(BaseModel):
    """A study: its settings, revisions with their errors (the error history), and the
    jobs acting on it."""

    id: str = Field(description="Study id.", examples=["study_0a1b2c3d4e5f60718293"])
    name: str = Field(description="Free label.")
    created_at: str = Field(description="Creation time, ISO 8601 UTC.")
    definition: StudyRequest = Field(description="The creation request, defaults filled "
                                     "in.")
    revisions: list[Revision] = Field(description="Revisions computed so far, in order.")
    history: list[HistoryRow] = Field(description="Error history: one row per revision.")
    history_chart: str | None = Field(
        None, description="Path of the error-history chart (PNG) of the latest revision.",
        examples=["/v1/jobs/job_7d0c5e1f2a3b4c5d6e7f/artefacts/history.png"])
    diagnoses: list[StudyDiagnosis] = Field(description="Diagnoses requested, in order.")
    jobs: list[StudyJob] = Field(description="Every job of the study, oldest first.")
    report: str | None = Field(
        None, description="Path of the study's one-page HTML report (figures embedded); "
        "null before revision 0.", examples=["/v1/studies/study_0a1b2c3d4e5f60718293/"
                                             "report.html"])


class StudySummary(BaseModel):
    """A study in a listing: what it is and where its error history stands."""

    id: str = Field(description="Study id.", examples=["study_0a1b2c3d4e5f60718293"])
    name: str = Field(description="Free label.")
    created_at: str = Field(description="Creation time, ISO 8601 UTC.")
    revisions: int = Field(description="Revisions computed so far.", examples=[2])
    nrmse_percent: float | None = Field(
        None, description="Validation NRMSE [%] of the latest revision; null before revision "
        "0 or if it could not be simulated.", examples=[0.49])
    noise_floor_percent: float | None = Field(None, description="Noise floor [%] of the "
                                              "validation data.", examples=[0.36])
    url: str = Field(description="Path of the study.",
                     examples=["/v1/studies/study_0a1b2c3d4e5f60718293"])


class StudyPage(BaseModel):
    """One page of studies, newest first."""

    items: list[StudySummary] = Field(description="Studies of this page.")
    next_cursor: NextCursor = None
