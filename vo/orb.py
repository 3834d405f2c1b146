"""ORB descriptors for point matching (thesis 6.5.1), as an alternative to patches.

Descriptors come from OpenCV's ORB (31-pixel patch) on keypoints we give it, so only the points
being matched are described, and each is described once: a frame's FAST corners keep theirs
(`CornerDescriptors`), map points keep theirs per pyramid level (the PointStore's `desc`
columns). Keypoints are oriented by their intensity centroid as in ORB's oriented FAST, so a
descriptor does not depend on the query and survives the camera rolling. Matching kernels
compare them by Hamming distance (accepted up to a threshold).

Kernels cannot call OpenCV, so a match runs in passes: a kernel pass marks the descriptors it
is missing (`need` masks, `pending` count) and skips those comparisons; Python computes them
(`OrbQuery.fill`) and the kernel runs again until nothing is pending.
"""

from __future__ import annotations

import threading
from collections.abc import Callable

import cv2
import numba
import numpy as np

from vo.patch import to_level

DESC_BYTES = 32
PATCH_SIZE = 31
# keypoints closer than this to the image border get no descriptor (half the patch plus
# ORB's own 7x7 smoothing)
EDGE = PATCH_SIZE // 2 + 4
UNKNOWN, VALID, NONE = 0, 1, -1
POPCOUNT = np.array([bin(i).count("1") for i in range(256)], dtype=np.int64)

_local = threading.local()


def _extractor() -> cv2.ORB:
    """One ORB object per thread (OpenCV algorithms are not meant to be shared)."""
    if not hasattr(_local, "orb"):
        _local.orb = cv2.ORB_create(nlevels=1, edgeThreshold=EDGE, patchSize=PATCH_SIZE)
    return _local.orb


