"""The automatic order of a nonlinear model by simulation, and the band with its harmonics,
against Newmark truth: a chain driven below its second mode whose cubic spring drives
the three modes above the band through its harmonics."""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg

from fnsi.identification import IdentificationSettings, identify
from fnsi.measurement import Measurement
from fnsi.nonlinear import NonlinearElement
from fnsi.simulation_order import (
    _lowest_within,
    _search_near,
    allowed_square,
    consistent_order,
    pooled_error,
    simulation_order,
    unseen_directions,
)
from fnsi.validation import compare_identified

BAND = (3.0, 16.0)          # the first mode (9.84 Hz) only; the others at 18.7-30.3 Hz
K3 = 3e8                    # cubic spring at a [N/m^3]: the linear model misses by 15 %
CUBIC = NonlinearElement("polynomial", "a", exponent=3.0)


@pytest.fixture(scope="module")
def records(chain, simulate_record):
    """Estimation and validation records (two realisations of a 10 N RMS multisine at d,
    0.5 % output noise, fs 200 Hz, 5 s periods) and the chain's natural frequencies."""
    model = chain(4, (NonlinearElement("polynomial", "a", exponent=3.0,
                                       coefficients=(K3,)),))
    eigenvalues = scipy.linalg.eigvalsh(model.K, model.M)
    natural = np.sqrt(eigenvalues) / (2 * np.pi)
    return [simulate_record(model, ["d"], fs=200.0, period=1000, periods=4, band=BAND,
                            rms=10.0, noise=0.005, seed=seed) for seed in (1, 2)], natural


def _validation(result, validation) -> tuple[float, float]:
    return pooled_error(compare_identified(result, validation).errors)


def test_the_band_with_its_harmonics_identifies_the_modes_the_forces_drive(records):
    (estimation, validation), natural = records
    by_modes = identify(estimation, IdentificationSettings(band=BAND, elements=(CUBIC,),
                                                           uncertainty=False))
    wide = identify(estimation, IdentificationSettings(
        band=BAND, elements=(CUBIC,), uncertainty=False, order_rule="simulation",
        harmonic_band=True))
    error, floor = _validation(wide, validation)
    # measured: 0.21 % for a 0.29 % floor (the floor is that of the period average's
    # noise, which one validation record estimates to about 30 %: 1.3 x is that margin)
    assert error < 1.3 * floor, (error, floor)
    # the modal order of the band alone keeps its one mode: 7.5 %, 26 times the floor
    assert _validation(by_modes, validation)[0] > 10 * floor
    # the model holds the three modes above the band, seen through the spring's
    # harmonics only (their frequencies within 1 %), and reports the band's mode alone
    poles = np.abs(np.log(np.linalg.eigvals(wide.model.A))) * wide.model.fs / (2 * np.pi)
    for f in natural[1:]:
        assert np.min(np.abs(poles - f)) < 0.01 * f, (f, np.sort(poles))
    np.testing.assert_allclose(wide.modal.frequencies, natural[:1], rtol=2e-3)
    assert wide.coefficients[0].mean_real == pytest.approx(K3, rel=0.01)


def test_the_lines_under_the_band_identify_the_mode_the_distortion_drives_there(
        chain, simulate_record):
    """Driven above its first mode (9.84 Hz), the chain's cubic spring drives that mode
    at the difference frequencies f_i + f_j - f_k of the band's lines; a model fitted on
    the band and its harmonics alone cannot hold it (measured before the lines under the
    band were fitted: order 30 at 3.7 times the floor, its coefficient 1000 times too
    small)."""
    band, k3 = (13.0, 40.0), 1e9       # the linear model misses by 27 %
    model = chain(4, (NonlinearElement("polynomial", "a", exponent=3.0,
                                       coefficients=(k3,)),))
    natural = np.sqrt(scipy.linalg.eigvalsh(model.K, model.M)) / (2 * np.pi)
    estimation, validation = (
        simulate_record(model, ["d"], fs=200.0, period=1000, periods=4, band=band,
                        rms=10.0, noise=0.005, seed=seed) for seed in (1, 2))
    result = identify(estimation, IdentificationSettings(
        band=band, elements=(CUBIC,), uncertainty=False, order_rule="simulation",
        harmonic_band=True))
    error, floor = _validation(result, validation)
    # measured 1.03 times the floor; 1.3 x: the floor's own uncertainty (see above)
    assert error < 1.3 * floor, (error, floor)
    # the four modes and no other state; the coefficient within 1 % (measured 0.14 %)
    assert result.order == 8
    poles = np.abs(np.log(np.linalg.eigvals(result.model.A))) * result.model.fs / (2 * np.pi)
    np.testing.assert_allclose(np.sort(poles)[::2], natural, rtol=1e-3)
    assert result.coefficients[0].mean_real == pytest.approx(k3, rel=0.01)


