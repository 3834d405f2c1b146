"""SDVL with depth (issue 30): a map from the first frame with depth, metric; new keyframes'
points at their measured inverse depth; depth ignored when switched off."""

from __future__ import annotations

import json

import numpy as np
import pytest
from vo_scenes import small_camera

from sdvl.cli import main
from sdvl.errors import InputError
from sim.metrics import evaluate
from sim.synth.flight import synthetic_sequence
from sim.trajectory import Trajectory
from vo.config import TrackerConfig
from vo.depth_seeds import measured_inverse_depth
from vo.map import CANDIDATE
from vo.result import Quality
from vo.tracker import Tracker


@pytest.fixture(scope="module")
def room():
    """A walk through the synthetic room with the D435's depth (noise, holes)."""
    return synthetic_sequence("room-handheld", 40, (320, 240), depth="d435")


def test_measured_inverse_depth_follows_the_sensor_model():
    cam = small_camera()
    depth = np.full((cam.height, cam.width), 2.0, np.float32)
    depth[:, 200:] = 3.0
    depth[100:110, 50:60] = 0.0  # a hole
    px = np.array([[20.0, 30.0], [250.0, 200.0], [55.0, 105.0], [199.0, 50.0], [300.0, 10.0]])
    f = cam.unproject(px)
    cfg = TrackerConfig(depth_noise_per_m2=0.004)
    rho, sigma = measured_inverse_depth(depth, px, f, cfg)
    for i, z in enumerate([2.0, 3.0, None, None, 3.0]):  # 199: a 3x3 across the depth edge
        if z is None:
            assert np.isnan(rho[i]) and np.isnan(sigma[i])
            continue
        X = f[i] / rho[i]  # the point rho puts on the bearing lies at depth z
        assert X[2] == pytest.approx(z)
        # sigma_z = k z^2 seen along the bearing: d(rho)/dz = -f_z / z^2
        assert sigma[i] == pytest.approx(0.004 * z * z * f[i, 2] / z ** 2)


def test_a_map_starts_on_the_first_frame_with_depth_and_is_metric(room):
    tracker = Tracker(room.camera)
    results = [tracker.process(img, t, room.depth(i)) for i, (t, img) in enumerate(room.frames())]
    first = results[0]
    assert first.has_pose and first.new_segment and np.allclose(first.T_w_c, np.eye(4))
    assert all(r.has_pose for r in results) and sum(r.new_segment for r in results) == 1
    assert sum(r.quality == Quality.GOOD for r in results) >= len(results) - 2
    est = Trajectory.from_matrices(room.timestamps, np.array([r.T_w_c for r in results]))
    se3, sim3 = evaluate(room.groundtruth, est, "se3"), evaluate(room.groundtruth, est, "sim3")
    assert se3.ate_rmse_m < 0.01 * se3.path_length_m
    assert sim3.scale == pytest.approx(1.0, abs=0.05)  # metric: no scale to find
    tracker.close()


def test_a_new_keyframes_points_start_at_their_measured_depth(room):
    cfg = TrackerConfig(depth_noise_per_m2=0.0123)  # a value no epipolar search gives
    tracker = Tracker(room.camera, cfg)
    for i, (t, img) in enumerate(room.frames()):
        result = tracker.process(img, t, room.depth(i))
        if result.keyframe and not result.new_segment:
            break
    else:
        pytest.fail("no second keyframe")
    pts = tracker.map.points
    new = np.flatnonzero((pts.status == CANDIDATE) & (pts.host == tracker.last.slot))
    assert len(new) >= 20
    px = np.column_stack((pts.u[new], pts.v[new]))
    rho, sigma = measured_inverse_depth(room.depth(i), px, pts.f[new], cfg)
    seeded = np.isfinite(rho)
    assert seeded.mean() > 0.5  # most corners have a depth (holes: searched as before)
    np.testing.assert_allclose(pts.rho[new[seeded]], rho[seeded])
    np.testing.assert_allclose(pts.sigma[new[seeded]], sigma[seeded])
    tracker.close()


