"""When a tracked frame becomes a keyframe (thesis 6.6): after enough frames when the points seen
fall below a ratio of those seen at the last keyframe, or at once when too many are lost."""

from __future__ import annotations

import numpy as np

from vo.config import TrackerConfig
from vo.frame import Frame
from vo.mapping import Mapper
from vo.se3 import rotation_angle_deg


class KeyframePolicy:
    """Counts the tracked frames since the last keyframe and the points seen then."""

    def __init__(self, config: TrackerConfig, mapper: Mapper):
        self.config = config
        self.mapper = mapper
        self.frames_since_kf = 0
        self.kf_visible: int | None = None  # points seen at the last keyframe

    def restart(self) -> None:
        """A new map: the first tracked frame sets the reference (the initial map's count,
        all LK tracks, is not comparable with a tracked frame's, one match per grid cell)."""
        self.frames_since_kf = 0
        self.kf_visible = None

    def due(self, n_seen: int, good: bool, frame: Frame) -> bool:
        """Count a tracked `frame` that sees n_seen map points; True when it becomes a keyframe
        (only a good frame can). The points "seen when the keyframe was made" (6.6) include
        its new candidates, which tracking uses once the mapper has added them and updated
        them candidate_min_updates times: until then the reference is the most points seen
        (else a keyframe taken with few points keeps the reference low and the next one comes
        too late). The window counts the frames mapped since the keyframe, not those tracked:
        a mapping thread that lags updates the candidates later. It applies to the count of
        grid cells with map points only: with inlier counts it took keyframes too often."""
        self.frames_since_kf += 1
        if self.kf_visible is None:
            self.kf_visible = n_seen
        elif (not self.config.kf_count_inliers
              and self.mapper.frames_since_keyframe <= self.config.candidate_min_updates):
            self.kf_visible = max(self.kf_visible, n_seen)
        if not (good and self._needed(n_seen, frame)):
            return False
        self.frames_since_kf = 0
        self.kf_visible = n_seen
        return True

    def _needed(self, n_seen: int, frame: Frame) -> bool:
        """Keyframe policy of 6.6: enough frames and points lost where the view is new, or too
        many points lost."""
        cfg = self.config
        if n_seen < (1.0 - cfg.lost_points_ratio) * self.kf_visible:
            return True
        # the thesis policy is relative to the last keyframe; a floor keeps a sparse map
        # (a keyframe taken where little was visible) from never growing again
        return (self.frames_since_kf >= cfg.kf_min_frames
                and (n_seen < cfg.kf_points_ratio * self.kf_visible
                     or n_seen < cfg.kf_min_points)
                and self._new_view(frame))

    def _new_view(self, frame: Frame) -> bool:
        """Whether no keyframe of the map stands within kf_min_baseline of the frame's median
        scene depth of it and within kf_min_turn_deg of its orientation: PTAM's "far enough
        from the other keyframes" (the thesis' chapter 2; its 6.6 counts only points)."""
        cfg = self.config
        if cfg.kf_min_baseline <= 0:
            return True
        # no map lock: a threaded mapping step holds it for milliseconds, and a hover asks on
        # every frame (66-74 % of the frames dropped in `sdvl fly --realtime --load 2`)
        depths = self.mapper.scene_depths(frame)
        if len(depths) == 0:
            return True
        reach = cfg.kf_min_baseline * float(np.median(depths))
        R_c_w, centre = frame.T_c_w[:3, :3], frame.position
        return not any(
            np.linalg.norm(kf.position - centre) < reach
            and rotation_angle_deg(kf.T_c_w[:3, :3] @ R_c_w.T) < cfg.kf_min_turn_deg
            for kf in list(self.mapper.map.keyframes.values()))
