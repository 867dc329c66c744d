"""Schemas of identification requests and of nonlinear elements."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import (
    ConfigDict,
    Field,
    SerializerFunctionWrapHandler,
    StrictBool,
    StrictFloat,
    StrictInt,
    WithJsonSchema,
    model_serializer,
    model_validator,
)

from fnsi.nonlinear import MAX_EXPONENT, NonlinearElement, NonlinearityKind
from service.schemas.base import RequestModel

MAX_BASIS = 1000
"""Most basis functions per element (spline intervals, breakpoints): bounds the work a
request can ask for before the library sees it."""


class _Element(RequestModel):
    """What every nonlinear element has: a restoring force f(x, v) between two output
    channels (or one channel and ground), x = y[dof] - y[ref] (docs/design.md section 6)."""

    kind: NonlinearityKind = Field(description="Functional form of the restoring force.")
    dof: str = Field(description="Output channel on which +f acts.", examples=["NC2w_Z"])
    ref: str | None = Field(None, description="Output channel on which -f acts; null for "
                            "ground.", examples=["NC2b_Z"])
    coefficients: list[StrictFloat] | None = Field(
        None, max_length=MAX_BASIS + 1, description="mu_j per basis function: the truth "
        "of a simulated element; ignored by identification.")

    @model_validator(mode="before")
    @classmethod
    def _own_parameters(cls, data: Any) -> Any:
        # Before pydantic's "extra inputs": the library's message lists what the kind takes.
        if isinstance(data, dict) and "kind" in data:
            NonlinearElement.check_keys(data)
        return data

    @model_validator(mode="after")
    def _valid_for_library(self) -> _Element:
        # The library owns the rules of each kind; its message says what to change.
        NonlinearElement.from_json(self.model_dump(mode="json"))
        return self

    @model_serializer(mode="wrap")
    def _library_json(self, handler: SerializerFunctionWrapHandler) -> dict[str, Any]:
        """Dump as fnsi.nonlinear reads it: the parameters that were given, and ref."""
        return {k: v for k, v in handler(self).items() if v is not None or k == "ref"}


class PolynomialElement(_Element):
    """g = |x|^exponent, times sign(x) when signed (a cubic spring: exponent 3)."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"kind": "polynomial", "dof": "x1", "ref": None, "exponent": 3.0}]})

    kind: Literal[NonlinearityKind.POLYNOMIAL] = Field(description="Polynomial stiffness.")
    exponent: StrictFloat | None = Field(
        None, gt=0, le=MAX_EXPONENT, description="Exponent p of g = |x|^p [-], 0 < p <= "
        f"{MAX_EXPONENT:g}; default 3.", examples=[3.0])
    signed: StrictBool | None = Field(None, description="Multiply by sign(x) (an odd "
                                      "force); default true.")


class ClearanceElement(_Element):
    """Dead zone: g = x - g+ beyond g+, x + g- below -g-, 0 between (a stop)."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z", "gap": 1.5}]})

    kind: Literal[NonlinearityKind.CLEARANCE] = Field(description="Clearance (stop).")
    gap: StrictFloat | None = Field(None, gt=0, description="Symmetric gap [length unit of "
                                    "the outputs].", examples=[1.5])
    gap_negative: StrictFloat | None = Field(None, gt=0, description="Gap for x < 0 [length].")
    gap_positive: StrictFloat | None = Field(None, gt=0, description="Gap for x > 0 [length].")
    side: Literal["both", "positive", "negative"] | None = Field(
        None, description="Which stops exist (one-sided stop); default both.")


class PiecewiseLinearElement(_Element):
    """One hinge per breakpoint b: max(x - b, 0) for b >= 0, min(x - b, 0) for b < 0."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"kind": "piecewise_linear", "dof": "x1", "ref": None, "breakpoints": [-1.0, 1.0]}]})

    kind: Literal[NonlinearityKind.PIECEWISE_LINEAR] = Field(description="Hinges.")
    breakpoints: list[StrictFloat] = Field(
        min_length=1, max_length=MAX_BASIS, description="Strictly increasing hinge "
        "positions [length].", examples=[[-1.0, 1.0]])


class SplineElement(_Element):
    """Natural cubic spline with zero force and slope at equilibrium (paper Eq. 19-22):
    give ``knots``, or ``intervals`` for automatic knots over the measured range."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"kind": "spline", "dof": "NC2w_Z", "ref": "NC2b_Z", "intervals": 13}]})

    kind: Literal[NonlinearityKind.SPLINE] = Field(description="Cubic spline.")
    knots: list[StrictFloat] | None = Field(
        None, max_length=MAX_BASIS + 1, description="Strictly increasing knot abscissas "
        "[length], 0 strictly inside an interval (paper Eq. 19-22).",
        examples=[[-3.0, -1.5, 1.5, 3.0]])
    intervals: StrictInt | None = Field(None, ge=2, le=MAX_BASIS,
                                        description="Number of intervals over the measured "
                                        "range (automatic knots: one interval over the inner "
                                        "half of the excursion around equilibrium, the "
                                        "others evenly over the outer halves).",
                                        examples=[13])


class CoulombFrictionElement(_Element):
    """g = tanh(v / width): dry friction smoothed over a velocity width."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"kind": "coulomb_friction", "dof": "x1", "ref": None, "width": 0.01}]})

    kind: Literal[NonlinearityKind.COULOMB_FRICTION] = Field(description="Dry friction.")
    width: StrictFloat = Field(gt=0, description="Velocity smoothing width [length/s].",
                               examples=[0.01])


