"""Automatic map initialisation (thesis 6.6.1): LK-track the first keyframe's corners until the
mean shift passes a threshold, then RANSAC homography, decomposition, choice by Sampson error,
triangulation and scaling to a median depth."""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass
from enum import Enum

import cv2
import numpy as np

from calib.camera import CameraModel
from vo.config import TrackerConfig
from vo.frame import Frame
from vo.matcher import triangulate_depth
from vo.se3 import orthonormalized

LK_WINDOW = (21, 21)
LK_LEVELS = 3
# a rotation alone explains the tracks when this fraction of them is within init_ransac_px
ROTATION_ONLY_FRACTION = 0.9
# two homography decompositions are a tie when their Sampson errors differ by less than
# TIE_RATIO, or both are within TIE_FRACTION of the inlier threshold (rms)
TIE_RATIO = 1.5
TIE_FRACTION = 0.25


class InitOutcome(Enum):
    """What a step of the initialiser decided when it built no map."""

    TRACKING = "tracking"  # keep tracking the reference's corners
    RESTART = "restart"  # the reference cannot make a map: replace it by this frame


@dataclass
class InitialMap:
    """Two-view result: T_cur_ref, and per point its ref/cur level-0 pixels, ref bearing, depth
    and track (index into the reference's corners: TrackedView.ids)."""

    T_cur_ref: np.ndarray
    px_ref: np.ndarray
    px_cur: np.ndarray
    f_ref: np.ndarray
    depth: np.ndarray
    track: np.ndarray


@dataclass
class TrackedView:
    """A frame the initialiser saw (the reference, or one tracked into since): its time, the
    tracks still followed (indices into the reference's corners) and where it saw them
    (level-0 pixels)."""

    t: float
    ids: np.ndarray
    px: np.ndarray


