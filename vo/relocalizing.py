"""The tracker's RELOCALIZING state: a pose the relocaliser (vo.relocalization) finds for a lost
frame is only a candidate. It must be reachable from the last pose before the loss (turned no
faster than the camera was turning then, with some leeway), and the next frame, tracked from it
as any frame is, must confirm it (enough inliers, good quality, reachable too). A wrong
relocalisation is a wrong pose with a confident covariance, so one frame is spent to check it:
the candidate frame gets no pose, the confirming frame is the relocalised one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vo.config import TrackerConfig
from vo.frame import Frame
from vo.frame_tracking import FrameTracking
from vo.map_matching import Matches
from vo.relocalization import Relocalizer
from vo.result import FrameResult, Quality
from vo.se3 import inv_se3, rotation_angle_deg


@dataclass
class Candidate:
    """A lost frame's pose found in the map, not yet confirmed."""

    frame: Frame
    matches: Matches
    covariance: np.ndarray


class Relocalizing:
    """Finds lost frames in the map and hands tracking a verified pose."""

    def __init__(self, config: TrackerConfig, relocalizer: Relocalizer,
                 tracking: FrameTracking):
        self.config, self.relocalizer, self.tracking = config, relocalizer, tracking
        self.candidate: Candidate | None = None

    def reset(self) -> None:
        """Tracking was lost anew: no candidate, the keyframes tried from the newest."""
        self.candidate = None
        self.relocalizer.restart()

    def step(self, frame: Frame, timings: dict[str, float], last: Frame | None
             ) -> tuple[FrameResult, bool]:
        """Frame's result while lost (quality LOST without a pose, or the relocalised pose
        tracking goes on from) and whether it becomes a keyframe. `last` is the last frame
        tracked before the loss (a reference to relocalise against)."""
        if self.candidate is not None:
            confirmed = self._confirm(frame, timings)
            if confirmed is not None:
                return confirmed
        found = self.relocalizer.find(frame, timings, last)
        lost = FrameResult(frame.t, None, Quality.LOST)
        if found is None or not self._reachable(last, frame.t, found[0].T,
                                                found[0].ids[found[0].inlier],
                                                self.tracking.turn_rate):
            return lost, False
        if not self.config.reloc_confirm:
            return self.tracking.resume(frame, *found), False
        self.candidate = Candidate(frame, *found)
        return lost, False

    def _confirm(self, frame: Frame, timings: dict[str, float]
                 ) -> tuple[FrameResult, bool] | None:
        """Track frame from the candidate; its result (a relocalised pose) when that confirms
        the candidate, else None (tracking as before the candidate)."""
        cand, self.candidate = self.candidate, None
        saved = self.tracking.save()
        last, rate = self.tracking.last, self.tracking.turn_rate
        self.tracking.resume(cand.frame, cand.matches, cand.covariance, count=False)
        result, keyframe = self.tracking.track(frame, timings)
        ids = frame.feat_point
        # reachable from the last pose, and from the candidate in one frame: a frame tracked
        # from a wrong candidate can still align to its own place
        if (result.has_pose and self._confirms(result)
                and self._reachable(last, frame.t, frame.T_c_w, ids, rate)
                and self._reachable(cand.frame, frame.t, frame.T_c_w, ids, rate)):
            self.tracking.matcher.count(cand.matches)
            result.new_segment = result.relocalized = True
            return result, keyframe
        self.tracking.restore(saved)
        return None

    def _confirms(self, result: FrameResult) -> bool:
        """The frame tracked from a candidate matched the map as a tracked frame must: at least
        reloc_min_matches inliers, quality good."""
        return (result.n_inliers >= self.config.reloc_min_matches
                and result.quality == Quality.GOOD)

    def _reachable(self, last: Frame | None, t: float, T_c_w: np.ndarray, ids: np.ndarray,
                   rate: float) -> bool:
        """A pose T_c_w at time t, matching map points ids, is one the camera could have
        reached from the last pose before the loss: turned by no more than
        reloc_turn_rate_factor times its turn rate then (`rate`, deg/s; at least
        reloc_min_turn_rate_deg_s) over the time since, and moved by at most
        reloc_max_move_depths times the median depth of those points. True without a last
        pose."""
        cfg = self.config
        if last is None:
            return True
        bound = max(cfg.reloc_turn_rate_factor * rate, cfg.reloc_min_turn_rate_deg_s)
        turned = rotation_angle_deg((T_c_w @ inv_se3(last.T_c_w))[:3, :3])
        X = self.tracking.matcher.map.points.pos_w[ids] @ T_c_w[:3, :3].T + T_c_w[:3, 3]
        moved = np.linalg.norm(inv_se3(T_c_w)[:3, 3] - last.position)
        return (turned <= bound * (t - last.t)
                and moved <= cfg.reloc_max_move_depths * float(np.median(X[:, 2])))