def describe(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """ORB descriptors (N, 32) of points (x, y) of one image, and their states (VALID, or
    NONE where the patch does not fit in the image)."""
    n = len(x)
    desc = np.zeros((n, DESC_BYTES), dtype=np.uint8)
    state = np.full(n, NONE, dtype=np.int8)
    if n == 0:
        return desc, state
    angle = orientations(image, np.asarray(x, np.float64), np.asarray(y, np.float64))
    kps = [cv2.KeyPoint(float(a), float(b), PATCH_SIZE, float(t), 0.0, 0, i)
           for i, (a, b, t) in enumerate(zip(x, y, angle, strict=True))]
    kps, des = _extractor().compute(image, kps)
    if des is not None and len(kps):
        ids = np.array([k.class_id for k in kps], dtype=np.int64)
        desc[ids] = des
        state[ids] = VALID
    return desc, state


@numba.njit(cache=True, nogil=True)
def orientations(image, x, y):
    """Keypoint orientation of ORB (oriented FAST): the direction, in degrees, from each point
    (rounded to a pixel) to the intensity centroid of the disc of radius PATCH_SIZE // 2 around
    it; 0 where the disc leaves the image. OpenCV's ORB computes this only for keypoints it
    detects itself, so it is done here for the keypoints we give it."""
    r = PATCH_SIZE // 2
    h, w = image.shape
    out = np.zeros(x.shape[0])
    for k in range(x.shape[0]):
        cx, cy = int(np.round(x[k])), int(np.round(y[k]))
        if cx < r or cy < r or cx >= w - r or cy >= h - r:
            continue
        m10 = m01 = 0.0
        for dv in range(-r, r + 1):
            half = int(np.sqrt(r * r - dv * dv + 0.5))
            for du in range(-half, half + 1):
                value = float(image[cy + dv, cx + du])
                m10 += du * value
                m01 += dv * value
        out[k] = np.degrees(np.arctan2(m01, m10)) % 360.0
    return out


def describe_levels(images: list[np.ndarray], u: np.ndarray, v: np.ndarray, need: np.ndarray,
                    desc: np.ndarray, state: np.ndarray) -> int:
    """Fill rows of desc (N, L, 32) / state (N, L) where need (N, L) and the state is UNKNOWN:
    descriptors of level-0 pixels (u, v) at each level of a pyramid. Returns how many."""
    rows, levels = np.nonzero(need & (state == UNKNOWN))
    for level in np.unique(levels):
        r = rows[levels == level]
        d, s = describe(images[level], to_level(u[r], level), to_level(v[r], level))
        desc[r, level] = d
        state[r, level] = s
    return len(rows)


class CornerDescriptors:
    """ORB descriptors of one frame's FAST corners, computed on demand and at most once.

    Kept per level: every `Corners` object of the frame lists a level's detections in the same
    order, so corner i of level l is row i - level_start[l] here, whichever object asks.
    """

    def __init__(self, images: list[np.ndarray]):
        self.images = images
        self.desc: dict[int, np.ndarray] = {}
        self.state: dict[int, np.ndarray] = {}
        self.computed = 0

    def _level(self, level: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        if level not in self.desc:
            self.desc[level] = np.zeros((n, DESC_BYTES), dtype=np.uint8)
            self.state[level] = np.zeros(n, dtype=np.int8)
        return self.desc[level], self.state[level]

    def tables(self, corners) -> tuple[np.ndarray, np.ndarray]:
        """Descriptors and states indexed like `corners` (a Corners of this frame)."""
        desc = np.zeros((len(corners.x), DESC_BYTES), dtype=np.uint8)
        state = np.zeros(len(corners.x), dtype=np.int8)
        starts = corners.level_start
        for level in range(len(starts) - 1):
            lo, hi = starts[level], starts[level + 1]
            if hi > lo:
                desc[lo:hi], state[lo:hi] = self._level(level, hi - lo)
        return desc, state

    def fill(self, corners, need: np.ndarray) -> None:
        """Describe the corners marked in `need` that have no descriptor yet."""
        starts = corners.level_start
        for level in range(len(starts) - 1):
            lo, hi = starts[level], starts[level + 1]
            rows = np.flatnonzero(need[lo:hi])
            if len(rows) == 0:
                continue
            desc, state = self._level(level, hi - lo)
            rows = rows[state[rows] == UNKNOWN]
            d, s = describe(self.images[level], corners.x[lo + rows], corners.y[lo + rows])
            desc[rows], state[rows] = d, s
            self.computed += len(rows)


class OrbQuery:
    """The ORB arguments of one matching call and the passes it takes.

    References are rows `pid` of a (N, L, 32) descriptor table (map points, or new features);
    `fill_refs(table rows, need (n, L))` computes the reference descriptors a pass asked for.
    `tables` is what kernels take (see `query`); with max_distance < 0 (patch matching) it is
    a dummy.
    """

    def __init__(self, max_distance: int, pid: np.ndarray, ref_desc: np.ndarray,
                 ref_state: np.ndarray, levels: int, frame_desc: CornerDescriptors | None,
                 corners, fill_refs: Callable[[np.ndarray, np.ndarray], None] | None):
        self.max_distance = max_distance
        self.pid = np.ascontiguousarray(pid, dtype=np.int64)
        self.ref_desc, self.ref_state = ref_desc, ref_state
        self.ref_need = np.zeros((len(pid), levels), dtype=np.bool_)
        self.frame_desc, self.corners, self.fill_refs = frame_desc, corners, fill_refs
        n = len(corners.x) if corners is not None else 0
        self.cur_need = np.zeros(n, dtype=np.bool_)
        self.pending = np.zeros(1, dtype=np.int64)
        self.tables = self._tables()

    @classmethod
    def patches(cls, n: int, levels: int) -> OrbQuery:
        """The dummy arguments of patch matching for n queries."""
        return cls(-1, np.zeros(n, dtype=np.int64), np.zeros((1, levels, DESC_BYTES), np.uint8),
                   np.zeros((1, levels), np.int8), levels, None, None, None)

    def _tables(self):
        if self.frame_desc is None:
            cur_desc = np.zeros((0, DESC_BYTES), dtype=np.uint8)
            cur_state = np.zeros(0, dtype=np.int8)
        else:
            cur_desc, cur_state = self.frame_desc.tables(self.corners)
        return (self.max_distance, self.pid, self.ref_desc, self.ref_state, self.ref_need,
                cur_desc, cur_state, self.cur_need, self.pending)

    def fill(self) -> bool:
        """After a kernel pass: compute what it asked for; True when it must run again."""
        if self.pending[0] == 0:
            return False
        rows = np.flatnonzero(self.ref_need.any(axis=1))
        if len(rows):
            self.fill_refs(self.pid[rows], self.ref_need[rows])
        self.frame_desc.fill(self.corners, self.cur_need)
        self.ref_need[:] = False
        self.cur_need[:] = False
        self.pending[0] = 0
        self.tables = self._tables()
        return True


@numba.njit(cache=True, nogil=True)
def query(tables, k):
    """The ORB arguments of match_epipolar for query k of a call's tables."""
    (max_distance, pid, ref_desc, ref_state, ref_need, cur_desc, cur_state, cur_need,
     pending) = tables
    p = pid[k]
    return (max_distance, ref_desc[p], ref_state[p], ref_need[k], cur_desc, cur_state, cur_need,
            pending)


@numba.njit(cache=True, nogil=True)
def hamming(a, b):
    """Number of differing bits of two descriptors."""
    d = 0
    for i in range(a.shape[0]):
        d += POPCOUNT[a[i] ^ b[i]]
    return d
