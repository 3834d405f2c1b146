"""The tracker wrapper that hands fusion the map points each frame matched (scene.py)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from daemon.fusion.config import FusionConfig
from daemon.fusion.measurements import update_scene
from daemon.fusion.scene import SceneResult, SceneTracker, matched_points
from daemon.fusion.state import LOG_SCALE, NavFilter
from vo.result import FrameResult

POINTS = np.arange(30.0).reshape(10, 3)


class FakeTracker:
    """Just what scene.py reads of a vo Tracker: the last frame and the map's points."""

    def __init__(self) -> None:
        self.map = SimpleNamespace(points=SimpleNamespace(pos_w=POINTS.copy()))
        self.last = None
        self.closed = False

    def process(self, image: np.ndarray, t: float, **extra) -> FrameResult:
        self.last = SimpleNamespace(t=t, feat_point=np.array([1, 4, 9]))
        return FrameResult(t, np.eye(4), "good", covariance=np.eye(6), n_matches=3)

    def close(self) -> None:
        self.closed = True


def test_results_carry_the_matched_points_and_the_rest_unchanged() -> None:
    tracker = SceneTracker(FakeTracker())
    result = tracker.process(np.zeros((4, 4), np.uint8), 1.5)
    assert isinstance(result, SceneResult)
    assert result.t == 1.5 and result.quality == "good" and result.n_matches == 3
    np.testing.assert_array_equal(result.scene_w, POINTS[[1, 4, 9]])
    tracker.map.points.pos_w[1] = -1.0  # a copy: the mapping thread may move the points
    assert result.scene_w[0, 0] == 3.0
    tracker.close()  # everything else is the tracker's
    assert tracker.tracker.closed


def test_no_points_without_a_pose_or_for_another_frame() -> None:
    tracker = FakeTracker()
    tracker.process(None, 1.0)
    assert matched_points(tracker, FrameResult(1.0, None, "lost")) is None
    assert matched_points(tracker, FrameResult(2.0, np.eye(4), "good")) is None
    tracker.last.feat_point = np.array([], dtype=np.int64)
    assert matched_points(tracker, FrameResult(1.0, np.eye(4), "good")) is None


def _scale_std_after_scene_height(spread_fraction: float) -> float:
    """The scale's std after one scene-height update at 12 m (the map says 12 units: scale 1)."""
    f = NavFilter(FusionConfig(terrain_relief_m=0.05, scene_height_std_fraction=0.005))
    f.start(0.0, 3.0)
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), 0.0, scale_std=0.05)
    f.reference("range", 12.0, 0.01)
    assert update_scene(f, float(np.log(12.0)), 0.0, spread_fraction)
    return float(np.sqrt(f.P[LOG_SCALE, LOG_SCALE]))


def test_scene_height_counts_the_spread_of_the_ground_it_sees() -> None:
    """With a 0.05 m relief floor and 0.5 % median noise: over open ground (spread under the
    floor) the map's height fixes the scale to about hypot(0.05 m, 0.5 %) / 12 m; over
    buildings (spread 7 % of the height) it is a weak hint."""
    flat = _scale_std_after_scene_height(0.001)
    assert flat == _scale_std_after_scene_height(0.0)
    assert 0.004 < flat < 0.008
    assert _scale_std_after_scene_height(0.07) > 0.04
