"""Mapping helpers: the plane that seeds candidates no keyframe matched."""

from __future__ import annotations

import numpy as np

from vo.mapping import PLANE_FIT_TOLERANCE, fit_plane


def _ground(rng, n=60, tilt=0.3, height=5.0):
    """Points on a plane `height` below a camera pitched by `tilt` rad, in the camera frame."""
    xy = rng.uniform(-3.0, 3.0, (n, 2))
    world = np.column_stack([xy, np.full(n, height)])
    c, s = np.cos(tilt), np.sin(tilt)
    R = np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    return world @ R.T, R @ np.array([0.0, 0.0, 1.0])


def test_plane_of_ground_points_despite_a_few_off_it():
    rng = np.random.default_rng(3)
    X, normal = _ground(rng)
    X[:4] *= 0.6  # four points on people's heads
    found = fit_plane(X, PLANE_FIT_TOLERANCE, 0.9)
    assert found is not None
    n, d = found
    assert np.allclose(n, normal, atol=1e-9) and abs(d - 5.0) < 1e-9


def test_no_plane_in_a_deep_scene_or_from_few_points():
    rng = np.random.default_rng(4)
    X = rng.uniform([-5, -2, 4], [5, 2, 40], (80, 3))  # a street: depths all over
    assert fit_plane(X, PLANE_FIT_TOLERANCE, 0.9) is None
    ground, _ = _ground(rng, n=5)
    assert fit_plane(ground, PLANE_FIT_TOLERANCE, 0.9) is None
