"""What the tracker returns for each frame."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

QUALITIES = ("initializing", "good", "insufficient", "bad", "lost")


@dataclass
class FrameResult:
    """One frame's outcome.

    `T_w_c` is world-from-camera (None when there is no pose); `covariance` is the 6x6 covariance
    of the pose in the tracker's world frame, translation xyz then rotation xyz (a left
    perturbation exp(d) * T_w_c); `new_segment` is true on the first pose of a new map.
    `n_attempts` counts the map points matching tried (the quality ratio's denominator),
    `n_hypotheses` the RANSAC hypotheses outlier rejection fitted (0 without it).
    """

    t: float
    T_w_c: np.ndarray | None
    quality: str
    covariance: np.ndarray | None = None
    n_matches: int = 0
    n_attempts: int = 0
    n_inliers: int = 0
    timings: dict[str, float] = field(default_factory=dict)
    new_segment: bool = False
    keyframe: bool = False
    n_hypotheses: int = 0

    @property
    def has_pose(self) -> bool:
        """True when the frame has a world-from-camera pose."""
        return self.T_w_c is not None
