"""Depth filter: the Gaussian x Beta update against brute-force moment matching of the exact
posterior on a grid, and the convergence index."""

from __future__ import annotations

import numpy as np
import pytest

from vo.depth_filter import converged, linearity_index, update_seed


def _grid_posterior_moments(mu, sigma2, a, b, x, tau2, rho_range):
    """Moments of p(rho, pi | x) proportional to N(rho|mu,s2) Beta(pi|a,b) [pi N(x|rho,tau2)
    + (1-pi) U(x)], integrated numerically on a grid."""
    rho = np.linspace(mu - 12 * np.sqrt(sigma2), mu + 12 * np.sqrt(sigma2), 6001)
    pi = np.linspace(1e-6, 1 - 1e-6, 4001)
    prior_rho = np.exp(-0.5 * (rho - mu) ** 2 / sigma2)
    prior_pi = pi ** (a - 1) * (1 - pi) ** (b - 1)
    lik_in = np.exp(-0.5 * (x - rho) ** 2 / tau2) / np.sqrt(2 * np.pi * tau2)
    # p factorises into an inlier and an outlier term, each separable in rho and pi
    w_in = np.trapezoid(prior_rho * lik_in, rho)
    w_out = np.trapezoid(prior_rho, rho) / rho_range
    p_pi_in = prior_pi * pi
    p_pi_out = prior_pi * (1 - pi)
    z = w_in * np.trapezoid(p_pi_in, pi) + w_out * np.trapezoid(p_pi_out, pi)

    def expect(f_rho, f_pi):
        return (np.trapezoid(prior_rho * lik_in * f_rho, rho) * np.trapezoid(p_pi_in * f_pi, pi)
                + np.trapezoid(prior_rho * f_rho, rho) / rho_range
                * np.trapezoid(p_pi_out * f_pi, pi)) / z

    one = np.ones_like
    m1 = expect(rho, one(pi))
    m2 = expect(rho ** 2, one(pi))
    e_pi = expect(one(rho), pi)
    e_pi2 = expect(one(rho), pi ** 2)
    return m1, m2 - m1 ** 2, e_pi, e_pi2


@pytest.mark.parametrize(("x", "tau"), [(1.02, 0.05), (1.3, 0.05), (0.5, 0.2), (1.0, 0.01)])
def test_update_matches_exact_posterior_moments(x, tau):
    mu, sigma, a, b, rho_range = 1.0, 0.1, 10.0, 10.0, 5.0
    m, s2, a1, b1 = update_seed(mu, sigma ** 2, a, b, x, tau ** 2, rho_range)
    ref_m, ref_var, e_pi, e_pi2 = _grid_posterior_moments(mu, sigma ** 2, a, b, x, tau ** 2,
                                                          rho_range)
    assert m == pytest.approx(ref_m, abs=1e-6)
    assert s2 == pytest.approx(ref_var, rel=1e-4)
    # the Beta's first two moments are matched exactly
    assert a1 / (a1 + b1) == pytest.approx(e_pi, rel=1e-4)
    assert a1 * (a1 + 1) / ((a1 + b1) * (a1 + b1 + 1)) == pytest.approx(e_pi2, rel=1e-4)


def test_repeated_inliers_converge_and_outliers_lower_inlier_ratio():
    rng = np.random.default_rng(3)
    mu, s2, a, b = 1.0, 1.0, 10.0, 10.0
    for _ in range(60):
        mu, s2, a, b = update_seed(mu, s2, a, b, 0.5 + rng.normal(0, 0.02), 0.02 ** 2, 10.0)
    assert mu == pytest.approx(0.5, abs=0.01) and np.sqrt(s2) < 0.01
    ratio = a / (a + b)
    for _ in range(10):
        mu2, _, a2, b2 = update_seed(mu, s2, a, b, rng.uniform(0, 10), 0.02 ** 2, 10.0)
    assert a2 / (a2 + b2) < ratio and mu2 == pytest.approx(0.5, abs=0.01)


def test_linearity_index():
    # sigma_d = sigma / rho^2; L = 4 sigma_d / d |cos a|
    assert linearity_index(0.5, 0.01, 2.0, 1.0) == pytest.approx(4 * 0.04 / 2.0)
    assert linearity_index(-0.1, 0.01, 2.0, 1.0) == np.inf
    pos = np.array([[0.0, 0.0, 2.0], [0.0, 0.0, 2.0]])
    done = converged(np.array([0.5, 0.5]), np.array([0.001, 0.1]), pos, np.zeros(3),
                     np.array([0.5, 0.0, 0.0]), 0.1)
    assert done.tolist() == [True, False]
