"""Block rows i of FNSI on periodic data: the automatic count and the dimension rule.

With a periodic excitation only the N_s harmonic lines of the period carry signal (2 N_s R
real columns). Eliminating E_i (Eq. 14) removes (m + s) i of them; when that leaves fewer
than the order, the outputs keep noise only, and the settings must be refused before any
heavy work, also with all lines of a multi-period record (whose other lines hold noise).
"""

from __future__ import annotations

import json

import numpy as np
import pytest

from fnsi.identification import IdentificationSettings, check_settings, identify, reaching
from fnsi.measurement import Measurement
from fnsi.nonlinear import NonlinearElement
from fnsi.subspace import AUTO_MAX_BLOCK_ROWS, auto_block_rows, check_dimensions

# 0.5 Hz harmonics: 80 harmonic lines in [5, 45) Hz; 5 kept periods give 400 lines in all
FS, PERIOD, PERIODS, BAND = 100.0, 200, 6, (5.0, 45.0)
HARMONIC_LINES, ALL_LINES = 80, 400


@pytest.fixture(scope="module")
def periodic() -> Measurement:
    """Random periodic records; the checks under test run before any numerics."""
    rng = np.random.default_rng(0)
    u = np.tile(rng.standard_normal((PERIOD, 1)), (PERIODS, 1))
    y = np.tile(rng.standard_normal((PERIOD, 2)), (PERIODS, 1))
    return Measurement.from_arrays(u, y, FS, input_names=("f",), output_names=("a", "b"),
                                   periods=PERIODS)


def spline(intervals: int) -> NonlinearElement:
    return NonlinearElement("spline", "a", "b", intervals=intervals)


def test_auto_block_rows_use_at_most_half_the_signal_columns():
    # SmallSat multi-18: 540 harmonic lines, 18 outputs, 1 force and 8 clearances or
    # 8 splines of 8 ordinates; with a diagram to order 600 the lines bind
    assert auto_block_rows(540, 1, 9, 18, max_order=600) == 20
    assert auto_block_rows(540, 1, 65, 18, max_order=600) == 6
    assert auto_block_rows(540, 2, 9, 18, max_order=600) == 40  # each realisation adds 2 N_s
    assert auto_block_rows(540, 1, 2, 3, max_order=600) == AUTO_MAX_BLOCK_ROWS  # 108 capped
    assert auto_block_rows(10, 1, 30, 3, max_order=60) == 2


def test_auto_block_rows_give_every_order_twice_the_rows_it_needs():
    # the shift property needs l (i - 1) >= n; the count is the smallest with twice that
    # for the diagram's largest order (18 outputs, order 60: 18 x 7 = 126 >= 120)
    assert auto_block_rows(540, 1, 9, 18, max_order=60) == 8
    assert auto_block_rows(540, 1, 2, 3, max_order=60) == 41
    assert 3 * (41 - 1) >= 2 * 60 > 3 * (40 - 1)
    # an explicit order above what the lines allow raises the count to n <= l (i - 1)
    assert auto_block_rows(30, 1, 2, 1, max_order=20, order=20) == 21


def test_line_counts_and_resolved_block_rows(periodic):
    settings = IdentificationSettings(band=BAND, elements=(spline(9),))
    assert settings.block_rows == "auto"  # the default
    assert settings.line_counts(periodic) == (ALL_LINES, HARMONIC_LINES)
    excited = IdentificationSettings(band=BAND, line_set="excited")
    assert excited.line_counts(periodic) == (HARMONIC_LINES, HARMONIC_LINES)
    q = 1 + spline(9).n_basis
    assert settings.resolved(periodic).block_rows == HARMONIC_LINES // (q + 2)
    # the outputs selected count, not the measurement's
    single = IdentificationSettings(band=BAND, outputs=("a",))
    assert single.resolved(periodic).block_rows == HARMONIC_LINES // 2
    explicit = IdentificationSettings(band=BAND, block_rows=7)
    assert explicit.resolved(periodic) is explicit
    assert json.loads(json.dumps(settings.to_json()))["block_rows"] == "auto"


