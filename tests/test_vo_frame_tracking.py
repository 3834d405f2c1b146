"""FrameTracking's handling of a frame's quality: held bad frames (vo.map_matching,
MapMatcher.held) are tracked on from without a pose and without a step towards lost."""

from __future__ import annotations

import numpy as np

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.frame_tracking import FrameTracking
from vo.map_matching import Matches
from vo.result import PriorUse, Quality


class _BadMatcher:
    """A matcher whose every frame is bad, held while `holding`; it records what it accepts."""

    def __init__(self):
        self.holding = True
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
        return self.holding

    def accept(self, frame, m, count=True):
        frame.T_c_w = m.T
        self.accepted.append((frame.id, count))


def test_held_frames_are_tracked_on_from_unpublished_and_do_not_lead_to_lost():
    camera = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)
    matcher = _BadMatcher()
    tracking = FrameTracking(TrackerConfig(lost_after_bad=2), matcher, None)
    tracking._align = lambda frame, last: PriorUse.NONE
    tracking.last = Frame(0, 0.0, np.zeros((48, 64), np.uint8), camera, 1)

    def track(i: int):
        frame = Frame(i, i / 30.0, np.zeros((48, 64), np.uint8), camera, 1)
        frame.T_c_w = tracking.last.T_c_w.copy()
        return frame, *tracking.track(frame, {})

    for i in range(1, 5):
        frame, result, keyframe = track(i)
        assert result.held and result.quality == Quality.BAD and result.T_w_c is None
        assert tracking.last is frame and not keyframe
    assert matcher.accepted == [(i, False) for i in range(1, 5)]  # no finds counted
    assert np.isclose(tracking.last.T_c_w[0, 3], -0.04)  # each went on from the one before
    matcher.holding = False
    assert [track(i)[1].quality for i in (5, 6)] == [Quality.BAD, Quality.LOST]
