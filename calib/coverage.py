"""Where in the image board corners were seen, which areas need more views, and a picture of it.

Distortion is estimated only where corners were observed; an empty image corner means the
model there is extrapolated, which is where a wide-angle lens bends most.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from sdvl.errors import InputError

GRID_COLS, GRID_ROWS = 12, 9
_AREA_NAMES = (("top-left", "top", "top-right"), ("left", "centre", "right"),
               ("bottom-left", "bottom", "bottom-right"))
_AREA_MIN_COVERED = 0.5


@dataclass
class Coverage:
    """Corner counts on a GRID_ROWS x GRID_COLS grid over the image, and what they mean."""

    counts: np.ndarray
    size: tuple[int, int]

    @property
    def fraction(self) -> float:
        """Share of grid cells in which at least one corner was seen."""
        return float(np.mean(self.counts > 0))

    def empty_areas(self) -> list[str]:
        """Names of the image areas (3x3 split) where under half the cells saw a corner."""
        out = []
        rows = np.array_split(np.arange(GRID_ROWS), 3)
        cols = np.array_split(np.arange(GRID_COLS), 3)
        for i, r in enumerate(rows):
            for j, c in enumerate(cols):
                if np.mean(self.counts[np.ix_(r, c)] > 0) < _AREA_MIN_COVERED:
                    out.append(_AREA_NAMES[i][j])
        return out


def corner_coverage(points: list[np.ndarray], size: tuple[int, int]) -> Coverage:
    """Count the corners of all views (each (N, 2) pixels) per cell of the image grid."""
    w, h = size
    counts = np.zeros((GRID_ROWS, GRID_COLS), dtype=int)
    if points:
        px = np.concatenate(points)
        col = np.clip((px[:, 0] / w * GRID_COLS).astype(int), 0, GRID_COLS - 1)
        row = np.clip((px[:, 1] / h * GRID_ROWS).astype(int), 0, GRID_ROWS - 1)
        np.add.at(counts, (row, col), 1)
    return Coverage(counts, size)


def _view_colour(i: int) -> tuple[int, int, int]:
    hsv = np.uint8([[[(i * 47) % 180, 220, 255]]])
    return tuple(int(c) for c in cv2.cvtColor(hsv, cv2.COLOR_HSV2BGR)[0, 0])


def draw_coverage(points: list[np.ndarray], coverage: Coverage, path: str | Path) -> None:
    """Write a PNG: empty grid cells red, seen cells green, each view's corners in its colour."""
    w, h = coverage.size
    canvas = np.full((h, w, 3), 40, dtype=np.uint8)
    xs = np.linspace(0, w, GRID_COLS + 1).astype(int)
    ys = np.linspace(0, h, GRID_ROWS + 1).astype(int)
    for r in range(GRID_ROWS):
        for c in range(GRID_COLS):
            tint = (40, 90, 40) if coverage.counts[r, c] else (40, 40, 150)
            canvas[ys[r]:ys[r + 1], xs[c]:xs[c + 1]] = tint
    canvas[ys[:-1], :] //= 2
    canvas[:, xs[:-1]] //= 2
    radius = max(2, round(min(w, h) / 200))
    for i, pts in enumerate(points):
        for u, v in np.round(pts).astype(int):
            cv2.circle(canvas, (int(u), int(v)), radius, _view_colour(i), -1, cv2.LINE_AA)
    text = f"{len(points)} views, {coverage.fraction:.0%} of the image covered (red: add views)"
    scale = max(0.4, min(w, h) / 900)
    cv2.putText(canvas, text, (8, int(24 * scale / 0.6)), cv2.FONT_HERSHEY_SIMPLEX, scale,
                (255, 255, 255), 1, cv2.LINE_AA)
    if not cv2.imwrite(str(path), canvas):
        raise InputError("cannot write the coverage picture", path)
