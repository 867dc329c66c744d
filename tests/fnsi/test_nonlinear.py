"""Nonlinear elements: basis values against closed forms, Eq. 19-22 splines, JSON, errors."""

import json
import math
import re

import numpy as np
import pytest
from scipy.interpolate import CubicSpline

from fnsi.nonlinear import (
    NonlinearElement,
    NonlinearityKind,
    basis_value,
    element_force,
    spline_matrices,
)

X = np.linspace(-3.0, 3.0, 121)

ELEMENTS = [
    NonlinearElement("polynomial", "a", "b", exponent=3.0, coefficients=(2.0,)),
    NonlinearElement("polynomial", "a", exponent=2.0, signed=False, coefficients=(-1.0,)),
    NonlinearElement("clearance", "NC2w_Z", "NC2b_Z", gap=1.5, coefficients=(100.0,)),
    NonlinearElement("clearance", "a", gap_negative=0.5, gap_positive=1.0, coefficients=(3.0,)),
    NonlinearElement("clearance", "a", gap=2.0, side="negative", coefficients=(40.0,)),
    NonlinearElement("piecewise_linear", "a", breakpoints=(-1.0, 0.5), coefficients=(1.0, 2.0)),
    NonlinearElement("spline", "a", "b", knots=(-2.0, -0.7, 0.5, 1.5, 3.0),
                     coefficients=(1.0, 3.0, 4.0)),
    NonlinearElement("spline", "a", intervals=9),
    NonlinearElement("coulomb_friction", "a", width=0.01, coefficients=(5.0,)),
    NonlinearElement("quadratic_damping", "a", "b", coefficients=(0.3,)),
]


def test_clearance_basis_is_dead_zone_with_contract_truth():
    e = ELEMENTS[2]
    x = np.array([-3.0, -1.5, -1.0, 0.0, 1.4, 1.5, 2.0])
    np.testing.assert_array_equal(e.basis(x)[:, 0], [-1.5, 0.0, 0.0, 0.0, 0.0, 0.0, 0.5])
    np.testing.assert_array_equal(e.force(x), 100.0 * e.basis(x)[:, 0])


def test_asymmetric_and_one_sided_clearance():
    x = np.array([-2.0, -0.6, -0.4, 0.9, 1.2, 3.0])
    np.testing.assert_allclose(ELEMENTS[3].basis(x)[:, 0], [-1.5, -0.1, 0, 0, 0.2, 2.0])
    np.testing.assert_allclose(ELEMENTS[4].basis(x)[:, 0], [0, 0, 0, 0, 0, 0])
    np.testing.assert_allclose(ELEMENTS[4].basis(np.array([-2.5, 2.5]))[:, 0], [-0.5, 0.0])
    positive = NonlinearElement("clearance", "a", gap=1.0, side="positive")
    np.testing.assert_allclose(positive.basis(x)[:, 0], [0, 0, 0, 0, 0.2, 2.0])


def test_piecewise_linear_hinges_equal_symmetric_clearance():
    hinges = NonlinearElement("piecewise_linear", "a", breakpoints=(-1.5, 1.5))
    clearance = NonlinearElement("clearance", "a", gap=1.5)
    np.testing.assert_array_equal(hinges.basis(X).sum(axis=1), clearance.basis(X)[:, 0])


def test_polynomial_signed_and_unsigned():
    np.testing.assert_allclose(ELEMENTS[0].basis(X)[:, 0], X**3, rtol=1e-14)
    np.testing.assert_allclose(ELEMENTS[1].basis(X)[:, 0], X**2, rtol=1e-14)
    half = NonlinearElement("polynomial", "a", exponent=1.5)
    np.testing.assert_allclose(half.basis(X)[:, 0], np.sign(X) * np.abs(X) ** 1.5, rtol=1e-14)


def test_velocity_kinds():
    v = np.array([-1.0, -0.005, 0.0, 0.02])
    np.testing.assert_allclose(ELEMENTS[8].basis(np.zeros(4), v)[:, 0], np.tanh(v / 0.01))
    np.testing.assert_allclose(ELEMENTS[9].basis(np.zeros(4), v)[:, 0], v * np.abs(v))
    with pytest.raises(ValueError, match="velocity"):
        ELEMENTS[9].basis(np.zeros(4))


