"""Output-error refinement against known truth: 3-DOF chains with a clearance, a cubic
spring, a spline and Coulomb friction, simulated by the project's Newmark integrator."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import scipy.linalg

import fnsi.identification
from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.refinement import (
    Refinement,
    _averaged_record,
    _closed_loop,
    _Loop,
    _loop_runs,
    _Problem,
    levenberg_marquardt,
    real_modal_form,
    refine,
    reflect_unstable_poles,
)
from fnsi.simulation import SimulationDivergedError
from fnsi.statespace import StateSpaceModel
from fnsi.validation import compare

GAP = 1e-4          # about the RMS relative displacement c - b of the records below
STOP = NonlinearElement("clearance", "c", "b", gap=GAP, coefficients=(3e4,))
BAND = (3.0, 45.0)


@pytest.fixture(autouse=True)
def bases_at_fs(monkeypatch):
    """FNSI models as refinement starts from them (``identify`` with ``refine``): bases
    evaluated once per sample at fs, not at the finer rate of :mod:`fnsi.oversampling`."""
    monkeypatch.setattr(fnsi.identification, "oversampling_factor", lambda *args: 1)


@pytest.fixture(scope="module")
def records(chain, simulate_record):
    """Estimation and validation records of the chain with the stop, 5 % output noise."""
    structure = chain(3, (STOP,))
    return tuple(simulate_record(structure, ["a"], noise=0.05, periods=4, seed=seed)
                 for seed in (3, 4))


def _settings(**kwargs) -> IdentificationSettings:
    element = NonlinearElement("clearance", "c", "b", gap=GAP)
    return IdentificationSettings(band=BAND, order=6, elements=(element,), discard_periods=1,
                                  **kwargs)


def test_real_modal_form_keeps_the_frf(records):
    model = identify(records[0], _settings()).model
    modal, sizes = real_modal_form(model)
    assert sizes.tolist() == [2, 2, 2]
    for k, block in enumerate(range(0, 6, 2)):
        a, b = modal.A[block, block], modal.A[block, block + 1]
        assert modal.A[block + 1, block] == pytest.approx(-b)
        assert modal.A[block + 1, block + 1] == pytest.approx(a)
        assert np.count_nonzero(modal.A[block:block + 2]) == 4, k
    f = np.linspace(3.0, 45.0, 50)
    np.testing.assert_allclose(modal.frequency_response(f), model.frequency_response(f),
                               rtol=1e-9, atol=1e-12 * np.abs(model.frequency_response(f)).max())


def test_jacobian_matches_finite_differences_on_the_loop_outputs(records):
    """Closed-loop sensitivities on the outputs the element acts on, the variable-projection
    Jacobian on the others."""
    model = identify(records[0], _settings()).model
    u, y, _ = _averaged_record(model, records[0], 1)
    modal, sizes = real_modal_form(model)
    problem = _Problem(modal, sizes, u, y, np.arange(1, 80), 0, max_radius=1.0)
    theta = problem.layout.pack(modal)
    J, fd = problem.jacobian(theta), _finite_difference_jacobian(problem, theta)
    loop = np.zeros(problem.Y.shape, dtype=bool)
    loop[:, :, problem.layout.loop] = True
    rows = np.concatenate([loop.ravel(), loop.ravel()])

    def column_errors(mask):
        return (np.linalg.norm(J[mask] - fd[mask], axis=0)
                / np.linalg.norm(fd[mask], axis=0))

    assert column_errors(rows).max() < 1e-4
    assert column_errors(~rows).max() < 1e-3
    # the minimisation's normal equations, formed without the projected rows
    gram, gradient = problem.normal_equations(theta)
    np.testing.assert_allclose(gram, J.T @ J, rtol=1e-9, atol=1e-12 * np.abs(gram).max())
    np.testing.assert_allclose(gradient, J.T @ problem.residual(theta), rtol=1e-9,
                               atol=1e-12 * np.abs(gradient).max())


def test_a_step_through_a_zero_gap_is_refused_as_a_divergence(records):
    """A Levenberg-Marquardt step that takes a gap to zero or below is a failed step the
    minimisation retreats from (SimulationDivergedError), not a ValueError of the
    element that ended the whole refinement (a stop whose contact lies past the mean of
    a zero-mean motion pulls its gap towards zero)."""
    model = identify(records[0], _settings()).model
    u, y, _ = _averaged_record(model, records[0], 1)
    modal, sizes = real_modal_form(model)
    problem = _Problem(modal, sizes, u, y, np.arange(1, 80), 0, max_radius=1.0)
    theta = problem.layout.pack(modal)
    theta[problem.layout.slices[4]] = -0.1 * GAP
    with pytest.raises(SimulationDivergedError, match="reached zero"):
        problem.evaluate(theta)
    # the step's residual is 10 times the measurement: rejected, the damping raised
    assert np.linalg.norm(problem.residual(theta)) == pytest.approx(10.0)


def _finite_difference_jacobian(problem: _Problem, theta: np.ndarray,
                                 step: float = 1e-6) -> np.ndarray:
    columns = []
    for k in range(theta.size):
        h = step * max(abs(theta[k]), 1e-3)
        up, down = theta.copy(), theta.copy()
        up[k] += h
        down[k] -= h
        columns.append((problem.residual(up) - problem.residual(down)) / (2 * h))
    return np.column_stack(columns)


def test_jacobian_with_two_inputs_two_elements_and_two_realisations(chain, simulate_record):
    """Multi-input, multi-element (one with five spline bases), two realisations, every
    output in the loop, residual in velocity units; the starting model's nonlinear
    feed-through is zeroed so that it simulates explicitly."""
    true = (NonlinearElement("clearance", "c", "b", gap=GAP, coefficients=(3e4,)),
            NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(1e10,)))
    record = simulate_record(chain(3, true), ["a", "c"], noise=0.02, periods=4, seed=3,
                             rms=[1.0, 1.5])
    elements = (NonlinearElement("clearance", "c", "b", gap=GAP),
                NonlinearElement("spline", "a", intervals=5))
    model = identify(record, IdentificationSettings(band=BAND, order=6, elements=elements,
                                                    discard_periods=1)).model
    D = model.D.copy()
    D[:, model.n_inputs:] = 0.0
    start = StateSpaceModel(model.A, model.B, model.C, D, model.fs, model.input_names,
                            model.output_names, model.elements)
    u, y, _ = _averaged_record(start, record, 1)
    modal, sizes = real_modal_form(start)
    problem = _Problem(modal, sizes, u, y, np.arange(1, 60), 1, max_radius=1.0)
    theta = problem.layout.pack(modal)
    # a clearance makes the residual piecewise smooth: a step that moves one sample across
    # the gap is no derivative (relative step 1e-6 does so for two pole columns of this
    # model, 2 % off; 1e-7 and 1e-8 agree with the Jacobian to 1e-8)
    J, fd = problem.jacobian(theta), _finite_difference_jacobian(problem, theta, step=1e-7)
    dynamic = slice(0, problem.layout.slices[2].stop)      # poles, B^e and C
    error = np.linalg.norm(J - fd, axis=0) / np.linalg.norm(fd, axis=0)
    assert error[dynamic].max() < 1e-4
    refinement = refine(start, record, discard_periods=1, band_high=BAND[1])
    # 5.1 % -> 2.8 % (39 % -> 2.8 % when E_i held the powers z^p)
    assert refinement.final_percent < refinement.initial_percent / 1.5


def test_refinement_brings_the_validation_error_to_the_noise_floor(records):
    """Output noise only: the output-error estimate is consistent, so what remains is the
    noise and the discrete-time model's own error (1.7 % on noise-free records of this
    chain, sampled at 200 Hz with a stiff stop), which add in quadrature."""
    estimation, validation = records
    fnsi = identify(estimation, _settings())
    refined = identify(estimation, _settings(refine=True))
    before, after = (compare(r.model, validation, discard_periods=1, band_high=BAND[1],
                             oversampling=1).errors for r in (fnsi, refined))
    floor = after.overall_noise_floor_percent
    # FNSI alone: 4.7 % (20 % when E_i held the powers z^p, which rounding made
    # dependent); refined: 3.4 %, floor 2.9 %
    assert after.overall_percent < 1.5 * floor
    assert after.overall_percent < 0.8 * before.overall_percent
    assert refined.refinement.final_percent < 0.8 * refined.refinement.initial_percent
    assert refined.timings["refinement"] > 0.0
    # the physical estimates stay FNSI's
    assert refined.coefficients[0].mean_real == fnsi.coefficients[0].mean_real
    np.testing.assert_array_equal(refined.modal.frequencies, fnsi.modal.frequencies)
    assert refined.to_json()["refinement"]["iterations"] == refined.refinement.iterations


def test_refinement_estimates_the_gap(records):
    """Started 10 % off the true gap, refinement moves the clearance to it (the gap is a
    parameter of the output-error fit) and returns the element with it."""
    estimation, validation = records
    wrong = NonlinearElement("clearance", "c", "b", gap=1.1 * GAP)
    settings = IdentificationSettings(band=BAND, order=6, elements=(wrong,),
                                      discard_periods=1)
    fnsi = identify(estimation, settings)
    refined = identify(estimation, dataclasses.replace(settings, refine=True))
    (element,) = refined.model.elements
    assert element.gap == pytest.approx(GAP, rel=0.02)
    before, after = (compare(r.model, validation, discard_periods=1, band_high=BAND[1],
                             oversampling=1).errors for r in (fnsi, refined))
    assert after.overall_percent < 1.5 * after.overall_noise_floor_percent
    assert before.overall_percent > 1.5 * after.overall_percent  # 6.1 % -> 3.4 %


def test_linear_model_is_refined_in_the_frequency_domain(chain, simulate_record):
    """A linear structure: FNSI is already consistent, so refinement, done wholly in the
    frequency domain, must not degrade it (validation 2.894 % -> 2.873 %, floor 2.892 %)."""
    structure = chain(3)
    record, validation = (simulate_record(structure, ["a"], noise=0.05, periods=4, seed=seed)
                          for seed in (5, 6))
    model = identify(record, IdentificationSettings(band=BAND, order=6,
                                                    discard_periods=1)).model
    refinement = refine(model, record, discard_periods=1, band_high=BAND[1])
    assert refinement.final_percent <= refinement.initial_percent
    assert refinement.iterations >= 1
    assert refinement.evaluations == 0            # no element: nothing to simulate
    errors = compare(refinement.model, validation, discard_periods=1, band_high=BAND[1],
                     oversampling=1).errors
    assert errors.overall_percent < 1.01 * errors.overall_noise_floor_percent


FRICTION_WIDTH = 0.01   # [m/s], about the RMS relative velocity c - b below (8.4e-3)


@pytest.fixture(scope="module")
def friction_records(chain, simulate_record):
    """Estimation and validation records of the chain with Coulomb friction between c
    and b, 2 % output noise."""
    friction = NonlinearElement("coulomb_friction", "c", "b", width=FRICTION_WIDTH,
                                coefficients=(0.3,))
    structure = chain(3, (friction,))
    return tuple(simulate_record(structure, ["a"], noise=0.02, periods=4, seed=seed)
                 for seed in (3, 4))


def test_velocity_dependent_elements_are_refined(friction_records):
    """Coulomb friction between c and b: the relative velocity is the simulator's central
    difference inside its implicit step, and its sensitivities are exact too, the
    smoothing width's included."""
    estimation, validation = friction_records
    settings = IdentificationSettings(band=BAND, order=6, discard_periods=1, elements=(
        NonlinearElement("coulomb_friction", "c", "b", width=0.01),))
    model = identify(estimation, settings).model
    u, y, _ = _averaged_record(model, estimation, 1)
    modal, sizes = real_modal_form(model)
    problem = _Problem(modal, sizes, u, y, np.arange(1, 80), 0, max_radius=1.0)
    theta = problem.layout.pack(modal)
    # a larger difference step than the smooth elements': the friction law's steep
    # regularisation makes the residual's rounding, divided by the step, the difference's
    # dominant error (measured 1e-4 at a relative step of 1e-5, 4e-3 at 1e-6, 3e-2 at 1e-7,
    # and varying with the BLAS kernel at the smaller steps)
    J, fd = problem.jacobian(theta), _finite_difference_jacobian(problem, theta, step=1e-5)
    assert (np.linalg.norm(J - fd, axis=0) / np.linalg.norm(fd, axis=0)).max() < 2e-3
    # FNSI 1.54 %, refined 1.18 %, floor 1.15 %
    before, after = (compare(identify(estimation, dataclasses.replace(settings, refine=flag))
                             .model, validation, discard_periods=1, band_high=BAND[1],
                             oversampling=1).errors for flag in (False, True))
    floor = after.overall_noise_floor_percent
    assert before.overall_percent > 1.25 * floor
    assert after.overall_percent < 1.05 * floor


