"""The map points a frame matched, passed with its tracker result so fusion can measure the
camera's height above the ground in map units.

A downward rangefinder gives the height in metres; the map gives it in its own units (the
points below the camera, projected on the vertical). Their ratio is the map's scale in level
flight at constant height too, where neither the IMU nor the barometer can tell it.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import numpy as np

from vo.result import FrameResult


@dataclass
class SceneResult(FrameResult):
    """A FrameResult with the tracker-world positions of the map points it matched, and
    whether its map is metric (started from a depth map: no scale to estimate)."""

    scene_w: np.ndarray | None = None  # (N, 3)
    metric: bool = False


class SceneTracker:
    """A vo Tracker whose results are SceneResults; everything else is the tracker's.

    A map is metric when the tracker started it from a depth map (its `depth_mode` at the
    map's first pose); relocalising into the same map keeps what the map was."""

    def __init__(self, tracker: object):
        self.tracker = tracker
        self._map: object = None  # the map of the last new segment, and whether it is metric
        self._metric = False

    def __getattr__(self, name: str) -> object:
        return getattr(self.tracker, name)

    def process(self, image: np.ndarray, t: float, **extra: object) -> SceneResult:
        """Track one frame (vo Tracker.process, with its depth map and the camera's
        orientation when given) and attach the points it matched."""
        result = self.tracker.process(image, t, **extra)
        if result.new_segment and self.tracker.map is not self._map:
            self._map = self.tracker.map
            self._metric = bool(getattr(self.tracker, "depth_mode", False))
        values = {f.name: getattr(result, f.name) for f in fields(FrameResult)}
        return SceneResult(**values, scene_w=matched_points(self.tracker, result),
                           metric=self._metric and result.has_pose)


def matched_points(tracker: object, result: FrameResult) -> np.ndarray | None:
    """World positions of the map points the tracker matched in the frame of `result` (a copy;
    the mapping thread may move them meanwhile), None when the frame has none."""
    last = getattr(tracker, "last", None)
    if not result.has_pose or last is None or last.t != result.t:
        return None
    ids = np.asarray(last.feat_point)
    points = tracker.map.points.pos_w
    ids = ids[(ids >= 0) & (ids < len(points))]
    return points[ids].astype(np.float64) if len(ids) else None
