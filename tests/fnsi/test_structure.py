"""Structural models: a mass matrix that cannot give accelerations is refused."""

from __future__ import annotations

import numpy as np
import pytest

from fnsi.structure import StructuralModel

K = np.array([[2.0, -1.0], [-1.0, 2.0]])
C = 0.01 * K


@pytest.mark.parametrize("M, says", [
    (np.diag([0.0, 1.0]), "positive definite"),            # a massless DOF: singular
    (np.diag([-1.0, 1.0]), "positive definite"),           # a negative mass: indefinite
    (np.zeros((2, 2)), "positive definite"),
    (np.array([[1.0, 1.0], [1.0, 1.0]]), "positive definite"),  # rank 1
    (np.array([[1.0, 0.5], [0.0, 1.0]]), "symmetric"),
], ids=["massless-dof", "negative-mass", "zero", "rank-one", "not-symmetric"])
def test_mass_matrix_must_be_symmetric_positive_definite(M, says):
    with pytest.raises(ValueError, match=says):
        StructuralModel(M, C, K, ("a", "b"))


def test_a_mass_matrix_rounded_to_twelve_digits_is_accepted():
    """A consistent mass matrix typed with rounding (asymmetric in its 13th digit) is a
    valid model, and its modes are those of its symmetric part."""
    M = np.array([[2.0, 0.5], [0.5 + 1e-13, 1.0]])
    model = StructuralModel(M, C, K, ("a", "b"))
    exact = StructuralModel(np.array([[2.0, 0.5], [0.5, 1.0]]), C, K, ("a", "b"))
    # rounding of 1e-13 moves the frequencies by about that relative amount
    np.testing.assert_allclose(model.linear_modes().frequencies,
                               exact.linear_modes().frequencies, rtol=1e-10)
