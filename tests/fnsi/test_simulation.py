"""Simulation of identified nonlinear state-space models against independent references."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy import optimize, signal

from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.simulation import (
    NoSteadyStateError,
    SimulationDivergedError,
    modal_coordinates,
    simulate,
    simulate_periodic,
)
from fnsi.statespace import StateSpaceModel
from fnsi.subspace import SubspaceDecomposition, decompose

FS = 1000.0
OMEGA = 2 * np.pi * 5.0      # SDOF natural frequency [rad/s], unit mass
ZETA = 0.02
K3 = 1e5                     # cubic stiffness [N/m^3]
CUBIC = NonlinearElement("polynomial", "q", exponent=3.0)


def _sdof(nonlinear_column: float, d_input: float = 0.0, d_basis: float = 0.0,
          elements: tuple = (CUBIC,), zeta: float = ZETA) -> StateSpaceModel:
    """Zero-order-hold discretisation of q'' + 2 zeta w q' + w^2 q + mu g = u (Eq. 3-5)."""
    Ac = np.array([[0.0, 1.0], [-OMEGA**2, -2 * zeta * OMEGA]])
    Be = np.array([[0.0, 0.0], [1.0, -nonlinear_column]])   # B_c^nl = -mu M^-1 b (Eq. 4)
    A, B, C, _, _ = signal.cont2discrete((Ac, Be, np.array([[1.0, 0.0]]), np.zeros((1, 2))),
                                         1 / FS)
    return StateSpaceModel(A=A, B=B, C=C, D=np.array([[d_input, d_basis]]), fs=FS,
                           input_names=("u",), output_names=("q",), elements=elements)


def _continuous_reference(acceleration, u: np.ndarray, substeps: int = 10) -> np.ndarray:
    """Displacement of q'' = acceleration(q, q', u) under the zero-order-held input u.

    Classical Runge-Kutta with ``substeps`` steps per sample: the input is constant within
    a sample, so the integrand is smooth there and the error, O((omega h)^4) ~ 1e-10 for
    h = 1e-4 s, is negligible against what the tests compare.
    """
    h = 1.0 / (FS * substeps)
    q = v = 0.0
    out = np.empty(u.size)
    for k, uk in enumerate(u.tolist()):
        out[k] = q
        for _ in range(substeps):
            a1 = acceleration(q, v, uk)
            a2 = acceleration(q + 0.5 * h * v, v + 0.5 * h * a1, uk)
            a3 = acceleration(q + 0.5 * h * (v + 0.5 * h * a1), v + 0.5 * h * a2, uk)
            a4 = acceleration(q + h * (v + 0.5 * h * a2), v + h * a3, uk)
            q, v = (q + h * (v + h * (a1 + a2 + a3) / 6.0),
                    v + h * (a1 + 2.0 * a2 + 2.0 * a3 + a4) / 6.0)
    return out


@pytest.fixture(scope="module")
def force():
    """Random input giving a peak displacement near 0.06 m (cubic force ~ 25 % of linear)."""
    u = np.random.default_rng(0).normal(size=3000)
    return u * 0.06 / np.max(np.abs(simulate(_sdof(0.0, elements=(CUBIC,)), u)))


def test_modal_coordinates_hold_the_poles_and_refuse_a_defective_matrix():
    rng = np.random.default_rng(3)
    A = 0.5 * rng.normal(size=(6, 6)) / np.sqrt(6)
    blocks, basis = modal_coordinates(A)
    # a similarity: the same poles, A recovered to rounding (condition number < 1e6)
    np.testing.assert_allclose(basis @ blocks @ np.linalg.inv(basis), A, atol=1e-12)
    assert np.count_nonzero(np.triu(blocks, 2) + np.tril(blocks, -2)) == 0
    # a Jordan block has one eigenvector for two poles: no modal basis
    assert modal_coordinates(np.array([[0.5, 1.0], [0.0, 0.5]])) is None