def best_per_cell(x: np.ndarray, y: np.ndarray, score: np.ndarray, cell: int,
                  width: int) -> np.ndarray:
    """Indices of the highest-scoring point in each grid cell."""
    cols = (width + cell - 1) // cell
    cid = (y // cell).astype(np.int64) * cols + (x // cell).astype(np.int64)
    order = np.lexsort((-score, cid))
    first = np.ones(len(order), dtype=bool)
    first[1:] = cid[order][1:] != cid[order][:-1]
    return order[first]


def sampson_error(E: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Sampson distance of normalised correspondences (N, 2) to the essential matrix E."""
    h1 = np.column_stack((x1, np.ones(len(x1))))
    h2 = np.column_stack((x2, np.ones(len(x2))))
    Ex1 = h1 @ E.T
    Etx2 = h2 @ E
    num = np.einsum("ij,ij->i", h2, Ex1) ** 2
    den = Ex1[:, 0] ** 2 + Ex1[:, 1] ** 2 + Etx2[:, 0] ** 2 + Etx2[:, 1] ** 2
    return num / np.maximum(den, 1e-30)


def pose_from_homography(x1: np.ndarray, x2: np.ndarray, threshold: float, seed: int):
    """(R, t, inlier mask) of the second view from normalised points via a RANSAC homography,
    picking among the physically valid decompositions by Sampson error; None on failure."""
    cv2.setRNGSeed(seed)
    H, mask = cv2.findHomography(x1, x2, cv2.RANSAC, threshold, maxIters=2000, confidence=0.999)
    if H is None:
        return None
    inl = mask.ravel().astype(bool)
    _, Rs, ts, ns = cv2.decomposeHomographyMat(H, np.eye(3))
    valid = cv2.filterHomographyDecompByVisibleRefpoints(
        Rs, ns, x1[inl].reshape(-1, 1, 2).astype(np.float32),
        x2[inl].reshape(-1, 1, 2).astype(np.float32))
    scored = []
    for i in range(len(Rs)) if valid is None else valid.ravel():
        R, t = Rs[i], ts[i].ravel()
        if np.linalg.norm(t) < 1e-12:
            continue
        tx = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]])
        scored.append((float(np.sum(sampson_error(tx @ R, x1[inl], x2[inl]))),
                       -abs(float(ns[i].ravel()[2])), R, t / np.linalg.norm(t)))
    if not scored:
        return None
    scored.sort(key=lambda c: c[0])
    noise = inl.sum() * (TIE_FRACTION * threshold) ** 2  # both fit to a fraction of the threshold
    if len(scored) > 1 and scored[1][0] < TIE_RATIO * scored[0][0] + noise:
        # a plane seen from two views: the true solution and the one with the plane normal
        # and the motion swapped explain the points equally well (the Sampson errors are
        # noise); that happens when the camera moves close to the plane normal (a drone
        # climbing over the ground). Prefer the plane that faces the camera: the wrong
        # choice tilts the whole map by the angle between motion and normal.
        scored[:2] = sorted(scored[:2], key=lambda c: c[1])
    _, _, R, t = scored[0]
    return R, t, inl


def pose_from_essential(x1: np.ndarray, x2: np.ndarray, threshold: float, seed: int):
    """(R, t, inlier mask) from the 5-point essential matrix (Stewenius, via OpenCV) in RANSAC,
    the cheirality-checked decomposition; None on failure."""
    cv2.setRNGSeed(seed)
    E, mask = cv2.findEssentialMat(x1, x2, np.eye(3), cv2.RANSAC, 0.999, threshold)
    if E is None or E.shape != (3, 3):
        return None
    n, R, t, pose_mask = cv2.recoverPose(E, x1, x2, np.eye(3), mask=mask.copy())
    if n == 0:
        return None
    return R, t.ravel() / np.linalg.norm(t), pose_mask.ravel().astype(bool)


def rotation_between(f_ref: np.ndarray, f_cur: np.ndarray) -> np.ndarray:
    """The rotation R minimising sum |f_cur - R f_ref|^2 over unit bearings (Kabsch)."""
    U, _, Vt = np.linalg.svd(f_ref.T @ f_cur)
    return Vt.T @ np.diag([1.0, 1.0, np.linalg.det(Vt.T @ U.T)]) @ U.T


def two_view_pose(x1: np.ndarray, x2: np.ndarray, threshold: float, seed: int,
                  homography_ratio: float):
    """The homography solution, unless the essential matrix explains clearly more points
    (inliers of H < homography_ratio x inliers of E: a non-planar scene)."""
    found = pose_from_homography(x1, x2, threshold, seed)
    if homography_ratio <= 0.0:
        return found
    alt = pose_from_essential(x1, x2, threshold, seed)
    if alt is not None and (found is None or found[2].sum() < homography_ratio * alt[2].sum()):
        return alt
    return found


class Initializer:
    """Tracks the reference frame's corners into new frames until a map can be built."""

    def __init__(self, camera: CameraModel, config: TrackerConfig):
        self.camera = camera
        self.config = config
        self.ref: Frame | None = None
        self.px_ref = np.zeros((0, 2), np.float32)
        self.px_cur = np.zeros((0, 2), np.float32)
        self.track = np.zeros(0, dtype=np.int64)  # each track's index among the reference's
        # the reference and the frames since, newest init_late_poses + 1 (vo.late_poses)
        self.views: deque[TrackedView] = deque(maxlen=config.init_late_poses + 1)

    def set_reference(self, frame: Frame) -> bool:
        """Start from `frame` if it has enough corners; False otherwise."""
        c = frame.corners(self.config.fast_threshold)
        x, y = c.level0()
        keep = best_per_cell(x, y, c.score, self.config.grid_cell, self.camera.width)
        keep = keep[np.argsort(-c.score[keep])][: self.config.init_max_features]
        if len(keep) < self.config.init_min_features:
            self.ref = None
            return False
        self.ref = frame
        self.px_ref = np.column_stack((x[keep], y[keep])).astype(np.float32)
        self.px_cur = self.px_ref.copy()
        self.track = np.arange(len(keep))
        self.views.clear()
        self.views.append(TrackedView(frame.t, self.track, self.px_ref))
        return True

    def add(self, frame: Frame, build: bool = True) -> InitialMap | InitOutcome:
        """Track into `frame`: an InitialMap when ready, else whether to keep tracking or to
        replace the reference by this frame. Without `build` the tracks are only followed (no
        map may be built yet: the two-view fit would be thrown away)."""
        nxt, status, _ = cv2.calcOpticalFlowPyrLK(
            self.ref.pyr.images[0], frame.pyr.images[0], self.px_ref, self.px_cur.copy(),
            winSize=LK_WINDOW, maxLevel=LK_LEVELS, flags=cv2.OPTFLOW_USE_INITIAL_FLOW,
            criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 30, 0.01))
        ok = status.ravel().astype(bool) & self.camera.in_image(nxt, 1.0)
        self.px_ref, self.px_cur, self.track = self.px_ref[ok], nxt[ok], self.track[ok]
        self.views.append(TrackedView(frame.t, self.track, self.px_cur))
        if len(self.px_ref) < self.config.init_min_tracked:
            return InitOutcome.RESTART
        shift = np.linalg.norm(self.px_cur - self.px_ref, axis=1)
        if not build or np.mean(shift) < self.config.init_min_disparity_px or \
                self.rotation_only():
            # a turn alone (a drone tilting as it starts to move) shifts the tracks without
            # parallax: its homography has no usable translation
            return InitOutcome.TRACKING
        result = self._two_view()
        return InitOutcome.RESTART if result is None else result

    def at_rest(self) -> bool:
        """True while the tracks have moved less than init_ransac_px (median) since the
        reference: neither a turn nor a move of the camera shows yet."""
        if self.ref is None or len(self.px_ref) == 0:
            return False
        shift = np.linalg.norm(self.px_cur - self.px_ref, axis=1)
        return bool(np.median(shift) < self.config.init_ransac_px)

    def rotation_only(self) -> tuple[np.ndarray, float] | None:
        """(R_cur_ref, rms residual in px) while the tracks show no parallax: a rotation alone
        moves ROTATION_ONLY_FRACTION of them to within init_ransac_px of where they are; None
        once parallax shows. A sideways move over a distant flat scene also fits a rotation, so
        only at_rest() bounds how far the camera may have moved."""
        if self.ref is None or len(self.px_ref) < self.config.init_min_tracked:
            return None
        f_ref = self.camera.unproject(self.px_ref)
        f_cur = self.camera.unproject(self.px_cur)
        focal = float(np.sqrt(self.camera.fx * self.camera.fy))
        inl = np.ones(len(f_ref), dtype=bool)
        for _ in range(2):  # fit on all tracks, then again on those the first fit explains
            R = rotation_between(f_ref[inl], f_cur[inl])
            err = np.linalg.norm(f_ref @ R.T - f_cur, axis=1) * focal
            inl = err < self.config.init_ransac_px
            if inl.mean() < ROTATION_ONLY_FRACTION:
                return None
        return R, float(np.sqrt(np.mean(err[inl] ** 2)))

    def _two_view(self) -> InitialMap | None:
        f_ref = self.camera.unproject(self.px_ref)
        f_cur = self.camera.unproject(self.px_cur)
        x1 = f_ref[:, :2] / f_ref[:, 2:]
        x2 = f_cur[:, :2] / f_cur[:, 2:]
        focal = float(np.sqrt(self.camera.fx * self.camera.fy))
        found = two_view_pose(x1, x2, self.config.init_ransac_px / focal, self.config.seed,
                              self.config.init_homography_ratio)
        if found is None:
            return None
        R, t, inl = found
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        T = orthonormalized(T)
        depth = np.array([triangulate_depth(T, f_ref[i], f_cur[i]) for i in range(len(f_ref))])
        X_cur = (f_ref * depth[:, None]) @ R.T + t
        with np.errstate(invalid="ignore", divide="ignore"):
            err = np.linalg.norm(X_cur[:, :2] / X_cur[:, 2:] - x2, axis=1) * focal
        good = inl & (depth > 0) & (X_cur[:, 2] > 0) & (err < 2.0 * self.config.init_ransac_px)
        if good.sum() < self.config.init_min_inliers:
            return None
        scale = self.config.init_map_depth / float(np.median(depth[good]))
        T[:3, 3] *= scale
        return InitialMap(T, self.px_ref[good].astype(np.float64),
                          self.px_cur[good].astype(np.float64), f_ref[good], depth[good] * scale,
                          self.track[good])