def test_refinement_estimates_the_friction_width(friction_records):
    """Started at a third of the true smoothing width (a fixed-pole search's error on a
    hidden-benchmark case was about half), refinement moves it to the truth (the width
    is a parameter of the output-error fit) and returns the element with it."""
    estimation, validation = friction_records
    settings = IdentificationSettings(band=BAND, order=6, discard_periods=1, elements=(
        NonlinearElement("coulomb_friction", "c", "b", width=0.3 * FRICTION_WIDTH),))
    fnsi, refined = (identify(estimation, dataclasses.replace(settings, refine=flag))
                     for flag in (False, True))
    (element,) = refined.model.elements
    # measured 0.9977 of the truth: the noise's share of the fit (2 % of the response)
    assert element.width == pytest.approx(FRICTION_WIDTH, rel=0.02)
    before, after = (compare(r.model, validation, discard_periods=1, band_high=BAND[1],
                             oversampling=1).errors for r in (fnsi, refined))
    # FNSI at the wrong width 1.60 %, refined 1.15 %, floor 1.15 %
    assert after.overall_percent < 1.05 * after.overall_noise_floor_percent
    assert before.overall_percent > 1.25 * after.overall_noise_floor_percent


@pytest.mark.parametrize("velocity", [False, True])
def test_the_closed_loop_starts_at_its_periodic_response(velocity):
    """A lightly damped loop (pole radius 0.999: its transient from rest decays by 1e-8
    in 72 periods of 256 samples) started from its monodromy matrix gives the periodic
    response that 400 periods from rest reach (0.999^102400 = 4e-45 left of the
    start-up), to rounding: measured 2.1e-16 and 2.5e-16 relative (I - Phi's condition
    number 1.2 and 2.5); 1e-9 is far above any rounding and far below the 1e-3 a
    start-up transient leaves after 2 periods."""
    rng = np.random.default_rng(1)
    N, n, s, E, p, gaps = 256, 4, 3, 2, 5, 1
    nz = 2 * E if velocity else E
    radius, angles = 0.999, np.array([0.3, 1.1])
    a, b = radius * np.cos(angles), radius * np.sin(angles)
    Bg, PC, PDg = (0.1 * rng.standard_normal(shape) for shape in ((n, s), (E, n), (E, s)))
    M = 0.1 * rng.standard_normal((nz, s))
    gain = 0.2 * rng.standard_normal((N, s, nz))
    M_inv = np.linalg.inv(np.eye(nz) - M @ gain)
    A = scipy.linalg.block_diag(*([[ai, bi], [-bi, ai]] for ai, bi in zip(a, b, strict=True)))
    loop = _Loop(a, b, np.array([2, 2]), Bg, PC, PC @ A, PDg, M, M_inv, gain)
    forcing = rng.standard_normal((N, nz, p))
    direct = rng.standard_normal((N, s, gaps))
    direct_index = np.array([-1, -1, 0, -1, -1])
    warmup = int(np.ceil(np.log(1e-8) / np.log(radius)))
    periodic = _closed_loop(loop, forcing, direct, direct_index, 1.0, warmup)
    d = 2 * n + s if velocity else n
    from_rest = np.empty((p, N, s))
    _loop_runs(*loop, np.ascontiguousarray(np.moveaxis(forcing, 2, 0)), np.arange(p),
               direct, direct_index, 1.0, np.zeros((p, d)), 400, from_rest, True)
    from_rest = np.moveaxis(from_rest, 0, 2)
    assert np.abs(periodic - from_rest).max() < 1e-9 * np.abs(from_rest).max()
    # and not what the warm-up the loop's slowest pole asks for misses by a period
    short = np.empty((p, N, s))
    _loop_runs(*loop, np.ascontiguousarray(np.moveaxis(forcing, 2, 0)), np.arange(p),
               direct, direct_index, 1.0, np.zeros((p, d)), 2, short, True)
    assert np.abs(np.moveaxis(short, 0, 2) - from_rest).max() > 1e-3 * np.abs(from_rest).max()