def test_linear_model_equals_scipy_dlsim():
    rng = np.random.default_rng(1)
    sys = signal.cont2discrete(
        (np.array([[0, 0, 1, 0], [0, 0, 0, 1], [-400, 100, -1, 0], [100, -900, 0, -2.0]]),
         rng.normal(size=(4, 2)), rng.normal(size=(3, 4)), np.zeros((3, 2))), 1 / FS)
    A, B, C = sys[:3]
    D = 1e-2 * rng.normal(size=(3, 2))
    model = StateSpaceModel(A, B, C, D, FS, ("u1", "u2"), ("y1", "y2", "y3"))
    u = rng.normal(size=(2000, 2))
    _, expected, _ = signal.dlsim((A, B, C, D, 1 / FS), u)
    # same recursion, different code and coordinates (modal, condition number 30): the
    # rounding of 2000 steps of a lightly damped system (measured 1.2e-12 of the peak)
    np.testing.assert_allclose(simulate(model, u), expected, rtol=0, atol=1e-11 * np.abs(
        expected).max())


def test_implicit_feedthrough_matches_a_newton_reference(force):
    # D^e_nl of the physical sign (residual flexibility: the cubic spring pushes back),
    # |D g| ~ 3 % of the output
    d_basis = -10.0
    model = _sdof(K3, d_input=1e-4, d_basis=d_basis)
    # independent reference: plain recursion with each output equation
    # q = C x + D_u u + D_nl q^3 solved by scipy's Newton iteration
    x = np.zeros(2)
    expected = np.empty_like(force)
    for k, uk in enumerate(force):
        linear = model.C[0] @ x + model.D[0, 0] * uk
        q = optimize.newton(lambda q, lin=linear: q - lin - d_basis * q**3, linear, tol=1e-14)
        expected[k] = q
        x = model.A @ x + model.B[:, 0] * uk + model.B[:, 1] * q**3
    assert np.max(np.abs(expected - simulate(_sdof(0.0), force)[:, 0])) > 0.01  # nonlinear
    # both solve the same equations to 1e-10 relative or better
    np.testing.assert_allclose(simulate(model, force)[:, 0], expected, rtol=0,
                               atol=1e-9 * np.abs(expected).max())


def test_explicit_feedthrough_matches_its_recursion(force):
    d_basis = 10.0
    model = _sdof(K3, d_input=1e-4, d_basis=d_basis)
    # the documented explicit step: bases on y_hat = C x + D_u u, then y = y_hat + D_nl g
    x = np.zeros(2)
    expected = np.empty_like(force)
    for k, uk in enumerate(force):
        y_hat = model.C[0] @ x + model.D[0, 0] * uk
        expected[k] = y_hat + d_basis * y_hat**3
        x = model.A @ x + model.B[:, 0] * uk + model.B[:, 1] * y_hat**3
    # same arithmetic in another order: rounding only
    np.testing.assert_allclose(simulate(model, force, feedthrough="explicit")[:, 0], expected,
                               rtol=0, atol=1e-12 * np.abs(expected).max())


def test_cubic_stiffness_matches_the_continuous_duffing_ode(force):
    y = simulate(_sdof(K3), force)[:, 0]
    exact = _continuous_reference(
        lambda q, v, u: u - OMEGA**2 * q - 2 * ZETA * OMEGA * v - K3 * q**3, force)
    linear = simulate(_sdof(0.0), force)[:, 0]
    assert np.max(np.abs(linear - exact)) > 0.1 * np.max(np.abs(exact))   # strong effect
    # the discrete model holds the cubic force over each sample (Eq. 8): a first-order
    # error in dt that accumulates as phase drift, 3.8 %, 1.9 %, 0.9 % of the peak at 1, 2,
    # 4 kHz over these 3 s; 6 % bounds it, while ignoring the cubic force costs > 10 %
    assert np.max(np.abs(y - exact)) < 0.06 * np.max(np.abs(exact))


