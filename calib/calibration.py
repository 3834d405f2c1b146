"""Intrinsic calibration from board views with OpenCV, mapped onto `CameraModel`.

'pinhole-radtan' uses cv2.calibrateCamera (k1 k2 p1 p2 k3 -> 'radtan_opencv'); 'fisheye' uses
cv2.fisheye.calibrate (k1..k4 -> 'equidistant'). Reprojection errors are recomputed with
`CameraModel.project`, so they measure the model the tracker will actually use.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from calib.board import Detection
from calib.camera import CameraModel
from sdvl.errors import InputError

MODELS = {"pinhole-radtan": "radtan_opencv", "fisheye": "equidistant"}
_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-12)


@dataclass
class View:
    """One usable image of the board: where it came from and the corners found in it."""

    name: str
    detection: Detection


@dataclass
class CalibrationResult:
    """The camera found, its RMS reprojection error and one RMS error per view (pixels)."""

    camera: CameraModel
    rms: float
    per_view_rms: np.ndarray
    rvecs: list[np.ndarray]
    tvecs: list[np.ndarray]
    std_intrinsics: dict[str, float] | None = None


def _radtan(views: list[View], size: tuple[int, int]):
    obj = [v.detection.object_points.astype(np.float32) for v in views]
    img = [v.detection.image_points.astype(np.float32) for v in views]
    out = cv2.calibrateCameraExtended(obj, img, size, None, None, criteria=_CRITERIA)
    _, K, dist, rvecs, tvecs, std_intr = out[:6]
    std = np.asarray(std_intr).ravel()
    names = ("fx", "fy", "cx", "cy", "k1", "k2", "p1", "p2", "k3")
    return K, np.asarray(dist).ravel()[:5], rvecs, tvecs, dict(zip(names, map(float, std),
                                                                      strict=False))


def _fisheye_flag(name: str) -> int:
    """OpenCV 4 keeps fisheye flags in cv2.fisheye, OpenCV 5 in cv2."""
    return int(getattr(cv2.fisheye, name, None) or getattr(cv2, name))


def _fisheye(views: list[View], size: tuple[int, int]):
    obj = [v.detection.object_points.reshape(1, -1, 3).astype(np.float64) for v in views]
    img = [v.detection.image_points.reshape(1, -1, 2).astype(np.float64) for v in views]
    flags = _fisheye_flag("CALIB_RECOMPUTE_EXTRINSIC") | _fisheye_flag("CALIB_FIX_SKEW")
    _, K, dist, rvecs, tvecs = cv2.fisheye.calibrate(
        obj, img, size, np.eye(3), np.zeros(4), flags=flags, criteria=_CRITERIA)
    return K, np.asarray(dist).ravel()[:4], rvecs, tvecs, None


def view_errors(camera: CameraModel, detection: Detection, rvec: np.ndarray,
                tvec: np.ndarray) -> np.ndarray:
    """Reprojection error (pixels) of each corner of one view, given the board pose."""
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    points = detection.object_points @ R.T + np.asarray(tvec, dtype=np.float64).reshape(1, 3)
    projected = camera.project(points)
    errors = np.linalg.norm(projected - detection.image_points, axis=1)
    return np.where(np.isfinite(errors), errors, np.inf)


def calibrate(views: list[View], size: tuple[int, int], model: str) -> CalibrationResult:
    """Calibrate a camera of image `size` (width, height) from `views` with `model`."""
    if model not in MODELS:
        raise InputError(f"unknown camera model '{model}' (expected {' or '.join(MODELS)})")
    solve = _radtan if model == "pinhole-radtan" else _fisheye
    try:
        K, dist, rvecs, tvecs, std = solve(views, size)
    except cv2.error as exc:
        raise InputError(f"OpenCV could not calibrate from these views ({exc.err}); add views "
                         "with the board tilted and in different parts of the image") from None
    if not (np.isfinite(K).all() and np.isfinite(dist).all() and K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError("calibration did not converge; add views with the board tilted and "
                         "in different parts of the image")
    camera = CameraModel(width=size[0], height=size[1], fx=float(K[0, 0]), fy=float(K[1, 1]),
                         cx=float(K[0, 2]), cy=float(K[1, 2]), distortion_model=MODELS[model],
                         distortion=tuple(float(d) for d in dist))
    errors = [view_errors(camera, v.detection, r, t) for v, r, t in zip(views, rvecs, tvecs,
                                                                         strict=True)]
    per_view = np.array([np.sqrt(np.mean(e**2)) for e in errors])
    rms = float(np.sqrt(np.mean(np.concatenate(errors) ** 2)))
    return CalibrationResult(camera, rms, per_view, list(rvecs), list(tvecs), std)
