"""The rotation prior: the turn between frames from the autopilot's attitude starts the image
alignment and pulls the pose refinement; a prior the images contradict is refused (and the
service says so); the fusion gives the camera's orientation from ATTITUDE and the mounting."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation
from vo_scenes import load_texture, look_down_pose, render_plane, small_camera

from daemon.config import MountingConfig
from daemon.fusion.config import FusionConfig
from daemon.fusion.estimator import FusionEstimator
from daemon.fusion.prior_watch import WINDOW, PriorWatch
from daemon.mounting import body_from_camera
from sim.metrics import evaluate
from sim.trajectory import Trajectory
from vo.config import TrackerConfig
from vo.result import PriorUse
from vo.rotation_prior import Orientation, relative_prior
from vo.tracker import Tracker

N = 90


def _turning_flight(i: int) -> np.ndarray:
    """T_c_w of a camera over a plane, sliding sideways while it yaws (a GUIDED corner)."""
    return look_down_pose(0.3 * np.sin(i * 0.04), 0.2 * np.sin(i * 0.03), 1.5,
                          yaw=0.6 * np.sin(0.03 * i))


@pytest.fixture(scope="module")
def flight(data_dir):
    cam = small_camera()
    tex = load_texture(data_dir)
    poses = [_turning_flight(i) for i in range(N)]
    frames = [(i / 30.0, render_plane(tex, cam, T)) for i, T in enumerate(poses)]
    return cam, frames, poses


def _track(cam, frames, orientations):
    tracker = Tracker(cam, TrackerConfig())
    try:
        results = [tracker.process(image, t, orientation=o)
                   for (t, image), o in zip(frames, orientations, strict=True)]
    finally:
        tracker.close()
    return results


def _ate(frames, poses, results) -> float:
    keep = [k for k, r in enumerate(results) if r.has_pose]
    gt = Trajectory.from_matrices(np.array([frames[k][0] for k in keep]),
                                  np.array([np.linalg.inv(poses[k]) for k in keep]))
    est = Trajectory.from_matrices(np.array([frames[k][0] for k in keep]),
                                   np.array([results[k].T_w_c for k in keep]))
    return evaluate(gt, est, "sim3").ate_rmse_m


def test_the_true_turn_is_used_and_keeps_the_track(flight):
    cam, frames, poses = flight
    # the camera's orientation in another fixed frame (a yawed NED): only turns matter
    R_x_w = Rotation.from_euler("z", 40, degrees=True).as_matrix()
    truth = [Orientation(R_x_w @ np.linalg.inv(T)[:3, :3]) for T in poses]
    with_prior = _track(cam, frames, truth)
    without = _track(cam, frames, [None] * N)
    used = [r.rotation_prior for r in with_prior if r.has_pose and not r.new_segment]
    assert used.count(PriorUse.USED) >= 0.9 * len(used)
    assert all(r.rotation_prior == PriorUse.NONE for r in without)
    assert sum(r.has_pose for r in with_prior) >= sum(r.has_pose for r in without) - 2
    assert _ate(frames, poses, with_prior) <= 1.2 * _ate(frames, poses, without) + 1e-3


def test_a_prior_the_images_contradict_is_refused_and_tracking_goes_on(flight):
    cam, frames, poses = flight
    # a camera mounted otherwise than configured: the attitude's turn is 5 degrees a frame off
    wrong = [Orientation(np.linalg.inv(T)[:3, :3]
                         @ Rotation.from_euler("x", 5 * k, degrees=True).as_matrix())
             for k, T in enumerate(poses)]
    results = _track(cam, frames, wrong)
    tracked = [r for r in results if r.has_pose and not r.new_segment]
    assert len(tracked) >= 0.8 * N
    assert all(r.rotation_prior == PriorUse.REFUSED for r in tracked)


def test_relative_prior_turns_the_last_rotation_by_the_turn_between_orientations():
    rng = np.random.default_rng(0)
    R_last_x, R_now_x, R_c_w = (Rotation.random(random_state=rng).as_matrix() for _ in range(3))
    R, info = relative_prior(Orientation(R_now_x, 1e-6), Orientation(R_last_x, 2e-6), R_c_w,
                             0.1)
    assert np.allclose(R, R_now_x.T @ R_last_x @ R_c_w)
    assert info == pytest.approx(1.0 / (np.radians(0.1) ** 2 + 3e-6))
    assert relative_prior(None, Orientation(R_last_x), R_c_w, 0.1) is None
    assert relative_prior(Orientation(R_now_x), Orientation(R_last_x), R_c_w, 0.0) is None


def test_refusals_in_most_frames_are_said_once_a_minute():
    said: list[str] = []
    watch = PriorWatch(said.append)
    for k in range(3 * WINDOW):
        watch.add(PriorUse.NONE, k / 30)  # frames without a prior do not count
        watch.add(PriorUse.REFUSED if k % 3 else PriorUse.USED, k / 30)
    assert len(said) == 1 and "[mounting]" in said[0]
    for k in range(3 * WINDOW, 3 * WINDOW + 61 * 30):
        watch.add(PriorUse.REFUSED, k / 30)
    assert len(said) == 2
    quiet = PriorWatch(said.append)
    for k in range(10 * WINDOW):
        quiet.add(PriorUse.REFUSED if k % 10 == 0 else PriorUse.USED, k / 30)
    assert len(said) == 2


def test_the_fusion_gives_the_camera_orientation_from_attitude_and_mounting():
    t = [100.0]
    estimator = FusionEstimator(FusionConfig(), MountingConfig(), now=lambda: t[0])
    estimator.set_clock_offset(100.0)
    assert estimator.orientation(100.0) is None
    mav = mavlink2.MAVLink(None, 1, 1)
    for k in range(51):  # 1 s of a 0.5 rad/s yaw at 50 Hz, 0.1 rad of roll
        t[0] = 100.0 + 0.02 * k + 0.003
        estimator.on_autopilot_message(
            mav.attitude_encode(20 * k, 0.1, 0.0, 0.01 * k, 0.0, 0.0, 0.5))
    got = estimator.orientation(100.51)
    R_n_b = Rotation.from_euler("ZYX", [0.255, 0.0, 0.1]).as_matrix()
    expected = R_n_b @ body_from_camera(MountingConfig())
    assert np.degrees(Rotation.from_matrix(got.R_x_c.T @ expected).magnitude()) < 0.01
    assert 0 <= got.var < 1e-6


def test_log_so3_is_scipys_rotation_vector():
    from vo.se3 import log_so3

    rng = np.random.default_rng(5)
    for R in Rotation.random(50, random_state=rng):
        assert np.allclose(log_so3(R.as_matrix()), R.as_rotvec(), atol=1e-9)
    small = Rotation.from_rotvec([1e-10, -2e-10, 3e-10])
    assert np.allclose(log_so3(small.as_matrix()), small.as_rotvec(), atol=1e-15)
