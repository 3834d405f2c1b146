"""Is one detected view good enough to calibrate from? Blur and cut-off board checks.

Each check returns a short reason when the view should be skipped, None when it is fine.
"""

from __future__ import annotations

import cv2
import numpy as np

from calib.board import BoardSpec, Detection, chessboard_cut_by_border

DEFAULT_MAX_BLUR_PX = 5.0
_MIN_EDGE_CONTRAST = 20.0


def edge_width(grey: np.ndarray, corners: np.ndarray, spacing_px: float) -> float:
    """Median width in pixels of the board edges around `corners`.

    Contrast over steepest gradient near each corner: about 2.5 sigma for a Gaussian-blurred
    step, 1.5-3 px in a sharp photo, more with defocus or motion blur.
    """
    gx = cv2.Sobel(grey, cv2.CV_32F, 1, 0, ksize=3) / 8.0
    gy = cv2.Sobel(grey, cv2.CV_32F, 0, 1, ksize=3) / 8.0
    magnitude = cv2.magnitude(gx, gy)
    h, w = grey.shape
    r = max(3, int(0.4 * spacing_px))
    widths = []
    for u, v in np.round(corners).astype(int):
        x0, x1, y0, y1 = max(u - r, 0), min(u + r + 1, w), max(v - r, 0), min(v + r + 1, h)
        if x1 - x0 < 3 or y1 - y0 < 3:
            continue
        lo, hi = np.percentile(grey[y0:y1, x0:x1], (5, 95))
        steepest = np.percentile(magnitude[y0:y1, x0:x1], 98)
        if hi - lo >= _MIN_EDGE_CONTRAST and steepest > 0:
            widths.append((hi - lo) / steepest)
    return float(np.median(widths)) if widths else float("inf")


def blur_problem(grey: np.ndarray, detection: Detection, max_blur_px: float) -> str | None:
    """A reason when the board's edges are wider than `max_blur_px` (defocus, motion)."""
    width = edge_width(grey, detection.image_points, detection.spacing_px)
    if width > max_blur_px:
        return f"too blurred (board edges {width:.1f} px wide, limit {max_blur_px:g} px)"
    return None


def border_problem(grey: np.ndarray, detection: Detection) -> str | None:
    """A reason when a complete board's outer squares run off the image."""
    if not detection.complete:
        return None
    h, w = grey.shape
    pts = detection.image_points
    gap = min(pts[:, 0].min(), pts[:, 1].min(), w - 1 - pts[:, 0].max(), h - 1 - pts[:, 1].max())
    if gap < 0.5 * detection.spacing_px:
        return f"board cut off by the image border (outer corners {gap:.0f} px from the edge)"
    return None


def view_problem(grey: np.ndarray, detection: Detection, max_blur_px: float) -> str | None:
    """Why a detected view should be skipped, or None when it is usable."""
    return blur_problem(grey, detection, max_blur_px) or border_problem(grey, detection)


def missing_board_reason(grey: np.ndarray, spec: BoardSpec) -> str:
    """Why no usable board was found: cut off by the image border, or simply not there."""
    if spec.kind == "charuco":
        return "no board found (fewer than 6 ChArUco corners recognised, or all in one line)"
    part = chessboard_cut_by_border(grey)
    if part is not None and part[0] * part[1] < spec.n_corners:
        return (f"board cut off by the image border (only a {part[0]}x{part[1]} corner grid "
                f"visible of {spec.cols}x{spec.rows})")
    return "no board found"
