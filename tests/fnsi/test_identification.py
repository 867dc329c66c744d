"""FNSI end to end on structures simulated with known parameters (paper Section IV)."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from fnsi.identification import IdentificationSettings, extended_spectra, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.stiffness import curve_error_percent

# Records: fs = 800 Hz, 20 s periods, 6 periods (1 discarded), excitation 3-45 Hz. The
# sampling rate is ~18 times the band edge so that the basis functions of non-smooth
# elements (kinks) alias little (the paper samples at 50 times the band edge); Newmark at
# 3.2 kHz keeps its period error below 0.03 % up to 30 Hz.
RECORD = dict(fs=800.0, period=16000, periods=6, oversample=4, band=(3.0, 45.0))
BAND = (3.0, 45.0)
BLOCK_ROWS = 8


def unknown(element: NonlinearElement) -> NonlinearElement:
    """The element as given to the identification: form known, coefficients unknown."""
    return dataclasses.replace(element, coefficients=None)


def relative_error(estimate, truth) -> np.ndarray:
    return np.asarray(estimate) / np.asarray(truth) - 1.0


@pytest.fixture(scope="session")
def cubic(chain, simulate_record):
    """3-DOF chain, cubic spring from DOF a to ground, 1 % output noise."""
    element = NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(1e9,))
    model = chain(3, (element,))
    return model, element, simulate_record(model, ["a"], rms=70.0, noise=0.01, **RECORD)


@pytest.fixture(scope="session")
def clearance(chain, simulate_record):
    """Wheel-like 3-DOF system: clearance (dead zone) between DOFs a and b, 1 % noise."""
    element = NonlinearElement("clearance", "a", "b", gap=3e-3, coefficients=(2e4,))
    model = chain(3, (element,), mass=(1.0, 2.0, 2.0), couplings=(3e3, 2e4),
                  grounds=(0.0, 0.0, 3e4), alpha=3.0)
    return model, element, simulate_record(model, ["a"], rms=30.0, noise=0.01, **RECORD)


@pytest.mark.parametrize("case", ["cubic", "clearance"])
def test_strong_nonlinearity_modes_and_coefficient(case, request):
    model, element, data = request.getfixturevalue(case)
    truth = model.linear_modes()
    linear = identify(data, IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                                   max_order=12))
    # the excitation is strong: a purely linear identification sees the first
    # resonance moved by at least 20 %
    assert relative_error(linear.modal.frequencies[0], truth.frequencies[0]) >= 0.20
    result = identify(data, IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                                   max_order=12, elements=(unknown(element),)))
    assert result.modal.n_modes == 3
    # 0.2 % and 3 %: the acceptance targets; with 1 % noise the scatter over noise seeds
    # is about 0.1 % (frequency) and 1.5 % (damping)
    np.testing.assert_array_less(np.abs(relative_error(result.modal.frequencies,
                                                       truth.frequencies)), 0.002)
    np.testing.assert_array_less(np.abs(relative_error(result.modal.damping_ratios,
                                                       truth.damping_ratios)), 0.03)
    (mu,) = result.coefficients
    assert mu.method == "driving point"
    # 1 %: acceptance target (observed scatter over seeds about 0.5 %)
    assert abs(relative_error(mu.mean_real, element.coefficients[0])) < 0.01
    assert mu.log10_real_imag >= 2.0


def test_excited_line_set_gives_the_same_coefficient(cubic):
    _, element, data = cubic
    result = identify(data, IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                                   line_set="excited",
                                                   elements=(unknown(element),)))
    assert result.coefficients[0].frequencies.size == 840  # 20 s periods over 3-45 Hz
    # 1 %: acceptance target, as with all lines
    assert abs(relative_error(result.coefficients[0].mean_real, 1e9)) < 0.01


def test_spline_with_automatic_knots_reconstructs_clearance(clearance):
    _, element, data = clearance
    spline = NonlinearElement("spline", "a", "b", intervals=14)
    result = identify(data, IdentificationSettings(band=BAND, block_rows=6, order=6,
                                                   max_order=8, elements=(spline,)))
    (curve,) = result.stiffness
    assert len(curve.element.knots) == 15
    assert curve.x[0] < -0.012 and curve.x[-1] > 0.013  # the measured range
    # 5 % RMS of the peak force: acceptance target (observed 1.3 %). The modes are not
    # asserted: with a spline that only approximates the clearance, the misfit biases
    # the underlying linear FRF (known gap, see the identification notes)
    assert curve_error_percent(curve, element) < 5.0


@pytest.fixture(scope="session")
def mimo(chain, simulate_record):
    """4-DOF chain, forces at a and c, cubic a-ground and clearance c-d."""
    elements = (NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(5e8,)),
                NonlinearElement("clearance", "c", "d", gap=2e-3, coefficients=(1e4,)))
    model = chain(4, elements)
    return model, elements, simulate_record(model, ["a", "c"], rms=50.0, noise=0.01, **RECORD)


def test_mimo_two_elements(mimo):
    model, elements, data = mimo
    truth = model.linear_modes()
    result = identify(data, IdentificationSettings(
        band=BAND, block_rows=BLOCK_ROWS, order=8, max_order=16,
        elements=tuple(unknown(e) for e in elements)))
    np.testing.assert_array_less(np.abs(relative_error(result.modal.frequencies,
                                                       truth.frequencies)), 0.002)
    for mu, element in zip(result.coefficients, elements, strict=True):
        # 2 %: acceptance target for the MIMO case
        assert abs(relative_error(mu.mean_real, element.coefficients[0])) < 0.02, mu.name


@pytest.fixture(scope="session")
def remote_force(chain, simulate_record):
    """Cubic spring at DOF a, force at DOF c (paper IV.C situation)."""
    element = NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(1e9,))
    model = chain(3, (element,))
    return model, element, simulate_record(model, ["c"], rms=90.0, noise=0.01, **RECORD)


def test_coefficient_with_force_away_from_element(remote_force):
    _, element, data = remote_force
    result = identify(data, IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                                   max_order=12, elements=(unknown(element),)))
    (mu,) = result.coefficients
    assert mu.method == "reciprocity"
    # 2 %: acceptance target for the synthesised FRF columns
    assert abs(relative_error(mu.mean_real, element.coefficients[0])) < 0.02


def test_coefficient_refused_without_driving_point(remote_force):
    _, element, data = remote_force
    result = identify(data, IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                                   max_order=12, outputs=("a", "b"),
                                                   elements=(unknown(element),)))
    (mu,) = result.coefficients
    assert not mu.identifiable and mu.values is None
    assert "driving point" in mu.reason
    assert np.isnan(mu.mean_real)
    assert result.stiffness == ()


def test_auto_order_progress_and_json(cubic):
    _, element, data = cubic
    calls = []
    result = identify(data, IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS,
                                                   max_order=16, elements=(unknown(element),)),
                      progress=lambda fraction, message: calls.append(fraction))
    assert result.order == 6
    assert result.stabilisation is not None and result.stabilisation.auto_order == 6
    assert calls == sorted(calls) and calls[-1] == 1.0
    assert set(result.timings) >= {"decomposition", "stabilisation", "model", "physical"}
    payload = json.loads(json.dumps(result.to_json()))
    assert payload["order"] == 6 and len(payload["modes"]) == 3
    # the automatic order keeps the confirmed modes only
    assert all(mode["confirmed"] is True for mode in payload["modes"])
    assert payload["coefficients"][0]["method"] == "driving point"
    assert payload["stabilisation"]["confirmation"] == 1


def test_explicit_order_keeps_every_pole_flagged(cubic):
    _, element, data = cubic
    # automatic block rows: 12, twice the rows order 16 needs (with i = 8, l (i - 1) = 21
    # barely holds order 16, and the 12.2 Hz mode drifts in damping from 3.1 to 3.9 %)
    settings = IdentificationSettings(band=BAND, order=12, max_order=16,
                                      elements=(unknown(element),))
    result = identify(data, settings)
    assert result.settings.block_rows == 12
    modal = result.modal
    assert modal.confirmed is not None and modal.confirmed.shape == (modal.n_modes,)
    # the three modes of the chain are confirmed; the extra poles of order 12 are listed
    # but not confirmed, so the user sees what the automatic choice would drop
    assert np.sum(modal.confirmed) == 3 and modal.n_modes > 3
    assert [m["confirmed"] for m in result.to_json()["modes"]] == modal.confirmed.tolist()
    # no verdict for an order outside the diagram, or at its top (nothing above it)
    for order, max_order in ((7, 16), (16, 16)):
        beyond = identify(data, dataclasses.replace(settings, order=order, max_order=max_order))
        assert beyond.modal.confirmed is None
        assert beyond.to_json()["modes"][0]["confirmed"] is None


def test_an_unsimulated_model_is_the_simulated_one_without_its_motion_offsets(cubic):
    # simulated=False skips only the simulation of the estimation record (the model
    # simulates here, so no repair): the estimate itself is the same, to the last bit
    _, element, data = cubic
    settings = IdentificationSettings(band=BAND, order=6, max_order=6,
                                      elements=(unknown(element),))
    simulated = identify(data, settings).model
    unsimulated = identify(data, settings, simulated=False).model
    for name in ("A", "B", "C", "D"):
        np.testing.assert_array_equal(getattr(unsimulated, name), getattr(simulated, name))
    assert simulated.motion_offsets is not None and unsimulated.motion_offsets is None


def test_coefficient_weights_follow_the_basis_power(cubic):
    _, element, data = cubic
    settings = IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                      elements=(unknown(element),))
    result = identify(data, settings)
    (mu,) = result.coefficients
    # element to ground: H b_j is the whole driving-point column, weight P_j ||H b_j||^2
    spectra, _, _ = extended_spectra(data, result.settings)
    power = np.mean(np.abs(spectra.inputs[:, :, 1]) ** 2, axis=0)
    column = result.model.frequency_response(spectra.frequencies)[:, :, 0]
    np.testing.assert_allclose(mu.weights, power * np.sum(np.abs(column) ** 2, axis=1),
                               rtol=1e-10)
    normalised = mu.weights / mu.weights.sum()
    assert mu.mean_real == pytest.approx(np.sum(normalised * mu.values.real))


def test_elements_without_a_driving_point_give_one_warning_saying_how(cubic):
    _, element, data = cubic
    renamed = dataclasses.replace(data, input_names=("shaker",))
    settings = IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                      elements=(unknown(element),), uncertainty=False)
    result = identify(renamed, settings)
    assert not result.coefficients[0].identifiable
    (warning,) = result.warnings
    assert warning.startswith("no driving point found by name (input 'shaker' names no "
                              "output)") and "--driving-point INPUT,OUTPUT" in warning
    given = identify(renamed, dataclasses.replace(settings, driving_points=(("shaker", "a"),)))
    assert given.warnings == () and given.coefficients[0].identifiable
    linear = identify(renamed, dataclasses.replace(settings, elements=()))
    assert linear.warnings == ()          # no coefficient to scale, nothing to say


def test_progress_can_cancel(cubic):
    def cancel(fraction, message):
        raise RuntimeError("cancelled")

    with pytest.raises(RuntimeError, match="cancelled"):
        identify(cubic[2], IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6),
                 progress=cancel)


@pytest.mark.parametrize(("change", "message"), [
    (dict(band=(3.0, 500.0)), "Nyquist"),
    (dict(block_rows=3000), "too many block rows"),
    (dict(order=40), "too large"),
    (dict(elements=(NonlinearElement("clearance", "a", "z", gap=1e-3),)), "unknown output"),
    (dict(outputs=("a", "q")), "unknown output channel"),
    (dict(discard_periods=6), "leaves no period"),
    (dict(memory_limit_mb=1.0), "MiB"),
])
def test_bad_settings_are_refused_with_the_reason(cubic, change, message):
    settings = dict(band=BAND, block_rows=BLOCK_ROWS, order=6) | change
    with pytest.raises(ValueError, match=message):
        identify(cubic[2], IdentificationSettings(**settings))


def test_weighting_needs_two_kept_periods(cubic):
    with pytest.raises(ValueError, match="two kept periods"):
        identify(cubic[2], IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6,
                                                  weighting=True, discard_periods=5))


def test_automatic_weighting_follows_the_measured_quantity(cubic):
    """Integrated velocity or acceleration noise is coloured as 1 / f^p: weighted when
    the order is chosen by simulation; white displacement noise, one kept period (no
    noise estimate) or the modal order rule: unweighted."""
    record = cubic[2]
    settings = IdentificationSettings(band=BAND, order_rule="simulation")
    assert settings.weighting == "auto"
    assert settings.weighted(record).weighting is False
    for quantity in ("velocity", "acceleration"):
        velocity = dataclasses.replace(record, quantity=quantity)
        assert settings.weighted(velocity).weighting is True
        one_period = dataclasses.replace(settings, discard_periods=record.periods - 1)
        assert one_period.weighted(velocity).weighting is False
        modal = dataclasses.replace(settings, order_rule="modes")
        assert modal.weighted(velocity).weighting is False
    result = identify(record, dataclasses.replace(settings, block_rows=BLOCK_ROWS, order=6))
    assert result.settings.weighting is False     # what was used, not "auto"
    with pytest.raises(ValueError, match="'auto'"):
        IdentificationSettings(band=BAND, weighting="yes")


def test_non_increasing_knots_are_refused():
    with pytest.raises(ValueError, match="increasing"):
        NonlinearElement("spline", "a", knots=(-1.0, 1.0, 0.5))


def test_basis_noise_bias_is_compensated(chain, simulate_record):
    # 20 % output noise and bases evaluated on the raw (not period-averaged) displacement:
    # the noise of the basis attenuates the coefficient (errors in variables)
    element = NonlinearElement("polynomial", "a", exponent=3.0, coefficients=(1e9,))
    data = simulate_record(chain(3, (element,)), ["a"], rms=70.0, noise=0.2, **RECORD)
    for block_rows in (BLOCK_ROWS, 12):
        errors = {}
        for compensate in (False, True):
            result = identify(data, IdentificationSettings(
                band=BAND, block_rows=block_rows, order=6, elements=(unknown(element),),
                average_bases=False, compensate_basis_noise=compensate))
            errors[compensate] = relative_error(result.coefficients[0].mean_real,
                                                element.coefficients[0])
        # observed -26 % plain and -15 % compensated at i = 8, -31 % and -7 % at i = 12;
        # the rest is the subspace stage's share of the bias (A and C from noisy E_i),
        # which the compensated least squares of B and D cannot remove
        assert errors[False] < -0.2
        assert abs(errors[True]) < 0.6 * abs(errors[False])


def test_identification_reports_a_spline_that_repeats_a_cubic(cubic):
    """A cubic and a spline at the same connection: the spline's central interval is a
    cubic, so the two share a force the data cannot split (a user adding a flexible law
    beside a known one); the cubic alone is separable."""
    _, element, data = cubic
    settings = IdentificationSettings(band=BAND, block_rows=BLOCK_ROWS, order=6, max_order=8,
                                      elements=(unknown(element),))
    alone = identify(data, settings)
    assert len(alone.separability) == 1 and not alone.separability[0].confounded
    both = identify(data, IdentificationSettings(
        band=BAND, block_rows=BLOCK_ROWS, order=6, max_order=8,
        elements=(settings.elements[0], NonlinearElement("spline", "a", intervals=5))))
    cubic_part, spline_part = both.separability
    assert cubic_part.confounded and cubic_part.partners[0] == spline_part.name
    assert spline_part.confounded and cubic_part.name in spline_part.partners
    document = json.loads(json.dumps(both.to_json()))
    assert document["separability"][0]["confounded"] is True


def test_smallsat_identification_is_fixed_by_the_data_not_by_rounding(single):
    """Single-39 of the paper (band 2 % of fs): with the powers z^p in the data matrices
    (i = 50) a perturbation of a few units in the last place moved the coefficient error
    between -0.07 and -0.26 % and the order between 6 and 10 (benchmarks/paper.py,
    *Rounding*); with the defaults (orthonormal band basis, automatic block rows and
    order) the result must not move."""
    measurement, truth = single
    clearance = next(e for e in truth.elements if e.dof == "NC2w_Z")
    settings = IdentificationSettings(band=(5.0, 50.0), discard_periods=2,
                                      elements=(unknown(clearance),))
    noise = np.random.default_rng(0).standard_normal(measurement.y.shape)
    perturbed = dataclasses.replace(measurement, y=measurement.y * (1 + 1e-13 * noise))
    results = [identify(m, settings) for m in (measurement, perturbed)]
    assert results[0].order == results[1].order
    mu = [r.coefficients[0].mean_real for r in results]
    assert mu[1] == pytest.approx(mu[0], rel=1e-6)  # observed 1e-10
    # observed -0.20 % (order 6, i = 5); over 20 noise realisations the paper's
    # estimate scattered by 0.30 % (benchmarks/paper.py)
    assert mu[0] == pytest.approx(clearance.coefficients[0], rel=0.01)
    # the three modes carrying 12, 44 and 44 % of the response, within the
    # paper-reproduction targets (20 realisations: within 0.07 % and 0.7 %)
    modes = results[0].modal
    assert modes.n_modes == 3
    for f, zeta in zip(modes.frequencies, modes.damping_ratios, strict=True):
        k = np.argmin(np.abs(truth.modal.frequencies - f))
        assert f == pytest.approx(truth.modal.frequencies[k], rel=0.002)
        assert zeta == pytest.approx(truth.modal.damping_ratios[k], rel=0.03)




def test_a_band_between_the_modes_is_refused_with_what_to_change(chain, simulate_record):
    # modes at 12.18, 22.51 and 29.41 Hz (chain_model): 14-20 Hz holds only their tails,
    # which the diagram confirms as poles carrying no share of the measured response
    data = simulate_record(chain(3), ["a"], noise=0.005, band=(3.0, 45.0))
    with pytest.raises(ValueError, match="no order holds a mode in the band") as error:
        identify(data, IdentificationSettings(band=(14.0, 20.0)))
    assert "widen the band" in str(error.value)
    # the same record in a band holding the three modes gives them
    result = identify(data, IdentificationSettings(band=(5.0, 40.0)))
    np.testing.assert_allclose(np.sort(result.modal.frequencies), [12.18, 22.51, 29.41],
                               rtol=5e-3)  # 0.5 % noise on a 4-period record