def test_quadratic_damping_matches_the_continuous_ode():
    c2 = 40.0   # quadratic damping [N s^2/m^2]: dominates the 2 % viscous damping here
    damper = NonlinearElement("quadratic_damping", "q")
    model = _sdof(c2, elements=(damper,))
    t = np.arange(3000) / FS
    u = 20 * np.sin(2 * np.pi * 5.0 * t) * np.minimum(t, 1.0)
    y = simulate(model, u)[:, 0]
    exact = _continuous_reference(
        lambda q, v, f: f - OMEGA**2 * q - 2 * ZETA * OMEGA * v - c2 * v * abs(v), u)
    linear = simulate(_sdof(0.0, elements=(damper,)), u)[:, 0]
    assert np.max(np.abs(linear - exact)) > 0.3 * np.max(np.abs(exact))   # strong effect
    # the discrete model holds the damping force over each sample (a dt / 2 delay, Eq. 8),
    # a first-order error in dt: 1.42 %, 0.71 %, 0.35 % of the peak at 1, 2, 4 kHz for
    # this resonant drive; 2.5 % leaves margin, a sign or scale error in v gives > 30 %
    assert np.max(np.abs(y - exact)) < 0.025 * np.max(np.abs(exact))


def test_periodic_steady_state_equals_the_frequency_domain_solution():
    model = _sdof(0.0, d_input=1e-4, elements=())
    model = StateSpaceModel(model.A, model.B[:, :1], model.C, model.D[:, :1], FS, ("u",),
                            ("q",))
    n = 500
    u = np.random.default_rng(2).normal(size=n)
    response = simulate_periodic(model, u, periods=2, tolerance=1e-12)
    z = np.exp(2j * np.pi * np.fft.rfftfreq(n))
    H = np.array([(model.C @ np.linalg.solve(zk * np.eye(2) - model.A, model.B))[0, 0]
                  for zk in z]) + model.D[0, 0]
    expected = np.fft.irfft(H * np.fft.rfft(u), n)
    # the transient left after the 1e-12 criterion is far below 1e-9 of the response
    np.testing.assert_allclose(response.y[:, 0], np.tile(expected, 2), rtol=0,
                               atol=1e-9 * np.abs(expected).max())
    assert response.steady_state_change <= 1e-12
    assert response.periods_run > 2


def _light_sdof(zeta: float, mu: float, elements: tuple) -> StateSpaceModel:
    """Zero-order-hold SDOF at 5 Hz with damping ratio ``zeta`` and basis column ``mu``."""
    Ac = np.array([[0.0, 1.0], [-OMEGA**2, -2 * zeta * OMEGA]])
    Be = np.array([[0.0, 0.0], [1.0, -mu]])[:, :1 + len(elements)]
    A, B, C, _, _ = signal.cont2discrete((Ac, Be, np.array([[1.0, 0.0]]),
                                          np.zeros((1, Be.shape[1]))), 1 / FS)
    return StateSpaceModel(A=A, B=B, C=C, D=np.zeros((1, B.shape[1])), fs=FS,
                           input_names=("u",), output_names=("q",), elements=elements)


def test_a_lightly_damped_linear_model_is_periodic_without_ringing_down():
    # 0.05 % damping at 5 Hz, 0.5 s periods: the transient falls by exp(-2 pi zeta f T),
    # 0.8 % per period, so marching to a 1e-10 change would take about 2900 periods
    model = _light_sdof(5e-4, 0.0, ())
    n = 500
    u = np.random.default_rng(3).normal(size=n)
    response = simulate_periodic(model, u, periods=1, tolerance=1e-10)
    z = np.exp(2j * np.pi * np.fft.rfftfreq(n))
    H = np.array([(model.C @ np.linalg.solve(zk * np.eye(2) - model.A, model.B))[0, 0]
                  for zk in z])
    expected = np.fft.irfft(H * np.fft.rfft(u), n)
    # one period from rest, one from the periodic state, one to see it repeat
    assert response.periods_run == 3
    # the periodic state solves (I - A^N) x = s with cond ~ 1 / (1 - 0.992): rounding only
    np.testing.assert_allclose(response.y[:, 0], expected, rtol=0,
                               atol=1e-9 * np.abs(expected).max())


