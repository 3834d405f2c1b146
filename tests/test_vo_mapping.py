"""Mapping helpers: the plane that seeds candidates no keyframe matched; candidates out of view."""

from __future__ import annotations

import numpy as np
import pytest
from test_vo_tracker import _flight
from vo_scenes import load_texture, render_plane, small_camera

from vo.config import TrackerConfig
from vo.frame import Frame
from vo.map import CANDIDATE, CONVERGED
from vo.mapping import PLANE_FIT_TOLERANCE, fit_plane
from vo.se3 import exp_se3
from vo.tracker import Tracker


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


@pytest.mark.parametrize("skip_unseen", [True, False])
def test_a_turn_away_does_not_delete_the_candidates(data_dir, skip_unseen):
    # thesis 6.6.3 searches only the candidates in view: the ground out of view while the
    # camera looks up for ten frames is not "not found", and is still there to come back to
    cam = small_camera()
    tex = load_texture(data_dir)
    tracker = Tracker(cam, TrackerConfig(seed_skip_unseen=skip_unseen))
    for i in range(40):
        tracker.process(render_plane(tex, cam, _flight(i)), i / 30.0)
    pts = tracker.map.points
    cand = np.flatnonzero(pts.status == CANDIDATE)
    assert len(cand) >= 20
    up = exp_se3(np.array([0.0, 0.0, 0.0, np.pi, 0.0, 0.0])) @ _flight(40)
    sky = np.full((cam.height, cam.width), 200, np.uint8)
    for k in range(10):
        frame = Frame(40 + k, (40 + k) / 30.0, sky, cam, tracker.config.pyramid_levels)
        frame.T_c_w = up
        tracker.mapper.step(frame, False)
    kept = np.isin(pts.status[cand], (CANDIDATE, CONVERGED))
    assert kept.all() if skip_unseen else not kept.any()

