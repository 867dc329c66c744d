"""Separability of nonlinear elements: principal angles of the extended-input spectra."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.linalg

from fnsi.nonlinear import NonlinearElement
from fnsi.separability import LINEAR_STRUCTURE, SEPARABILITY_LIMIT, separability
from fnsi.spectra import Spectra

LINES = 400


def spectra_of(columns: list[np.ndarray], outputs: dict[str, np.ndarray] | None = None,
               ) -> Spectra:
    """Spectra whose extended inputs are ``columns`` (one realisation, LINES lines) and
    whose displacement outputs are ``outputs`` (default: one zero channel "y", so that
    no element's DOFs are measured and only the extended inputs count)."""
    outputs = outputs or {"y": np.zeros(LINES, complex)}
    inputs = np.stack(columns, axis=1)[None]
    names = tuple(f"e{k}" for k in range(inputs.shape[2]))
    return Spectra(np.linspace(1.0, 40.0, LINES), 200.0, inputs,
                   np.stack(list(outputs.values()), axis=1)[None], names, tuple(outputs))


def random_line_spectrum(rng: np.random.Generator) -> np.ndarray:
    return rng.standard_normal(LINES) + 1j * rng.standard_normal(LINES)


def reference_sine(own: list[np.ndarray], others: list[np.ndarray]) -> float:
    """Sine of the smallest principal angle by SciPy, real and imaginary parts stacked."""
    def real(columns):
        stacked = np.stack(columns, axis=1)
        return np.concatenate([stacked.real, stacked.imag])
    return float(np.sin(np.min(scipy.linalg.subspace_angles(real(own), real(others)))))


CUBIC_A = NonlinearElement("polynomial", "a", exponent=3.0)
CUBIC_C = NonlinearElement("polynomial", "c", exponent=3.0)


def test_mirror_image_elements_are_confounded_and_name_each_other():
    rng = np.random.default_rng(0)
    u, g = random_line_spectrum(rng), random_line_spectrum(rng)
    # x_c = -x_a: an odd law at c repeats the one at a with the opposite sign
    result = separability(spectra_of([u, g, -g]), 1, (CUBIC_A, CUBIC_C))
    for own, other in zip(result, reversed(result), strict=True):
        assert own.unexplained < 1e-6
        assert own.confounded and own.partners == (other.name,)
        assert other.name in own.concern and "mirror-image" in own.concern


@pytest.mark.parametrize("mix", [0.02, 0.08, 0.5])
def test_unexplained_fraction_is_the_sine_of_the_smallest_principal_angle(mix):
    rng = np.random.default_rng(1)
    u, g, h = (random_line_spectrum(rng) for _ in range(3))
    near = -g + mix * h * np.linalg.norm(g) / np.linalg.norm(h)
    result = separability(spectra_of([u, g, near]), 1, (CUBIC_A, CUBIC_C))
    expected = reference_sine([near], [u, g])
    assert result[1].unexplained == pytest.approx(expected, rel=1e-6)
    assert result[1].confounded == (expected < SEPARABILITY_LIMIT)
    assert (result[1].concern is None) == (not result[1].confounded)


def test_independent_elements_are_separable():
    rng = np.random.default_rng(2)
    columns = [random_line_spectrum(rng) for _ in range(3)]
    result = separability(spectra_of(columns), 1, (CUBIC_A, CUBIC_C))
    # random columns of 800 real rows are nearly orthogonal: cosines ~ 1 / sqrt(800)
    assert all(s.unexplained > 0.9 and not s.confounded for s in result)
    assert json.loads(json.dumps([s.to_json() for s in result]))[0]["concern"] is None


def test_repeated_basis_functions_of_one_element_are_reported():
    rng = np.random.default_rng(3)
    u, g = random_line_spectrum(rng), random_line_spectrum(rng)
    hinges = NonlinearElement("piecewise_linear", "a", breakpoints=(1.0, 2.0))
    result = separability(spectra_of([u, g, 2.0 * g]), 1, (hinges,))
    assert result[0].unexplained == 0.0 and result[0].partners == ("its other basis functions",)


def test_column_count_must_match_the_elements():
    rng = np.random.default_rng(4)
    with pytest.raises(ValueError, match="2 extended inputs"):
        separability(spectra_of([random_line_spectrum(rng)] * 2), 1, (CUBIC_A, CUBIC_C))


def test_a_law_that_a_linear_spring_reproduces_is_confounded_with_the_linear_structure():
    """g = x (a polynomial of exponent 1) is what the underlying linear model already
    holds; a cubic of the same motion is not."""
    rng = np.random.default_rng(5)
    u, x = random_line_spectrum(rng), random_line_spectrum(rng)
    spring = NonlinearElement("polynomial", "a", exponent=1.0)
    outputs = {"a": x, "b": random_line_spectrum(rng)}
    linear, = separability(spectra_of([u, 3.0 * x], outputs), 1, (spring,))
    assert linear.unexplained < 1e-6 and linear.partners == (LINEAR_STRUCTURE,)
    cubic, = separability(spectra_of([u, random_line_spectrum(rng)], outputs), 1, (CUBIC_A,))
    assert not cubic.confounded
