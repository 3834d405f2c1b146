"""The RGB-D odometry baseline: rigid fits against scipy's, RANSAC with outliers, the fit's
covariance against Monte Carlo, tracking a synthetic room, and its place in sdvl track and
sdvl track-table."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sdvl.cli import main
from sim.metrics import evaluate
from sim.synth.flight import synthetic_sequence
from sim.trajectory import Trajectory
from vo.depth_seeds import corner_depth
from vo.rgbd_odometry import RgbdConfig, RgbdOdometry
from vo.rigid_ransac import motion_covariance, ransac_rigid, rigid_fit


def random_motion(rng):
    R = Rotation.from_rotvec(rng.normal(0, 0.3, 3)).as_matrix()
    return R, rng.normal(0, 0.5, 3)


def test_rigid_fit_matches_scipys_kabsch():
    rng = np.random.default_rng(0)
    src = rng.normal(0, 1, (4, 20, 3))
    for h in range(4):
        R, t = random_motion(rng)
        dst = src[h] @ R.T + t + rng.normal(0, 0.01, (20, 3))
        fit_R, fit_t, _ = rigid_fit(src[h], dst)
        ref, _ = Rotation.align_vectors(dst - dst.mean(0), src[h] - src[h].mean(0))
        np.testing.assert_allclose(fit_R, ref.as_matrix(), atol=1e-9)
        np.testing.assert_allclose(fit_t, dst.mean(0) - fit_R @ src[h].mean(0), atol=1e-9)
    batch_R, _, _ = rigid_fit(src, src @ R.T + t)  # a batch of four at once
    np.testing.assert_allclose(batch_R, np.broadcast_to(R, (4, 3, 3)), atol=1e-9)


def test_weights_pull_the_fit_to_the_heavy_points():
    rng = np.random.default_rng(1)
    src = rng.normal(0, 1, (30, 3))
    dst = src.copy()
    dst[:5] += 0.5  # five pairs disagree
    weights = np.ones(30)
    weights[:5] = 1e-9
    R, t, _ = rigid_fit(src, dst, weights)
    np.testing.assert_allclose(R, np.eye(3), atol=1e-6)
    np.testing.assert_allclose(t, 0.0, atol=1e-6)


def test_ransac_finds_the_motion_among_outliers():
    rng = np.random.default_rng(2)
    R, t = random_motion(rng)
    src = rng.uniform(-2, 2, (100, 3)) + np.array([0.0, 0.0, 4.0])
    dst = src @ R.T + t
    outliers = rng.random(100) < 0.5
    dst[outliers] += rng.uniform(-1, 1, (outliers.sum(), 3))
    motion = ransac_rigid(src, dst, np.full(100, 0.01), 200, np.random.default_rng(0))
    np.testing.assert_allclose(motion.R, R, atol=1e-9)
    np.testing.assert_allclose(motion.t, t, atol=1e-9)
    np.testing.assert_array_equal(motion.inliers, ~outliers)
    assert ransac_rigid(src[:2], dst[:2], np.full(2, 0.01), 10, rng) is None
    line = np.outer(np.arange(10.0), (1, 0, 0))  # collinear: rotation about it is free
    assert ransac_rigid(line, line, np.full(10, 0.01), 10, rng) is None


def test_motion_covariance_matches_monte_carlo():
    rng = np.random.default_rng(3)
    src = rng.uniform(-1, 1, (40, 3)) + np.array([0.0, 0.0, 3.0])
    sigma, xis, covs = 0.02, [], []
    for _ in range(400):
        dst = src + rng.normal(0, sigma, src.shape)
        R, t, _ = rigid_fit(src, dst)
        # the fit's error as a left perturbation of the true (identity) motion
        xis.append(np.concatenate([t, Rotation.from_matrix(R).as_rotvec()]))
        covs.append(motion_covariance(R, t, src, dst))
    empirical = np.cov(np.array(xis).T)
    predicted = np.mean(covs, axis=0)
    np.testing.assert_allclose(np.diag(predicted), np.diag(empirical), rtol=0.25)


def test_keypoint_depth_skips_holes_and_edges():
    depth = np.full((10, 10), 2.0, np.float32)
    depth[:, 6:] = 4.0
    depth[2, 2] = 0.0
    depth[4, 4] = 2.1  # noise: the median ignores it
    px = np.array([[4.2, 4.4], [3.0, 2.0], [5.6, 5.0], [8.0, 5.0]])
    np.testing.assert_array_equal(corner_depth(depth, px, 0.1), [2.0, 0.0, 0.0, 4.0])


@pytest.fixture(scope="module")
def room():
    return synthetic_sequence("room-handheld", 25, (320, 240), depth="ideal")


def test_tracks_a_room_with_ideal_depth(room):
    odo = RgbdOdometry(room.camera)
    results = [odo.process(img, t, room.depth(i)) for i, (t, img) in enumerate(room.frames())]
    assert results[0].new_segment and np.allclose(results[0].T_w_c, np.eye(4))
    assert all(r.quality == "good" for r in results) and results[5].n_inliers >= 40
    est = Trajectory.from_matrices(np.array([r.t for r in results]),
                                   np.array([r.T_w_c for r in results]))
    ev = evaluate(room.groundtruth, est, "se3")
    assert ev.ate_rmse_m < 0.005 and ev.rot_rmse_deg < 0.2
    assert np.all(np.linalg.eigvalsh(results[-1].covariance) > 0)
    assert results[-1].covariance[0, 0] > results[2].covariance[0, 0]  # it grows


def test_frames_without_depth_lose_then_start_a_new_segment(room):
    odo = RgbdOdometry(room.camera, RgbdConfig(lost_after=2))
    out = [odo.process(room.image(i), room.timestamps[i], None if i in (3, 4) else room.depth(i))
           for i in range(7)]
    assert [r.quality for r in out[2:6]] == ["good", "bad", "lost", "good"]
    assert out[5].new_segment and np.allclose(out[5].T_w_c, out[2].T_w_c)


def test_sdvl_track_method_rgbd_sift_scores_se3(capsys):
    assert main(["track", "room-handheld", "--method", "rgbd-sift", "--size", "160x120",
                 "--max-frames", "8", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["align"] == "se3" and report["tracked"] == 8 and report["scale"] == 1.0
    assert {"features", "match", "ransac", "track"} <= set(report["stages"])


def test_depth_method_on_a_sequence_without_depth_is_an_error(data_dir, capsys):
    assert main(["track", str(data_dir / "vamr_ex01_checkerboard736"), "--method",
                 "rgbd-sift"]) == 2
    assert "needs depth" in capsys.readouterr().err


def test_track_table_has_an_rgbd_row(capsys):
    assert main(["track-table", "room-handheld", "--configs", "patch,rgbd-sift",
                 "--max-frames", "6", "--warm-up", "0", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    assert [r["config"] for r in rows] == ["patch", "rgbd-sift"]
    assert rows[1]["align"] == "se3" and rows[1]["tracked"] == 6
