"""Stiffness curves from known forms and spline ordinates, and their error measure."""

from __future__ import annotations

import json

import numpy as np
import pytest

from fnsi.nonlinear import NonlinearElement
from fnsi.stiffness import curve_error_percent, stiffness_curve

CLEARANCE = NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=1.5, coefficients=(100.0,))


def test_known_form_times_coefficient_gives_the_closed_form_curve():
    curve = stiffness_curve(CLEARANCE.__class__("clearance", "NC2w_Z", "NC2b_Z", gap=1.5),
                            np.array([100.0]), (-3.0, 3.0), points=13)
    x = np.linspace(-3.0, 3.0, 13)
    expected = np.where(x > 1.5, 100 * (x - 1.5), np.where(x < -1.5, 100 * (x + 1.5), 0.0))
    np.testing.assert_allclose(curve.force, expected, atol=1e-12)
    assert curve.element.coefficients == (100.0,)
    assert curve.variable == "displacement"
    assert curve_error_percent(curve, CLEARANCE) == 0.0


def test_curve_error_of_a_mis_scaled_cubic():
    truth = NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(2.0,))
    curve = stiffness_curve(truth, np.array([2.2]), (-1.0, 1.0), points=2001)
    # 100 * RMS(0.2 x^3) / max|2 x^3| over uniform x in [-1, 1] = 10 / sqrt(7); the
    # 2001-point sampling of the integral of x^6 is exact to about 1e-3
    assert curve_error_percent(curve, truth) == pytest.approx(10 / np.sqrt(7), rel=2e-3)


def test_spline_curve_passes_through_its_ordinates_at_the_knots():
    knots = (-3.0, -1.65, -1.55, -1.45, -1.35, -0.5, 0.5, 1.35, 1.45, 1.55, 1.65, 3.0)
    spline = NonlinearElement("spline", "NC2w_Z", "NC2b_Z", knots=knots)
    outer = np.array(knots[:5] + knots[7:])      # all knots but those around 0
    ordinates = np.linspace(-1.0, 2.0, outer.size) ** 3
    curve = stiffness_curve(spline, ordinates, outer)
    # the coefficients are the ordinates there (Eq. 19, natural ends): exact up to rounding
    np.testing.assert_allclose(curve.force, ordinates, atol=1e-12)


def test_least_squares_spline_reproduces_the_clearance_law():
    knots = (-3.0, -1.65, -1.55, -1.45, -1.35, -0.5, 0.5, 1.35, 1.45, 1.55, 1.65, 3.0)
    spline = NonlinearElement("spline", "NC2w_Z", "NC2b_Z", knots=knots)
    x = np.linspace(-3.0, 3.0, 2001)
    ordinates = np.linalg.lstsq(spline.basis(x), CLEARANCE.force(x), rcond=None)[0]
    curve = stiffness_curve(spline, ordinates)     # default range: the knot span
    assert curve.x[0] == knots[0] and curve.x[-1] == knots[-1]
    # the best spline only rounds the kink within the +-0.15 knots around each contact:
    # 0.17 % of the peak force here; 0.5 % allows for sampling of the range
    assert curve_error_percent(curve, CLEARANCE) < 0.5
    # the error measure sees a 10 % coefficient error: 100 * 0.1 * RMS(f) / peak(f)
    scaled = stiffness_curve(spline, 1.1 * ordinates)
    f = CLEARANCE.force(scaled.x)
    expected = 10 * np.sqrt(np.mean(f**2)) / np.max(np.abs(f))
    assert curve_error_percent(scaled, CLEARANCE) == pytest.approx(expected, abs=0.5)


def test_velocity_element_is_drawn_against_velocity():
    damper = NonlinearElement("quadratic_damping", "a", "b")
    curve = stiffness_curve(damper, np.array([5.0]), (-2.0, 2.0), points=5)
    np.testing.assert_allclose(curve.force, 5.0 * curve.x * np.abs(curve.x))
    assert curve.variable == "velocity"
    data = json.loads(json.dumps(curve.to_json()))
    assert data["variable"] == "velocity" and data["element"]["coefficients"] == [5.0]


def test_bad_coefficients_and_ranges_are_rejected():
    bare = NonlinearElement("clearance", "a", gap=1.0)
    with pytest.raises(ValueError, match="real part"):
        stiffness_curve(bare, np.array([100 + 1j]), (-2.0, 2.0))
    with pytest.raises(ValueError, match="1 basis"):
        stiffness_curve(bare, np.array([1.0, 2.0]), (-2.0, 2.0))
    with pytest.raises(ValueError, match="measured range"):
        stiffness_curve(bare, np.array([1.0]))
    with pytest.raises(ValueError, match="no coefficients"):
        stiffness_curve(bare, x=(-2.0, 2.0))
    inside = stiffness_curve(bare, np.array([1.0]), (-0.5, 0.5))
    with pytest.raises(ValueError, match="widen the range"):
        curve_error_percent(inside, NonlinearElement("clearance", "a", gap=1.0,
                                                     coefficients=(1.0,)))