def test_a_duffing_started_from_the_linear_periodic_state_reaches_the_marched_one(force):
    # the start only moves the first periods: the steady state is the one marching from
    # rest reaches (2 % damping at 5 Hz, 0.5 s periods: 0.73 of a transient left per
    # period, 1e-8 after 60)
    model = _sdof(K3)
    u = 2.0 * force[:500]   # peak 0.035 m: the cubic force changes the response by 13 %
    response = simulate_periodic(model, u, tolerance=1e-10)
    marched = simulate(model, np.tile(u, 100))[-500:, 0]
    linear = simulate(_sdof(0.0), np.tile(u, 100))[-500:, 0]
    assert np.max(np.abs(linear - marched)) > 0.05 * np.max(np.abs(marched))
    np.testing.assert_allclose(response.y[:, 0], marched, rtol=0,
                               atol=1e-7 * np.abs(marched).max())


def test_repeated_corrections_reach_the_same_steady_state_in_fewer_periods(force):
    # each correction moves the state to the linear part's periodic state under the
    # forces of the period just run: a fixed-point step whose rate is the cubic force's
    # share of the response (13 %), against the 0.73 a period of marching
    model = _sdof(K3)
    u = 2.0 * force[:500]
    marched = simulate_periodic(model, u, tolerance=1e-10)
    corrected = simulate_periodic(model, u, tolerance=1e-10, corrections=30)
    assert corrected.periods_run <= marched.periods_run / 3, (corrected.periods_run,
                                                              marched.periods_run)
    np.testing.assert_allclose(corrected.y, marched.y, rtol=0,
                               atol=1e-7 * np.abs(marched.y).max())


def test_corrections_that_do_not_settle_give_way_to_marching():
    # 10 % damping: a period of marching leaves exp(-2 pi 0.1 5 0.5) = 0.21 of a
    # transient, while the fixed-point steps for a cubic force this strong hardly
    # contract (changes 0.45, 0.12, 0.11, 0.11, 0.10, 0.085): the corrected periods are
    # judged unable to reach 1e-10 in the periods left, and the marched steady state is
    # returned instead (the same run, so the same numbers)
    u0 = np.random.default_rng(0).normal(size=3000)
    u = 2.0 * (u0 * 0.06 / np.max(np.abs(simulate(_sdof(0.0, zeta=0.1), u0))))[:500]
    model = _sdof(K3, zeta=0.1)
    marched = simulate_periodic(model, u, tolerance=1e-10)
    corrected = simulate_periodic(model, u, tolerance=1e-10, corrections=30)
    assert corrected.periods_run == marched.periods_run
    np.testing.assert_allclose(corrected.y, marched.y, rtol=0, atol=0)


def test_corrections_stop_on_a_periodic_solution_the_dynamics_leave(force):
    # a softening cubic that escapes in the fourth period when marched from rest: the
    # corrections move the state towards a periodic solution (it escapes a period later),
    # but the steady state is declared only on periods run freely from it, so the
    # simulation fails as it does without them
    model = _sdof(-2 * K3)
    u = 2.0 * force[:500]
    with pytest.raises(SimulationDivergedError):
        simulate_periodic(model, u)
    with pytest.raises(SimulationDivergedError):
        simulate_periodic(model, u, corrections=30)


# a lightly damped Duffing marched from rest rings down by exp(-2 pi zeta f T) a period
# (5 Hz, T = 0.5 s); the tolerance is 1e-6 and 100 periods are allowed


def test_a_response_too_slow_to_settle_is_given_up_early(force):
    # at zeta = 0.008 the change would need ~150 periods to fall from about 0.3 to the
    # tolerance, and its decay over the first periods tells so (all 100 ran before,
    # ending at 7e-6)
    with pytest.raises(NoSteadyStateError, match=r"in 100 periods \(after 12,"):
        simulate_periodic(_sdof(K3, zeta=0.008), 2.0 * force[:500], max_periods=100)


def test_a_response_slow_but_able_to_settle_is_not_given_up(force):
    # at zeta = 0.012 it settles in 75 periods, as it did before the early verdict
    response = simulate_periodic(_sdof(K3, zeta=0.012), 2.0 * force[:500], max_periods=100)
    assert response.periods_run == 75


