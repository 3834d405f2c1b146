"""Poses of the frames a two-view start waited through (issue 31: vamr's first ten frames).

The initialiser (vo.initialization) follows its reference's corners through every frame until
they have moved far enough apart to build a map from the reference and the current frame. Once
that map exists, those tracks are its points, so each frame in between has matches to them: its
pose is refined from them as tracking refines any frame's (vo.map_matching), newest first, each
from the one after it. The poses are late: a live consumer sent those frames' results (no pose)
long ago, so they come in the map's first result (FrameResult.earlier) for whoever records a
trajectory; the service does not compute them.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from vo.config import TrackerConfig
from vo.initialization import InitialMap, TrackedView
from vo.map_matching import MapMatcher
from vo.pose_optimizer import pose_covariance
from vo.quality import classify
from vo.result import FrameResult
from vo.se3 import inv_se3, orthonormalized


def late_poses(views: Sequence[TrackedView], start: InitialMap, point_ids: np.ndarray,
               matcher: MapMatcher, config: TrackerConfig,
               posed_until: float | None) -> list[FrameResult]:
    """Results with poses, oldest first, for the initialiser's `views` (the map's second
    keyframe last, left out) taken after `posed_until`, the time of the last pose given from
    the same reference (None: none was, and the first late pose starts the new segment).
    `start` is the two-view map whose tracks became the map's points `point_ids`. Each view is
    refined from the pose of the one after it, the newest from the second keyframe's (the
    reference may have left the views: they are the newest init_late_poses); a view with
    fewer than init_min_inliers inliers gets none."""
    results: list[FrameResult] = []
    T_c_w = start.T_cur_ref
    after = -np.inf if posed_until is None else posed_until
    for view in reversed(views[:-1]):
        if view.t <= after:
            break
        _, in_view, in_map = np.intersect1d(view.ids, start.track, assume_unique=True,
                                            return_indices=True)
        if len(in_map) < config.init_min_inliers:
            continue
        ids = point_ids[in_map]
        T, H, sigma, err = matcher.optimize_from(T_c_w, ids, view.px[in_view].astype(np.float64),
                                                 np.zeros(len(ids), dtype=np.int64))
        inliers = int(np.sum(err * matcher.focal < config.reprojection_inlier_px))
        if inliers < config.init_min_inliers:
            continue
        T_c_w = orthonormalized(T)
        T_w_c = inv_se3(T_c_w)
        results.append(FrameResult(view.t, T_w_c, classify(inliers, len(ids), config),
                                   covariance=pose_covariance(H, sigma, T_w_c),
                                   n_matches=len(ids), n_attempts=len(ids), n_inliers=inliers))
    results.reverse()
    if results:
        results[0].new_segment = posed_until is None
    return results
