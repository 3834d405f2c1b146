"""A slow mapping thread, emulated deterministically (`sdvl track --mapping-period`): the
tracker maps stepped (vo.tracker.Tracker stepped_mapping), and this clock runs its mapping
steps as a mapping thread of a given speed would have finished them, in camera frame
periods. A frame that comes while the tracker's mapping backlog is full is skipped, as the
service skips it (it tracks the newest frame once the backlog has room)."""

from __future__ import annotations

from collections import deque

import numpy as np


class SlowMapping:
    """Offers camera frames to a tracker with stepped mapping: each tracked frame's mapping
    step takes `period` frame periods (a keyframe's `keyframe_period`, default the same),
    starts once the mapper is free and `delay` periods after the frame was tracked, and
    tracking sees it from the first frame after it ended (so at period 1 the map lags one
    frame, as with a mapping thread that keeps up)."""

    def __init__(self, tracker, period: int, delay: int = 0, keyframe_period: int | None = None):
        if not tracker.stepped_mapping:
            raise ValueError("SlowMapping needs a tracker with stepped_mapping")
        if period < 1 or delay < 0 or (keyframe_period or period) < 1:
            raise ValueError("the mapping periods must be >= 1 and the delay >= 0")
        self.tracker, self.period, self.delay = tracker, period, delay
        self.keyframe_period = keyframe_period or period
        self.skipped = 0
        self._now = 0  # the camera frame's index
        self._free_at = 0  # when the mapper finishes its last scheduled step
        self._ends: deque[int] = deque()  # when each waiting frame's mapping step ends

    def offer(self, image: np.ndarray, t: float):
        """Camera frame at time t: its FrameResult, or None when it was skipped."""
        now, self._now = self._now, self._now + 1
        backlog = self.tracker.backlog
        result = None
        if backlog is None or backlog.has_room():
            n_before = 0 if backlog is None else len(backlog)
            result = self.tracker.process(image, t)
            if self.tracker.backlog is not backlog:  # a new map: the old backlog is gone
                self._ends.clear()
                self._free_at, n_before = now, 0
            for _ in range(len(self.tracker.backlog or ()) - n_before):
                period = self.keyframe_period if result.keyframe else self.period
                self._free_at = max(self._free_at, now + self.delay) + period
                self._ends.append(self._free_at)
        else:
            self.skipped += 1
        while self._ends and self._ends[0] <= now:  # ended before the next frame
            self._ends.popleft()
            self.tracker.map_waiting(1)
        return result
