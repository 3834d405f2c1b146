"""RGB-D visual odometry, the baseline SDVL-with-depth is compared with: SIFT features (OpenCV)
matched between consecutive frames, their 3D points from the depth maps, the rigid motion
between the two point sets by SVD inside RANSAC, chained into a trajectory. Poses are metric
(no scale to align), so compare them with an SE(3) alignment.

The public surface is the tracker's: build it from a camera model and a config, give it
`process(image, t, depth)`, get a vo.result.FrameResult.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from calib.camera import CameraModel
from sdvl.tables import dataclass_from_table, read_toml
from vo.depth_seeds import corner_depth
from vo.result import FrameResult, Quality, ms_since
from vo.rigid_ransac import motion_covariance, ransac_rigid
from vo.se3 import adjoint, orthonormalized


@dataclass
class RgbdConfig:
    """Parameters of the RGB-D odometry (TOML table [rgbd])."""

    features: int = 1000  # SIFT keypoints per frame (the strongest)
    ratio: float = 0.8  # Lowe's ratio test: best match distance below this times the second's
    # a keypoint's depth (the median of its 3x3 neighbourhood) is used only where the
    # neighbourhood spans at most this fraction of it: keypoints sit on corners, often on depth
    # edges where a pixel off is metres off (the noise alone spans ~4 sigma: 6% for a D435 at
    # 4 m)
    depth_edge_rel: float = 0.1
    hypotheses: int = 200  # RANSAC 3-point samples per frame
    # a pair is an inlier within inlier_m + inlier_per_m2 * z^2 metres (depth noise grows with
    # the square of the distance: Kinect 1.4e-3 z^2 rms, D435 at 848x480 3.6e-3 z^2)
    inlier_m: float = 0.02
    inlier_per_m2: float = 0.01
    min_inliers: int = 12  # fewer: the frame gets no pose
    good_inliers: int = 40  # fewer: the pose is "insufficient"
    # this many frames in a row without a pose start a new segment from the last pose
    lost_after: int = 3
    seed: int = 0

    @classmethod
    def from_dict(cls, d: dict[str, Any], path: str | Path | None = None) -> RgbdConfig:
        """A config from a mapping of parameter names; unknown keys and wrong types are errors."""
        return dataclass_from_table(cls, d, "rgbd", path)

    @classmethod
    def from_toml(cls, path: str | Path) -> RgbdConfig:
        """The [rgbd] table of a TOML file (defaults without one)."""
        return cls.from_dict(read_toml(path).get("rgbd", {}), path)

    def to_dict(self) -> dict[str, Any]:
        """The parameters as a plain mapping."""
        return asdict(self)


@dataclass
class _Keyed:
    """A frame's usable keypoints: SIFT descriptors and camera-frame 3D points."""

    descriptors: np.ndarray
    points: np.ndarray