def test_depth_switched_off_is_the_monocular_tracker(room):
    def poses(feed_depth: bool) -> list:
        tracker = Tracker(room.camera, TrackerConfig(depth=False))
        out = [tracker.process(room.image(i), room.timestamps[i],
                               room.depth(i) if feed_depth else None) for i in range(12)]
        tracker.close()
        return [None if r.T_w_c is None else r.T_w_c.tolist() for r in out]

    with_depth = poses(True)
    assert with_depth[0] is None  # the monocular initialiser needs two views
    assert with_depth == poses(False)


def test_no_monocular_map_once_depth_is_given(room):
    tracker = Tracker(room.camera)
    empty = np.zeros((room.camera.height, room.camera.width), np.float32)
    out = [tracker.process(room.image(i), room.timestamps[i], d)
           for i, d in enumerate([empty, None, None, room.depth(3)])]
    assert [r.has_pose for r in out] == [False, False, False, True]
    assert out[3].new_segment and np.allclose(out[3].T_w_c, np.eye(4))
    tracker.close()


def test_lost_with_depth_starts_a_new_map_from_depth():
    walk = synthetic_sequence("room-handheld", 460, (320, 240), depth="d435")  # frames lazily
    tracker = Tracker(walk.camera, TrackerConfig(reinit_after_lost_s=0.15))
    blank = np.full((walk.camera.height, walk.camera.width), 128, np.uint8)
    frames = [(walk.image(i), walk.depth(i)) for i in range(6)] + [(blank, walk.depth(6))] * 4
    frames += [(walk.image(i), walk.depth(i)) for i in range(450, 454)]  # far on: no relocation
    out = [tracker.process(img, 0.1 * k, d) for k, (img, d) in enumerate(frames)]
    assert [r.quality for r in out[8:12]] == [Quality.LOST] * 4
    # blank frames (a covered lens) do not count: the view can start a map from frame 10 on
    assert out[12].new_segment and np.allclose(out[12].T_w_c, np.eye(4))
    assert len(tracker.map.keyframes) == 1 and out[13].has_pose
    tracker.close()


def test_a_depth_map_of_the_wrong_size_is_an_input_error():
    cam = small_camera()
    with pytest.raises(InputError, match="depth map"):
        Tracker(cam).process(np.zeros((240, 320), np.uint8), 0.0, np.zeros((120, 160)))


def test_sdvl_track_method_sdvl_depth_scores_se3_from_the_first_frame(capsys):
    assert main(["track", "room-handheld", "--method", "sdvl-depth", "--size", "320x240",
                 "--max-frames", "10", "--json", "--quiet"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["align"] == "se3" and report["tracked"] == 10 and report["segments"] == 1
    assert report["first_pose_frame"] == 0 and report["first_depth_frame"] == 0


def test_track_table_has_sdvl_depth_rows_with_variants(capsys):
    assert main(["track-table", "room-handheld", "--size", "320x240", "--configs",
                 "patch,sdvl-depth", "--set", "depth_noise_per_m2=0.004,0.01", "--max-frames",
                 "6", "--warm-up", "0", "--json"]) == 0
    rows = [json.loads(line) for line in capsys.readouterr().out.splitlines()]
    rows = [r for r in rows if "summary" not in r]
    depth_rows = [r for r in rows if r["config"] == "sdvl-depth"]
    assert [r["variant"] for r in depth_rows] == ["depth_noise_per_m2=0.004",
                                                  "depth_noise_per_m2=0.01"]
    assert all(r["align"] == "se3" and r["tracked"] == 6 for r in depth_rows)
    patch = next(r for r in rows if r["config"] == "patch")
    assert patch["align"] == "sim3" and patch["tracked"] < 6  # two views before a map