def test_the_simulation_rule_records_why_and_picks_the_lowest_order_near_the_best(records):
    (estimation, _), _ = records
    result = identify(estimation, IdentificationSettings(
        band=BAND, elements=(CUBIC,), uncertainty=False, order_rule="simulation",
        harmonic_band=True))
    search = result.simulation_order
    assert search.order == result.order
    finite = {k: v for k, v in search.errors.items() if math.isfinite(v)}
    best, floor = min(finite.values()), search.noise_floor_percent
    lower = [k for k, v in finite.items() if k < result.order]
    allowed = allowed_square(best, floor)
    assert search.errors[result.order] ** 2 <= allowed
    assert all(finite[k] ** 2 > allowed for k in lower)
    # four modes, eight states: the lowest order that holds them all; order 8 sits at
    # the rule's edge (0.210-0.211 % against an allowed 0.2106 % for a 0.2008 % floor)
    # and order 10 validates closer to the floor (0.204 against 0.220 %, floor 0.203 %):
    # either is right, no higher one is
    assert result.order in (8, 10)
    json = result.to_json()["simulation_order"]
    assert json["order"] == result.order and str(result.order) in json["errors_percent"]
    # searched near another order, the search lands on the same choice
    near = identify(estimation, IdentificationSettings(
        band=BAND, elements=(CUBIC,), uncertainty=False, order_rule="simulation",
        harmonic_band=True), order_near=result.order + 6)
    assert near.order == result.order
    assert len(near.simulation_order.errors) < len(search.errors)


def test_lowest_order_within_the_tolerance_above_the_floor():
    # excess above a floor of 1: order 6 is 1.08 times the best's (order 10), 4 is 1.24 times
    errors = {2: 9.0, 4: 2.3, 6: math.sqrt(1.1 + 1.08**2 * 3), 8: math.inf, 10: 2.0}
    assert _lowest_within(errors, 1.0) == 6
    assert _lowest_within({2: math.inf}, 1.0) is None
    # near the floor every order within the floor's own uncertainty is as good
    assert _lowest_within({2: 1.04, 4: 0.98}, 1.0) == 2
    assert _lowest_within({2: 1.06, 4: 0.98}, 1.0) == 4


def test_the_order_rule_is_checked():
    with pytest.raises(ValueError, match="order_rule must be one of"):
        IdentificationSettings(band=BAND, order_rule="best")


def test_a_lower_local_minimum_of_the_sparse_search_is_searched_around():
    """Every fourth order far from the expected one: a dip between two of them (noisy
    bases make the curve rough) is found from the local minimum next to it."""
    orders = list(range(2, 62, 2))
    # the 5-DOF chain's curve of the docstring: order 10 at 1.97 %, 12 at 1.19 %, the
    # best of the sparse search 28 at 1.47 %
    curve = {o: 3.0 for o in orders} | {10: 1.97, 12: 1.19, 26: 1.70, 28: 1.47, 30: 3.47}
    errors: dict[int, float] = {}
    _search_near(orders, 34, errors, lambda order: errors.setdefault(order, curve[order]))
    assert 12 in errors and _lowest_within(errors, 0.9) == 12
    # a local minimum far above the best is not worth the simulations
    curve[10], curve[12] = 3.5, 3.2
    errors.clear()
    _search_near(orders, 34, errors, lambda order: errors.setdefault(order, curve[order]))
    assert 12 not in errors


def test_an_order_whose_model_diverges_is_searched_with_its_repair(records):
    """A model that diverges, implicitly and explicitly, counts with its repaired model
    (fnsi.feedthrough) when one is given, and the search says which orders needed it."""
    (estimation, _), _ = records
    good = identify(estimation, IdentificationSettings(
        band=BAND, elements=(CUBIC,), order=8, uncertainty=False, harmonic_band=True)).model
    # a feed-through of the softening sign, 1e5 / 3 times what folds the implicit step at
    # the largest motion, and the spring's force on the states turned softening and 100
    # times stronger: the explicit step escapes too (with the feed-through alone, the
    # explicit step of the model fitted under the band as well stayed bounded, at 63 %)
    peak = np.abs(estimation.y[..., estimation.output_names.index("a")]).max()
    D, B = good.D.copy(), good.B.copy()
    D[good.output_names.index("a"), good.n_inputs] = 1e5 / (3 * peak**2)
    B[:, good.n_inputs] *= -100.0
    broken = dataclasses.replace(good, D=D, B=B)
    search = dict(discard_periods=1, band_high=BAND[1])
    assert simulation_order([8], lambda order: broken, estimation, **search) is None
    repaired = simulation_order([8], lambda order: broken, estimation, **search,
                                repaired_at=lambda order: good)
    assert repaired.order == 8 and repaired.repaired == (8,) and repaired.chosen_repaired
    assert math.isfinite(repaired.errors[8])
    assert repaired.to_json()["repaired_orders"] == [8]


