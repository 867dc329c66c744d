"""Force columns at measured DOFs from one driving point (fnsi.reciprocity)."""

import numpy as np
import pytest
from scipy.signal import cont2discrete

from fnsi.reciprocity import force_columns, location_column
from fnsi.statespace import StateSpaceModel

FS = 200.0  # [Hz]


def _chain(damping: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Discrete (ZOH at FS) A, B (a force at each of 3 DOFs), C (their displacements) of
    a 3-DOF chain to ground: symmetric M, C, K, so its FRF matrix is symmetric."""
    M = np.diag([1.0, 2.0, 1.5])                                   # [kg]
    K = np.array([[3e4, -1e4, 0.0], [-1e4, 2e4, -1e4], [0.0, -1e4, 1e4]])   # [N/m]
    Minv = np.linalg.inv(M)
    Ac = np.block([[np.zeros((3, 3)), np.eye(3)], [-Minv @ K, -Minv @ damping]])
    Bc = np.vstack([np.zeros((3, 3)), Minv])
    Cc = np.hstack([np.eye(3), np.zeros((3, 3))])
    A, B, C, _, _ = cont2discrete((Ac, Bc, Cc, np.zeros((3, 3))), 1.0 / FS)
    return A, B, C


def _model(A: np.ndarray, B: np.ndarray, C: np.ndarray, driven: int) -> StateSpaceModel:
    return StateSpaceModel(A=A, B=B[:, [driven]], C=C, D=np.zeros((3, 1)), fs=FS,
                           input_names=(f"F_x{driven}",),
                           output_names=("x0", "x1", "x2"))


@pytest.mark.parametrize("damping", [
    np.diag([2.0, 3.0, 1.0]) * 1.0,                                   # nonproportional
    1e-4 * np.array([[3e4, -1e4, 0.0], [-1e4, 2e4, -1e4], [0.0, -1e4, 1e4]]),  # proportional
], ids=["nonproportional", "proportional"])
def test_a_force_at_each_dof_enters_as_the_structure_says(damping):
    # the model knows only the input at x1; reciprocity gives the columns of forces at x0
    # and x2, which must be the true ones (the same state coordinates: the model's A, C)
    A, B, C = _chain(damping)
    columns = force_columns(_model(A, B, C, driven=1), ("F_x1", "x1"))
    for dof in range(3):
        # exact up to the eigendecomposition's rounding (cond(V) ~ 1e2 here)
        np.testing.assert_allclose(columns[f"x{dof}"], B[:, dof], rtol=0,
                                   atol=1e-9 * np.abs(B).max())


def test_a_force_between_two_dofs_enters_through_the_difference():
    A, B, C = _chain(np.diag([2.0, 3.0, 1.0]))
    columns = force_columns(_model(A, B, C, driven=0), ("F_x0", "x0"))
    np.testing.assert_allclose(location_column(columns, "x2", "x1"), B[:, 2] - B[:, 1],
                               atol=1e-9 * np.abs(B).max())
    np.testing.assert_array_equal(location_column(columns, "x2", None), columns["x2"])


def test_an_unknown_driving_point_is_refused():
    A, B, C = _chain(np.diag([2.0, 3.0, 1.0]))
    with pytest.raises(ValueError, match="driving point"):
        force_columns(_model(A, B, C, driven=0), ("F_x0", "x5"))


def test_a_model_without_separable_modes_gives_no_columns():
    # a Jordan block: one double pole with one eigenvector, no modal split of B
    model = StateSpaceModel(A=np.array([[0.9, 1.0], [0.0, 0.9]]), B=np.array([[0.0], [1.0]]),
                            C=np.eye(2), D=np.zeros((2, 1)), fs=FS, input_names=("F_x0",),
                            output_names=("x0", "x1"))
    with pytest.raises(ValueError, match="eigenvectors"):
        force_columns(model, ("F_x0", "x0"))