def test_a_model_that_cannot_be_simulated_is_not_refined(records):
    """A feed-through of the softening sign folds the implicit step (fnsi.simulation):
    refine says so, and identify keeps FNSI's model with the reason."""
    model = identify(records[0], _settings()).model
    D = model.D.copy()
    D[model.output_names.index("c"), model.n_inputs] = 50.0
    folded = StateSpaceModel(model.A, model.B, model.C, D, model.fs, model.input_names,
                             model.output_names, model.elements)
    with pytest.raises(ValueError, match="starting model cannot be simulated"):
        refine(folded, records[0], discard_periods=1, band_high=BAND[1])
    refused = Refinement.refused(folded, "why")
    assert refused.summary == "not refined: why" and refused.model is folded
    assert refused.to_json()["initial_percent"] is None


def test_poles_clipped_onto_the_settling_circle_land_inside_it():
    """The refinement refuses a starting model with a pole beyond its settling radius, and
    clipping poles onto that radius exactly left 53 of these 200 an ulp outside: a study
    then refined or not by the rounding of its modal form (an order-50 revision of the
    hidden benchmark refined on one BLAS kernel only). Every clipped or reflected pole
    must now pass the refinement's own test, hypot(a, b) <= max radius."""
    rng = np.random.default_rng(0)
    max_radius = float(np.exp(np.log(1e-6) / (50 * 4096)))
    radii = rng.uniform(max_radius, 1.001, 200)
    angles = rng.uniform(0.01, 3.1, 200)
    blocks = [np.array([[r * np.cos(t), r * np.sin(t)], [-r * np.sin(t), r * np.cos(t)]])
              for r, t in zip(radii, angles, strict=True)]
    A = np.zeros((400, 400))
    for k, block in enumerate(blocks):
        A[2 * k:2 * k + 2, 2 * k:2 * k + 2] = block
    model = StateSpaceModel(A, np.ones((400, 1)), np.ones((1, 400)), np.zeros((1, 1)),
                            100.0, ("u",), ("y",))
    clipped = reflect_unstable_poles(model, np.full(200, 2), max_radius).A
    radius = np.hypot(clipped[0::2, 0::2].diagonal(), clipped[0::2, 1::2].diagonal())
    assert np.all(radius <= max_radius)
    # onto the circle, not further in (and a reflected one at 1 / r): the damping
    # raised only as much as needed
    expected = np.minimum(np.where(radii >= 1.0, 1.0 / radii, radii), max_radius)
    assert radius == pytest.approx(expected, rel=1e-11)


