"""The epipolar segment a point's inverse-depth interval projects to, and a match's distance from
it (vo.depth_segments), against a slow, obvious reference."""

from __future__ import annotations

import numpy as np

from vo.depth_segments import segment_distances
from vo.se3 import exp_se3


def _reference(T_c_w, kf_T_c_w, host, f, rho, half_width, obs):
    """Many points along each interval (the ray's direction where it reaches out to
    infinity), projected: the nearest one's distance (inf with one behind the camera)."""
    out = np.full(len(host), np.inf)
    for i in range(len(host)):
        T = T_c_w @ np.linalg.inv(kf_T_c_w[host[i]])
        r = np.linspace(max(rho[i] - half_width[i], 0.0), rho[i] + half_width[i], 20001)
        X = T[:3, :3] @ f[i] + r[:, None] * T[:3, 3]  # inverse depth r times the point
        if (X[:, 2] <= 1e-9).any():
            continue
        out[i] = np.min(np.hypot(*(X[:, :2] / X[:, 2:] - obs[i]).T))
    return out


def test_segment_distances_agree_with_points_sampled_along_the_interval():
    rng = np.random.default_rng(7)
    kf = np.array([exp_se3(rng.normal(0.0, 0.2, 6)) for _ in range(3)])
    T_c_w = exp_se3(rng.normal(0.0, 0.2, 6))
    n = 200
    host = rng.integers(0, 3, n)
    f = np.column_stack((rng.uniform(-0.5, 0.5, (n, 2)), np.ones(n)))
    f /= np.linalg.norm(f, axis=1)[:, None]
    rho = rng.uniform(0.2, 2.0, n)
    half = rho * rng.uniform(0.0, 1.3, n)  # a quarter reach out to infinity
    obs = rng.uniform(-0.6, 0.6, (n, 2))
    # half of them a few pixels (at 500 px) from a point on their segment
    near = np.arange(n) < n // 2
    for i in np.flatnonzero(near):
        T = T_c_w @ np.linalg.inv(kf[host[i]])
        X = T[:3, :3] @ f[i] + rng.uniform(max(rho[i] - half[i], 0.0), rho[i] + half[i]) * T[:3, 3]
        obs[i] = X[:2] / X[2] + rng.normal(0.0, 3.0 / 500.0, 2)
    got = segment_distances(T_c_w, kf, host, f, rho, half, obs)
    want = _reference(T_c_w, kf, host, f, rho, half, obs)
    assert np.array_equal(np.isinf(got), np.isinf(want))
    finite = np.isfinite(want)
    assert np.allclose(got[finite], want[finite], atol=2e-4)
    assert (got[near & finite] < 10.0 / 500.0).mean() > 0.9  # the near ones are near


def test_a_match_anywhere_on_its_interval_is_on_it_and_beyond_it_is_not():
    """Camera 0.2 m to the side of the host keyframe, a point straight ahead at inverse depth
    1 +- 0.5: matches at depths 0.7-2 m lie on the segment, one at 4 m lies 0.05 off it; with
    1 +- 1.5 the segment reaches the vanishing point, so a match at 100 m is on it too."""
    kf = np.eye(4)[None]
    T_c_w = np.eye(4)
    T_c_w[0, 3] = -0.2
    at = np.array([[-0.2 / d, 0.0] for d in (0.7, 1.0, 2.0, 4.0, 100.0)])
    half = np.array([0.5, 0.5, 0.5, 0.5, 1.5])
    d = segment_distances(T_c_w, kf, np.zeros(5, np.int64), np.tile([0.0, 0.0, 1.0], (5, 1)),
                          np.ones(5), half, at)
    assert np.allclose(d, [0.0, 0.0, 0.0, 0.05, 0.0])
