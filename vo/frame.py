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
        imgs = [np.ascontiguousarray(image)]
        for _ in range(levels - 1):
            imgs.append(cv2.pyrDown(imgs[-1]))
        self.images = imgs
        self.widths = np.array([im.shape[1] for im in imgs], dtype=np.int64)
        self.heights = np.array([im.shape[0] for im in imgs], dtype=np.int64)
        sizes = self.widths * self.heights
        self.offsets = np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)
        self.flat = np.concatenate([im.ravel() for im in imgs])
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
    return pts, np.fromiter((k.response for k in kps), np.float64, len(kps))


class Corners:
    """FAST corners of the levels >= min_level, sorted by (level, row, column), with per-level
    row starts (levels below min_level are left empty).

    Columns: `x`, `y` (level pixels), `level`, `score`, `xn`, `yn` (undistorted normalised
    image-plane coordinates), `level_start` (L+1), `row_start[l]` (height_l + 1 entries).
    """

    def __init__(self, pyramid: Pyramid, camera: CameraModel,
                 detections: list[tuple[np.ndarray, np.ndarray] | None]):
        xs, ys, lv, sc = [], [], [], []
        for level, found in enumerate(detections):
            pts, resp = found if found is not None else (np.zeros((0, 2)), np.zeros(0))
            order = np.lexsort((pts[:, 0], pts[:, 1]))
            xs.append(pts[order, 0])
            ys.append(pts[order, 1])
            sc.append(resp[order])
            lv.append(np.full(len(order), level, dtype=np.int64))
        self.x = np.concatenate(xs)
        self.y = np.concatenate(ys)
        self.score = np.concatenate(sc)
        self.level = np.concatenate(lv)
        counts = np.array([len(a) for a in xs], dtype=np.int64)
        self.level_start = np.concatenate(([0], np.cumsum(counts))).astype(np.int64)
        max_h = int(pyramid.heights[0]) + 1
        self.row_start = np.zeros((len(xs), max_h + 1), dtype=np.int64)
        for level in range(len(xs)):
            lo, hi = self.level_start[level], self.level_start[level + 1]
            rows = self.y[lo:hi].astype(np.int64)
            self.row_start[level] = lo + np.searchsorted(rows, np.arange(max_h + 1), side="left")
        self.xn, self.yn = _normalised(camera.params, self.x, self.y, self.level)
        # what the matching kernels take (vo.matcher.match_epipolar)
        self.tables = (self.x, self.y, self.xn, self.yn, self.row_start)

    def level0(self) -> tuple[np.ndarray, np.ndarray]:
        """Corner coordinates in level-0 pixels."""
        s = 2.0 ** self.level
        return (self.x + 0.5) * s - 0.5, (self.y + 0.5) * s - 0.5


@numba.njit(cache=True, nogil=True)
def _normalised(params, x, y, level):
    """Undistorted normalised-plane coordinates of level pixels."""
    n = x.shape[0]
    xn = np.empty(n)
    yn = np.empty(n)
    for i in range(n):
        bx, by, bz = unproject_pixel(params, from_level(x[i], level[i]),
                                     from_level(y[i], level[i]))
        xn[i] = bx / bz
        yn[i] = by / bz
    return xn, yn


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
        self._corners: dict[int, Corners] = {}
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

    def corners(self, threshold: int, min_level: int = 0) -> Corners:
        """FAST corners of the levels from min_level up (each level detected on first use)."""
        if 0 in self._corners:
            return self._corners[0]
        if min_level not in self._corners:
            for level in range(min_level, len(self._detections)):
                if self._detections[level] is None:
                    self._detections[level] = detect_fast(self.pyr.images[level], threshold)
            wanted = [d if lv >= min_level else None for lv, d in enumerate(self._detections)]
            self._corners[min_level] = Corners(self.pyr, self.camera, wanted)
        return self._corners[min_level]

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