def test_spline_is_the_natural_cubic_spline_through_its_knot_values():
    # Eq. 19-20 with natural ends: through its values at all the knots the spline is the
    # natural C2 interpolating cubic spline (unique), here scipy's; Eq. 21-22 hold at 0
    e = ELEMENTS[6]
    q = np.asarray(e.knots)
    c = np.asarray(e.coefficients)
    reference = CubicSpline(q, e.basis(q) @ c, bc_type="natural")
    inside = np.linspace(q[0], q[-1], 501)
    np.testing.assert_allclose(e.force(inside), reference(inside), atol=1e-12)
    np.testing.assert_allclose([reference(0.0), reference(0.0, 1)], 0.0, atol=1e-13)
    # linear continuation with the end slopes outside the knots (g'' = 0 there already)
    outside = np.array([q[0] - 0.5, q[-1] + 0.5])
    ends = reference(q[[0, -1]]) + reference(q[[0, -1]], 1) * np.array([-0.5, 0.5])
    np.testing.assert_allclose(e.force(outside), ends, rtol=1e-12)


def test_spline_reproduces_a_smooth_stop_exactly():
    # s(x) = (x-1)+^3 - 2 (x-2)+^3 + (x-3)+^3 is C2, zero for x < 1 and linear with slope
    # 6 beyond 3 (natural end); g(x) = s(x) - s(-x) satisfies Eq. 20-22, so the spline
    # with its ordinates at the outer knots is g everywhere, extrapolation included
    def stop(x):
        return sum(a * (np.maximum(x - k, 0) ** 3 - np.maximum(-x - k, 0) ** 3)
                   for a, k in ((1, 1), (-2, 2), (1, 3)))

    e = NonlinearElement("spline", "a", knots=(-3.0, -2.0, -1.0, 1.0, 2.0, 3.0),
                         coefficients=tuple(stop(np.array([-3.0, -2.0, 2.0, 3.0]))))
    x = np.linspace(-5.0, 5.0, 1001)
    np.testing.assert_allclose(e.force(x), stop(x), atol=1e-12)
    slopes = [element_force(e.kernel_kind, e.kernel_parameters, 0,
                            np.asarray(e.coefficients), 0, 4, xi, 0.0)[1] for xi in x]
    np.testing.assert_allclose(slopes, 3 * sum(a * (np.maximum(x - k, 0) ** 2
                                                     + np.maximum(-x - k, 0) ** 2)
                                                for a, k in ((1, 1), (-2, 2), (1, 3))),
                               atol=1e-12)


def test_spline_coefficients_are_ordinates_outside_the_central_interval():
    e = ELEMENTS[6]   # 0 lies in (-0.7, 0.5): those two ordinates follow from Eq. 21-22
    outer = np.array([-2.0, 1.5, 3.0])
    np.testing.assert_allclose(e.basis(outer), np.eye(3), atol=1e-14)
    assert e.n_basis == 3 and e.basis_names == ["spline a-b q=-2", "spline a-b q=1.5",
                                                "spline a-b q=3"]
    at_zero = np.array([basis_value(e.kernel_kind, e.kernel_parameters, 0, j, 0.0, 0.0)
                        for j in range(3)])
    np.testing.assert_allclose(at_zero[:, 0], 0.0, atol=1e-15)  # Eq. 21 for every basis
    np.testing.assert_allclose(at_zero[:, 1], 0.0, atol=1e-14)  # Eq. 22


def test_spline_matrices_satisfy_continuity_equation_20_and_natural_ends():
    q = np.array([-1.0, -0.2, 0.3, 1.1, 2.0])
    ordinates, slopes = spline_matrices(q) @ np.array([0.4, 0.5, 1.5])
    h = np.diff(q)
    for k in range(1, 4):
        lhs = (slopes[k - 1] / h[k - 1] + 2 * (1 / h[k - 1] + 1 / h[k]) * slopes[k]
               + slopes[k + 1] / h[k])
        rhs = 3 * ((ordinates[k] - ordinates[k - 1]) / h[k - 1] ** 2
                   + (ordinates[k + 1] - ordinates[k]) / h[k] ** 2)
        assert lhs == pytest.approx(rhs, rel=1e-12)
    # g'' = 0 at both end knots, in Hermite form
    assert 2 * slopes[0] + slopes[1] == pytest.approx(3 * (ordinates[1] - ordinates[0]) / h[0])
    assert slopes[-2] + 2 * slopes[-1] == pytest.approx(3 * (ordinates[-1] - ordinates[-2])
                                                        / h[-1])