def test_divergence_is_detected_and_explained(force):
    unstable = _sdof(0.0, elements=())
    unstable = StateSpaceModel(1.01 * unstable.A, unstable.B[:, :1], unstable.C,
                               unstable.D[:, :1], FS, ("u",), ("q",))
    with pytest.raises(SimulationDivergedError, match="unstable"):
        simulate(unstable, force)
    softening = _sdof(-K3)     # negative cubic stiffness: escapes its potential well
    with pytest.raises(SimulationDivergedError, match="diverged at t ="):
        simulate(softening, 3 * force)
    # D^e_nl of the softening sign: q = q_hat + 1e4 q^3 has no root near q_hat once
    # |q_hat| > 2 / (3 sqrt(3e4)) = 3.8 mm, which this input reaches
    folding = _sdof(K3, d_basis=1e4)
    with pytest.raises(SimulationDivergedError, match="has no solution"):
        simulate(folding, force)
    simulate(folding, force, feedthrough="explicit")     # first order: no fold
    with pytest.raises(ValueError, match="feedthrough must be one of"):
        simulate(folding, force, feedthrough="ignore")


def test_inconsistent_models_and_inputs_are_rejected(force):
    stray = NonlinearElement("polynomial", "elsewhere", exponent=3.0)
    with pytest.raises(ValueError, match="not an output"):
        simulate(_sdof(K3, elements=(stray,)), force)
    with pytest.raises(ValueError, match="basis functions"):
        simulate(_sdof(K3, elements=(CUBIC, CUBIC)), force)
    with pytest.raises(ValueError, match=r"u must be \(samples, 1\)"):
        simulate(_sdof(K3), np.ones((10, 2)))


def test_identified_model_reproduces_the_measurement_near_the_noise_floor():
    """End to end: Newmark truth -> FNSI model -> simulation -> errors (docs/design.md
    section 3, step 7)."""
    from fnsi.acquisition import acquire
    from fnsi.errors import model_errors
    from fnsi.excitation import Excitation, periodic_noise
    from fnsi.identification import IdentificationSettings, identify
    from fnsi.structure import StructuralModel

    cubic = NonlinearElement("polynomial", "x2", "x3", exponent=3.0)
    structure = StructuralModel(
        np.diag([1.0, 1.0, 0.5]),
        np.diag([20.0, 10.0, 5.0]),
        np.array([[2e4, -1e4, 0], [-1e4, 2e4, -1e4], [0, -1e4, 1e4]]),
        ("x1", "x2", "x3"),
        (NonlinearElement("polynomial", "x2", "x3", exponent=3.0, coefficients=(2e9,)),),
    )
    fs, n = 500.0, 2000
    excitation = Excitation.along(periodic_noise(n, fs, (3.0, 60.0), rms=20.0, seed=1), fs,
                                  {"x1": 1.0}, name="F")
    measurement, _ = acquire(structure, excitation, fs=fs, fs_int=8000.0, periods=8,
                             noise_percent=0.5, discard_periods=3)
    u = measurement.u[0, -n:]
    measured = measurement.y[0, 3 * n:]
    nrmse = {}
    for label, elements, order in (("nonlinear", (cubic,), "auto"), ("linear", (), 6)):
        settings = IdentificationSettings(
            inputs=None, outputs=None, band=(3.0, 60.0), block_rows=20, order=order,
            max_order=20, line_set="all", discard_periods=3, elements=elements,
            weighting=False)
        result = identify(measurement, settings)
        if order == "auto":   # three modes in the band: the stabilisation diagram picks 6
            assert result.order == 6
        simulated = simulate_periodic(result.model, u).y
        errors = model_errors(measured, simulated, fs, periods=5)
        nrmse[label] = errors.nrmse_percent
    # cubic force ~20 % of the linear one: a linear model misses it by ~10-20 %; the FNSI
    # model comes within 0.4-0.7 % (floor 0.25 %: left are the O(dt) hold of g and the
    # noise in the measured bases); 1.5 % and a tenfold gain bound both with margin
    assert np.all(nrmse["nonlinear"] < 1.5)
    assert np.all(nrmse["nonlinear"] < nrmse["linear"] / 10)