def _decay_fit():
    """Residuals of a * exp(-b t) against noise-free samples of 2 exp(-0.7 t)."""
    t = np.linspace(0.0, 5.0, 200)
    y = 2.0 * np.exp(-0.7 * t)

    def residual(x):
        return x[0] * np.exp(-x[1] * t) - y

    def normal_equations(x):
        e = np.exp(-x[1] * t)
        J = np.column_stack([e, -x[0] * t * e])
        return J.T @ J, J.T @ residual(x)
    return residual, normal_equations


def test_levenberg_marquardt_finds_a_known_minimum():
    residual, normal_equations = _decay_fit()
    costs = []
    found = levenberg_marquardt(residual, normal_equations, np.array([0.5, 3.0]), max_iterations=60,
                                tolerance=1e-2, report=lambda k, cost: costs.append(cost))
    np.testing.assert_allclose(found.x, [2.0, 0.7], rtol=1e-6)
    assert found.cost < 1e-12 and found.iterations == len(costs)
    assert costs == sorted(costs, reverse=True)      # accepted steps only lower the cost


def test_levenberg_marquardt_stops_at_the_step_limit():
    residual, normal_equations = _decay_fit()
    found = levenberg_marquardt(residual, normal_equations, np.array([0.5, 3.0]), max_iterations=2,
                                tolerance=1e-2)
    assert found.iterations == 2 and found.message == "2 steps taken"
    assert 0.5 * np.sum(residual(found.x) ** 2) == pytest.approx(found.cost)


