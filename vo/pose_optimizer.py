"""Final pose (thesis 6.7.3): Gauss-Newton on reprojection error with Tukey weights, errors on the
undistorted normalised image plane (scaled down by the match's pyramid level), and the pose
covariance from the final normal equations."""

from __future__ import annotations

import numba
import numpy as np

from vo.se3 import adjoint, exp_se3, plane_jacobian, transform

TUKEY_C = 4.6851
MAD_TO_SIGMA = 1.4826


@numba.njit(cache=True, nogil=True)
def _residuals(pos_w, obs, scale, T_c_w, err):
    """Fill err (N, 2) with level-scaled errors obs - proj(T_c_w pos_w); False if behind."""
    for i in range(pos_w.shape[0]):
        X, Y, Z = transform(T_c_w, pos_w[i, 0], pos_w[i, 1], pos_w[i, 2])
        if Z <= 1e-9:
            err[i, 0] = 1e3
            err[i, 1] = 1e3
            continue
        err[i, 0] = (obs[i, 0] - X / Z) * scale[i]
        err[i, 1] = (obs[i, 1] - Y / Z) * scale[i]


@numba.njit(cache=True, nogil=True)
def optimize_pose(pos_w, obs, level, T_c_w, iterations, sigma_floor):
    """Refine T_c_w from world points pos_w observed at normalised coordinates obs.

    Returns (T_c_w, H, sigma, err_norm): the normal matrix of the last iteration (twist in
    the camera frame, left perturbation), the robust residual scale and per-match errors.
    """
    n = pos_w.shape[0]
    scale = np.empty(n)
    for i in range(n):
        scale[i] = 1.0 / 2.0 ** level[i]
    err = np.empty((n, 2))
    norms = np.empty(n)
    T = T_c_w.copy()
    J = np.zeros((2, 6))
    H = np.zeros((6, 6))
    _residuals(pos_w, obs, scale, T, err)
    for i in range(n):
        norms[i] = np.sqrt(err[i, 0] ** 2 + err[i, 1] ** 2)
    sigma = max(MAD_TO_SIGMA * np.median(norms), sigma_floor)
    c = TUKEY_C * sigma
    for _ in range(iterations):
        H[:, :] = 0.0
        b = np.zeros(6)
        for i in range(n):
            e = np.sqrt(err[i, 0] ** 2 + err[i, 1] ** 2)
            if e >= c:
                continue
            wgt = (1.0 - (e / c) ** 2) ** 2
            X, Y, Z = transform(T, pos_w[i, 0], pos_w[i, 1], pos_w[i, 2])
            plane_jacobian(X, Y, Z, J)
            for a in range(6):
                ja0 = J[0, a] * scale[i]
                ja1 = J[1, a] * scale[i]
                b[a] += wgt * (ja0 * err[i, 0] + ja1 * err[i, 1])
                for q in range(6):
                    H[a, q] += wgt * (ja0 * J[0, q] + ja1 * J[1, q]) * scale[i]
        if abs(np.linalg.det(H)) < 1e-30:
            break
        xi = np.linalg.solve(H, b)
        T = exp_se3(xi) @ T
        _residuals(pos_w, obs, scale, T, err)
        if np.sqrt(xi @ xi) < 1e-10:
            break
    for i in range(n):
        norms[i] = np.sqrt(err[i, 0] ** 2 + err[i, 1] ** 2)
    return T, H, sigma, norms


def pose_covariance(H: np.ndarray, sigma: float, T_w_c: np.ndarray) -> np.ndarray | None:
    """Covariance of T_w_c in the world frame (translation, rotation) from the camera-frame normal
    matrix H of a left perturbation of T_c_w and residual std sigma; None if H is singular."""
    try:
        cov_c = np.linalg.inv(H) * sigma * sigma
    except np.linalg.LinAlgError:
        return None
    if not np.all(np.isfinite(cov_c)):
        return None
    Ad = adjoint(T_w_c)
    cov = Ad @ cov_c @ Ad.T
    return 0.5 * (cov + cov.T)
