"""Tracking quality as in thesis 6.10, and the lost state after consecutive bad frames (6.9)."""

from __future__ import annotations

from vo.config import TrackerConfig
from vo.result import Quality


def classify(n_matches: int, n_attempts: int, config: TrackerConfig) -> Quality:
    """GOOD when matched/attempted > ratio; BAD when not and matches < minimum; else
    INSUFFICIENT. The tracker counts as matched the matches that survive the pose
    refinement (inliers)."""
    ratio = n_matches / n_attempts if n_attempts > 0 else 0.0
    if ratio > config.quality_min_ratio:
        return Quality.GOOD
    if n_matches < config.quality_min_matches:
        return Quality.BAD
    return Quality.INSUFFICIENT


class LostCounter:
    """Counts consecutive bad frames; lost after `lost_after_bad` of them."""

    def __init__(self, config: TrackerConfig):
        self.limit = config.lost_after_bad
        self.bad_run = 0

    def update(self, quality: Quality) -> bool:
        """Record one frame's quality; True when tracking is now lost."""
        self.bad_run = self.bad_run + 1 if quality == Quality.BAD else 0
        return self.bad_run >= self.limit
