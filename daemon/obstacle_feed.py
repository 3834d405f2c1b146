"""The depth frames' obstacle distances for the autopilot (daemon/obstacles.py), at
`obstacles.rate_hz` by frame time, computed in the tracking thread right after a frame's
estimate (a few milliseconds per depth map) and sent by the loop as OBSTACLE_DISTANCE."""

from __future__ import annotations

import numpy as np

from daemon.config import Config
from daemon.estimate import VisionEstimate
from daemon.frames import Frame
from daemon.mounting import body_T_camera, euler_zyx
from daemon.obstacles import ObstacleDistances, ObstacleScan, ObstacleSettings


class ObstacleFeed:
    """Scans the depth map of each frame that is due; the camera model comes with the first
    (the tracker's, built for the frames' size)."""

    def __init__(self, config: Config):
        o = config.obstacles
        self.settings = ObstacleSettings(min_m=o.min_m, max_m=o.max_m, band_m=o.band_m)
        self.period_s = 1.0 / o.rate_hz
        self.T_b_c = body_T_camera(config)
        self._scanner: ObstacleDistances | None = None
        self._t0: float | None = None  # frame time of the first scan
        self._slot = -1  # the last period (since _t0) that had its scan

    def scan(self, frame: Frame, camera: object,
             estimate: VisionEstimate | None) -> ObstacleScan | None:
        """The frame's obstacle scan when one is due and it has a depth map (levelled with the
        estimate's roll and pitch when there is one); None otherwise."""
        if frame.depth is None or camera is None or not self._due(frame.t_source):
            return None
        if self._scanner is None or self._scanner.camera is not camera:
            self._scanner = ObstacleDistances(camera, self.T_b_c, self.settings)
        level = None if estimate is None else euler_zyx(estimate.R_local_body)[:2]
        return self._scanner.scan(frame.depth, frame.t_capture, level)

    def _due(self, t: float) -> bool:
        """Whether the frame at time t is the first of its period: rate_hz on average whatever
        the frame rate, never more than one period and one frame apart."""
        if self._t0 is None:
            self._t0 = t
        slot = int(np.floor((t - self._t0) / self.period_s + 1e-6))
        if slot <= self._slot:
            return False
        self._slot = slot
        return True
