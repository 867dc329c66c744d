"""Gaussian elimination for the small dense systems of the compiled time-stepping loops.

The Newton steps of the simulators (:mod:`fnsi.simulation`, :mod:`fnsi.newmark`) solve a
system with one or two unknowns per nonlinear element at every time step; a LAPACK call
and its allocation cost more than the arithmetic at these sizes.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def solve_small(J, b):
    """Overwrite b with J^-1 b by Gaussian elimination with partial pivoting (J is
    destroyed). Returns the sign of det J: 0 (falsy), with b all NaN, when J is
    singular (a zero pivot), else +1 or -1.

    Examples
    --------
    >>> J, b = np.array([[0.0, 2.0], [1.0, 1.0]]), np.array([2.0, 3.0])
    >>> solve_small(J, b), b.tolist()
    (-1, [2.0, 1.0])
    """
    n = b.shape[0]
    sign = 1
    for col in range(n):
        pivot = col
        for row in range(col + 1, n):
            if abs(J[row, col]) > abs(J[pivot, col]):
                pivot = row
        if J[pivot, col] == 0.0:
            b[:] = np.nan
            return 0
        if J[pivot, col] < 0.0:
            sign = -sign
        if pivot != col:
            sign = -sign
            for j in range(n):
                J[col, j], J[pivot, j] = J[pivot, j], J[col, j]
            b[col], b[pivot] = b[pivot], b[col]
        for row in range(col + 1, n):
            factor = J[row, col] / J[col, col]
            for j in range(col, n):
                J[row, j] -= factor * J[col, j]
            b[row] -= factor * b[col]
    for row in range(n - 1, -1, -1):
        acc = b[row]
        for j in range(row + 1, n):
            acc -= J[row, j] * b[j]
        b[row] = acc / J[row, row]
    return sign