def _smallsat_true_decomposition(data, stop: NonlinearElement, band: tuple[float, float],
                                 max_order: int, basis: str) -> SubspaceDecomposition:
    """FNSI decomposition of the true extended FRF of SmallSat (models up to ``max_order``).

    H^e = [H_w, -mu (H_w - H_b)] with H_w, H_b the receptance columns (K - w^2 M + j w C)^-1
    of forces at the stop's two nodes (Eq. 17), on 0.5 Hz lines in ``band``, times a
    random extended input: the data FNSI would see without noise or sampling effects.
    """
    from fnsi.smallsat import smallsat_model
    from fnsi.spectra import Spectra

    structure = smallsat_model()
    rows = [structure.dof_index(name) for name in data.output_names]
    ends = [structure.dof_index(stop.dof), structure.dof_index(stop.ref)]
    frequencies = np.arange(band[0], band[1], 0.5)
    H = np.empty((frequencies.size, len(rows), 2), dtype=complex)
    for k, w in enumerate(2 * np.pi * frequencies):
        dynamic = structure.K - w**2 * structure.M + 1j * w * structure.C
        columns = np.linalg.solve(dynamic, np.eye(structure.n_dofs)[:, ends])[rows]
        H[k] = np.column_stack((columns[:, 0], -stop.coefficients[0] * (columns[:, 0]
                                                                         - columns[:, 1])))
    rng = np.random.default_rng(0)
    E = rng.normal(size=(2, frequencies.size, 2)) + 1j * rng.normal(size=(2, frequencies.size, 2))
    spectra = Spectra(frequencies, data.fs, E, np.einsum("klq,rkq->rkl", H, E),
                      (*data.input_names, stop.name), data.output_names)
    element = NonlinearElement("clearance", stop.dof, stop.ref, gap=stop.gap)
    return decompose(spectra, block_rows=20, max_order=max_order, n_inputs=1,
                     elements=(element,), basis=basis)


def test_stiff_smallsat_contact_simulates_to_the_floor_with_its_out_of_band_dynamics():
    """SmallSat single (Section IV.A): the implicit feed-through handles the stiff NC2-Z stop.

    The stop (slope 100) is about ten times stiffer than the structure between its nodes
    (static relative flexibility 0.107), and the contact force excites modes beyond the
    band: 55 Hz, and heavily damped WEMS modes at 75 Hz (71 %) and 157 Hz (43 %). A model
    holding those modes (order 24 on 5-150 Hz) reproduces the Newmark record to the noise
    floor, so the simulation is not what limits identified models; a model of the in-band
    modes only (order 8, fitted to the same truth in 5-50 Hz) lumps them into D^e and
    misses the contact path to NC2b_Z by ~10 %, which the stiff loop turns into errors of
    several hundred times the floor.

    The order-24 model is fitted in the paper's powers basis (``basis="powers"``): this
    exact response is no discrete-time model of order 24, and the truncation in the
    orthonormal basis keeps a real pole at 1.3 kHz whose contact loop diverges (the two
    bases weigh the lines differently where no exact model exists). The in-band response
    holds the out-of-band modes only through singular values below 1e-4 of the largest
    (issue 7), which the noise of any record hides.
    """
    from fnsi.smallsat import simulate_preset
    from fnsi.validation import compare

    data, truth = simulate_preset("single", periods=4, samples_per_period=7500,
                                  outputs=("NC2w_Z", "NC2b_Z", "W_Z"), seed=2)
    stop = next(e for e in truth.elements if (e.dof, e.ref) == ("NC2w_Z", "NC2b_Z"))
    wide = _smallsat_true_decomposition(data, stop, (5.0, 150.0), 24, "powers")
    in_band = _smallsat_true_decomposition(data, stop, (5.0, 50.0), 8, "orthonormal")
    models = {24: wide.model(24), 8: in_band.model(8)}
    errors = {order: compare(model, data, discard_periods=1, band_high=50.0).errors
              for order, model in models.items()}
    floor = errors[8].noise_floor_percent
    # observed 1.0-1.13 x the floor over seeds of the random input and block rows 20-30;
    # 1.5 x leaves room for the noise of one realisation
    assert np.all(errors[24].nrmse_percent < 1.5 * floor)
    # observed 240-410 x the floor here (25-35 x on 5 s periods): in-band modes alone
    # cannot meet issue 7's 3 x
    assert np.all(errors[8].nrmse_percent > 10 * floor)


