"""A frame's FAST corners: scores from the numba kernel equal OpenCV's responses, the sorted
corner table and row index equal a lexsort and searchsorted, normalised coordinates computed on
first use equal the camera's, and tracking's corners (its levels only) are those of the full
table."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib.camera import CameraModel
from sim.datasets import open_sequence
from vo.frame import (
    FAST_ARC,
    FAST_CIRCLE,
    Frame,
    Pyramid,
    _sorted_corners,
    corner_normalised,
    fast_scores,
)


def _slow_score(image: np.ndarray, x: int, y: int) -> int:
    """The FAST score by its definition: the largest threshold t at which FAST_ARC contiguous
    circle pixels are all brighter than centre + t or all darker than centre - t, minus 1."""
    centre = int(image[y, x])
    ring = [int(image[y + dy, x + dx]) - centre for dx, dy in FAST_CIRCLE]
    best = 0
    for t in range(256):
        arcs = [ring[(s + j) % 16] for s in range(16) for j in range(FAST_ARC)]
        arcs = np.array(arcs).reshape(16, FAST_ARC)
        if np.any(np.all(arcs > t, axis=1)) or np.any(np.all(arcs < -t, axis=1)):
            best = t + 1
    return best - 1


def _opencv(image: np.ndarray, threshold: int):
    kps = cv2.FastFeatureDetector_create(threshold=threshold, nonmaxSuppression=True).detect(image)
    return (cv2.KeyPoint_convert(kps).astype(np.float64),
            np.array([k.response for k in kps], dtype=np.float64))


def test_scores_equal_the_definition_on_a_random_image():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (40, 50)).astype(np.uint8)
    pts, _ = _opencv(image, 10)
    assert len(pts) > 20
    scores = fast_scores(image, pts)
    assert [int(s) for s in scores] == [_slow_score(image, int(x), int(y)) for x, y in pts]


@pytest.mark.parametrize("name", ["vamr_ex01_checkerboard736", "kitti00_first200"])
def test_scores_equal_opencv_responses_on_real_images(data_dir, name):
    seq = open_sequence(data_dir / name)
    for index in (0, len(seq) // 2):
        for image in Pyramid(seq.image(index), 3).images:
            pts, responses = _opencv(image, 10)
            assert np.array_equal(fast_scores(image, pts), responses)


def test_sorted_corners_and_row_starts_against_lexsort_and_searchsorted():
    rng = np.random.default_rng(1)
    counts = np.array([0, 40, 25])
    heights = np.array([60, 30, 15])
    pts = np.concatenate([np.column_stack((rng.integers(0, 2 * h, n), rng.integers(0, h, n)))
                          for n, h in zip(counts, heights, strict=True)]).astype(np.float64)
    pts = np.unique(np.column_stack((np.repeat(np.arange(3), counts), pts)), axis=0)
    rng.shuffle(pts)  # out of order: the kernel sorts
    pts = pts[np.argsort(pts[:, 0], kind="stable")]  # grouped by level, as detections come
    level = pts[:, 0].astype(np.int64)
    starts = np.concatenate(([0], np.cumsum(np.bincount(level, minlength=3)))).astype(np.int64)
    scores = rng.uniform(10, 50, len(pts))
    x, y, s, lv, row_start = _sorted_corners(np.ascontiguousarray(pts[:, 1:]), scores, starts,
                                             120, 61)
    order = np.lexsort((pts[:, 1], pts[:, 2], level))
    assert np.array_equal(x, pts[order, 1]) and np.array_equal(y, pts[order, 2])
    assert np.array_equal(s, scores[order]) and np.array_equal(lv, level[order])
    for k in range(3):
        rows = y[starts[k]:starts[k + 1]].astype(np.int64)
        assert np.array_equal(row_start[k],
                              starts[k] + np.searchsorted(rows, np.arange(62), side="left"))


def test_normalised_coordinates_on_first_use_equal_the_cameras():
    cam = CameraModel(320, 240, 300.0, 310.0, 160.0, 120.0, "radtan_opencv",
                      (-0.2, 0.05, 0.001, -0.001, 0.0))
    rng = np.random.default_rng(2)
    image = cv2.GaussianBlur(rng.integers(0, 256, (240, 320)).astype(np.uint8), (3, 3), 0)
    c = Frame(0, 0.0, image, cam, 4).corners(10, 1)
    assert np.all(np.isnan(c.xn))
    for i in range(0, len(c.x), 7):
        level = int(c.level[i])
        s = 2.0 ** level
        f = cam.unproject(np.array([[(c.x[i] + 0.5) * s - 0.5, (c.y[i] + 0.5) * s - 0.5]]))[0]
        assert corner_normalised(cam.params, c.tables, i, level) == pytest.approx(
            (f[0] / f[2], f[1] / f[2]), abs=1e-12)
        assert c.xn[i] == pytest.approx(f[0] / f[2], abs=1e-12)


def test_tracking_levels_are_the_full_tables_levels():
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur(rng.integers(0, 256, (240, 320)).astype(np.uint8), (3, 3), 0)
    cam = CameraModel(320, 240, 300.0, 300.0, 160.0, 120.0)
    frame = Frame(0, 0.0, image, cam, 5)
    part = frame.corners(10, 1, 2)
    assert np.all((part.level >= 1) & (part.level <= 2))
    full = frame.corners(10)
    assert frame.corners(10, 1, 2) is full  # once all levels are known, the full table serves
    keep = (full.level >= 1) & (full.level <= 2)
    assert np.array_equal(part.x, full.x[keep]) and np.array_equal(part.score, full.score[keep])
