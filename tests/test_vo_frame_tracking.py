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


class _BadMatcher:
    """A matcher whose every frame is bad and held; it records what it accepts."""

    def __init__(self):
        self.accepted: list[tuple[int, bool]] = []

    def match(self, frame, timings):
        frame.T_c_w = frame.T_c_w.copy()
        frame.T_c_w[0, 3] -= 0.01  # the consensus's pose: 1 cm further
        none = np.zeros(0, np.int64)
        return Matches(none, np.zeros((0, 2)), none, 50, 50, none, np.zeros(0, bool),
                       frame.T_c_w, None, 0.0)

    def quality(self, m):
        return Quality.BAD

    def held(self, m):
        return True

    def accept(self, frame, m, count=True):
        frame.T_c_w = m.T
        self.accepted.append((frame.id, count))


def test_held_frames_are_tracked_on_from_unpublished_for_at_most_hold_max_s():
    """Bad frames the matcher holds are tracked on from (each from the one before), without a
    pose, without counting finds and without a step towards lost, for hold_max_s (0.3 s:
    frames 1-9 at 30 fps) after the last frame published; then bad frames lead to lost, and
    relocalisation goes on from the last frame published."""
    camera = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)
    matcher = _BadMatcher()
    tracking = FrameTracking(TrackerConfig(lost_after_bad=2), matcher, None)
    tracking._align = lambda frame, last: PriorUse.NONE
    published = Frame(0, 0.0, np.zeros((48, 64), np.uint8), camera, 1)
    tracking.last, tracking.published = published, (published, 5.0)

    def track(i: int):
        frame = Frame(i, i / 30.0, np.zeros((48, 64), np.uint8), camera, 1)
        frame.T_c_w = tracking.last.T_c_w.copy()
        return frame, *tracking.track(frame, {})

    for i in range(1, 10):
        frame, result, keyframe = track(i)
        assert result.held and result.quality == Quality.BAD and result.T_w_c is None
        assert tracking.last is frame and not keyframe
    assert matcher.accepted == [(i, False) for i in range(1, 10)]  # no finds counted
    assert np.isclose(tracking.last.T_c_w[0, 3], -0.09)  # each went on from the one before
    results = [track(i)[1] for i in (10, 11)]
    assert [r.quality for r in results] == [Quality.BAD, Quality.LOST]
    assert not any(r.held for r in results)
    assert tracking.last is published and tracking.turn_rate == 5.0
