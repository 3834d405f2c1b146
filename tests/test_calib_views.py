"""View checks and selection: blur width, outliers, board motion, coverage advice."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib.board import BoardDetector, BoardSpec, Detection, chessboard_object_points
from calib.calibration import View
from calib.coverage import corner_coverage
from calib.view_collection import collect_views, thin_views
from calib.view_quality import edge_width
from calib.view_selection import MotionGate, board_displacement, outlier_mask

SPEC = BoardSpec("chessboard", 6, 4, 0.03)


def flat_board(px_per_square: int = 40, offset: int = 60) -> np.ndarray:
    """A fronto-parallel chessboard image (6x4 inner corners) with a white margin."""
    h, w = 7 * px_per_square + 2 * offset, 9 * px_per_square + 2 * offset
    yy, xx = np.mgrid[0:h, 0:w]
    i, j = (xx - offset) // px_per_square, (yy - offset) // px_per_square
    inside = (i >= 1) & (i <= 7) & (j >= 1) & (j <= 5)
    return np.where(inside & ((i + j) % 2 == 0), 30, 225).astype(np.uint8)


@pytest.mark.parametrize("sigma", [1.5, 2.5, 4.0])
def test_edge_width_grows_with_blur_like_a_gaussian(sigma):
    image = cv2.GaussianBlur(flat_board(), (0, 0), sigma)
    detection = BoardDetector(SPEC).detect(image)
    assert detection is not None
    width = edge_width(image, detection.image_points, detection.spacing_px)
    assert width == pytest.approx(np.sqrt(2 * np.pi) * sigma, rel=0.2)


def test_collect_skips_blurred_view_by_name():
    sharp = cv2.GaussianBlur(flat_board(), (0, 0), 0.7)
    blurred = cv2.GaussianBlur(flat_board(), (0, 0), 3.0)
    out = collect_views([("sharp", sharp), ("blurred", blurred), ("blank", np.full_like(sharp, 99)),
                         ("broken", "not an image, or corrupt")], BoardDetector(SPEC), 5.0)
    assert [v.name for v in out.views] == ["sharp"]
    reasons = dict(out.skipped)
    assert "too blurred" in reasons["blurred"] and "no board found" in reasons["blank"]
    assert "cannot read image" in reasons["broken"]


def test_outliers_stand_far_above_the_median_and_a_floor():
    assert outlier_mask(np.array([0.2, 0.21, 0.19, 0.18, 0.9])).tolist() == [False] * 4 + [True]
    assert not outlier_mask(np.array([0.02, 0.02, 0.03, 0.08])).any()


def detection(shift: float = 0.0, rows: slice = slice(None)) -> Detection:
    obj = chessboard_object_points(SPEC).astype(np.float64)[rows]
    return Detection(obj[:, :2] * 2000 + 100 + shift, obj, complete=True)


def test_motion_gate_keeps_moved_boards_only():
    gate = MotionGate(min_move_px=20)
    assert gate.accept(detection())
    assert not gate.accept(detection(shift=5))
    assert gate.accept(detection(shift=30))
    assert not gate.accept(detection(shift=1))  # close to the first view kept


def test_displacement_matches_corners_by_board_position():
    assert board_displacement(detection(), detection(shift=7, rows=slice(6, 18))) == \
        pytest.approx(7 * np.sqrt(2))
    assert board_displacement(detection(rows=slice(0, 3)), detection()) == np.inf


def test_coverage_names_the_empty_areas():
    u, v = np.mgrid[220:420:20, 165:315:20]  # the middle third of a 640x480 image
    coverage = corner_coverage([np.column_stack([u.ravel(), v.ravel()])], (640, 480))
    assert coverage.fraction == pytest.approx(12 / 108)
    assert len(coverage.empty_areas()) == 8 and "centre" not in coverage.empty_areas()


def test_thin_views_spreads_over_the_sequence():
    views = [View(str(i), detection()) for i in range(10)]
    assert [v.name for v in thin_views(views, 4)] == ["0", "3", "6", "9"]


def test_live_collection_stops_at_enough_views_or_ctrl_c():
    image = cv2.GaussianBlur(flat_board(), (0, 0), 0.7)

    def stream(n_moves: int):
        for k in range(n_moves):
            moved = np.roll(image, 25 * k, axis=1)
            yield f"f{k}a", moved
            yield f"f{k}b", moved  # the board held still: not kept again
        raise KeyboardInterrupt

    detector = BoardDetector(SPEC, thorough=False)
    out = collect_views(stream(4), detector, 5.0, gate=MotionGate(10.0), stop_after=3)
    assert [v.name for v in out.views] == ["f0a", "f1a", "f2a"]
    out = collect_views(stream(2), detector, 5.0, gate=MotionGate(10.0), stop_after=10)
    assert [v.name for v in out.views] == ["f0a", "f1a"] and out.counts["board did not move"] == 2
