"""Newmark integration against exact solutions; StructuralModel modes against closed forms."""

import numpy as np
import pytest
import scipy.linalg
from scipy.integrate import solve_ivp

from fnsi.newmark import NewmarkConvergenceError, newmark
from fnsi.nonlinear import NonlinearElement
from fnsi.structure import StructuralModel

STEPS_PER_PERIOD = 50


def sdof(freq=1.0, zeta=0.05, elements=()):
    w = 2 * np.pi * freq
    return StructuralModel(np.eye(1), 2 * zeta * w * np.eye(1), w**2 * np.eye(1), ("x",),
                           elements)


def three_dof():
    """Chain of three masses, a discrete dashpot between 1 and 2: non-proportional damping."""
    M = np.diag([1.0, 2.0, 1.5])
    K = 1000.0 * np.array([[2.0, -1.0, 0.0], [-1.0, 2.0, -1.0], [0.0, -1.0, 1.0]])
    C = 0.002 * K + np.array([[3.0, -3.0, 0.0], [-3.0, 3.0, 0.0], [0.0, 0.0, 0.0]])
    return StructuralModel(M, C, K, ("a", "b", "c"))


def harmonic_amplitude(x, samples_per_period):
    """First-harmonic amplitude of the last whole period of x (samples, channels)."""
    last = x[-samples_per_period:]
    spectrum = np.fft.rfft(last, axis=0)
    return 2 * np.abs(spectrum[1]) / samples_per_period


def steady_state(model, freq, amplitude=10.0, periods=80, dof=0):
    dt = 1 / (freq * STEPS_PER_PERIOD)
    t = np.arange(periods * STEPS_PER_PERIOD + 1) * dt
    force = np.zeros((t.size, model.n_dofs))
    force[:, dof] = amplitude * np.sin(2 * np.pi * freq * t)
    q = newmark(model, force, dt).displacement
    return harmonic_amplitude(q[1:], STEPS_PER_PERIOD), dt


def frf_amplitude(model, omega, amplitude=10.0, dof=0):
    H = np.linalg.inv(-(omega**2) * model.M + 1j * omega * model.C + model.K)
    return amplitude * np.abs(H[:, dof])


@pytest.mark.parametrize(("model", "freq"), [(sdof(), 0.4), (three_dof(), 0.6)],
                         ids=["sdof", "3dof"])
def test_linear_harmonic_steady_state_matches_analytical_amplitude(model, freq):
    amplitude, dt = steady_state(model, freq)
    omega = 2 * np.pi * freq
    # Average acceleration warps omega to (2/dt) tan(omega dt/2): +0.13 % at 50 steps per
    # period; below the first resonance this moves |H| by <= 0.05 % here, hence 0.1 %.
    np.testing.assert_allclose(amplitude, frf_amplitude(model, omega), rtol=1e-3)
    # and exactly (to the transient's e^-40 and rounding) the FRF at the warped frequency
    warped = 2 / dt * np.tan(omega * dt / 2)
    np.testing.assert_allclose(amplitude, frf_amplitude(model, warped), rtol=1e-8)


def test_resonant_forcing_follows_frequency_warping_exactly():
    # at resonance of a lightly damped mode the 50-step amplitude error is the warping's
    # (0.2-1 %); the scheme itself is exact at the warped frequency
    model = three_dof()
    freq = np.sqrt(scipy.linalg.eigh(model.K, model.M, eigvals_only=True)[0]) / (2 * np.pi)
    amplitude, dt = steady_state(model, freq, periods=200)
    omega = 2 * np.pi * freq
    warped = 2 / dt * np.tan(omega * dt / 2)
    np.testing.assert_allclose(amplitude, frf_amplitude(model, warped), rtol=1e-7)


def test_undamped_free_vibration_conserves_energy():
    model = three_dof()
    model = StructuralModel(model.M, np.zeros((3, 3)), model.K, model.dof_names)
    highest = np.sqrt(scipy.linalg.eigh(model.K, model.M, eigvals_only=True)[-1]) / (2 * np.pi)
    dt = 1 / (highest * STEPS_PER_PERIOD)
    res = newmark(model, np.zeros((1000 * STEPS_PER_PERIOD + 1, 3)), dt,
                  initial_displacement=[0.01, -0.02, 0.03], initial_velocity=[0.0, 0.1, 0.0])
    q, v = res.displacement, res.velocity
    energy = 0.5 * np.einsum("ki,ij,kj->k", v, model.M, v) + 0.5 * np.einsum(
        "ki,ij,kj->k", q, model.K, q)
    # average acceleration conserves this energy exactly; rounding drift ~ sqrt(steps) eps
    assert np.max(np.abs(energy / energy[0] - 1)) < 1e-9


