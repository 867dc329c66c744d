"""Screening with the poles identified again at each location (issue 21).

Truth: a 5-DOF grounded chain (unit masses, 10 kN/m springs, modes 16-34 Hz) driven at x1
by periodic noise in 5-60 Hz, with a hardening cubic spring between x3 and x4 strong
enough to move the resonances, simulated by the project's Newmark integrator with 0.5 %
output noise.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from fnsi.acquisition import acquire
from fnsi.excitation import Excitation, periodic_noise
from fnsi.identification import IdentificationSettings, identify
from fnsi.nonlinear import NonlinearElement
from fnsi.reidentified_screening import held_part, reidentified_scores
from fnsi.screening import ScreeningProblem
from fnsi.structure import StructuralModel

NAMES = ("x1", "x2", "x3", "x4", "x5")
FS, PERIOD, BAND = 1000.0, 2500, (5.0, 60.0)
SETTINGS = IdentificationSettings(band=BAND, block_rows=15, order=10, max_order=20,
                                  discard_periods=1)
TRUE = ("x3", "x4")


def generic(dof: str, ref: str | None) -> tuple[NonlinearElement, ...]:
    return (NonlinearElement("polynomial", dof, ref, exponent=2.0, signed=False),
            NonlinearElement("polynomial", dof, ref, exponent=3.0),
            NonlinearElement("quadratic_damping", dof, ref))


@pytest.fixture(scope="module")
def case():
    k = 1e4 * (np.diag([3.0, 3.0, 3.0, 3.0, 2.0]) - np.eye(5, k=1) - np.eye(5, k=-1))
    cubic = NonlinearElement("polynomial", *TRUE, exponent=3.0, coefficients=(5e8,))
    structure = StructuralModel(np.eye(5), 2e-4 * k + np.eye(5), k, NAMES, (cubic,))
    signal = periodic_noise(PERIOD, FS, BAND, 20.0, seed=1)
    data, _ = acquire(structure, Excitation.at_dof(signal, FS, "x1"), fs=FS, fs_int=4 * FS,
                      periods=4, quantity="displacement", noise_percent=0.5,
                      discard_periods=1, seed=101)
    linear = identify(data, SETTINGS).model
    return data, ScreeningProblem(data, linear, BAND, SETTINGS.discard_periods), linear


def test_the_true_location_ranks_first_and_its_model_leaves_only_noise(case):
    data, problem, linear = case
    places = [(name, None) for name in NAMES] + [
        (a, b) for i, a in enumerate(NAMES) for b in NAMES[i + 1:]]
    scores = reidentified_scores(data, SETTINGS, 10, problem,
                                 [(place, generic(*place)) for place in places])
    assert scores[0].key == TRUE
    # The cost is the noise-weighted squared residual summed over lines, channels and
    # realisations: about 1 per term for a model that leaves only noise (0.5 % noise;
    # the band's lines fitted by 10 states and 4 columns of B^e absorb a little of it),
    # far more for the linear model, which misses the cubic spring's response.
    terms = problem.lines.size * len(NAMES) * data.n_realisations
    assert 0.5 < scores[0].cost / terms < 2.0
    assert np.sum(np.abs(problem.model_residual(linear)) ** 2) / terms > 20.0


def test_the_held_part_keeps_the_poles_and_the_held_columns(case):
    data, problem, _ = case
    held = NonlinearElement("polynomial", "x1", exponent=3.0)
    settings = dataclasses.replace(SETTINGS, elements=(held,))
    model = reidentified_scores(data, settings, 10, problem, [(TRUE, generic(*TRUE))])[0].model
    part = held_part(model, 1)
    assert part.elements == model.elements[:1]
    assert part.B.shape == (10, 2) and part.D.shape == (5, 2)
    np.testing.assert_array_equal(part.A, model.A)
    np.testing.assert_array_equal(part.B, model.B[:, :2])
    np.testing.assert_array_equal(part.C, model.C)