def test_spline_basis_stays_of_order_one():
    # Eq. 20-22 solved outwards from 0 without end conditions (the paper's form) make
    # basis functions of 13 uniform intervals reach about 2,500; natural ends keep them
    # near their unit ordinates, so noise in one coefficient stays local
    x = np.linspace(-1.0, 1.0, 2001)
    uniform = np.concatenate([np.linspace(-1.0, -1 / 13, 7), np.linspace(1 / 13, 1.0, 7)])
    paper_like = (-1.0, -0.85, -0.8, -0.75, 0.75, 0.8, 0.85, 1.0)
    for knots in (uniform, paper_like):
        assert np.abs(NonlinearElement("spline", "a", knots=knots).basis(x)).max() < 1.5


def test_resolve_places_a_wide_central_interval_and_uniform_outer_halves():
    x = np.linspace(-1.2, 3.0, 50)
    q = np.asarray(NonlinearElement("spline", "a", intervals=7).resolve(x).knots)
    # every coefficient must be seen by data: the end knots are the measured extremes
    assert q.size == 8 and q[0] == x.min() and q[-1] == x.max()
    # central interval: the inner half of the excursion on each side
    k = np.searchsorted(q, 0.0) - 1
    assert (q[k], q[k + 1]) == (pytest.approx(-0.6), pytest.approx(1.5))
    # 6 outer intervals in proportion to the outer halves (0.6 and 1.5): 2 and 4, uniform
    np.testing.assert_allclose(np.diff(q[: k + 1]), 0.3)
    np.testing.assert_allclose(np.diff(q[k + 1:]), 0.375)


def test_resolve_one_sided_record_brackets_the_equilibrium():
    q = NonlinearElement("spline", "a", intervals=3).resolve(np.array([0.5, 2.0])).knots
    # no data below 0: the central interval reaches -hi / 2 and both intervals are outside
    assert q == pytest.approx((-1.0, 1.0, 1.5, 2.0))
    q = NonlinearElement("spline", "a", intervals=4).resolve(np.array([-3.0, 0.01])).knots
    assert q[0] == -3.0 and q[-1] == 1.5 and len(q) == 5


def test_automatic_spline_cannot_imitate_a_linear_spring():
    # the trade-off between spline coefficients and the connection's linear stiffness:
    # the best imitation of g = x on Gaussian samples leaves a large residual (26 % on
    # the SmallSat record; uniform knots leave 5 %, the paper's knots 39 %)
    x = np.random.default_rng(1).normal(size=20000)
    for intervals in (5, 9, 13, 21):
        basis = NonlinearElement("spline", "a", intervals=intervals).resolve(x).basis(x)
        fit = basis @ np.linalg.lstsq(basis, x, rcond=None)[0]
        assert np.sqrt(np.mean((fit - x) ** 2) / np.mean(x**2)) > 0.2


def test_kernel_derivatives_match_finite_differences():
    # central differences with step 1e-6 away from kinks: truncation ~1e-12 relative
    for e in ELEMENTS:
        if e.coefficients is None:
            continue
        c = np.asarray(e.coefficients)

        def force(x, v, e=e, c=c):
            return element_force(e.kernel_kind, e.kernel_parameters, 0, c, 0, e.n_basis, x, v)
        for x, v in [(-2.7, -0.013), (-0.31, 0.004), (1.73, 0.021), (2.9, -0.3)]:
            f, fx, fv = force(x, v)
            d = 1e-6
            assert fx == pytest.approx((force(x + d, v)[0] - force(x - d, v)[0]) / (2 * d),
                                       rel=1e-5, abs=1e-6), e.name
            assert fv == pytest.approx((force(x, v + d)[0] - force(x, v - d)[0]) / (2 * d),
                                       rel=1e-5, abs=1e-6), e.name
            assert f == pytest.approx(float(e.force(np.array([x]), np.array([v]))[0]), rel=1e-14)


@pytest.mark.parametrize("element", ELEMENTS, ids=lambda e: e.kind.value)
def test_json_round_trip(element):
    d = json.loads(json.dumps(element.to_json()))
    assert d["kind"] == element.kind.value and d["dof"] == element.dof
    back = NonlinearElement.from_json(d)
    assert back == element
    assert back.basis_names == element.basis_names