def test_automatic_block_rows_reach_the_order_a_search_starts_from(periodic):
    """Each basis function lowers the automatic count (80 lines, q = 9, l = 2: 7 rows,
    orders up to 12); the order a model with one element fewer needed is reached by
    raising it where the dimension rule allows, never beyond."""
    settings = IdentificationSettings(band=BAND, elements=(spline(9),))
    assert settings.resolved(periodic).block_rows == 7
    assert reaching(periodic.layout, settings, 12) is settings
    assert reaching(periodic.layout, settings, 20).block_rows == 11   # l (i - 1) = 20
    # 16 rows for order 30: q i + n = 9 x 16 + 30 > the 160 columns of the signal
    assert reaching(periodic.layout, settings, 30) is settings
    for fixed in (dict(block_rows=7), dict(order=8)):
        given = IdentificationSettings(band=BAND, elements=(spline(9),), **fixed)
        assert reaching(periodic.layout, given, 20) is given


@pytest.mark.parametrize("value", [1, 0, -3, 2.5, "10", "automatic", True, None, float("nan")])
def test_invalid_block_rows_are_refused(value):
    with pytest.raises(ValueError, match="block_rows must be an integer >= 2 or 'auto'"):
        IdentificationSettings(band=BAND, block_rows=value)


def test_integral_block_rows_are_kept_as_int():
    assert IdentificationSettings(band=BAND, block_rows=np.int64(12)).block_rows == 12
    assert type(IdentificationSettings(band=BAND, block_rows=12.0).block_rows) is int


def test_block_rows_that_remove_the_periodic_signal_are_refused_with_all_lines(periodic):
    element = spline(9)
    q = 1 + element.n_basis
    i = 2 * HARMONIC_LINES // q + 1  # (m + s) i > 2 N_s: no signal column is left
    assert (q + 2) * i < 2 * ALL_LINES  # the column count of all lines would allow it
    settings = IdentificationSettings(band=BAND, block_rows=i, order=4, elements=(element,))
    most = (2 * HARMONIC_LINES - 2 * (i - 1)) // q  # orders up to l (i - 1) are decomposed
    with pytest.raises(ValueError, match=rf"periodic signal.*block_rows <= {most} "):
        identify(periodic, settings)
    # the same count on the harmonic lines alone breaks the column count of rule 1
    with pytest.raises(ValueError, match="too many block rows for the data"):
        identify(periodic, IdentificationSettings(band=BAND, block_rows=i, order=4,
                                                  line_set="excited", elements=(element,)))


def test_order_counts_in_the_signal_rule():
    # 160 signal columns, q i = 150: an order of 10 fits, 12 does not
    check_dimensions(ALL_LINES, 1, 10, 2, 15, 10, signal_lines=HARMONIC_LINES)
    with pytest.raises(ValueError, match="largest order decomposed, 12"):
        check_dimensions(ALL_LINES, 1, 10, 2, 15, 12, signal_lines=HARMONIC_LINES)
    # without signal lines every line counts (the rule before periodic data was known)
    check_dimensions(ALL_LINES, 1, 10, 2, 15, 12)


def test_basis_count_beyond_the_signal_suggests_no_block_rows():
    with pytest.raises(ValueError, match="use fewer basis functions, a lower max_order"):
        check_dimensions(ALL_LINES, 1, 90, 2, 2, 2, signal_lines=HARMONIC_LINES)


def test_a_layout_is_checked_like_its_measurement(periodic):
    # what a service holding only a dataset's summary can refuse before loading the data
    layout = periodic.layout
    assert (layout.n_samples, layout.n_inputs, layout.n_outputs) == (
        periodic.n_samples, periodic.n_inputs, periodic.n_outputs)
    settings = IdentificationSettings(band=BAND, elements=(spline(9),))
    assert check_settings(layout, settings) == check_settings(periodic, settings)
    assert check_settings(layout, settings).block_rows == settings.resolved(periodic).block_rows
    refused = IdentificationSettings(band=BAND, block_rows=2 * HARMONIC_LINES, order=4,
                                     elements=(spline(9),))
    for record in (layout, periodic):
        with pytest.raises(ValueError, match="too many block rows"):
            check_settings(record, refused)
        with pytest.raises(ValueError, match="unknown output channel 'c'; outputs are"):
            check_settings(record, IdentificationSettings(band=BAND, outputs=("a", "c")))
