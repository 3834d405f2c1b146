"""Sparse image alignment of a frame to an earlier frame through the map points that frame saw
(thesis 6.7.1): the first step of tracking, and of relocalising against a keyframe."""

from __future__ import annotations

import numpy as np

from calib.camera import CameraModel
from vo import sparse_align
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.map import CANDIDATE, CONVERGED, PointStore
from vo.map_matching import MIN_POSE_MATCHES
from vo.se3 import inv_se3


def align_frame(frame: Frame, ref: Frame, ids: np.ndarray, px: np.ndarray, pts: PointStore,
                camera: CameraModel, config: TrackerConfig, measure: bool = False,
                rotation_only: bool = False) -> float:
    """Move frame's pose (its prior set) to where the patches around pixels `px` of points
    `ids` in `ref` fit frame's image (turning it only, with `rotation_only`); with
    `measure`, return how badly they fit afterwards (sparse_align.residual_ratio at the
    finest level aligned; inf when alignment was impossible), else NaN."""
    alive = (pts.status[ids] == CANDIDATE) | (pts.status[ids] == CONVERGED)
    if alive.sum() < MIN_POSE_MATCHES:
        return np.inf
    ids, px = ids[alive], px[alive]
    X = pts.pos_w[ids] @ ref.T_c_w[:3, :3].T + ref.T_c_w[:3, 3]
    depth = np.linalg.norm(X, axis=1)
    xyz = camera.unproject(px) * depth[:, None]
    T_cur_ref = frame.T_c_w @ inv_se3(ref.T_c_w)
    T_cur_ref = sparse_align.align(camera.params, ref.pyr, frame.pyr, px, xyz, T_cur_ref,
                                   config.align_max_level, config.align_min_level,
                                   config.align_iterations, config.align_robust, rotation_only)
    frame.T_c_w = T_cur_ref @ ref.T_c_w
    if not measure:
        return np.nan
    return sparse_align.residual_ratio(camera.params, ref.pyr, frame.pyr, px, xyz, T_cur_ref,
                                       config.align_min_level)
