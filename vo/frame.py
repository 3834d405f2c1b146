"""A frame: its image pyramid in one flat buffer, FAST corners per level with a row index, pose.

The pyramid is stored flat (`pyr`, with per-level `offsets`, `widths`, `heights`) so numba
kernels take any level, and a keyframe's pyramid can be copied into a slot of the map's store.
Pixel coordinates at level l are level-0 coordinates divided by 2**l.
"""

from __future__ import annotations

import cv2
import numba
import numpy as np

from calib.camera import CameraModel, unproject_pixel
from sdvl.errors import InputError
from vo.orb import CornerDescriptors
from vo.patch import from_level


class Pyramid:
    """Image pyramid with `levels` levels packed into one uint8 buffer."""

    def __init__(self, image: np.ndarray, levels: int):
        h, w = image.shape
        sizes = [(w, h)]
        for _ in range(levels - 1):
            sizes.append(((sizes[-1][0] + 1) // 2, (sizes[-1][1] + 1) // 2))  # pyrDown's size
        self.widths = np.array([s[0] for s in sizes], dtype=np.int64)
        self.heights = np.array([s[1] for s in sizes], dtype=np.int64)
        areas = self.widths * self.heights
        self.offsets = np.concatenate(([0], np.cumsum(areas)[:-1])).astype(np.int64)
        # each level is made in its place in the flat buffer (no copies of the levels)
        self.flat = np.empty(int(areas.sum()), dtype=np.uint8)
        self.images = [self.flat[o:o + a].reshape(sh, sw)
                       for o, a, (sw, sh) in zip(self.offsets, areas, sizes, strict=True)]
        self.images[0][:] = image
        for level in range(1, levels):
            cv2.pyrDown(self.images[level - 1], dst=self.images[level])
        # what kernels take to find a level in `flat` (the same for every frame of a camera)
        self.layout = (self.offsets, self.widths, self.heights)

    @staticmethod
    def flat_size(width: int, height: int, levels: int) -> int:
        """Buffer length a pyramid of an image of this size needs."""
        total, w, h = 0, width, height
        for _ in range(levels):
            total += w * h
            w, h = (w + 1) // 2, (h + 1) // 2
        return total


def detect_fast(image: np.ndarray, threshold: int) -> tuple[np.ndarray, np.ndarray]:
    """FAST corners (N, 2) of one image and their scores."""
    detector = cv2.FastFeatureDetector_create(threshold=threshold, nonmaxSuppression=True)
    kps = detector.detect(image)
    if not kps:
        return np.zeros((0, 2)), np.zeros(0)
    pts = cv2.KeyPoint_convert(kps).astype(np.float64)
    return pts, fast_scores(image, pts)


# the FAST circle of radius 3, (dx, dy) in order around it, and the arc a corner needs
FAST_CIRCLE = np.array([(0, -3), (1, -3), (2, -2), (3, -1), (3, 0), (3, 1), (2, 2), (1, 3),
                        (0, 3), (-1, 3), (-2, 2), (-3, 1), (-3, 0), (-3, -1), (-2, -2),
                        (-1, -3)], dtype=np.int64)
FAST_ARC = 9


@numba.njit(cache=True, nogil=True)
def fast_scores(image, pts):
    """FAST scores (OpenCV's responses) of corners pts (N, 2: integer x, y, 3 pixels inside):
    the largest threshold at which each would still be a corner, minus 1, i.e. over the arcs
    of FAST_ARC contiguous circle pixels, the largest of an arc's smallest difference from
    the centre (all brighter, or all darker), minus 1. OpenCV gives its responses only one
    Python attribute access at a time, which cost more than finding the corners (issue 31)."""
    ring = np.empty(32, dtype=np.int64)
    out = np.empty(pts.shape[0])
    for i in range(pts.shape[0]):
        x, y = int(pts[i, 0]), int(pts[i, 1])
        v = np.int64(image[y, x])
        for k in range(16):
            ring[k] = np.int64(image[y + FAST_CIRCLE[k, 1], x + FAST_CIRCLE[k, 0]]) - v
            ring[k + 16] = ring[k]
        best = 0
        for start in range(16):
            lo = hi = ring[start]
            for j in range(1, FAST_ARC):
                lo = min(lo, ring[start + j])
                hi = max(hi, ring[start + j])
            best = max(best, lo, -hi)  # all brighter by lo, or all darker by -hi
        out[i] = best - 1
    return out


class Corners:
    """FAST corners of the levels >= min_level, sorted by (level, row, column), with per-level
    row starts (levels below min_level are left empty).

    Columns: `x`, `y` (level pixels), `level`, `score`, `xn`, `yn` (undistorted normalised
    image-plane coordinates, NaN until a search first needs them: corner_normalised),
    `level_start` (L+1), `row_start[l]` (height_l + 1 entries).
    """

    def __init__(self, pyramid: Pyramid, detections: list[tuple[np.ndarray, np.ndarray] | None]):
        found = [d for d in detections if d is not None]
        counts = np.array([0 if d is None else len(d[1]) for d in detections], dtype=np.int64)
        pts = np.concatenate([d[0] for d in found]) if found else np.zeros((0, 2))
        scores = np.concatenate([d[1] for d in found]) if found else np.zeros(0)
        self.level_start = np.concatenate(([0], np.cumsum(counts))).astype(np.int64)
        self.x, self.y, self.score, self.level, self.row_start = _sorted_corners(
            pts, scores, self.level_start, int(pyramid.widths[0]), int(pyramid.heights[0]) + 1)
        self.xn = np.full(len(self.x), np.nan)
        self.yn = np.full(len(self.x), np.nan)
        # what the matching kernels take (vo.matcher.match_epipolar)
        self.tables = (self.x, self.y, self.xn, self.yn, self.row_start)

    def level0(self) -> tuple[np.ndarray, np.ndarray]:
        """Corner coordinates in level-0 pixels."""
        s = 2.0 ** self.level
        return (self.x + 0.5) * s - 0.5, (self.y + 0.5) * s - 0.5


@numba.njit(cache=True, nogil=True)
def _sorted_corners(pts, scores, level_start, width, max_h):
    """Corners (x, y, score, level) sorted by (level, row, column) (OpenCV finds them in that
    order: then nothing moves), and per level the index of its first corner in each row
    0..max_h (entries past a level's last corner point at the next level's first)."""
    n_levels = level_start.shape[0] - 1
    level = np.empty(pts.shape[0], dtype=np.int64)
    key = np.empty(pts.shape[0], dtype=np.int64)
    for lv in range(n_levels):
        for i in range(level_start[lv], level_start[lv + 1]):
            level[i] = lv
            key[i] = (lv * (max_h + 1) + int(pts[i, 1])) * (width + 1) + int(pts[i, 0])
    order = np.arange(pts.shape[0])
    for i in range(1, key.shape[0]):
        if key[i] <= key[i - 1]:
            order = np.argsort(key, kind="mergesort")
            break
    x, y, score, lv_out = pts[order, 0], pts[order, 1], scores[order], level[order]
    row_start = np.empty((n_levels, max_h + 1), dtype=np.int64)
    for lv in range(n_levels):
        i, hi = level_start[lv], level_start[lv + 1]
        for row in range(max_h + 1):
            while i < hi and int(y[i]) < row:
                i += 1
            row_start[lv, row] = i
    return x, y, score, lv_out, row_start


@numba.njit(cache=True, nogil=True)
def corner_normalised(params, tables, i, level):
    """Undistorted normalised image-plane coordinates of corner i (at `level`) of a Corners'
    tables, computed on first use (a search looks at a few of a frame's corners)."""
    x, y, xn, yn, _ = tables
    if np.isnan(xn[i]):
        bx, by, bz = unproject_pixel(params, from_level(x[i], level), from_level(y[i], level))
        xn[i] = bx / bz
        yn[i] = by / bz
    return xn[i], yn[i]


class Frame:
    """One camera image with its pyramid, lazily its FAST corners (and their ORB descriptors),
    and its pose T_c_w.

    `feat_*` columns hold the map points matched in this frame (filled by tracking).
    """

    def __init__(self, frame_id: int, t: float, image: np.ndarray, camera: CameraModel,
                 levels: int):
        self.id = frame_id
        self.t = t
        self.camera = camera
        self.pyr = Pyramid(image, levels)
        self.orb = CornerDescriptors(self.pyr.images)
        self.T_c_w = np.eye(4)
        self._detections: list[tuple[np.ndarray, np.ndarray] | None] = [None] * levels
        self._corners: dict[tuple[int, int], Corners] = {}
        self.feat_point = np.zeros(0, dtype=np.int64)
        self.feat_px = np.zeros((0, 2))
        self.feat_level = np.zeros(0, dtype=np.int64)
        self.n_visible = 0
        self.is_keyframe = False
        self.slot = -1
        # the information of the tracked pose's twist (left perturbation of T_c_w, normalised
        # image plane at unit weight; None: not tracked), a keyframe's BA prior
        self.pose_info: np.ndarray | None = None
        # the camera's orientation from outside the images (vo.rotation_prior), and the prior
        # on R_c_w the pose refinement uses with its information, 1/rad^2 (0: none)
        self.orientation = None
        self.R_prior = np.eye(3)
        self.prior_info = 0.0
        # the depth map registered to this image (vo.depth_seeds), until mapping has used it
        self.depth: np.ndarray | None = None

    @property
    def T_w_c(self) -> np.ndarray:
        """World-from-camera pose."""
        R = self.T_c_w[:3, :3]
        out = np.eye(4)
        out[:3, :3] = R.T
        out[:3, 3] = -R.T @ self.T_c_w[:3, 3]
        return out

    @property
    def position(self) -> np.ndarray:
        """Camera centre in the world."""
        return -self.T_c_w[:3, :3].T @ self.T_c_w[:3, 3]

    def corners(self, threshold: int, min_level: int = 0, max_level: int | None = None
                ) -> Corners:
        """FAST corners of the levels min_level..max_level (default: the top one), each level
        detected on first use; the corners of all levels once they have been asked for."""
        top = len(self._detections) - 1
        key = (min_level, top if max_level is None else max_level)
        if (0, top) in self._corners:
            return self._corners[(0, top)]
        if key not in self._corners:
            for level in range(key[0], key[1] + 1):
                if self._detections[level] is None:
                    self._detections[level] = detect_fast(self.pyr.images[level], threshold)
            wanted = [d if key[0] <= lv <= key[1] else None
                      for lv, d in enumerate(self._detections)]
            self._corners[key] = Corners(self.pyr, wanted)
        return self._corners[key]

    def set_features(self, point: np.ndarray, px: np.ndarray, level: np.ndarray) -> None:
        """Record the map points matched in this frame and where."""
        self.feat_point = point
        self.feat_px = px
        self.feat_level = level


def check_image(image: np.ndarray, camera: CameraModel) -> np.ndarray:
    """The image as a 2-D uint8 array of the camera's size; InputError otherwise."""
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 2:
        raise InputError(f"tracker needs a 2-D uint8 grey image, got {image.dtype} "
                         f"{image.shape}")
    if image.shape != (camera.height, camera.width):
        raise InputError(f"image is {image.shape[1]}x{image.shape[0]}, camera is "
                         f"{camera.width}x{camera.height}")
    return image
