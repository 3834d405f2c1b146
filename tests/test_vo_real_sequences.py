"""Whole real sequences through the tracker (sequential mode): VAMR and KITTI 00 (defaults and its
preset) accuracy, TUM fr1/rpy runs to the end with every frame accounted for."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.datasets import open_sequence
from sim.metrics import evaluate
from sim.track_command import TrackLog
from sim.trajectory import Trajectory
from vo.config import TrackerConfig
from vo.map import FREE
from vo.tracker import Tracker

PRESETS = Path(__file__).resolve().parents[1] / "vo" / "presets"


def _track(path: Path, config: TrackerConfig | None = None):
    """The sequence, the trajectory and map segments as `sdvl track` counts them (late poses
    in, relocalisations and merged maps no new segment), and each frame's quality."""
    seq = open_sequence(path)
    tracker = Tracker(seq.camera, config)
    log, qualities = TrackLog(None), []
    for stamp, image in seq.frames():
        r = tracker.process(image, stamp)
        qualities.append(r.quality)
        if r.has_pose:
            assert np.all(np.isfinite(r.T_w_c)) and np.all(np.isfinite(r.covariance))
        log.add(stamp, r)
    est = Trajectory.from_matrices(np.array(log.times), np.array(log.poses))
    return seq, est, qualities, max(log.segment) + 1


def test_vamr_checkerboard_full(data_dir):
    seq, est, qualities, segments = _track(data_dir / "vamr_ex01_checkerboard736")
    assert len(qualities) == 736
    assert len(est) >= 0.95 * 736 and segments == 1
    assert evaluate(seq.groundtruth, est, "sim3").ate_rmse_m <= 0.010


def test_tum_rpy_runs_through(data_dir):
    # fast rotations at 2-3.5 deg/frame: the map is lost in one turn (frame 190, haswell)
    # and a new one taken, which joins the old one where the view comes back (vo.map_merge;
    # RESULTS.md: tracker-map-merge): one segment, as issue 31 asks
    _, est, qualities, segments = _track(data_dir / "tum_fr1_rpy")
    assert len(qualities) == 723
    assert segments == 1 and len(est) >= 680


def test_kitti_with_defaults_keeps_one_map(data_dir):
    # the 80-degree turn at up to 3.7 deg/frame: keyframes come as the map's points leave the
    # grid cells (with inlier counts it was lost: 165/200 in 3 maps, 33.6 m); outlier
    # rejection keeps wrong corners on the epipolar segments out, at thresholds grown with the
    # 1241-pixel width (0.64 m; 1.13 m at 2 / 4 px, 2.79 m without, the C++ original
    # 1.49-1.68 m); issue 31 asks 1.0 m
    seq, est, qualities, segments = _track(data_dir / "kitti00_first200")
    assert len(qualities) == 200
    assert len(est) >= 198 and segments == 1
    assert evaluate(seq.groundtruth, est, "sim3").ate_rmse_m <= 1.0


def test_kitti_with_its_preset_meets_the_acceptance(data_dir):
    # forward motion and a 90-degree turn: one map segment through the whole sequence
    config = TrackerConfig.from_toml(PRESETS / "kitti_10hz.toml")
    seq, est, qualities, segments = _track(data_dir / "kitti00_first200", config)
    assert len(qualities) == 200
    assert len(est) >= 0.9 * 200 and segments == 1
    assert evaluate(seq.groundtruth, est, "sim3").ate_rmse_m <= 3.0


def test_frames_waiting_for_mapping_keep_their_points(data_dir, monkeypatch):
    """A mapping thread behind tracking maps frames whose matched points may since have been
    deleted: their slots must not be recycled before those frames are mapped (a keyframe would
    record observations of, and seed depths from, other points). Mapping runs here LAG frames
    behind tracking, deterministically, as a slow mapping thread would (kitti00: 13 stale
    references when slots were recycled after two mapping steps, whatever the frames)."""
    seq = open_sequence(data_dir / "kitti00_first200")
    config = TrackerConfig.from_toml(PRESETS / "kitti_10hz.toml")
    tracker = Tracker(seq.camera, config)
    lag, waiting, stale, mapper = 4, [], [], [tracker.mapper]

    def lagging_map_step(frame, keyframe):
        if tracker.mapper is not mapper[0]:  # a new map: the old one's frames are forgotten
            mapper[0] = tracker.mapper
            waiting.clear()
        pts = tracker.map.points
        waiting.append((frame, keyframe, pts.host[frame.feat_point].copy(),
                        pts.u[frame.feat_point].copy()))
        while len(waiting) > lag:
            old, is_kf, host, u = waiting.pop(0)
            ids = old.feat_point
            same = (pts.status[ids] != FREE) & (pts.host[ids] == host) & (pts.u[ids] == u)
            stale.append(int((~same).sum()))
            tracker.mapper.step(old, is_kf)

    monkeypatch.setattr(tracker.mapping, "submit", lagging_map_step)
    for t, image in seq.frames(None):
        tracker.process(image, t)
    assert len(stale) > 100
    assert sum(stale) == 0