class RgbdOdometry:
    """Frame-to-frame RGB-D odometry (see the module docstring)."""

    def __init__(self, camera: CameraModel, config: RgbdConfig | None = None):
        self.camera = camera
        self.config = config or RgbdConfig()
        self.sift = cv2.SIFT_create(nfeatures=self.config.features)
        self.matcher = cv2.BFMatcher(cv2.NORM_L2)
        self.rng = np.random.default_rng(self.config.seed)
        self.ref: _Keyed | None = None  # the last frame with a pose
        self.T_w_ref = np.eye(4)
        self.cov_ref = np.zeros((6, 6))
        self.failed = 0  # frames in a row without a pose

    def close(self) -> None:
        """Nothing runs in the background; for the tracker's interface."""

    def process(self, image: np.ndarray, t: float, depth: np.ndarray | None) -> FrameResult:
        """The pose of the frame at time t (world = the first frame with depth)."""
        start = time.perf_counter()
        timings: dict[str, float] = {}
        keyed = None if depth is None else self._keypoints(image, depth, timings)
        if keyed is None or len(keyed.points) < 3:
            result = self._fail(t, 0, 0, 0)
        elif self.ref is None:
            result = self._start(t, keyed)
        else:
            result = self._step(t, keyed, timings)
        timings["track"] = (time.perf_counter() - start) * 1e3
        result.timings = timings
        return result

    def _keypoints(self, image: np.ndarray, depth: np.ndarray,
                   timings: dict[str, float]) -> _Keyed:
        """SIFT keypoints with a trustworthy depth, as 3D points."""
        t0 = time.perf_counter()
        keypoints, descriptors = self.sift.detectAndCompute(image, None)
        timings["features"] = ms_since(t0)
        if not keypoints:
            return _Keyed(np.zeros((0, 128), np.float32), np.zeros((0, 3)))
        px = np.array([k.pt for k in keypoints])
        z = corner_depth(depth, px, self.config.depth_edge_rel)
        ok = z > 0
        rays = self.camera.unproject(px[ok])
        return _Keyed(descriptors[ok], rays / rays[:, 2:3] * z[ok, None])

    def _start(self, t: float, keyed: _Keyed) -> FrameResult:
        """This frame is the reference, at the last pose (identity for the first): a new
        segment."""
        self.ref, self.failed = keyed, 0
        n = len(keyed.points)
        return FrameResult(t, self.T_w_ref.copy(), Quality.GOOD, covariance=self.cov_ref.copy(),
                           n_matches=n, n_attempts=n, n_inliers=n, new_segment=True,
                           keyframe=True)

    def _step(self, t: float, keyed: _Keyed, timings: dict[str, float]) -> FrameResult:
        """Match to the reference, fit the motion, chain it."""
        cfg = self.config
        t0 = time.perf_counter()
        i_cur, i_ref = ratio_matches(self.matcher, keyed.descriptors, self.ref.descriptors,
                                     cfg.ratio)
        t1 = time.perf_counter()
        timings["match"] = (t1 - t0) * 1e3
        src, dst = keyed.points[i_cur], self.ref.points[i_ref]
        z = np.maximum(src[:, 2], dst[:, 2])
        # depth noise grows with z^2: weight each pair by the inverse of its variance
        weights = 1.0 / (src[:, 2] ** 4 + dst[:, 2] ** 4)
        motion = ransac_rigid(src, dst, cfg.inlier_m + cfg.inlier_per_m2 * z * z,
                              cfg.hypotheses, self.rng, weights)
        timings["ransac"] = (time.perf_counter() - t1) * 1e3
        n_in = 0 if motion is None else int(motion.inliers.sum())
        if n_in < cfg.min_inliers:
            return self._fail(t, len(i_cur), len(keyed.points), n_in)
        T_ref_cur = np.eye(4)
        T_ref_cur[:3, :3], T_ref_cur[:3, 3] = motion.R, motion.t
        inc = motion_covariance(motion.R, motion.t, src[motion.inliers], dst[motion.inliers])
        A = adjoint(self.T_w_ref)
        self.cov_ref = self.cov_ref + A @ inc @ A.T
        self.T_w_ref = orthonormalized(self.T_w_ref @ T_ref_cur)
        self.ref, self.failed = keyed, 0
        quality = Quality.GOOD if n_in >= cfg.good_inliers else Quality.INSUFFICIENT
        return FrameResult(t, self.T_w_ref.copy(), quality, covariance=self.cov_ref.copy(),
                           n_matches=len(i_cur), n_attempts=len(keyed.points), n_inliers=n_in,
                           n_hypotheses=motion.hypotheses)

    def _fail(self, t: float, matches: int, attempts: int, inliers: int) -> FrameResult:
        """No pose for this frame; after `lost_after` in a row the next frame with depth
        starts a new segment at the last pose."""
        self.failed += 1
        lost = self.failed >= self.config.lost_after
        if lost:
            self.ref = None
        return FrameResult(t, None, Quality.LOST if lost else Quality.BAD, n_matches=matches,
                           n_attempts=attempts, n_inliers=inliers)


def ratio_matches(matcher, query: np.ndarray, train: np.ndarray,
                  ratio: float) -> tuple[np.ndarray, np.ndarray]:
    """Indices (query, train) of the matches that pass Lowe's ratio test."""
    if len(query) < 2 or len(train) < 2:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    pairs = [p for p in matcher.knnMatch(query, train, k=2)
             if len(p) == 2 and p[0].distance < ratio * p[1].distance]
    return (np.array([p[0].queryIdx for p in pairs], np.int64),
            np.array([p[0].trainIdx for p in pairs], np.int64))
