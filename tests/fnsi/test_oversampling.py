"""Non-smooth elements at a finer internal rate, against Newmark truth sampled at 5 times
the band edge."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.oversampling import (
    finer_model,
    oversampled_bases,
    oversampling_factor,
    rate_multiple,
    simulate_oversampled,
)
from fnsi.refinement import refine
from fnsi.simulation import simulate_periodic
from fnsi.statespace import StateSpaceModel
from fnsi.validation import compare

FS = 250.0                  # 5 times the band edge
BAND = (3.0, 50.0)
PERIOD = 500                # 2 s: 0.5 Hz lines
TRUE_ELEMENTS = {
    # a stop from d to ground, gap about the RMS displacement there, 3 times a chain spring
    "stop": NonlinearElement("clearance", "d", gap=1e-3, coefficients=(3e4,)),
    # friction between a and b, 8 N against a 20 N RMS input, sliding above 0.03 m/s
    "friction": NonlinearElement("coulomb_friction", "a", "b", width=0.03,
                                 coefficients=(8.0,)),
}


@pytest.fixture(scope="module", params=sorted(TRUE_ELEMENTS))
def identified(request, chain, simulate_record):
    """A 4-DOF chain with a stop or friction: Newmark at 20 kHz sampled at 250 Hz, 0.5 %
    output noise; FNSI with the true element (kind, place, gap or width) on 8 periods,
    a second realisation of 4 periods to validate on."""
    true = TRUE_ELEMENTS[request.param]
    structure = chain(4, (true,))
    records = [simulate_record(structure, ["a"], fs=FS, period=PERIOD, periods=periods,
                               band=BAND, rms=20.0, noise=0.005, seed=seed, oversample=80)
               for periods, seed in ((8, 1), (4, 101))]
    given = NonlinearElement.from_json({k: v for k, v in true.to_json().items()
                                        if k != "coefficients"})
    # i = 8: the automatic i (15, the most the 94 lines allow) adds an estimation error of
    # FNSI's own at this noise density (all channels 1.8-1.9 x the floor with the stop
    # whatever the simulation), which is not what this test is about
    result = identify(records[0], IdentificationSettings(band=BAND, order=8, block_rows=8,
                                                         elements=(given,)))
    return request.param, result, records[1], records[0]


def test_true_element_validates_within_one_and_a_half_noise_floors(identified):
    """Issue 20's acceptance: a stop and friction at fs = 5 x the band edge."""
    kind, result, validation, _ = identified
    errors = compare(result.model, validation, discard_periods=1, band_high=BAND[1]).errors
    at_fs = compare(result.model, validation, discard_periods=1, band_high=BAND[1],
                    oversampling=1).errors
    ratio = errors.nrmse_percent / errors.noise_floor_percent
    ratio_at_fs = at_fs.nrmse_percent / at_fs.noise_floor_percent
    # 1.5 x (the figure): an exact model sits at 1 x the floor, and errors add in
    # quadrature, so 1.5 x admits a model error of 1.1 floors. Per channel on this seed:
    # stop 1.04-1.41, friction 1.29-1.44 (the same under every BLAS kernel and thread
    # count). Over seeds 1-8 of both records the stop stays within 0.87-1.47, friction
    # spans 1.21-2.06: with noise-free estimation data it keeps 1.3-1.6 on seeds 2-3,
    # whatever the internal rate beyond 40 x the band edge, so what remains there is
    # FNSI's (its bases come from motion cut at fs / 2), not the simulation
    assert np.all(ratio < 1.5), (kind, ratio)
    # the same model simulated at fs, one force per sample: this seed stop 4.2-7.5,
    # friction 6.4-7.1; over seeds 1-8 2.0-7.6 (stop) and 4.5-10.2 (friction)
    assert np.all(ratio_at_fs > 3.0), (kind, ratio_at_fs)


def test_finer_model_keeps_the_poles_and_the_band_response(identified):
    _, result, _, _ = identified
    model = result.model
    lines = np.arange(101) * FS / PERIOD                 # the simulated lines to 50 Hz
    fine = finer_model(model, 4, lines)
    poles = np.sort_complex(np.log(np.linalg.eigvals(model.A).astype(complex)) * FS)
    fine_poles = np.sort_complex(np.log(np.linalg.eigvals(fine.A).astype(complex)) * 4 * FS)
    np.testing.assert_allclose(fine_poles, poles, rtol=1e-9)
    # the fit leaves 1.4e-4 of each column's peak on the stop's model (the response of
    # the images at multiples of fs, which no model at 4 fs holds)
    H, H_fine = model.frequency_response(lines), fine.frequency_response(lines)
    assert np.all(np.abs(H_fine - H).max(axis=0) < 1e-3 * np.abs(H).max(axis=0))


