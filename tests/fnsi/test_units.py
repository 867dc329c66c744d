"""Units end to end (issue 22): derived units, and the axis labels of every figure the
library draws for a record in volts, one in mm and N, and one without units.

The figures are PNG bytes; the test records each :class:`matplotlib.figure.Figure` as
it is rendered (``png_bytes`` of :mod:`fnsi.plots` and :mod:`fnsi.study_plots`) and
reads the labels of its axes and colour bars.
"""

from __future__ import annotations

import dataclasses
import re

import pytest

from fnsi import plots, study_plots
from fnsi.diagnosis import DiagnosisSettings, diagnose
from fnsi.distortion import analyse_distortion
from fnsi.identification import identify
from fnsi.nonlinear import NonlinearElement
from fnsi.report import identification_report
from fnsi.smallsat import FORCE_UNIT, OUTPUT_UNITS, simulate_preset
from fnsi.study import Study
from fnsi.units import ModelUnits
from tests.fnsi.test_diagnosis import NAMES, SETTINGS, chain, measure

HIDDEN = NonlinearElement("clearance", "x4", "x5", gap_negative=0.002, gap_positive=0.001,
                          coefficients=(1e4,))
CUBIC = NonlinearElement("polynomial", "x4", "x5", exponent=3.0)
#: Units of the axes that do not depend on the data.
GENERIC = {"Hz", "-", "deg", "%", "s", "dB", "Hz]"}


@pytest.mark.parametrize("kind, parameters, unit", [
    ("polynomial", {"exponent": 3.0}, "N/mm^3"),
    ("polynomial", {"exponent": 1.5}, "N/mm^1.5"),
    ("clearance", {"gap": 1.0}, "N/mm"),
    ("piecewise_linear", {"breakpoints": (1.0,)}, "N/mm"),
    ("spline", {"knots": (-1.0, 0.5, 1.0)}, "N"),
    ("coulomb_friction", {"width": 0.1}, "N"),
    ("quadratic_damping", {}, "N/(mm/s)^2"),
])
def test_coefficient_units_are_force_per_basis_unit(kind, parameters, unit):
    element = NonlinearElement(kind, "x1", None, **parameters)
    assert ModelUnits("N", "mm", "displacement").coefficient(element) == unit


def test_derived_units_of_velocity_acceleration_and_volts():
    assert ModelUnits("N", "mm/s", "velocity").length == "mm"
    assert ModelUnits("N", "m/s^2", "acceleration").curve("velocity") == ("m/s", "N")
    assert ModelUnits("V", "V", "velocity").length == "V·s"
    assert ModelUnits("", "", "displacement").coefficient(CUBIC) == "input unit/output unit^3"


@pytest.mark.parametrize("output, quantity, velocity, damper", [
    ("mm", "displacement", "mm/s", "N/(mm/s)^2"),
    ("mm/s", "velocity", "mm/s", "N/(mm/s)^2"),
    ("m/s^2", "acceleration", "m/s", "N/(m/s)^2"),
    ("m/s²", "acceleration", "m/s", "N/(m/s)^2"),
    ("V", "velocity", "V", "N/V^2"),                 # not N/((V·s)/s)^2
    ("g", "acceleration", "g·s", "N/(g·s)^2"),        # not N/((g·s^2)/s)^2
    ("", "acceleration", "output unit·s", "N/(output unit·s)^2"),
])
def test_velocity_units_carry_one_derivative_less_than_written(output, quantity, velocity,
                                                                damper):
    """A damper's velocity and its coefficient read in the simplest unit: accelerations in
    "output unit" gave "input unit/((output unit·s^2)/s)^2" (seed 37 case 3)."""
    units = ModelUnits("N", output, quantity)
    assert units.velocity == velocity
    assert units.curve("velocity") == (velocity, "N")
    assert units.coefficient(NonlinearElement("quadratic_damping", "x1")) == damper


def test_smallsat_presets_declare_mm_and_units_of_20_newtons():
    """The model's force unit is kappa * delta = 2e4 N/m x 1 mm = 20 N (fnsi.smallsat):
    the WEMS stops read in mm and their slopes in 20 N/mm."""
    units = ModelUnits(FORCE_UNIT, OUTPUT_UNITS["displacement"], "displacement")
    assert (units.frf, units.curve("displacement")) == ("mm/(20 N)", ("mm", "20 N"))
    assert units.coefficient(NonlinearElement("clearance", "x", None, gap=1.5)) == "(20 N)/mm"
    assert OUTPUT_UNITS["acceleration"] == "mm/s^2"


@pytest.mark.parametrize("quantity, unit, frf", [("displacement", "mm", "mm/(20 N)"),
                                                  ("velocity", "mm/s", "(mm/s)/(20 N)")])
def test_simulated_smallsat_records_carry_the_presets_units(quantity, unit, frf):
    m, _ = simulate_preset("single", periods=3, samples_per_period=2500,
                           outputs=("NC2w_Z", "NC2b_Z"), quantity=quantity)
    assert (m.input_units, m.output_units) == (("20 N",), (unit, unit))
    assert (m.units.length, m.units.frf) == ("mm", frf)


