"""OpenCV FileStorage calibration files (YAML or XML), as OpenCV's calibration samples write.

Keys: image_width, image_height, camera_matrix (3x3), distortion_coefficients (k1 k2 p1 p2 k3,
or k1..k4 with `fisheye_model: 1`). The tutorial sample's Camera_Matrix and
Distortion_Coefficients spellings are read too. XML is chosen by the output file's suffix.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calib.camera import CameraModel
from calib.formats.documents import full_coefficients, make_camera, number, numbers
from sdvl.errors import InputError

NAME = "opencv"
DESCRIPTION = "OpenCV FileStorage YAML/XML (camera_matrix, distortion_coefficients; .xml = XML)"
_K_KEYS = ("camera_matrix", "Camera_Matrix", "cameraMatrix", "K")
_D_KEYS = ("distortion_coefficients", "Distortion_Coefficients", "distCoeffs", "D")


def _first(data: dict, keys: tuple[str, ...]):
    return next((data[k] for k in keys if isinstance(data.get(k), np.ndarray)), None)


def matches(data: dict) -> bool:
    """True when the file holds an OpenCV camera matrix."""
    return _first(data, _K_KEYS) is not None


def from_mapping(data: dict, path: str | Path) -> CameraModel:
    """The camera of an OpenCV calibration file."""
    K = numbers(_first(data, _K_KEYS), "camera_matrix", path, 9)
    dist = _first(data, _D_KEYS)
    coeffs = numbers(dist, "distortion_coefficients", path) if dist is not None else []
    fisheye = number(data, "fisheye_model", path, default=0) != 0
    size = (number(data, "image_width", path), number(data, "image_height", path))
    return make_camera(path, size, (K[0], K[4], K[2], K[5]),
                       "equidistant" if fisheye else "radtan_opencv", coeffs)


def write(camera: CameraModel, path: str | Path) -> None:
    """Write with cv2.FileStorage (doubles keep all 17 significant digits)."""
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    except (cv2.error, SystemError) as exc:
        raise InputError(f"cannot write: {exc}", path) from None
    if not storage.isOpened():
        raise InputError("cannot write", path)
    storage.write("image_width", camera.width)
    storage.write("image_height", camera.height)
    storage.write("camera_matrix", camera.K)
    coeffs = np.array(full_coefficients(camera), dtype=np.float64).reshape(-1, 1)
    storage.write("distortion_coefficients", coeffs)
    storage.write("fisheye_model", int(camera.distortion_model == "equidistant"))
    storage.release()
