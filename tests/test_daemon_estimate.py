"""The pass-through estimator: camera mounting, scale, levelling, velocity, reset_counter."""

from __future__ import annotations

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from daemon.config import MavlinkConfig, MountingConfig
from daemon.estimate import PassThroughEstimator
from daemon.mounting import body_from_camera, euler_zyx
from vo.result import FrameResult

DT = 0.05


def pose(R=None, p=(0.0, 0.0, 0.0)) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = np.eye(3) if R is None else R, p
    return T


def run(estimator, poses, quality="good", covariance=None, first_new=True):
    """Feed poses at 20 Hz; the list of estimates (None where nothing is sent)."""
    out = []
    for i, T in enumerate(poses):
        result = FrameResult(i * DT, T, quality, covariance=covariance, n_matches=50,
                             n_attempts=60, n_inliers=45, new_segment=first_new and i == 0)
        out.append(estimator.on_frame(result, 100.0 + i * DT))
    return out


def estimator(preset="forward", scale=1.0, **angles):
    return PassThroughEstimator(MountingConfig(preset=preset, scale=scale, **angles),
                                MavlinkConfig())


@pytest.mark.parametrize(("preset", "angles", "camera_motion", "body_motion"), [
    ("forward", {}, (0, 0, 1), (1, 0, 0)),  # along the optical axis: nose
    ("forward", {}, (1, 0, 0), (0, 1, 0)),  # image right: right
    ("forward", {}, (0, 1, 0), (0, 0, 1)),  # image down: down
    ("down", {}, (0, 0, 1), (0, 0, 1)),  # optical axis down
    ("down", {}, (0, -1, 0), (1, 0, 0)),  # image top is the nose
    ("down", {}, (1, 0, 0), (0, 1, 0)),
    ("custom", {"yaw_deg": 90.0}, (0, 0, 1), (0, 1, 0)),  # looking right
    ("custom", {"pitch_deg": -90.0}, (0, -1, 0), (1, 0, 0)),  # same as "down"
    ("custom", {"roll_deg": 180.0}, (1, 0, 0), (0, -1, 0)),  # upside down
])
def test_mounting_maps_camera_motion_to_body_frd(preset, angles, camera_motion, body_motion):
    est = estimator(preset, scale=2.0, **angles)
    poses = [pose(p=np.array(camera_motion) * 0.1 * i) for i in range(4)]
    out = run(est, poses)
    assert out[0] is None  # the first pose anchors the local frame
    e = out[-1]
    assert np.allclose(e.position, 2.0 * 0.3 * np.array(body_motion), atol=1e-12)
    assert np.allclose(e.velocity_local, 2.0 * 0.1 / DT * np.array(body_motion), atol=1e-9)
    assert np.allclose(e.velocity_body, e.velocity_local, atol=1e-9)  # no rotation
    assert np.allclose(e.R_local_body, np.eye(3), atol=1e-12)
    assert e.quality == 100 and e.reset_counter == 0 and e.t_capture == 100.0 + 3 * DT


def test_down_preset_equals_custom_pitch_minus_90():
    down = body_from_camera(MountingConfig(preset="down"))
    custom = body_from_camera(MountingConfig(preset="custom", pitch_deg=-90.0))
    assert np.allclose(down, custom, atol=1e-12)
    assert np.allclose(down @ [0, 0, 1], [0, 0, 1], atol=1e-12)


def test_rotation_rates_and_body_velocity():
    """Forward camera turning about its y axis (down) is the vehicle yawing right."""
    est = estimator("forward")
    w = 0.4
    poses = [pose(Rotation.from_rotvec([0, w * i * DT, 0]).as_matrix(), (0, 0, 0.05 * i))
             for i in range(5)]
    e = run(est, poses)[-1]
    roll, pitch, yaw = euler_zyx(e.R_local_body)
    assert yaw == pytest.approx(w * 4 * DT) and abs(roll) < 1e-12 and abs(pitch) < 1e-12
    assert np.allclose(e.angular_rate, [0, 0, w], atol=1e-9)
    assert np.allclose(e.velocity_body, e.R_local_body.T @ e.velocity_local, atol=1e-12)