class QuadraticDampingElement(_Element):
    """g = v |v|: no parameters."""

    model_config = ConfigDict(json_schema_extra={"examples": [
        {"kind": "quadratic_damping", "dof": "x1", "ref": None}]})

    kind: Literal[NonlinearityKind.QUADRATIC_DAMPING] = Field(description="Quadratic "
                                                               "damping.")


NonlinearElementSpec = Annotated[
    PolynomialElement | ClearanceElement | PiecewiseLinearElement | SplineElement
    | CoulombFrictionElement | QuadraticDampingElement,
    Field(discriminator="kind")]
"""A nonlinear element, one model per ``kind`` holding only that kind's parameters (any
other field is refused)."""


#: The word "auto" in an integer-or-"auto" field. Published as a one-value string enum
#: rather than the ``const`` pydantic emits for a Literal: openapi-python-client parses an
#: integer-or-const union as the const only, so generated clients could not send integers.
Auto = Annotated[Literal["auto"], WithJsonSchema({"type": "string", "enum": ["auto"]})]


class IdentificationRequest(RequestModel):
    """An FNSI identification of one dataset (paper Section II)."""

    model_config = ConfigDict(json_schema_extra={"examples": [{
        "dataset_id": "ds_5f1c0e2a9b7d4c3e8a10", "outputs": ["NC2w_Z", "NC2b_Z", "W_Z"],
        "band": [5.0, 50.0], "block_rows": 100, "order": "auto", "max_order": 40,
        "elements": [{"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z", "gap": 1.5}]}]})

    dataset_id: str = Field(description="Estimation dataset.")
    validation_dataset_id: str | None = Field(
        None, description="Separate dataset to compute validation errors on (same channels).")
    inputs: list[str] | None = Field(None, min_length=1,
                                     description="Input channels to use; default all.")
    outputs: list[str] | None = Field(None, min_length=1,
                                      description="Output channels to use; default all.")
    band: tuple[StrictFloat, StrictFloat] = Field(description="Analysis band [Hz], low < high.",
                                      examples=[[5.0, 50.0]])
    block_rows: Annotated[StrictInt, Field(ge=2, le=10_000)] | Auto = Field(
        "auto", description="Block rows i of the data matrices (Eq. 10), or \"auto\": the "
        "largest i with (inputs + basis functions + outputs) i <= harmonic lines of the "
        "period in the band, at most 100. Must exceed order / outputs; with periodic data "
        "(inputs + basis functions) i + order may not exceed twice the harmonic lines.",
        examples=["auto", 100])
    order: StrictInt | Auto = Field(
        "auto", description="Model order n, or \"auto\" to choose it from the stabilisation "
        "diagram.", examples=["auto", 20])
    max_order: StrictInt = Field(60, ge=2, le=2000, description="Highest order of the "
                                 "stabilisation diagram.", examples=[60])
    line_set: Literal["all", "excited"] = Field(
        "all", description="Spectral lines used: all in the band, or only the lines the "
        "input excites.")
    discard_periods: StrictInt = Field(1, ge=0, description="Leading periods dropped as "
                                 "transient.", examples=[1])
    weighting: StrictBool | Literal["auto"] = Field(
        "auto", description="Weight the data by the noise covariance estimated from the "
        "periods. auto: on for velocity and acceleration records (their noise grows as "
        "1/f^p once integrated into displacement) when the order is chosen by simulation, "
        "as in studies; off for displacement records and for the modal order rule.")
    frequency_warping: StrictBool = Field(
        False, description="Build the FNSI data matrices in a warped frequency variable that "
        "spreads the band over the unit circle (the model is mapped back exactly). Use it "
        "when the band is a small fraction of the sampling rate and many block rows are "
        "used (e.g. 5-50 Hz at 2.5 kHz, i = 50): there, without it, the order and the "
        "coefficients can change with rounding.")
    refine: StrictBool = Field(
        False, description="Refine the identified model by minimising its simulation error "
        "on the estimation data (output error): the model, its simulation and its errors "
        "get much closer to the measurement when the elements drive the structure outside "
        "the band or the bases are noisy; modes and coefficients stay FNSI's. Takes seconds "
        "to about a minute. A model that cannot be simulated is returned unrefined: "
        "result.refinement.message says why.")
    uncertainty: StrictBool = Field(
        True, description="Standard deviations of the frequencies [Hz], damping ratios "
        "[-], mode-shape components [-] and coefficients (units of the coefficient) from "
        "the period-to-period noise, in the *_std fields of the result (needs two kept "
        "periods; with one, result.uncertainty.note says no error bar can be given). Adds "
        "about 15-50 % to the identification's time.")
    elements: list[NonlinearElementSpec] = Field(
        default_factory=list, max_length=100, description="Nonlinear elements whose "
        "coefficients are "
        "identified; empty for a linear model.")
    driving_points: list[tuple[str, str]] = Field(
        default_factory=list, description="(input, output) pairs where the output is "
        "measured at the point and direction of the force; scales the coefficients. "
        "Outputs named like an input are driving points anyway.",
        examples=[[["F_x1", "x1"]]])
    remove_offsets: StrictBool = Field(
        False, description="Remove each channel's mean over the kept periods (a sensor "
        "offset) before the estimation, so that the nonlinear elements see zero-mean "
        "displacement: for displacement sensors not zeroed at the equilibrium. The errors "
        "never compare 0 Hz and report the offsets either way (errors.*.offsets).")

    @model_validator(mode="after")
    def _band_increasing(self) -> IdentificationRequest:
        low, high = self.band
        if not 0 <= low < high:
            raise ValueError(f"band must be [low, high] in Hz with 0 <= low < high; got "
                             f"{list(self.band)}")
        if isinstance(self.order, int) and not 1 <= self.order <= self.max_order:
            raise ValueError(f"order {self.order} must lie in 1..max_order ({self.max_order})")
        return self
