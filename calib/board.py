"""Calibration boards and finding their corners in an image with sub-pixel accuracy.

Chessboard: `cols` x `rows` inner corners; the whole board must be visible. ChArUco: `cols` x
`rows` squares (OpenCV's CharucoBoard size); any part of it with enough corners is usable.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sdvl.errors import InputError

BOARD_KINDS = ("chessboard", "charuco")
MIN_CHARUCO_CORNERS = 6
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 0.001)
_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SB_FLAGS = cv2.CALIB_CB_NORMALIZE_IMAGE | cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY


@dataclass(frozen=True)
class BoardSpec:
    """What the user holds up: board kind, size, square (and ArUco marker) length in metres."""

    kind: str
    cols: int
    rows: int
    square: float
    marker: float | None = None
    dictionary: str = "DICT_5X5_100"
    legacy: bool = False

    def __post_init__(self) -> None:
        if self.kind not in BOARD_KINDS:
            raise InputError(f"unknown board '{self.kind}' (expected {' or '.join(BOARD_KINDS)})")
        smallest = 3 if self.kind == "chessboard" else 2
        if self.cols < smallest or self.rows < smallest:
            what = "inner corners" if self.kind == "chessboard" else "squares"
            raise InputError(f"a {self.kind} needs at least {smallest}x{smallest} {what}, "
                             f"got {self.cols}x{self.rows}")
        if not self.square > 0:
            raise InputError(f"square size must be positive, got {self.square}")
        if self.kind == "charuco":
            if self.marker is not None and not 0 < self.marker < self.square:
                raise InputError(f"marker length {self.marker} must be between 0 and the square "
                                 f"size {self.square}")
            if not self.dictionary.startswith("DICT_") or not hasattr(cv2.aruco, self.dictionary):
                raise InputError(f"unknown ArUco dictionary '{self.dictionary}' "
                                 "(e.g. DICT_4X4_50, DICT_5X5_100, DICT_6X6_250)")

    @property
    def n_corners(self) -> int:
        """How many corners a complete view of the board has."""
        if self.kind == "chessboard":
            return self.cols * self.rows
        return (self.cols - 1) * (self.rows - 1)

    def describe(self) -> str:
        """One line naming the board, for reports and file comments."""
        if self.kind == "chessboard":
            return f"chessboard {self.cols}x{self.rows} inner corners, {self.square * 1000:g} mm"
        return (f"ChArUco {self.cols}x{self.rows} squares, {self.square * 1000:g} mm, "
                f"{self.dictionary}")


@dataclass
class Detection:
    """Board corners found in one image: pixels (N, 2) and board-frame points (N, 3), metres."""

    image_points: np.ndarray
    object_points: np.ndarray
    complete: bool

    @property
    def spacing_px(self) -> float:
        """Median distance in pixels from each corner to its nearest neighbour."""
        return _spacing(self.image_points)


def chessboard_object_points(spec: BoardSpec) -> np.ndarray:
    """Inner-corner coordinates (cols*rows, 3) on the board plane z = 0, row by row."""
    xs, ys = np.meshgrid(np.arange(spec.cols), np.arange(spec.rows))
    pts = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    return (pts * spec.square).astype(np.float32)


def _subpix_half_window(corners: np.ndarray) -> int:
    """Half size of the cornerSubPix window: a third of the corner spacing, 3..11 pixels."""
    return int(np.clip(round(0.3 * _spacing(corners)), 3, 11))


def _find_chessboard(grey: np.ndarray, spec: BoardSpec, thorough: bool) -> np.ndarray | None:
    """Sub-pixel inner corners (N, 2) of the complete chessboard, or None."""
    size = (spec.cols, spec.rows)
    flags = _CLASSIC_FLAGS if thorough else _CLASSIC_FLAGS | cv2.CALIB_CB_FAST_CHECK
    found, corners = cv2.findChessboardCorners(grey, size, flags=flags)
    if found:
        half = _subpix_half_window(corners.reshape(-1, 2))
        corners = cv2.cornerSubPix(grey, corners, (half, half), (-1, -1), _SUBPIX_CRITERIA)
        return corners.reshape(-1, 2).astype(np.float64)
    if not thorough:
        return None
    found, corners = cv2.findChessboardCornersSB(grey, size, flags=_SB_FLAGS)
    return corners.reshape(-1, 2).astype(np.float64) if found else None


def _spacing(points: np.ndarray) -> float:
    """Median distance in pixels from each point (N, 2) to its nearest neighbour."""
    d = np.linalg.norm(points[:, None, :] - points[None, :, :], axis=2)
    np.fill_diagonal(d, np.inf)
    return float(np.median(d.min(axis=1)))


def _is_grid(points: np.ndarray, cols: int, rows: int) -> bool:
    """True when row-major `points` look like a (perspective, mildly distorted) corner grid."""
    xs, ys = np.meshgrid(np.arange(cols), np.arange(rows))
    ideal = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    H, _ = cv2.findHomography(ideal, points)
    if H is None:
        return False
    fitted = cv2.perspectiveTransform(ideal.reshape(-1, 1, 2), H).reshape(-1, 2)
    return float(np.abs(fitted - points).max()) < 0.35 * _spacing(points)


def chessboard_cut_by_border(grey: np.ndarray) -> tuple[int, int] | None:
    """(cols, rows) of a chessboard corner grid (3x3 or more) running into the image border.

    Tells a board that is cut off from an image with no board at all; a grid-like patch in the
    middle of a scene (windows, tiles) does not count.
    """
    flags = _SB_FLAGS | cv2.CALIB_CB_LARGER
    found, corners, meta = cv2.findChessboardCornersSBWithMeta(grey, (3, 3), flags=flags)
    if not found or meta is None or corners is None:
        return None
    pts = corners.reshape(-1, 2).astype(np.float64)
    rows, cols = meta.shape[:2]
    if rows * cols != len(pts) or not _is_grid(pts, cols, rows):
        return None
    h, w = grey.shape
    gap = min(pts[:, 0].min(), pts[:, 1].min(), w - 1 - pts[:, 0].max(), h - 1 - pts[:, 1].max())
    return (int(meta.shape[1]), int(meta.shape[0])) if gap < 1.5 * _spacing(pts) else None


def charuco_board(spec: BoardSpec) -> cv2.aruco.CharucoBoard:
    """The OpenCV ChArUco board object for `spec` (also draws it, for printing or tests)."""
    dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, spec.dictionary))
    marker = spec.marker if spec.marker is not None else 0.75 * spec.square
    board = cv2.aruco.CharucoBoard((spec.cols, spec.rows), spec.square, marker, dictionary)
    board.setLegacyPattern(spec.legacy)
    return board


class BoardDetector:
    """Finds one board in grey images; `thorough=False` trades recall for speed (live video)."""

    def __init__(self, spec: BoardSpec, thorough: bool = True):
        self.spec = spec
        self.thorough = thorough
        if spec.kind == "charuco":
            self._board = charuco_board(spec)
            self._charuco = cv2.aruco.CharucoDetector(self._board)
        else:
            self._object_points = chessboard_object_points(spec)

    def detect(self, grey: np.ndarray) -> Detection | None:
        """The board's corners in `grey`, or None when it is not found (well enough)."""
        if self.spec.kind == "chessboard":
            corners = _find_chessboard(grey, self.spec, self.thorough)
            if corners is None:
                return None
            return Detection(corners, self._object_points.astype(np.float64), complete=True)
        corners, ids, _, _ = self._charuco.detectBoard(grey)
        if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return None
        ids = np.asarray(ids).reshape(-1)
        if self._board.checkCharucoCornersCollinear(ids):
            return None
        obj = np.asarray(self._board.getChessboardCorners())[ids]
        return Detection(np.asarray(corners, dtype=np.float64).reshape(-1, 2),
                         obj.astype(np.float64), complete=len(ids) == self.spec.n_corners)
