"""ROS camera_info YAML (camera_calibration_parsers): image_width, camera_matrix, ...

'plumb_bob' is OpenCV's k1 k2 p1 p2 k3; 'rational_polynomial' is read when k4..k6 are zero;
'equidistant' is OpenCV's fisheye.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from calib.camera import CameraModel
from calib.formats.documents import full_coefficients, make_camera, number, numbers, write_text
from sdvl.errors import InputError

NAME = "ros"
DESCRIPTION = "ROS camera_info YAML (image_width, camera_matrix, distortion_model, ...)"
_MODELS = {"plumb_bob": "radtan_opencv", "rational_polynomial": "radtan_opencv",
           "equidistant": "equidistant", "fisheye": "equidistant"}


def _matrix(rows: int, cols: int, data: list[float]) -> dict:
    return {"rows": rows, "cols": cols, "data": data}


def matches(data: dict) -> bool:
    """True for a camera_info YAML: a camera_matrix mapping with a data list."""
    return isinstance(data.get("camera_matrix"), dict) and "image_width" in data


def from_mapping(data: dict, path: str | Path) -> CameraModel:
    """The camera of a camera_info YAML."""
    K = numbers((data.get("camera_matrix") or {}).get("data"), "camera_matrix.data", path, 9)
    model = data.get("distortion_model", "plumb_bob")
    if model not in _MODELS:
        raise InputError(f"ROS distortion_model '{model}' is not supported (expected "
                         f"{', '.join(_MODELS)})", path)
    dist = data.get("distortion_coefficients") or {}
    coeffs = numbers(dist.get("data", []), "distortion_coefficients.data", path)
    size = (number(data, "image_width", path), number(data, "image_height", path))
    return make_camera(path, size, (K[0], K[4], K[2], K[5]), _MODELS[model], coeffs)


def write(camera: CameraModel, path: str | Path) -> None:
    """A camera_info YAML that ROS camera drivers and image_proc load."""
    fx, fy, cx, cy = camera.fx, camera.fy, camera.cx, camera.cy
    coeffs = full_coefficients(camera)
    doc = {
        "image_width": camera.width,
        "image_height": camera.height,
        "camera_name": "camera",
        "camera_matrix": _matrix(3, 3, [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]),
        "distortion_model": "equidistant" if camera.distortion_model == "equidistant"
        else "plumb_bob",
        "distortion_coefficients": _matrix(1, len(coeffs), coeffs),
        "rectification_matrix": _matrix(3, 3, [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]),
        "projection_matrix": _matrix(3, 4, [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0,
                                            0.0, 0.0, 1.0, 0.0]),
    }
    write_text(path, yaml.safe_dump(doc, sort_keys=False, default_flow_style=None))
