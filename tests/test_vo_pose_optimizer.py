"""Pose refinement: Gauss-Newton with Tukey weights recovers a pose despite outliers; its
covariance agrees with the scatter of repeated noisy solves; depth whitening."""

from __future__ import annotations

import numpy as np
import pytest

from vo.pose_optimizer import depth_whitening, optimize_pose, pose_covariance
from vo.se3 import exp_se3, inv_se3, rotation_angle_deg

FOCAL = 400.0
NO_PRIOR = (np.eye(3), 0.0)


def _scene(rng, n=120, away=0.0):
    """Points, T_c_w and observations; the camera `away` m from the world origin (behind)."""
    P = rng.uniform([-2, -1.5, 3], [2, 1.5, 6], (n, 3))
    T = exp_se3(np.array([0.1, -0.05, 0.2 + away, 0.03, -0.02, 0.05]))
    P[:, 2] -= away
    X = P @ T[:3, :3].T + T[:3, 3]
    return P, T, X[:, :2] / X[:, 2:]


def test_recovers_pose_with_outliers():
    rng = np.random.default_rng(0)
    P, T_true, obs = _scene(rng)
    obs = obs + rng.normal(0, 0.5 / FOCAL, obs.shape)
    bad = rng.choice(len(obs), 20, replace=False)
    obs[bad] += rng.uniform(5, 40, (20, 2)) * rng.choice([-1, 1], (20, 2)) / FOCAL
    T0 = exp_se3(np.array([0.03, 0.02, -0.02, 0.01, 0.02, -0.01])) @ T_true
    ident = np.tile(np.eye(2), (len(P), 1, 1))
    T, _, _, err = optimize_pose(P, obs, np.zeros(len(P), np.int64), ident, T0, 10, 0.5 / FOCAL,
                                 *NO_PRIOR)
    D = T @ inv_se3(T_true)
    assert rotation_angle_deg(D[:3, :3]) < 0.2
    assert np.linalg.norm(D[:3, 3]) < 0.01
    # the same as a solve that is simply not shown the outliers
    good = np.setdiff1d(np.arange(len(P)), bad)
    T_ref, *_ = optimize_pose(P[good], obs[good], np.zeros(len(good), np.int64), ident[good],
                              T0, 20, 0.5 / FOCAL, *NO_PRIOR)
    D = T @ inv_se3(T_ref)
    assert rotation_angle_deg(D[:3, :3]) < 0.02 and np.linalg.norm(D[:3, 3]) < 0.002
    inliers = err * FOCAL < 2.0
    assert not inliers[bad].any() and inliers.sum() >= 95


def test_a_sure_rotation_prior_fixes_the_rotation_and_the_translation_fits_it():
    """With a rotation prior far surer than the images, the refined rotation is the prior's
    and the translation the least-squares one for it (scipy on the translation alone)."""
    from scipy.optimize import least_squares

    rng = np.random.default_rng(3)
    P, T_true, obs = _scene(rng, 60)
    obs = obs + rng.normal(0, 0.5 / FOCAL, obs.shape)
    R_prior = exp_se3(np.array([0, 0, 0, 0.004, -0.003, 0.002]))[:3, :3] @ T_true[:3, :3]
    ident = np.tile(np.eye(2), (len(P), 1, 1))
    T, *_ = optimize_pose(P, obs, np.zeros(len(P), np.int64), ident, T_true, 20, 0.5 / FOCAL,
                          R_prior, 1e12)
    assert rotation_angle_deg(T[:3, :3] @ R_prior.T) < 1e-3

    def residuals(t):
        X = P @ R_prior.T + t
        return (obs - X[:, :2] / X[:, 2:]).ravel()

    t_ref = least_squares(residuals, T_true[:3, 3]).x  # plain least squares: Tukey's weights
    assert np.linalg.norm(T[:3, 3] - t_ref) < 1e-3  # differ by a fraction of a millimetre
    T_free, *_ = optimize_pose(P, obs, np.zeros(len(P), np.int64), ident, T_true, 20,
                               0.5 / FOCAL, *NO_PRIOR)
    assert np.linalg.norm(T_free[:3, 3] - t_ref) > 5e-3  # the prior moved it (centimetres)


def test_no_prior_information_is_no_prior():
    rng = np.random.default_rng(4)
    P, T_true, obs = _scene(rng, 60)
    obs = obs + rng.normal(0, 0.5 / FOCAL, obs.shape)
    ident = np.tile(np.eye(2), (len(P), 1, 1))
    levels = np.zeros(len(P), np.int64)
    T0 = exp_se3(np.array([0.02, 0.01, -0.02, 0.01, 0.0, -0.01])) @ T_true
    T_a, *_ = optimize_pose(P, obs, levels, ident, T0, 10, 0.5 / FOCAL, *NO_PRIOR)
    T_b, *_ = optimize_pose(P, obs, levels, ident, T0, 10, 0.5 / FOCAL, np.eye(3) * -1, 0.0)
    assert np.array_equal(T_a, T_b)


@pytest.mark.parametrize("away", [0.0, 5.0])
def test_covariance_matches_monte_carlo(away):
    # 5 m from the world origin, rotation errors move the camera position the most
    rng = np.random.default_rng(1)
    P, T_true, obs0 = _scene(rng, 60, away)
    ident = np.tile(np.eye(2), (len(P), 1, 1))
    levels = np.zeros(len(P), np.int64)
    noise = 1.0 / FOCAL
    samples, cov = [], None
    for _ in range(150):
        obs = obs0 + rng.normal(0, noise, obs0.shape)
        T, H, _, _ = optimize_pose(P, obs, levels, ident, T_true, 10, 0.1 / FOCAL, *NO_PRIOR)
        T_w_c = inv_se3(T)
        cov = pose_covariance(H, noise, T_w_c)
        d = T_w_c @ inv_se3(inv_se3(T_true))  # exp(d) T_w_c_true = T_w_c
        position_error = T_w_c[:3, 3] - inv_se3(T_true)[:3, 3]
        samples.append(np.concatenate((position_error, [d[2, 1], d[0, 2], d[1, 0]])))
    emp = np.cov(np.array(samples).T)
    ratio = np.diag(emp) / np.diag(cov)
    assert np.all(ratio > 0.6) and np.all(ratio < 1.6)
    assert np.allclose(cov, cov.T) and np.all(np.linalg.eigvalsh(cov) > 0)


def test_depth_whitening_down_weights_along_the_epipolar_direction():
    kf = np.tile(np.eye(4), (1, 1, 1))
    T_c_w = np.eye(4)
    T_c_w[:3, 3] = (-0.5, 0.0, 0.0)  # camera moved along +x: depth error shows along x
    f = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]])
    A = depth_whitening(T_c_w, kf, np.zeros(2, np.int64), f, np.array([0.5, 0.5]),
                        np.array([1e-6, 0.2]), 1.0 / FOCAL)
    assert np.allclose(A[0], np.eye(2), atol=1e-3)
    assert A[1, 0, 0] < 0.05 and abs(A[1, 1, 1] - 1.0) < 1e-9
