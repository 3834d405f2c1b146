"""Solving the small normal equations H x = b of the Gauss-Newton loops (6 unknowns), inside
kernels: a LAPACK call costs more than the arithmetic of a 6x6 system, and these run every
iteration of every alignment, pose refinement and RANSAC hypothesis."""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def solve_spd(H, b):
    """(det(H), x) with H x = b for a symmetric positive definite H, by Cholesky; det is 0
    (and x zero) when H is not numerically positive definite."""
    n = b.shape[0]
    L = np.zeros((n, n))
    x = np.zeros(n)
    det = 1.0
    for j in range(n):
        d = H[j, j]
        for k in range(j):
            d -= L[j, k] * L[j, k]
        if not d > 0.0:  # also NaN
            return 0.0, x
        det *= d
        L[j, j] = np.sqrt(d)
        for i in range(j + 1, n):
            s = H[i, j]
            for k in range(j):
                s -= L[i, k] * L[j, k]
            L[i, j] = s / L[j, j]
    for i in range(n):  # L y = b
        s = b[i]
        for k in range(i):
            s -= L[i, k] * x[k]
        x[i] = s / L[i, i]
    for i in range(n - 1, -1, -1):  # L^T x = y
        s = x[i]
        for k in range(i + 1, n):
            s -= L[k, i] * x[k]
        x[i] = s / L[i, i]
    return det, x