STOP_GAP = 0.01              # m, a positive-side stop at about a third of the peak motion


def _stop_model(gap: float, **fields) -> StateSpaceModel:
    """The SDOF with a one-sided stop as stiff as its spring (unit mass)."""
    stop = NonlinearElement("clearance", "q", gap_positive=gap, side="positive")
    return dataclasses.replace(_sdof(OMEGA**2, elements=(stop,)), **fields)


def test_motion_offsets_shift_the_motion_the_elements_see(force):
    # a positive-side stop at gap g seeing q + o engages where one at g - o sees q
    u = force[:1000]
    shifted = simulate(_stop_model(STOP_GAP, motion_offsets=np.array([0.004])), u)
    moved = simulate(_stop_model(STOP_GAP - 0.004), u)
    assert np.max(np.abs(shifted)) > 1.5 * STOP_GAP     # the stop is engaged
    np.testing.assert_allclose(shifted, moved, rtol=0, atol=1e-12 * np.abs(moved).max())


def test_the_output_mean_is_what_the_elements_see_and_the_offsets_keep_it(force):
    # the stop pushes the motion to a negative mean by itself (15 % of its RMS); asked
    # for mean 0, the elements see the motion shifted to it, and a model given the
    # offsets found reproduces that steady state without being told the mean
    u = force[:500]
    steady = {"tolerance": 1e-9, "corrections": 30}
    own = simulate_periodic(_stop_model(STOP_GAP), u, **steady)
    assert own.motion[:, 0].mean() < -0.05 * own.motion[:, 0].std()
    centred = simulate_periodic(_stop_model(STOP_GAP), u, output_mean=np.zeros(1), **steady)
    assert abs(centred.motion[:, 0].mean()) < 1e-6 * centred.motion[:, 0].std()
    assert centred.motion_offsets[0] > 0.0
    frozen = simulate_periodic(_stop_model(STOP_GAP, motion_offsets=centred.motion_offsets),
                               u, output_mean=np.full(1, 1.0), **steady)  # ignored
    np.testing.assert_allclose(frozen.y, centred.y, rtol=0,
                               atol=1e-7 * np.abs(centred.y).max())


def test_a_steep_friction_law_that_pushes_back_is_solved_at_every_step(chain, simulate_record):
    """Coulomb friction regularised over 0.1 mm/s between c and b of a 3-DOF chain, band
    10-33 Hz at 200 Hz: FNSI's order-6 model has the pushing-back feed-through, 40 times
    the law's slope, where Newton's full step cycles from the first sample (as on arctan
    from afar); halved until the residual falls, it converges, so the model simulates
    and refines (measured 12.7 % -> 1.87 % on the estimation record, floor 0.57 %) with
    no repair of its feed-through."""
    width = 1e-4
    structure = chain(3, (NonlinearElement("coulomb_friction", "c", "b", width=width,
                                           coefficients=(0.3,)),))
    record = simulate_record(structure, ["a"], noise=0.01, periods=4, seed=3,
                             band=(10.0, 33.0))
    friction = NonlinearElement("coulomb_friction", "c", "b", width=width)
    result = identify(record, IdentificationSettings(
        band=(10.0, 33.0), order=6, discard_periods=1, elements=(friction,), refine=True,
        uncertainty=False))
    refinement = result.refinement
    assert refinement.iterations >= 1, refinement.summary
    assert refinement.final_percent < 0.2 * refinement.initial_percent
    assert not any("feed-through held at zero" in w for w in result.warnings)
