"""Map initialisation on a synthetic planar scene: LK tracking until enough shift, homography,
decomposition chosen by Sampson error; relative pose within 0.5 deg / 2 deg."""

from __future__ import annotations

import numpy as np
import pytest
from vo_scenes import load_texture, look_down_pose, render_plane, small_camera

from vo.config import TrackerConfig
from vo.frame import Frame
from vo.initialization import (
    Initializer,
    InitialMap,
    InitOutcome,
    pose_from_homography,
    sampson_error,
)
from vo.se3 import inv_se3, rotation_angle_deg


def _direction_error_deg(a, b):
    c = a @ b / (np.linalg.norm(a) * np.linalg.norm(b))
    return float(np.degrees(np.arccos(np.clip(c, -1, 1))))


@pytest.mark.parametrize("tilt", [(0.0, 0.0), (0.25, -0.1)])
def test_initializer_recovers_relative_pose(data_dir, tilt):
    cam = small_camera()
    tex = load_texture(data_dir)
    config = TrackerConfig(init_homography_ratio=0.0)
    init = Initializer(cam, config)
    poses = [look_down_pose(0.012 * i, 0.004 * i, 1.5, yaw=0.004 * i, tilt=tilt)
             for i in range(40)]
    frames = [Frame(i, float(i), render_plane(tex, cam, T), cam, 5) for i, T in enumerate(poses)]
    assert init.set_reference(frames[0])
    result, frame = None, None
    for frame in frames[1:]:
        result = init.add(frame)
        if isinstance(result, InitialMap):
            break
        assert result is InitOutcome.TRACKING
    assert isinstance(result, InitialMap)
    T_true = poses[frame.id] @ inv_se3(poses[0])
    assert rotation_angle_deg(T_true[:3, :3].T @ result.T_cur_ref[:3, :3]) < 0.5
    assert _direction_error_deg(T_true[:3, 3], result.T_cur_ref[:3, 3]) < 2.0
    assert np.median(result.depth) == pytest.approx(config.init_map_depth)
    assert len(result.depth) >= config.init_min_inliers


def test_too_few_corners_is_refused(data_dir):
    cam = small_camera()
    init = Initializer(cam, TrackerConfig())
    flat = Frame(0, 0.0, np.full((cam.height, cam.width), 128, np.uint8), cam, 5)
    assert not init.set_reference(flat)


def test_homography_choice_by_sampson_on_exact_points():
    rng = np.random.default_rng(0)
    P = np.column_stack((rng.uniform(-1, 1, (80, 2)), np.full(80, 3.0)))
    R = np.eye(3)
    t = np.array([0.3, 0.05, 0.02])
    x1 = P[:, :2] / P[:, 2:]
    Q = P @ R.T + t
    x2 = Q[:, :2] / Q[:, 2:]
    R_est, t_est, inl = pose_from_homography(x1, x2, 1e-3, 0)
    assert inl.all()
    assert rotation_angle_deg(R_est.T @ R) < 0.01
    assert _direction_error_deg(t_est, t) < 0.1
    tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
    assert np.max(sampson_error(tx @ R, x1, x2)) < 1e-20


def _track_until_map(cam, tex, poses, config):
    init = Initializer(cam, config)
    frames = [Frame(i, float(i), render_plane(tex, cam, T), cam, 5) for i, T in enumerate(poses)]
    assert init.set_reference(frames[0])
    for frame in frames[1:]:
        result = init.add(frame)
        if isinstance(result, InitialMap):
            return result, frame
    raise AssertionError("no map")


def test_climb_over_the_ground_picks_the_plane_facing_the_camera(data_dir):
    # climbing 19 deg off the ground's normal: both homography decompositions explain the
    # tracks (Sampson errors within noise); the wrong one tilts the plane by 19 deg
    cam = small_camera()
    tex = load_texture(data_dir)
    poses = [look_down_pose(0.0012 * i, -0.0006 * i, 1.5 + 0.004 * i, yaw=0.002 * i,
                            tilt=(0.003 * i, 0.002 * i)) for i in range(40)]
    result, frame = _track_until_map(cam, tex, poses, TrackerConfig(init_homography_ratio=0.0))
    T_true = poses[frame.id] @ inv_se3(poses[0])
    assert rotation_angle_deg(T_true[:3, :3].T @ result.T_cur_ref[:3, :3]) < 0.3
    assert _direction_error_deg(T_true[:3, 3], result.T_cur_ref[:3, 3]) < 4.0


def test_homography_tie_on_exact_points_takes_the_facing_plane():
    rng = np.random.default_rng(1)
    P = np.column_stack((rng.uniform(-1, 1, (80, 2)), np.full(80, 3.0)))
    t = np.array([0.03, -0.015, -0.09])  # mostly along the normal of the plane z = 3
    x1 = P[:, :2] / P[:, 2:]
    Q = P + t
    x2 = Q[:, :2] / Q[:, 2:]
    R_est, t_est, _ = pose_from_homography(x1, x2, 1e-3, 0)
    assert rotation_angle_deg(R_est) < 0.05
    assert _direction_error_deg(t, t_est) < 0.5


def test_rotation_only_while_no_parallax(data_dir):
    cam = small_camera()
    tex = load_texture(data_dir)
    config = TrackerConfig()
    init = Initializer(cam, config)
    turn = [look_down_pose(0.0, 0.0, 1.5, yaw=0.004 * i, tilt=(0.003 * i, 0.0))
            for i in range(6)]
    frames = [Frame(i, float(i), render_plane(tex, cam, T), cam, 5) for i, T in enumerate(turn)]
    assert init.set_reference(frames[0])
    for frame in frames[1:]:
        assert init.add(frame) is InitOutcome.TRACKING
    R, rms = init.rotation_only()
    R_true = (turn[-1] @ inv_se3(turn[0]))[:3, :3]
    assert rotation_angle_deg(R_true.T @ R) < 0.1 and rms < 0.5
    # a sideways move of 5% of the height shows parallax: no rotation-only pose
    moved = Frame(9, 9.0, render_plane(tex, cam, look_down_pose(0.075, 0.0, 1.5)), cam, 5)
    init.add(moved)
    assert init.rotation_only() is None


def test_at_rest_only_while_the_tracks_stay_put(data_dir):
    """Poses before the map need the camera at rest: a small sideways move over the plane
    (tracks shifted by several pixels, which a turn could explain as well) is not rest."""
    cam = small_camera()
    tex = load_texture(data_dir)
    init = Initializer(cam, TrackerConfig())
    still = look_down_pose(0.0, 0.0, 1.5)
    assert init.set_reference(Frame(0, 0.0, render_plane(tex, cam, still), cam, 5))
    init.add(Frame(1, 1.0, render_plane(tex, cam, still), cam, 5))
    assert init.at_rest()
    moved = look_down_pose(0.03, 0.0, 1.5)
    init.add(Frame(2, 2.0, render_plane(tex, cam, moved), cam, 5))
    shift = np.median(np.linalg.norm(init.px_cur - init.px_ref, axis=1))
    assert shift > TrackerConfig().init_ransac_px and not init.at_rest()
