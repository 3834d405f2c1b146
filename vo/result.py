"""What the tracker returns for each frame."""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from vo.map_merge import Similarity


class Quality(StrEnum):
    """Tracking quality of a frame (thesis 6.10), and the states around it. Members compare
    equal to their strings, so code that still compares strings keeps working."""

    INITIALIZING = "initializing"  # no map yet
    GOOD = "good"  # matched / attempted above the ratio
    INSUFFICIENT = "insufficient"  # below the ratio, enough matches
    BAD = "bad"  # below the ratio and too few matches: no pose
    LOST = "lost"  # bad frames in a row: relocalising or starting a new map


class PriorUse(StrEnum):
    """How a tracked frame used the caller's rotation prior (vo.rotation_prior)."""

    NONE = "none"  # not given (or for this frame's predecessor), or off
    USED = "used"
    REFUSED = "refused"  # the image alignment turned beyond the gate from it


@dataclass
class FrameResult:
    """One frame's outcome.

    `T_w_c` is world-from-camera (None when there is no pose); `covariance` is the 6x6 covariance
    of the pose in the tracker's world frame, translation xyz then rotation xyz (a left
    perturbation exp(d) * T_w_c); `new_segment` is true where the poses jump: on the first pose
    of a new map and on a relocalised one (`relocalized`: in the same map, its world frame and
    scale go on, but the pose may jump from where dead reckoning put it, so the service
    increments its reset counter as on any discontinuity).
    `n_attempts` counts the map points matching tried (the quality ratio's denominator),
    `n_hypotheses` the RANSAC hypotheses outlier rejection fitted (0 without it),
    `rotation_prior` how the caller's orientation was used. `held` marks a bad frame tracking
    goes on from though it has no pose to publish (vo.map_matching, MapMatcher.held).
    `earlier` holds late poses of frames before this one, oldest first: on a new map's first
    result, the frames its initialiser waited through (vo.late_poses), whose own results had
    none; when the first of them has new_segment, the new segment starts there and this frame
    goes on with it.
    A live consumer has sent those frames' results already and does not publish them.
    `merged` (vo.map_merge.Similarity) is set when, since the previous result, the map before
    the newest re-initialisation was joined to the one after it (vo.map_merge): it takes the
    older map's world into the newer one's, where the poses went on (the poses given in the
    older one can be re-expressed; nothing jumps). It concerns the poses before this result's
    (a result that starts a new map may carry the merge of the two before it).
    Everything after `quality` is given by keyword.
    """

    t: float
    T_w_c: np.ndarray | None
    quality: Quality
    covariance: np.ndarray | None = field(default=None, kw_only=True)
    n_matches: int = field(default=0, kw_only=True)
    n_attempts: int = field(default=0, kw_only=True)
    n_inliers: int = field(default=0, kw_only=True)
    timings: dict[str, float] = field(default_factory=dict, kw_only=True)
    new_segment: bool = field(default=False, kw_only=True)
    relocalized: bool = field(default=False, kw_only=True)
    keyframe: bool = field(default=False, kw_only=True)
    n_hypotheses: int = field(default=0, kw_only=True)
    rotation_prior: PriorUse = field(default=PriorUse.NONE, kw_only=True)
    held: bool = field(default=False, kw_only=True)
    earlier: list[FrameResult] = field(default_factory=list, kw_only=True)
    merged: Similarity | None = field(default=None, kw_only=True)

    @property
    def has_pose(self) -> bool:
        """True when the frame has a world-from-camera pose."""
        return self.T_w_c is not None


def ms_since(t0: float) -> float:
    """Milliseconds since perf_counter() was t0 (a stage's entry in FrameResult.timings)."""
    return (time.perf_counter() - t0) * 1e3