def test_local_frame_levelled_with_the_autopilot_attitude():
    est = estimator("forward")
    mav = mavlink2.MAVLink(None, 1, 1)
    est.on_autopilot_message(mav.attitude_encode(0, 0.1, -0.2, 1.0, 0, 0, 0))
    e = run(est, [pose(), pose(p=(0, 0, 0.1))])[-1]
    roll, pitch, yaw = euler_zyx(e.R_local_body)
    assert (roll, pitch, yaw) == pytest.approx((0.1, -0.2, 0.0), abs=1e-6)
    # moving along the tilted nose: the local frame sees the tilt
    assert np.allclose(e.position, e.R_local_body @ [0.1, 0, 0], atol=1e-7)


def test_covariance_rotated_into_local_frame_and_floored():
    est = estimator("forward", scale=3.0)
    cov = np.diag([1.0, 2.0, 3.0, 0.1, 0.2, 0.3]) * 1e-4  # camera axes x right, y down, z fwd
    e = run(est, [pose(), pose(p=(0, 0, 0.1))], covariance=cov)[-1]
    floor = np.array([0.1**2] * 3 + [0.05**2] * 3)
    expected = np.array([9 * 3.0, 9 * 1.0, 9 * 2.0, 0.3, 0.1, 0.2]) * 1e-4 + floor
    assert np.allclose(np.diag(e.pose_covariance), expected)
    assert np.allclose(np.diag(e.velocity_covariance),
                       2 * (expected - floor) / DT**2 + floor)


def test_no_estimate_without_a_good_pose():
    est = estimator()
    assert run(est, [pose()] * 3, quality="initializing") == [None] * 3
    assert run(est, [None] * 3, quality="lost") == [None] * 3
    bad = pose(p=(np.nan, 0, 0))
    assert run(est, [pose(), bad, bad], first_new=True)[1:] == [None, None]


def test_new_segment_increments_reset_counter_and_continues_from_last_pose():
    est = estimator("forward")
    first = run(est, [pose(p=(0, 0, 0.1 * i)) for i in range(4)])
    assert first[-1].reset_counter == 0
    last = first[-1].position
    # a new map with its own arbitrary world frame
    R = Rotation.from_euler("xyz", [0.3, -0.2, 1.0]).as_matrix()
    second = []
    for i in range(3):
        result = FrameResult(1.0 + i * DT, pose(R, (5, 5, 5 + 0.1 * i)), "good",
                             new_segment=(i == 0))
        second.append(est.on_frame(result, 200.0 + i * DT))
    assert second[0] is None and est.reset_counter == 1
    assert second[1].reset_counter == 1
    assert np.linalg.norm(second[1].position - last) == pytest.approx(0.1, abs=1e-9)
    assert np.allclose(second[1].R_local_body, first[-1].R_local_body, atol=1e-9)


def test_reset_counter_wraps():
    est = estimator()
    est.reset_counter = 255
    run(est, [pose(), pose(p=(0, 0, 0.1))])
    run(est, [pose(), pose(p=(0, 0, 0.1))])  # new_segment on its first frame
    assert est.reset_counter == 0


def test_degraded_tracking_inflates_covariance_and_lowers_quality():
    good = run(estimator(), [pose(), pose(p=(0, 0, 0.1))])[-1]
    weak = run(estimator(), [pose(), pose(p=(0, 0, 0.1))], quality="insufficient")[-1]
    bad = run(estimator(), [pose(), pose(p=(0, 0, 0.1))], quality="bad")[-1]
    assert (good.quality, weak.quality, bad.quality) == (100, 50, 10)
    assert np.allclose(weak.pose_covariance, 4 * good.pose_covariance)
    assert np.allclose(bad.velocity_covariance, 25 * good.velocity_covariance)