def duffing_reference(omega, force, k3, periods, samples):
    """Steady state of x'' + 0.1 x' + x + k3 x^3 = force cos(omega t) by solve_ivp."""
    def rhs(t, y):
        return [y[1], force * np.cos(omega * t) - 0.1 * y[1] - y[0] - k3 * y[0] ** 3]
    t_end = periods * 2 * np.pi / omega
    t_eval = np.linspace(t_end - 2 * np.pi / omega, t_end, samples + 1)
    sol = solve_ivp(rhs, (0, t_end), [0.0, 0.0], method="DOP853", rtol=1e-11, atol=1e-12,
                    t_eval=t_eval)
    return sol.y[0]


def test_duffing_steady_state_amplitude_within_one_percent_of_solve_ivp():
    omega, force, k3, periods, n = 0.9, 0.3, 0.5, 70, 100
    cubic = NonlinearElement("polynomial", "x", exponent=3.0, coefficients=(k3,))
    model = StructuralModel(np.eye(1), 0.1 * np.eye(1), np.eye(1), ("x",), (cubic,))
    dt = 2 * np.pi / omega / n
    t = np.arange(periods * n + 1) * dt
    x = newmark(model, force * np.cos(omega * t)[:, None], dt).displacement[-n - 1:, 0]
    reference = duffing_reference(omega, force, k3, periods, n)
    amplitude, expected = np.ptp(x) / 2, np.ptp(reference) / 2
    # 1 %: Newmark's frequency warping at 100 steps per period is 0.03 %, the rest is margin
    assert amplitude == pytest.approx(expected, rel=0.01)
    # the cubic spring matters: the linear amplitude differs by far more than the tolerance
    linear = force / abs(1 - omega**2 + 0.1j * omega)
    assert abs(amplitude / linear - 1) > 0.1


def test_relative_elements_match_solve_ivp_transient():
    # two masses, cubic spring and quadratic damper between them, both to ground linearly
    cubic = NonlinearElement("polynomial", "b", "a", exponent=3.0, coefficients=(40.0,))
    drag = NonlinearElement("quadratic_damping", "b", "a", coefficients=(0.5,))
    M, K = np.diag([1.0, 0.5]), np.array([[30.0, -10.0], [-10.0, 10.0]])
    C = 0.01 * K
    model = StructuralModel(M, C, K, ("a", "b"), (cubic, drag))
    dt, n = 1e-3, 4001
    t = np.arange(n) * dt
    force = np.zeros((n, 2))
    force[:, 0] = 5 * np.sin(2 * np.pi * 1.3 * t)
    q = newmark(model, force, dt).displacement

    def rhs(time, y):
        x, v = y[1] - y[0], y[3] - y[2]
        f = 40 * x**3 + 0.5 * v * abs(v)
        p = np.array([5 * np.sin(2 * np.pi * 1.3 * time) + f, -f])
        return np.concatenate([y[2:], np.linalg.solve(M, p - C @ y[2:] - K @ y[:2])])
    ref = solve_ivp(rhs, (0, t[-1]), np.zeros(4), method="DOP853", rtol=1e-10, atol=1e-12,
                    t_eval=t).y[:2].T
    # 4 s at ~1,000 steps per period of the fastest mode: phase error ~1e-5 relative
    assert np.max(np.abs(q - ref)) < 1e-3 * np.max(np.abs(ref))


def test_clearance_response_matches_solve_ivp():
    # the dead-zone force is continuous (only its slope jumps), so a tight adaptive
    # Runge-Kutta solution is an accurate independent reference
    w, gap, mu = 2 * np.pi, 0.01, 300.0
    stop = NonlinearElement("clearance", "x", gap=gap, coefficients=(mu,))
    dt = 2e-4
    t = np.arange(20001) * dt
    x = newmark(sdof(elements=(stop,)), 2.0 * np.sin(1.3 * w * t)[:, None], dt).displacement

    def rhs(time, y):
        g = y[0] - gap if y[0] > gap else (y[0] + gap if y[0] < -gap else 0.0)
        return [y[1], 2.0 * np.sin(1.3 * w * time) - 0.1 * w * y[1] - w**2 * y[0] - mu * g]
    reference = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], method="DOP853", rtol=1e-11,
                          atol=1e-14, t_eval=t).y[0]
    assert np.max(np.abs(reference)) > 2 * gap  # deep in contact: 300 vs 39.5 stiffness
    # 4 s at 2,000 steps per period of the contact frequency (2.9 Hz): warping ~1e-6 per
    # radian, plus first-order errors where a step straddles a kink
    assert np.max(np.abs(x[:, 0] - reference)) < 1e-3 * np.max(np.abs(reference))


def test_realisations_batched_equal_one_by_one():
    stop = NonlinearElement("clearance", "x", gap=0.01, coefficients=(300.0,))
    model = sdof(elements=(stop,))
    force = np.random.default_rng(1).standard_normal((3, 2000, 1))
    batched = newmark(model, force, 1e-3)
    for k in range(3):
        single = newmark(model, force[k], 1e-3)
        np.testing.assert_array_equal(batched.displacement[k], single.displacement)
        np.testing.assert_array_equal(batched.acceleration[k], single.acceleration)


