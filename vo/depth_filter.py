"""Gaussian x Beta depth filter in inverse depth (Vogiatzis & Hernandez 2011, thesis 6.3, 6.6.3).

Each point's inverse depth rho ~ N(mu, sigma^2) and inlier probability pi ~ Beta(a, b) are
updated by moment matching with each new measurement x ~ pi N(rho, tau^2) + (1-pi) U(0, range).
"""

from __future__ import annotations

import numba
import numpy as np


@numba.njit(cache=True, nogil=True)
def update_seed(mu, sigma2, a, b, x, tau2, rho_range):
    """One measurement x (variance tau2) folded into (mu, sigma2, a, b); returns the new values."""
    s = sigma2 + tau2
    c1 = a / (a + b) * np.exp(-0.5 * (x - mu) ** 2 / s) / np.sqrt(2.0 * np.pi * s)
    c2 = b / (a + b) / rho_range
    total = c1 + c2
    c1 /= total
    c2 /= total
    s2 = 1.0 / (1.0 / sigma2 + 1.0 / tau2)
    m = s2 * (mu / sigma2 + x / tau2)
    f = c1 * (a + 1.0) / (a + b + 1.0) + c2 * a / (a + b + 1.0)
    e = (c1 * (a + 1.0) * (a + 2.0) / ((a + b + 1.0) * (a + b + 2.0))
         + c2 * a * (a + 1.0) / ((a + b + 1.0) * (a + b + 2.0)))
    mu_new = c1 * m + c2 * mu
    sigma2_new = c1 * (s2 + m * m) + c2 * (sigma2 + mu * mu) - mu_new * mu_new
    a_new = (e - f) / (f - e / f)
    b_new = a_new * (1.0 - f) / f
    return mu_new, max(sigma2_new, 1e-30), a_new, b_new


@numba.njit(cache=True, nogil=True)
def linearity_index(rho, sigma, distance, cos_parallax):
    """Civera's linearity index L = 4 sigma_d / d |cos alpha| with sigma_d = sigma / rho^2."""
    if rho <= 0.0:
        return np.inf
    return 4.0 * (sigma / (rho * rho)) / distance * abs(cos_parallax)


@numba.njit(cache=True, nogil=True)
def update_seeds(idx, x, tau, mu, sigma, a, b, rho_range):
    """Apply measurements x[k] (std tau[k]) to points idx[k] of the columns mu, sigma, a, b."""
    for k in range(idx.shape[0]):
        i = idx[k]
        m, s2, aa, bb = update_seed(mu[i], sigma[i] ** 2, a[i], b[i], x[k], tau[k] ** 2,
                                    rho_range[i])
        mu[i] = m
        sigma[i] = np.sqrt(s2)
        a[i] = aa
        b[i] = bb


def converged(rho: np.ndarray, sigma: np.ndarray, pos_w: np.ndarray, host_centre: np.ndarray,
              cam_centre: np.ndarray, threshold: float) -> np.ndarray:
    """Vectorised convergence test L < threshold for points seen from a host and a camera."""
    ray_h = pos_w - host_centre
    ray_c = pos_w - cam_centre
    d = np.linalg.norm(ray_c, axis=1)
    cos_par = np.einsum("ij,ij->i", ray_h, ray_c) / (np.linalg.norm(ray_h, axis=1) * d)
    with np.errstate(divide="ignore", invalid="ignore"):
        L = 4.0 * sigma / (rho * rho) / d * np.abs(cos_par)
    return (rho > 0) & (threshold > L)
