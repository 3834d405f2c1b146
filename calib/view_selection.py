"""Which views to calibrate from: reprojection-error outliers out, near-duplicate video frames out.

`calibrate_robustly` drops views whose RMS reprojection error stands far above the others (a
misdetected corner, a moving board, rolling shutter) and calibrates again. `MotionGate` keeps a
video or live frame only when the board has moved since every view already kept.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from calib.board import Detection
from calib.calibration import CalibrationResult, View, calibrate
from sdvl.errors import InputError

DEFAULT_MIN_VIEWS = 8
DEFAULT_OUTLIER_FACTOR = 3.0
OUTLIER_FLOOR_PX = 0.3
_MAX_ROUNDS = 3


def require_views(n_good: int, min_views: int, why: str = "") -> None:
    """InputError saying how many more good views are needed when there are too few."""
    if n_good < min_views:
        raise InputError(
            f"only {n_good} good view(s) of the board{why}; {min_views - n_good} more needed "
            f"(at least {min_views}): take more images with the whole board sharp and visible, "
            "tilted and in different parts of the image")


def outlier_mask(per_view_rms: np.ndarray, factor: float = DEFAULT_OUTLIER_FACTOR) -> np.ndarray:
    """True for views whose RMS error is above `factor` x the median (and above 0.3 px)."""
    limit = max(factor * float(np.median(per_view_rms)), OUTLIER_FLOOR_PX)
    return per_view_rms > limit


@dataclass
class RobustCalibration:
    """The final calibration, the views it used and the views rejected with their error."""

    result: CalibrationResult
    views: list[View]
    rejected: list[tuple[str, float]] = field(default_factory=list)


def calibrate_robustly(views: list[View], size: tuple[int, int], model: str,
                       min_views: int = DEFAULT_MIN_VIEWS,
                       factor: float = DEFAULT_OUTLIER_FACTOR) -> RobustCalibration:
    """Calibrate, drop outlier views by reprojection error, calibrate again (a few rounds)."""
    require_views(len(views), min_views)
    rejected: list[tuple[str, float]] = []
    result = calibrate(views, size, model)
    for _ in range(_MAX_ROUNDS):
        bad = outlier_mask(result.per_view_rms, factor)
        if not bad.any():
            break
        rejected += [(v.name, float(e)) for v, e, b in
                     zip(views, result.per_view_rms, bad, strict=True) if b]
        views = [v for v, b in zip(views, bad, strict=True) if not b]
        require_views(len(views), min_views,
                      f" left after rejecting {len(rejected)} with outlier reprojection error")
        result = calibrate(views, size, model)
    return RobustCalibration(result, views, rejected)


def board_displacement(a: Detection, b: Detection) -> float:
    """Mean pixel distance between the corners two detections share (inf if fewer than 4)."""
    index = {tuple(np.round(p, 6)): i for i, p in enumerate(a.object_points)}
    pairs = [(index[key], j) for j, p in enumerate(b.object_points)
             if (key := tuple(np.round(p, 6))) in index]
    if len(pairs) < 4:
        return float("inf")
    ia, ib = np.array(pairs).T
    return float(np.mean(np.linalg.norm(a.image_points[ia] - b.image_points[ib], axis=1)))


class MotionGate:
    """Accepts a detection only when it differs by `min_move_px` from every accepted one."""

    def __init__(self, min_move_px: float):
        self.min_move_px = min_move_px
        self._kept: list[Detection] = []

    def moved(self, detection: Detection) -> float:
        """Smallest displacement from the accepted detections (inf when none accepted yet)."""
        return min((board_displacement(k, detection) for k in self._kept), default=float("inf"))

    def accept(self, detection: Detection) -> bool:
        """Remember and accept `detection` when the board has moved enough; else False."""
        if self.moved(detection) < self.min_move_px:
            return False
        self._kept.append(detection)
        return True
