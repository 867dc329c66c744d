"""Units of measured channels and of what is identified from them.

A measurement names the unit of each channel (:attr:`fnsi.measurement.Measurement.
input_units`, ``output_units``), as free text ("N", "mm", "V", "20 N"), from the file or
from the options given with it. The identification computes in those units: an FRF is in
output unit per input unit, a nonlinear coefficient mu_j in input (force) unit per unit
of its basis function g_j (paper Eq. 1-2), a stiffness curve in displacement and force
units. :class:`ModelUnits` derives each of them for labels and JSON results.

No unit is guessed: a channel whose unit is not given (empty string) is written as a
neutral placeholder naming its role, "input unit" or "output unit", and the derived units
are built from the placeholders (an FRF in "output unit/input unit", a cubic coefficient
in "input unit/output unit^3"), so a label never claims metres or newtons for data that
may be volts.

Examples
--------
>>> units = ModelUnits(force="N", output="mm", quantity="displacement")
>>> units.frf, units.curve("displacement")
('mm/N', ('mm', 'N'))
>>> ModelUnits(force="20 N", output="mm/s", quantity="velocity").frf
'(mm/s)/(20 N)'
>>> ModelUnits(force="", output="", quantity="displacement").frf
'output unit/input unit'
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass

from fnsi.nonlinear import NonlinearElement, NonlinearityKind

NOT_GIVEN = ""
"""A channel's unit when neither the file nor the options give it."""
INPUT_PLACEHOLDER = "input unit"
OUTPUT_PLACEHOLDER = "output unit"
_PLACEHOLDERS = (INPUT_PLACEHOLDER, OUTPUT_PLACEHOLDER)
#: Derivatives of displacement written as a suffix of the output unit ("mm/s", "m/s^2").
_PER_SECOND = {"velocity": re.compile(r"/s$"), "acceleration": re.compile(r"/s(\^2|²|2)$")}
_SECONDS = {"displacement": "", "velocity": "·s", "acceleration": "·s^2"}


def common(units: Sequence[str], placeholder: str) -> str:
    """The unit all ``units`` share, else ``placeholder`` (none given, or they differ)."""
    distinct = set(units)
    return distinct.pop() if len(distinct) == 1 and NOT_GIVEN not in distinct else placeholder


def _grouped(unit: str, binding: str = "/· *") -> str:
    """``unit`` in parentheses when it holds an operator of ``binding`` ("mm/s", "20 N";
    a power binds tighter than a quotient, so "mm^3" stays bare under a fraction bar)."""
    outside = unit
    for placeholder in _PLACEHOLDERS:   # their space is no operator
        outside = outside.replace(placeholder, "U")
    while (inner := re.sub(r"\([^()]*\)", "", outside)) != outside:  # operators at top level
        outside = inner
    if not any(c in outside for c in binding):
        return unit
    return f"({unit})"


def per(numerator: str, denominator: str) -> str:
    """``numerator`` divided by ``denominator`` ("mm/N"; "1" divides by nothing)."""
    if denominator == "1":
        return numerator
    return f"{_grouped(numerator)}/{_grouped(denominator)}"


def power(unit: str, exponent: float) -> str:
    """``unit`` raised to ``exponent`` ("mm^3", "(mm/s)^2", "mm^1.5")."""
    return unit if exponent == 1 else f"{_grouped(unit, '/· *^')}^{exponent:g}"


def displacement_unit(output_unit: str, quantity: str) -> str:
    """Unit of the displacements integrated from outputs in ``output_unit``.

    "mm/s" of a velocity gives "mm", "m/s^2" of an acceleration "m"; a unit without the
    time derivative written in it (volts, g, a placeholder) gets the seconds appended
    ("V·s").
    """
    pattern = _PER_SECOND.get(quantity)
    if pattern is not None and pattern.search(output_unit):
        return pattern.sub("", output_unit)
    return f"{output_unit}{_SECONDS[quantity]}" if output_unit else output_unit


def velocity_unit(output_unit: str, quantity: str) -> str:
    """Unit of the velocities derived from outputs in ``output_unit``.

    "mm/s" of a velocity stays, "m/s^2" of an acceleration gives "m/s", "mm" of a
    displacement "mm/s"; a unit without the time derivative written in it (volts, g, a
    placeholder) is a velocity as it is, or gets one second ("V·s" of an acceleration in V)
    rather than "(V·s^2)/s".
    """
    if not output_unit or quantity == "velocity":
        return output_unit
    if quantity == "acceleration":
        pattern = _PER_SECOND[quantity]
        return (pattern.sub("/s", output_unit) if pattern.search(output_unit)
                else f"{output_unit}·s")
    return per(output_unit, "s")


@dataclass(frozen=True)
class ModelUnits:
    """Units of a model identified from one measurement.

    Attributes
    ----------
    force : str
        Unit of the inputs (forces), placeholder when not given or not shared.
    output : str
        Unit of the outputs, placeholder when not given or not shared.
    quantity : {"displacement", "velocity", "acceleration"}
        What the outputs measure.
    """

    force: str
    output: str
    quantity: str

    def __post_init__(self) -> None:
        object.__setattr__(self, "force", self.force or INPUT_PLACEHOLDER)
        object.__setattr__(self, "output", self.output or OUTPUT_PLACEHOLDER)

    @classmethod
    def of(cls, input_units: Sequence[str], output_units: Sequence[str],
           quantity: str) -> ModelUnits:
        """The units of a measurement's channels (:meth:`Measurement.units`)."""
        return cls(common(input_units, INPUT_PLACEHOLDER),
                   common(output_units, OUTPUT_PLACEHOLDER), quantity)

    @property
    def length(self) -> str:
        """Unit of the displacements the nonlinear bases take (x of Eq. 1-2)."""
        return displacement_unit(self.output, self.quantity)

    @property
    def velocity(self) -> str:
        """Unit of the velocities the dissipative bases take (x-dot of Eq. 1-2)."""
        return velocity_unit(self.output, self.quantity)

    @property
    def frf(self) -> str:
        """Unit of an FRF H = Y / U: output unit per input unit."""
        return per(self.output, self.force)

    def basis(self, element: NonlinearElement) -> str:
        """Unit of the basis functions g_j of ``element`` (table of :mod:`fnsi.nonlinear`).

        Polynomials: length^p; clearances and hinges: length; quadratic damping:
        (length/s)^2; spline (knot ordinates are forces) and friction (tanh): "1".
        """
        kind = NonlinearityKind(element.kind)
        if kind == NonlinearityKind.POLYNOMIAL:
            return power(self.length, element.exponent)
        if kind in (NonlinearityKind.CLEARANCE, NonlinearityKind.PIECEWISE_LINEAR):
            return self.length
        if kind == NonlinearityKind.QUADRATIC_DAMPING:
            return power(self.velocity, 2)
        return "1"

    def coefficient(self, element: NonlinearElement) -> str:
        """Unit of the coefficients mu_j of ``element``: force per basis unit (Eq. 1-2)."""
        return per(self.force, self.basis(element))

    def curve(self, variable: str) -> tuple[str, str]:
        """Abscissa and force units of a stiffness (``"displacement"``) or damping
        (``"velocity"``) curve."""
        x = self.length if variable == "displacement" else self.velocity
        return x, self.force

    def to_json(self) -> dict[str, str]:
        """JSON-ready units: input, output, displacement, FRF."""
        return {"input": self.force, "output": self.output, "displacement": self.length,
                "frf": self.frf}