def test_oversampled_bases_converge_to_the_fourier_series_of_the_force(chain):
    """A stop on a band-limited motion: its force's DFT lines at fs fold the harmonics
    above fs / 2 back (3.9 % of the force on the band's lines); evaluated at 4 and 16
    times fs they miss 0.25 % and 0.013 %, the kinks' 1 / factor^2."""
    from tests.fnsi.conftest import multisine

    x = multisine(1, PERIOD, FS, BAND, 1.0, np.random.default_rng(0))[None]
    stop = NonlinearElement("clearance", "x", gap=1.0)
    exact = np.fft.rfft(oversampled_bases((stop,), x, None, 256)[0, :, 0])
    band = slice(6, 101)

    def error(factor):
        g = np.fft.rfft(oversampled_bases((stop,), x, None, factor)[0, :, 0])
        return np.linalg.norm((g - exact)[band]) / np.linalg.norm(exact[band])

    assert error(1) > 0.02
    assert error(4) < 0.004 and error(16) < 3e-4


def test_oversampling_factor_follows_the_elements_and_the_rates():
    stop = NonlinearElement("clearance", "a", gap=1.0)
    cubic = NonlinearElement("polynomial", "a", exponent=3.0)
    friction = NonlinearElement("coulomb_friction", "a", width=0.1)
    assert oversampling_factor((), 250.0, 50.0) == 1                # linear
    assert oversampling_factor((stop,), 250.0, 50.0) == 4           # 20 x the band edge
    assert oversampling_factor((cubic, friction), 250.0, 50.0) == 4
    assert oversampling_factor((cubic,), 200.0, 45.0) == 2          # 3rd harmonic < fs/2
    assert oversampling_factor((cubic,), 500.0, 60.0) == 1
    assert oversampling_factor((stop,), 2500.0, 50.0) == 1          # SmallSat: unchanged
    assert oversampling_factor((stop,), 10.0, 4.9) == 10


def test_linear_model_is_simulated_at_its_rate(identified):
    _, result, validation, _ = identified
    linear = StateSpaceModel(result.model.A, result.model.B[:, :1], result.model.C,
                                    result.model.D[:, :1], FS, result.model.input_names,
                                    result.model.output_names)
    u = validation.u[:, -PERIOD:]
    np.testing.assert_array_equal(simulate_oversampled(linear, u, BAND[1])[0],
                                  simulate_periodic(linear, u[0]).y[None])


def test_a_model_at_a_multiple_of_the_rate_is_simulated_at_its_own(identified):
    """The finer model of the oversampled simulation, given as the model itself (as a
    refined one is kept), simulates the record exactly as the oversampled path does."""
    _, result, validation, _ = identified
    model = result.model
    u = validation.u[:, -PERIOD:]
    lines = np.arange(101) * FS / PERIOD                 # the lines the path matches: 50 Hz
    fine = finer_model(model, 4, lines)
    np.testing.assert_array_equal(simulate_oversampled(fine, u, BAND[1], fs=FS)[0],
                                  simulate_oversampled(model, u, BAND[1])[0])
    assert rate_multiple(fine, FS) == 4 and rate_multiple(model, FS) == 1
    with pytest.raises(ValueError, match="not a whole multiple"):
        rate_multiple(fine, 1.5 * FS)


def test_refinement_at_the_internal_rate_stays_within_the_floor(identified):
    """Refined through the simulation it is judged by (4 times fs, the rate of
    non-smooth elements at 5 times the band edge), the model keeps FNSI's accuracy on
    another realisation; refined at fs it learnt the per-sample simulation's errors and
    validated at 5-10 times the floor (this chain, :mod:`fnsi.oversampling`)."""
    kind, result, validation, estimation = identified
    refined = refine(result.model, estimation, discard_periods=1, band_high=BAND[1])
    assert refined.model.fs == 4 * FS
    assert refined.final_percent <= refined.initial_percent
    errors = compare(refined.model, validation, discard_periods=1, band_high=BAND[1],
                     oversampling=1).errors
    ratio = errors.nrmse_percent / errors.noise_floor_percent
    # 1.3 x: a model error of 0.8 floors, below the 1.1 floors FNSI's own model is
    # allowed above (stop 1.04-1.41, friction 1.29-1.44 on this seed); refined here the
    # channels come to 1.05-1.17 (stop) and 1.01-1.05 (friction)
    assert np.all(ratio < 1.3), (kind, ratio)
