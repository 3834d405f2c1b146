"""Final pose (thesis 6.7.3): Gauss-Newton on reprojection error with Tukey weights, errors on the
undistorted normalised image plane (scaled down by the match's pyramid level), and the pose
covariance from the final normal equations."""

from __future__ import annotations

import numba
import numpy as np

from vo.normal_equations import solve_spd
from vo.se3 import adjoint, compose, exp_se3, inv_se3, log_so3, plane_jacobian, skew, transform

TUKEY_C = 4.6851
MAD_TO_SIGMA = 1.4826


@numba.njit(cache=True, nogil=True)
def depth_whitening(T_c_w, kf_T_c_w, host, f, rho, sigma, pixel_sigma):
    """Per point a 2x2 matrix whitening its reprojection error for the depth uncertainty:
    the error along the projected inverse-depth interval rho +- sigma is down-weighted by
    1 / sqrt(1 + (spread / pixel_sigma)^2); across it the weight stays 1."""
    n = host.shape[0]
    A = np.zeros((n, 2, 2))
    T_slot = np.empty((kf_T_c_w.shape[0], 4, 4))  # T_c_w times each slot's inverse, on use
    have = np.zeros(kf_T_c_w.shape[0], dtype=np.bool_)
    for i in range(n):
        A[i, 0, 0] = 1.0
        A[i, 1, 1] = 1.0
        if not have[host[i]]:
            T_slot[host[i]] = compose(T_c_w, inv_se3(kf_T_c_w[host[i]]))
            have[host[i]] = True
        T = T_slot[host[i]]
        near = rho[i] + sigma[i]
        far = max(rho[i] - sigma[i], 1e-6)
        X1, Y1, Z1 = transform(T, f[i, 0] / near, f[i, 1] / near, f[i, 2] / near)
        X2, Y2, Z2 = transform(T, f[i, 0] / far, f[i, 1] / far, f[i, 2] / far)
        if Z1 <= 1e-9 or Z2 <= 1e-9:
            continue
        dx = 0.5 * (X1 / Z1 - X2 / Z2)
        dy = 0.5 * (Y1 / Z1 - Y2 / Z2)
        spread = np.sqrt(dx * dx + dy * dy)
        if spread < 1e-12:
            continue
        ex = dx / spread
        ey = dy / spread
        k = spread / pixel_sigma
        beta = 1.0 - 1.0 / np.sqrt(1.0 + k * k)
        A[i, 0, 0] -= beta * ex * ex
        A[i, 0, 1] -= beta * ex * ey
        A[i, 1, 0] -= beta * ey * ex
        A[i, 1, 1] -= beta * ey * ey
    return A


@numba.njit(cache=True, nogil=True)
def _residuals(pos_w, obs, scale, whiten, T_c_w, err):
    """Fill err (N, 2) with whitened, level-scaled errors obs - proj(T_c_w pos_w)."""
    for i in range(pos_w.shape[0]):
        X, Y, Z = transform(T_c_w, pos_w[i, 0], pos_w[i, 1], pos_w[i, 2])
        if Z <= 1e-9:
            err[i, 0] = 1e3
            err[i, 1] = 1e3
            continue
        ex = (obs[i, 0] - X / Z) * scale[i]
        ey = (obs[i, 1] - Y / Z) * scale[i]
        err[i, 0] = whiten[i, 0, 0] * ex + whiten[i, 0, 1] * ey
        err[i, 1] = whiten[i, 1, 0] * ex + whiten[i, 1, 1] * ey


@numba.njit(cache=True, nogil=True)
def optimize_pose(pos_w, obs, level, whiten, T_c_w, iterations, sigma_floor, R_prior,
                  prior_info):
    """Refine T_c_w from world points pos_w observed at normalised coordinates obs, errors
    whitened by the 2x2 matrices `whiten` (see depth_whitening).

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
    Jw = np.zeros((2, 6))
    H = np.zeros((6, 6))
    _residuals(pos_w, obs, scale, whiten, T, err)
    sigma = sigma_floor
    for _ in range(iterations):
        # robust scale re-estimated each iteration (MAD), so outliers drop out as T improves
        for i in range(n):
            norms[i] = np.sqrt(err[i, 0] ** 2 + err[i, 1] ** 2)
        sigma = max(MAD_TO_SIGMA * np.median(norms), sigma_floor)
        c = TUKEY_C * sigma
        H[:, :] = 0.0
        b = np.zeros(6)
        for i in range(n):
            e = np.sqrt(err[i, 0] ** 2 + err[i, 1] ** 2)
            if e >= c:
                continue
            wgt = (1.0 - (e / c) ** 2) ** 2
            X, Y, Z = transform(T, pos_w[i, 0], pos_w[i, 1], pos_w[i, 2])
            plane_jacobian(X, Y, Z, J)
            W = whiten[i]
            for a in range(6):
                Jw[0, a] = (W[0, 0] * J[0, a] + W[0, 1] * J[1, a]) * scale[i]
                Jw[1, a] = (W[1, 0] * J[0, a] + W[1, 1] * J[1, a]) * scale[i]
            for a in range(6):
                b[a] += wgt * (Jw[0, a] * err[i, 0] + Jw[1, a] * err[i, 1])
                for q in range(6):
                    H[a, q] += wgt * (Jw[0, a] * Jw[0, q] + Jw[1, a] * Jw[1, q])
        if prior_info > 0.0:
            e_r = log_so3(R_prior @ np.ascontiguousarray(T[:3, :3].T))
            w_r = prior_info * sigma * sigma
            for a in range(3):
                H[3 + a, 3 + a] += w_r
                b[3 + a] += w_r * e_r[a]
        det, xi = solve_spd(H, b)
        if abs(det) < 1e-30:
            break
        T = compose(exp_se3(xi), T)
        _residuals(pos_w, obs, scale, whiten, T, err)
        if np.sqrt(xi @ xi) < 1e-10:
            break
    for i in range(n):
        norms[i] = np.sqrt(err[i, 0] ** 2 + err[i, 1] ** 2)
    return T, H, sigma, norms


def pose_covariance(H: np.ndarray, sigma: float, T_w_c: np.ndarray) -> np.ndarray | None:
    """Covariance of the camera's world position and world rotation (R -> exp(phi) R) from the
    camera-frame normal matrix H of a left perturbation of T_c_w and residual std sigma; None if
    H is singular.

    A left perturbation exp((rho, phi)) of T_w_c moves the position by rho + phi x p: far from
    the world origin (a drone at 6 m over a map started at 1.5 m) the rotation's share of the
    position error is what matters, so it is folded in here."""
    try:
        cov = _covariance(np.ascontiguousarray(H, dtype=np.float64), float(sigma),
                          np.ascontiguousarray(T_w_c, dtype=np.float64))
    except np.linalg.LinAlgError:
        return None
    return cov if np.all(np.isfinite(cov)) else None


@numba.njit(cache=True, nogil=True)
def _covariance(H, sigma, T_w_c):
    """pose_covariance's matrices (non-finite where H is near singular)."""
    cov_c = np.linalg.inv(H) * sigma * sigma
    J = adjoint(T_w_c)  # camera-frame twist -> left perturbation of T_w_c
    J[:3] -= skew(np.ascontiguousarray(T_w_c[:3, 3])) @ J[3:]  # -> (position, rotation)
    cov = J @ cov_c @ J.T
    return 0.5 * (cov + cov.T)
