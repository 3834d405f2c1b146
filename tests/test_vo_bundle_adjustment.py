"""Local bundle adjustment (thesis 6.6.4): free keyframes and inverse depths recover from a
perturbation with fixed keyframes holding the gauge; the depth prior holds a point that the
views barely constrain; gross outliers are cut by the chi-square test; every solver gives the
same answer."""

from __future__ import annotations

import numpy as np
import pytest

from vo import bundle_adjustment as ba
from vo.se3 import exp_se3, inv_se3

FOCAL = 400.0


def _problem(rng, n_points=60, outliers=0, sigma_rho=0.02):
    """Four keyframes looking at points 3-5 m ahead; the first two free, the last two fixed;
    points hosted by keyframe 0 (free) and 2 (fixed), seen by the other three."""
    T_true = np.array([exp_se3(np.array([0.3 * k, 0.05 * k, 0.0, 0.01 * k, -0.02 * k, 0.0]))
                       for k in range(4)])
    host = np.where(np.arange(n_points) % 2 == 0, 0, 2)
    local = np.column_stack([rng.uniform(-2, 2, n_points), rng.uniform(-1.5, 1.5, n_points),
                             rng.uniform(3, 5, n_points)])
    depth = np.linalg.norm(local, axis=1)
    f = local / depth[:, None]
    T_w = np.array([inv_se3(T_true[h]) for h in host])
    P_true = np.einsum("nij,nj->ni", T_w[:, :3, :3], local) + T_w[:, :3, 3]
    kf = np.repeat(np.arange(4), n_points)
    pt = np.tile(np.arange(n_points), 4)
    seen = kf != host[pt]
    kf, pt = kf[seen], pt[seen]
    X = np.einsum("nij,nj->ni", T_true[kf, :3, :3], P_true[pt]) + T_true[kf, :3, 3]
    xy = X[:, :2] / X[:, 2:] + rng.normal(0, 0.5 / FOCAL, (len(kf), 2))
    bad = rng.choice(len(kf), outliers, replace=False)
    xy[bad] += 30.0 / FOCAL
    T0 = T_true.copy()
    for k in range(2):
        T0[k] = exp_se3(rng.normal(0, 0.01, 6)) @ T_true[k]
    rho0 = 1.0 / depth * (1.0 + rng.normal(0, sigma_rho, n_points))
    p = ba.Problem(slots=np.arange(4), n_free=2, T0=T0, points=np.arange(n_points), host=host,
                   f=f, rho0=rho0, prior_w=1.0 / (sigma_rho / depth), obs_kf=kf, obs_pt=pt,
                   obs_xy=xy, obs_scale=np.full(len(kf), FOCAL), obs_slot=kf.copy())
    return p, T_true, 1.0 / depth, bad


def _rms(p, T, rho, keep=None):
    keep = np.ones(len(p.obs_kf), bool) if keep is None else keep
    return np.sqrt(np.mean(ba.reprojection_errors(p, T, rho, keep) ** 2))


@pytest.mark.parametrize("method", ["trf", "dogbox", "lm"])
def test_free_keyframes_and_depths_recover(method):
    p, T_true, rho_true, _ = _problem(np.random.default_rng(0))
    assert p.rms_px() > 1.0
    T, rho, keep = ba.solve(p, 10, 10, method=method)
    assert keep.all()
    assert _rms(p, T, rho) < 0.6  # pixels: down to the 0.5 px noise
    start = np.abs(p.T0[:2, :3, 3] - T_true[:2, :3, 3]).max()
    assert np.abs(T[:2, :3, 3] - T_true[:2, :3, 3]).max() < 0.8 * start
    assert np.median(np.abs(rho / rho_true - 1)) < np.median(np.abs(p.rho0 / rho_true - 1))
    assert np.array_equal(T[2:], p.T0[2:])  # fixed keyframes stay


def test_depth_prior_holds_an_unconstrained_point():
    p, _, _, _ = _problem(np.random.default_rng(2))
    # point 0 keeps only one observation, by a keyframe that barely moved from its host
    only = (p.obs_pt != 0) | (p.obs_kf == 1)
    p = ba.Problem(**{**p.__dict__, "obs_kf": p.obs_kf[only], "obs_pt": p.obs_pt[only],
                      "obs_xy": p.obs_xy[only], "obs_scale": p.obs_scale[only],
                      "obs_slot": p.obs_slot[only]})
    _, rho, _ = ba.solve(p)
    assert abs(rho[0] / p.rho0[0] - 1) < 0.05


def test_outlier_observations_are_dropped():
    p, _, _, bad = _problem(np.random.default_rng(1), outliers=8)
    T, rho, keep = ba.solve(p, 10, 10)
    assert not keep[bad].any()
    # the first iterations still feel the outliers, so some good observations go too
    assert keep.sum() >= 0.7 * len(keep)
    assert _rms(p, T, rho, keep) < 0.6
