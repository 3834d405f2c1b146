"""FrameTracking's handling of a frame's quality: held bad frames (vo.map_matching,
MapMatcher.held) are tracked on from without a pose and without a step towards lost, for a
while."""

from __future__ import annotations

import numpy as np

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.frame_tracking import FrameTracking
from vo.map_matching import Matches
from vo.result import PriorUse, Quality


class _Matcher:
    """A matcher whose frames have the quality `qualities` gives their id (bad otherwise) and
    are held unless their id is in `refused`; it records what it accepts."""

    def __init__(self, qualities: dict[int, Quality], refused: set[int]):
        self.qualities, self.refused = qualities, refused
        self.accepted: list[tuple[int, bool]] = []

    def match(self, frame, timings):
        frame.T_c_w = frame.T_c_w.copy()
        frame.T_c_w[0, 3] -= 0.01  # the consensus's pose: 1 cm further
        none = np.zeros(0, np.int64)
        m = Matches(none, np.zeros((0, 2)), none, 50, 50, none, np.zeros(0, bool),
                    frame.T_c_w, np.eye(6), 1.0)
        m.frame_id = frame.id
        return m

    def quality(self, m):
        return self.qualities.get(m.frame_id, Quality.BAD)

    def held(self, m):
        return m.frame_id not in self.refused

    def accept(self, frame, m, count=True):
        frame.T_c_w = m.T
        frame.feat_point = np.zeros(0, np.int64)
        self.accepted.append((frame.id, count))


class _NoKeyframes:
    def due(self, n_seen, good, frame):
        return False


def test_held_frames_are_tracked_on_from_unpublished_for_at_most_hold_max_s():
    """Bad frames the matcher holds are tracked on from (each from the one before), without a
    pose, without counting finds and without a step towards lost, for hold_max_s (0.25 s)
    after the last frame published; after a hold an insufficient frame is held too, a good
    one is published. A bad frame not held (6) and one past the window (13) make lost
    (lost_after_bad 2), and relocalisation goes on from the last frame published (5)."""
    camera = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)
    matcher = _Matcher({4: Quality.INSUFFICIENT, 5: Quality.GOOD}, {6})
    config = TrackerConfig(lost_after_bad=2, hold_max_s=0.25)
    tracking = FrameTracking(config, matcher, _NoKeyframes())
    tracking._align = lambda frame, last: PriorUse.NONE
    first = Frame(0, 0.0, np.zeros((48, 64), np.uint8), camera, 1)
    tracking.last, tracking.published = first, (first, np.eye(4), 0.0, 5.0)
    frames, results = {}, {}
    for i in range(1, 14):
        frames[i] = Frame(i, i / 30.0, np.zeros((48, 64), np.uint8), camera, 1)
        frames[i].T_c_w = tracking.last.T_c_w.copy()
        results[i], keyframe = tracking.track(frames[i], {})
        assert not keyframe
    held = [i for i, r in results.items() if r.held]
    assert held == [1, 2, 3, 4, 7, 8, 9, 10, 11, 12]
    assert all(results[i].T_w_c is None and results[i].quality == Quality.BAD for i in held)
    assert results[5].quality == Quality.GOOD and results[5].T_w_c is not None
    assert np.isclose(results[5].T_w_c[0, 3], 0.05)  # from the held frames before it
    assert results[6].quality == Quality.BAD and results[13].quality == Quality.LOST
    assert [c for i, c in matcher.accepted if i in held] == [False] * len(held)
    assert [i for i, c in matcher.accepted if c] == [5]  # finds counted only when published
    assert tracking.last is frames[5] and tracking.published[0] is frames[5]
    assert np.isclose(tracking.turn_rate, 0.0)  # frame 5's: its motion did not turn
