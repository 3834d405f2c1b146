"""The tracker's RELOCALIZING state: a pose the relocaliser (vo.relocalization) finds for a lost
frame is only a candidate; it is accepted when the next frame, tracked from it as any frame is,
confirms it (enough inliers, a plausible motion from the candidate). A wrong relocalisation is a
wrong pose with a confident covariance, so one frame is spent to check it: the candidate frame
gets no pose, the confirming frame is the relocalised one."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vo.config import TrackerConfig
from vo.frame import Frame
from vo.frame_tracking import FrameTracking
from vo.map_matching import Matches
from vo.relocalization import Relocalizer
from vo.result import FrameResult, Quality
from vo.se3 import inv_se3


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
        self.refused = 0  # candidates the next frame did not confirm

    def reset(self) -> None:
        """Tracking was lost anew: no candidate."""
        self.candidate = None

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
        if found is None:
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
        self.tracking.resume(cand.frame, cand.matches, cand.covariance, count=False)
        result, keyframe = self.tracking.track(frame, timings)
        if result.has_pose and self._consistent(cand.frame, frame, result):
            self.tracking.matcher.count(cand.matches)
            result.new_segment = result.relocalized = True
            return result, keyframe
        self.tracking.restore(saved)
        self.refused += 1
        return None

    def _consistent(self, cand: Frame, frame: Frame, result: FrameResult) -> bool:
        """The confirming frame matched the map from the candidate as a tracked frame must
        (at least reloc_min_matches inliers, quality good) and moved from it no more than
        reloc_confirm_max_turn_deg."""
        cfg = self.config
        if result.n_inliers < cfg.reloc_min_matches or result.quality != Quality.GOOD:
            return False
        rel = frame.T_c_w @ inv_se3(cand.T_c_w)
        turn = np.degrees(np.arccos(np.clip((np.trace(rel[:3, :3]) - 1.0) / 2.0, -1.0, 1.0)))
        return turn <= cfg.reloc_confirm_max_turn_deg