def _labelled(input_unit: str, output_unit: str):
    """Estimation and validation records of the chain with the given channel units."""
    model = chain(HIDDEN)
    return [dataclasses.replace(measure(model, seed), input_units=(input_unit,),
                                output_units=(output_unit,) * len(NAMES)) for seed in (1, 2)]


def _figures(monkeypatch, estimation, validation) -> dict[str, list[tuple[str, ...]]]:
    """Labels of every figure drawn for the records: identification report, distortion
    analysis, study revision and diagnosis."""
    drawn: list = []
    for module in (plots, study_plots):
        original = module.png_bytes
        monkeypatch.setattr(module, "png_bytes",
                            lambda figure, original=original: drawn.append(figure)
                            or original(figure))
    settings = dataclasses.replace(SETTINGS, elements=(CUBIC,))
    names: list[str] = []

    def record(new: dict[str, bytes]) -> None:
        names.extend(new)
        assert len(names) == len(drawn), "a figure was drawn without going through png_bytes"

    result = identify(estimation, settings)
    record({k: v for k, v in identification_report(result, settings, estimation,
                                                   validation=validation).artefacts.items()
            if k.endswith(".png")})
    record({"distortion.png": plots.plot_distortion(analyse_distortion(estimation))})
    study = Study.create(estimation, validation, SETTINGS)
    record(study_plots.study_figures(study))
    diagnosis = diagnose(study, settings=DiagnosisSettings(
        validated_candidates=1, curve_locations=1, top_locations=2,
        include_missing_mode=False))
    record({f"diagnosis-{name}": png for name, png in
            study_plots.diagnosis_figures(diagnosis).items()})
    return {name: _labels(figure) for name, figure in zip(names, drawn, strict=True)}


def _labels(figure) -> list[str]:
    return [label for ax in figure.axes if ax.get_visible()
            for label in (ax.get_xlabel(), ax.get_ylabel()) if label]


EXPECTED = {  # figure -> labels it must carry, for input unit {f} and output unit {y}
    "frf.png": ["|H| [{y}/{f}]"],
    "stabilisation.png": ["sum of FRF magnitudes [{y}/{f}]"],
    "coefficients.png": ["Re mu_j [{f}/{y}^3]", "Im mu_j [{f}/{y}^3]"],
    "stiffness.png": ["Relative displacement [{y}]", "Restoring force [{f}]"],
    "errors.png": ["Amplitude [{y}]"],
    "distortion.png": ["Level [dB re 1 {y}]"],
    "revision-0-comparison.png": ["x1 [{y}]", "Amplitude [{y}]"],
    "revision-0-residual-spectra.png": ["Amplitude [{y}]"],
    "diagnosis-screening.png": ["Relative displacement [{y}]"],
    "diagnosis-stiffness.png": ["Relative displacement [{y}]", "Restoring force [{f}]"],
}


@pytest.mark.parametrize("force, output", [("V", "V"), ("N", "mm"), ("", "")],
                         ids=["volts", "mm-and-newtons", "not-given"])
def test_every_figure_is_labelled_in_the_records_units(monkeypatch, force, output):
    estimation, validation = _labelled(force, output)
    figures = _figures(monkeypatch, estimation, validation)
    f, y = force or "input unit", output or "output unit"
    allowed = GENERIC | {f, y, f"{y}/{f}", f"{f}/{y}^3", f"dB re 1 {y}"}
    for name, labels in figures.items():
        for label in labels:
            for unit in re.findall(r"\[([^\]]*)\]", label):
                assert unit in allowed, f"{name}: {label!r} is not in the record's units"
    for name, labels in EXPECTED.items():   # 5 outputs: every channel has its panels
        for label in labels:
            assert label.format(f=f, y=y) in figures[name], (name, figures[name])
    assert set(figures) == {"frf.png", "coefficients.png", "stiffness.png", "errors.png",
                            "stabilisation.png", "macx.png", "distortion.png", "history.png",
                            *(f"revision-0-{kind}.png" for kind in ("comparison",
                                                                    "residual-spectra",
                                                                    "residual-map")),
                            *(f"diagnosis-{kind}.png" for kind in ("screening", "stiffness",
                                                                   "candidates"))}


def test_results_carry_the_units():
    estimation, _ = _labelled("N", "mm")
    settings = dataclasses.replace(SETTINGS, elements=(CUBIC,))
    document = identify(estimation, settings).to_json()
    assert document["units"] == {"input": "N", "output": "mm", "displacement": "mm",
                                 "frf": "mm/N"}
    assert [c["unit"] for c in document["coefficients"]] == ["N/mm^3"]
    assert [(c["x_unit"], c["force_unit"]) for c in document["stiffness"]] == [("mm", "N")]
    assert analyse_distortion(estimation).to_json()["unit"] == "mm"
