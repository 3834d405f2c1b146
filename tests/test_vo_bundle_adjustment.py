"""Local bundle adjustment (thesis 6.6.4): free keyframes and points recover from a perturbation
with fixed keyframes holding the gauge; gross outliers are cut by the chi-square test."""

from __future__ import annotations

import numpy as np

from vo import bundle_adjustment as ba
from vo.se3 import exp_se3

FOCAL = 400.0


def _problem(rng, n_points=60, outliers=0):
    """Four keyframes looking at points 3-5 m ahead; the first two free, the last two fixed."""
    T_true = np.array([exp_se3(np.array([0.3 * k, 0.05 * k, 0.0, 0.01 * k, -0.02 * k, 0.0]))
                       for k in range(4)])
    P_true = np.column_stack([rng.uniform(-2, 2, n_points), rng.uniform(-1.5, 1.5, n_points),
                              rng.uniform(3, 5, n_points)])
    kf = np.repeat(np.arange(4), n_points)
    pt = np.tile(np.arange(n_points), 4)
    X = np.einsum("nij,nj->ni", T_true[kf, :3, :3], P_true[pt]) + T_true[kf, :3, 3]
    xy = X[:, :2] / X[:, 2:] + rng.normal(0, 0.5 / FOCAL, (len(kf), 2))
    bad = rng.choice(len(kf), outliers, replace=False)
    xy[bad] += 30.0 / FOCAL
    T0 = T_true.copy()
    for k in range(2):
        T0[k] = exp_se3(rng.normal(0, 0.03, 6)) @ T_true[k]
    p = ba.Problem(slots=np.arange(4), n_free=2, T0=T0, points=np.arange(n_points),
                   P0=P_true + rng.normal(0, 0.03, P_true.shape), obs_kf=kf, obs_pt=pt,
                   obs_xy=xy, obs_scale=np.full(len(kf), FOCAL), obs_row=np.arange(len(kf)))
    return p, T_true, P_true, bad


def _rms(p, T, P):
    x = np.concatenate((np.zeros(6 * p.n_free), P.ravel()))
    q = ba.Problem(**{**p.__dict__, "T0": T})
    return np.sqrt(np.mean(ba._residuals(x, q, np.ones(len(p.obs_kf), bool)) ** 2))


def test_free_keyframes_and_points_recover():
    p, T_true, _, _ = _problem(np.random.default_rng(0))
    before = _rms(p, p.T0, p.P0)
    T, P, keep = ba.solve(p)
    assert keep.all()
    assert _rms(p, T, P) < 0.6 < before  # pixels: down to the 0.5 px noise
    start = np.abs(p.T0[:2, :3, 3] - T_true[:2, :3, 3]).max()
    assert np.abs(T[:2, :3, 3] - T_true[:2, :3, 3]).max() < 0.3 * start
    assert np.array_equal(T[2:], p.T0[2:])  # fixed keyframes stay


def test_outlier_observations_are_dropped():
    p, _, _, bad = _problem(np.random.default_rng(1), outliers=8)
    T, P, keep = ba.solve(p)
    assert not keep[bad].any()
    # the first iterations still feel the outliers, so some good observations go too
    assert keep.sum() >= 0.7 * len(keep)
    kept = ba.Problem(**{**p.__dict__, "T0": T})
    x = np.concatenate((np.zeros(6 * p.n_free), P.ravel()))
    assert np.sqrt(np.mean(ba._residuals(x, kept, keep) ** 2)) < 0.6