def test_a_model_too_large_for_the_work_budget_takes_fewer_steps(records, monkeypatch):
    """Each step's normal equations cost the cube of the order (fnsi.refinement.step_work):
    beyond MAX_REFINEMENT_WORK a refinement stops after fewer steps, at least
    STALL_WINDOW, and its message says why. Here the budget is cut to one step's work."""
    import fnsi.refinement

    model = identify(records[0], _settings()).model
    full = refine(model, records[0], discard_periods=1, band_high=BAND[1])
    assert full.iterations > fnsi.refinement.STALL_WINDOW     # 7 steps measured
    monkeypatch.setattr(fnsi.refinement, "MAX_REFINEMENT_WORK", 1.0)
    cut = refine(model, records[0], discard_periods=1, band_high=BAND[1])
    assert cut.iterations == fnsi.refinement.STALL_WINDOW
    assert "the most this model's size allows" in cut.message
    assert cut.final_percent >= full.final_percent


def test_lightly_damped_modes_are_not_damped_more_by_the_refinement(chain, simulate_record):
    """Mass-proportional damping of 0.15 /s (0.2 % at the first mode, 12.2 Hz) and a
    period of 1 s: a transient decays by 1e-6 only over 92 periods. The simulator starts
    each period from the linear part's periodic state, so the refined model needs no
    such decay; bounding its poles by a decay within 50 periods clipped all three modes
    to 0.28 /s and left the refined linear model at 8 times the noise floor (3.6 %
    against 0.45 %; now 0.47 %, FNSI's own model 0.48 %)."""
    structure = chain(3, alpha=0.3, beta=0.0, extra_damper=0.0)
    record, validation = (simulate_record(structure, ["a"], noise=0.01, periods=100,
                                          period=200, seed=seed) for seed in (7, 8))
    settings = IdentificationSettings(band=BAND, order=6, discard_periods=95)
    model = identify(record, settings).model
    refinement = refine(model, record, discard_periods=95, band_high=BAND[1])
    errors = compare(refinement.model, validation, discard_periods=95, band_high=BAND[1],
                     oversampling=1).errors
    # FNSI's model fits the lines to the noise already (1.05 times the floor); refined
    # it must not lose that
    assert errors.overall_percent < 1.1 * errors.overall_noise_floor_percent
    # decay rates -ln|z| fs [1/s], identified within 3.5 % of the truth at 1 % noise
    damping = -np.log(np.abs(np.linalg.eigvals(refinement.model.A))) * record.fs
    np.testing.assert_allclose(damping, 0.15, rtol=0.05)