def test_progress_is_reported_and_can_cancel():
    calls = []
    newmark(sdof(), np.zeros((120_001, 1)), 1e-3, progress=lambda f, m: calls.append(f))
    assert calls[-1] == 1.0 and len(calls) >= 3 and calls == sorted(calls)

    def cancel(fraction, message):
        raise KeyboardInterrupt("cancelled")
    with pytest.raises(KeyboardInterrupt):
        newmark(sdof(), np.zeros((120_001, 1)), 1e-3, progress=cancel)


def test_newton_failure_names_time_and_element():
    # a softening cubic with no equilibrium beyond the escape amplitude: Newton must fail
    soft = NonlinearElement("polynomial", "x", exponent=3.0, coefficients=(-1e4,))
    model = sdof(elements=(soft,))
    force = np.full((2000, 1), 1e3)
    with pytest.raises(NewmarkConvergenceError, match=r"t = .* polynomial x"):
        newmark(model, force, 1e-3)


def test_bad_input_is_rejected():
    with pytest.raises(ValueError, match="force must be"):
        newmark(sdof(), np.zeros((10, 2)), 1e-3)
    with pytest.raises(ValueError, match="dt"):
        newmark(sdof(), np.zeros((10, 1)), 0.0)
    with pytest.raises(ValueError, match="stable"):
        newmark(sdof(), np.zeros((10, 1)), 1e-3, gamma=0.4)
    with pytest.raises(ValueError, match="stable"):
        newmark(sdof(), np.zeros((10, 1)), 1e-3, beta=0.2)
    with pytest.raises(ValueError, match="unknown DOF"):
        StructuralModel(np.eye(1), np.eye(1), np.eye(1), ("x",),
                        (NonlinearElement("clearance", "y", gap=1.0, coefficients=(1.0,)),))
    with pytest.raises(ValueError, match="coefficients"):
        StructuralModel(np.eye(1), np.eye(1), np.eye(1), ("x",),
                        (NonlinearElement("clearance", "x", gap=1.0),))


def test_linear_modes_of_non_proportionally_damped_model():
    model = three_dof()
    modes = model.linear_modes()
    poles = scipy.linalg.eigvals(np.block([[np.zeros((3, 3)), np.eye(3)],
                                           [-np.linalg.solve(model.M, model.K),
                                            -np.linalg.solve(model.M, model.C)]]))
    poles = np.sort_complex(poles[poles.imag > 0])
    poles = poles[np.argsort(np.abs(poles))]
    np.testing.assert_allclose(modes.frequencies, np.abs(poles) / (2 * np.pi), rtol=1e-10)
    np.testing.assert_allclose(modes.damping_ratios, -poles.real / np.abs(poles), rtol=1e-8)
    # each shape solves the quadratic eigenproblem (lambda^2 M + lambda C + K) phi = 0
    for lam, phi in zip(poles, modes.shapes, strict=True):
        residual = (lam**2 * model.M + lam * model.C + model.K) @ phi
        assert np.linalg.norm(residual) < 1e-9 * np.linalg.norm(model.K)
    assert modes.output_names == ("a", "b", "c")
    single = sdof(2.0, 0.03).linear_modes()
    assert single.frequencies[0] == pytest.approx(2.0) and single.damping_ratios[0] == (
        pytest.approx(0.03))


def test_spline_element_integrates_like_the_cubic_it_approximates():
    # natural splines (Eq. 19-22) cannot hold x^3 exactly (g'' = 0 at the end knots); the
    # least-squares spline on 24 knots follows 0.5 x^3 to 0.2 % of the peak force, and the
    # responses agree to 1e-4 of the peak displacement (1e-3 asserted)
    knots = tuple(np.linspace(-1.25, 1.25, 24))
    x = np.linspace(-1.25, 1.25, 501)
    ordinates = np.linalg.lstsq(NonlinearElement("spline", "x", knots=knots).basis(x),
                                0.5 * x**3, rcond=None)[0]
    spline = NonlinearElement("spline", "x", knots=knots, coefficients=tuple(ordinates))
    cubic = NonlinearElement("polynomial", "x", exponent=3.0, coefficients=(0.5,))
    assert np.max(np.abs(spline.force(x) - cubic.force(x))) < 2.5e-3 * 0.5 * 1.25**3
    dt = 2 * np.pi / 0.9 / 100
    force = 0.3 * np.cos(0.9 * np.arange(3001) * dt)[:, None]
    responses = [newmark(StructuralModel(np.eye(1), 0.1 * np.eye(1), np.eye(1), ("x",), (e,)),
                         force, dt).displacement for e in (spline, cubic)]
    assert np.max(np.abs(responses[0])) < 1.25
    np.testing.assert_allclose(responses[0], responses[1], atol=1e-3)