def _two_shaker_record(realisations: int) -> Measurement:
    """Two inputs driven by ``realisations`` random-phase multisines on lines 5-40 of a
    256-sample period (fs 256 Hz, 3 periods); the outputs do not matter here."""
    rng = np.random.default_rng(7)
    spectrum = np.zeros((realisations, 129, 2), dtype=complex)
    spectrum[:, 5:41] = np.exp(2j * np.pi * rng.random((realisations, 36, 2)))
    u = np.tile(np.fft.irfft(spectrum, n=256, axis=1), (1, 3, 1))
    return Measurement.from_arrays(u, u[:, :, :1], 256.0, periods=3)


def test_one_realisation_of_two_inputs_leaves_one_direction_unseen_on_every_line():
    """An FRF row change d is seen through d u_k only: its unseen part d P is invisible
    (d P u_k = 0 to rounding), P is an orthogonal projector of rank 2 - 1 on each of the
    band's 36 excited lines, and two realisations see every direction."""
    record = _two_shaker_record(1)
    unseen = unseen_directions(record, (4.5, 41.0), 1)
    P = unseen.projectors
    assert unseen.frequencies.tolist() == list(np.arange(5.0, 41.0))
    np.testing.assert_allclose(np.einsum("kaa->k", P).real, 1.0, atol=1e-12)
    np.testing.assert_allclose(P @ P, P, atol=1e-12)
    np.testing.assert_allclose(P, np.conj(np.swapaxes(P, 1, 2)), atol=1e-12)
    U = np.fft.rfft(record.u[0, :256], axis=0)[5:41]                   # (K, 2)
    d = np.random.default_rng(1).standard_normal((36, 2)) * (1 + 1j)
    np.testing.assert_allclose(np.einsum("ka,kab,kb->k", d, P, U), 0.0, atol=1e-10)
    assert np.abs(np.einsum("ka,kb->k", d, U)).min() > 1e-3             # d itself is seen
    assert unseen_directions(_two_shaker_record(2), (4.5, 41.0), 1) is None


class _FRF:
    """A stand-in model of two inputs and three outputs with a given FRF on the lines."""

    n_inputs = 2

    def __init__(self, response: np.ndarray) -> None:
        self.response = response

    def frequency_response(self, frequencies: np.ndarray) -> np.ndarray:
        return self.response


@pytest.mark.parametrize("direction", ["unseen", "seen"])
def test_an_order_whose_frf_departs_where_the_record_does_not_see_is_passed_over(direction):
    """Four orders fit the record alike; the lowest one's FRF departs from the others'
    by 30 % of the FRF, they from each other by 1 % (seed 30 case 14 of the hidden
    benchmark: 14.6 times the least departure against 1.0-1.9). In the unseen direction
    the record cannot have chosen it for its FRF: it is passed over. In the seen
    direction its fit would show the departure, so it stays the lowest order."""
    unseen = unseen_directions(_two_shaker_record(1), (4.5, 41.0), 1)
    rng = np.random.default_rng(3)

    def noise(scale: float) -> np.ndarray:
        return scale * (rng.standard_normal((36, 3, 2)) + 1j * rng.standard_normal((36, 3, 2)))

    common, departure = noise(1.0), noise(0.3)
    hidden = departure @ unseen.projectors
    departure = hidden if direction == "unseen" else departure - hidden
    models = {4: _FRF(common + departure),
              **{order: _FRF(common + noise(0.01)) for order in (6, 8, 10)}}
    chosen, passed = consistent_order([4, 6, 8, 10], models.__getitem__, unseen)
    assert (chosen, passed) == ((6, (4,)) if direction == "unseen" else (4, ()))
    # fewer than three orders: none can stand out
    assert consistent_order([4, 6], models.__getitem__, unseen) == (4, ())


def test_orders_alike_to_rounding_do_not_make_the_others_outliers():
    """Four of five orders give the same FRF to rounding (an extra state that nothing
    excites): their departure, the median of their distances to the others, is at the
    level of rounding, and twice it would pass over the lowest order, which departs by
    1e-10 of the FRF: no difference an identification can resolve. The least departure
    is bounded below by sqrt(eps) of the FRF, so the lowest order is kept; one that
    departs by 1 % is still passed over."""
    unseen = unseen_directions(_two_shaker_record(1), (4.5, 41.0), 1)
    rng = np.random.default_rng(4)

    def frf(scale: float) -> np.ndarray:
        return scale * (rng.standard_normal((36, 3, 2)) + 1j * rng.standard_normal((36, 3, 2)))

    common = frf(1.0)
    alike = {order: _FRF(common + frf(1e-15)) for order in (6, 8, 10, 12)}
    for departure, expected in ((1e-10, (4, ())), (1e-2, (6, (4,)))):
        models = {4: _FRF(common + frf(departure) @ unseen.projectors), **alike}
        assert consistent_order([4, 6, 8, 10, 12], models.__getitem__, unseen) == expected