def test_json_shape_of_design_document():
    assert ELEMENTS[2].to_json() == {"kind": "clearance", "dof": "NC2w_Z", "ref": "NC2b_Z",
                                     "gap": 1.5, "side": "both", "coefficients": [100.0]}
    assert ELEMENTS[2].kind is NonlinearityKind.CLEARANCE


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"kind": "cubic", "dof": "a"}, "unknown nonlinearity kind"),
        ({"kind": "clearance", "dof": "a", "gap": 0.0}, "positive"),
        ({"kind": "clearance", "dof": "a", "gap": -1.0}, "positive"),
        ({"kind": "clearance", "dof": "a"}, "needs a gap"),
        ({"kind": "clearance", "dof": "a", "gap_positive": 1.0}, "negative side"),
        ({"kind": "clearance", "dof": "a", "gap": 1.0, "gap_positive": 2.0}, "not both"),
        ({"kind": "clearance", "dof": "a", "gap": 1.0, "side": "up"}, "side"),
        ({"kind": "clearance", "dof": "a", "gap": 1.0, "coefficients": (1.0, 2.0)}, "one finite"),
        ({"kind": "clearance", "dof": "a", "gap": 1.0, "knots": (-1.0, 1.0)}, "not parameters"),
        ({"kind": "spline", "dof": "a", "knots": (-1.0, 1.0, 0.5)}, "strictly increasing"),
        ({"kind": "spline", "dof": "a", "knots": (-1.0, 0.0, 1.0)}, "strictly inside"),
        ({"kind": "spline", "dof": "a", "knots": (0.5, 1.0, 2.0)}, "strictly inside"),
        ({"kind": "spline", "dof": "a"}, "knots .* or intervals"),
        ({"kind": "spline", "dof": "a", "intervals": 1}, ">= 2"),
        ({"kind": "spline", "dof": "a", "knots": (-1.0, 1.0)}, "at least 3"),
        ({"kind": "spline", "dof": "a", "knots": (-1.0, 0.5, 1.0), "intervals": 3},
         "intervals=3"),
        ({"kind": "piecewise_linear", "dof": "a", "breakpoints": (1.0, 1.0)}, "increasing"),
        ({"kind": "coulomb_friction", "dof": "a"}, "width"),
        ({"kind": "coulomb_friction", "dof": "a", "width": 0.0}, "positive"),
        ({"kind": "polynomial", "dof": "a", "exponent": 0.0}, "positive"),
        ({"kind": "polynomial", "dof": "a", "exponent": "three"}, "positive"),
        ({"kind": "polynomial", "dof": "a", "exponent": 1e9}, "at most 10"),
        ({"kind": "polynomial", "dof": "a", "exponent": math.inf}, "positive finite"),
        ({"kind": "polynomial", "dof": "a", "exponent": math.nan}, "positive finite"),
        ({"kind": "spline", "dof": "a", "knots": (-1.0, None, 1.0)}, "spline knots must be"),
        ({"kind": "spline", "dof": "a", "knots": (-1.0, math.nan, 1.0)}, "finite"),
        ({"kind": "piecewise_linear", "dof": "a", "breakpoints": (math.inf,)}, "finite"),
        ({"kind": "polynomial", "dof": "a", "signed": "no"}, "true or false"),
        ({"kind": "polynomial", "dof": "a", "ref": "a"}, "another DOF"),
        ({"kind": "polynomial", "dof": ""}, "non-empty"),
    ],
)
def test_bad_parameters_raise_clear_errors(kwargs, match):
    with pytest.raises(ValueError, match=match):
        NonlinearElement(**kwargs)


def test_bad_use_raises_clear_errors():
    with pytest.raises(ValueError, match="resolve"):
        ELEMENTS[7].basis(X)
    with pytest.raises(ValueError, match="no coefficients"):
        NonlinearElement("clearance", "a", gap=1.0).force(X)
    with pytest.raises(ValueError, match="unknown nonlinear element keys"):
        NonlinearElement.from_json({"kind": "clearance", "dof": "a", "gap": 1.0, "gapp": 2})


@pytest.mark.parametrize("foreign", [{"exponent": 3.0}, {"signed": True}, {"width": None}])
def test_json_refuses_another_kinds_parameter_even_at_its_default(foreign):
    """A clearance given an exponent (3.0 is the dataclass default) would be silently
    ignored if only values were compared; the JSON names the keys given."""
    said = re.escape(f"{list(foreign)} are not parameters of a clearance")
    with pytest.raises(ValueError, match=said):
        NonlinearElement.from_json({"kind": "clearance", "dof": "a", "gap": 1.0, **foreign})


def test_json_accepts_the_largest_exponent_and_its_own_parameters():
    element = NonlinearElement.from_json({"kind": "polynomial", "dof": "a", "exponent": 10.0,
                                          "signed": False, "coefficients": [1.0]})
    assert element.force(np.array([-2.0])).tolist() == [1024.0]
    with pytest.raises(ValueError, match="1-D"):
        ELEMENTS[0].basis(np.zeros((3, 2)))
