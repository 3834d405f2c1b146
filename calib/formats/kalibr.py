"""Kalibr camchain YAML (`cam0: {camera_model, intrinsics, distortion_model, ...}`).

Kalibr's 'radtan' has four coefficients (k1 k2 r1 r2, no k3); 'equidistant' is OpenCV's
fisheye. Only pinhole cameras are read; other Kalibr projection models are refused.
"""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from calib.camera import CameraModel
from calib.formats.documents import make_camera, numbers, write_text
from sdvl.errors import InputError

NAME = "kalibr"
DESCRIPTION = "Kalibr camchain YAML (cam0: intrinsics, distortion_coeffs, resolution)"
_CAM_KEY = re.compile(r"^cam\d+$")
_MODELS = {"radtan": "radtan_opencv", "equidistant": "equidistant", "none": "none"}


def _camera_entry(data: dict) -> dict | None:
    keys = sorted((k for k in data if isinstance(k, str) and _CAM_KEY.match(k)),
                  key=lambda k: int(k[3:]))
    if keys and isinstance(data[keys[0]], dict):
        return data[keys[0]]
    return data if "intrinsics" in data and "resolution" in data else None


def matches(data: dict) -> bool:
    """True for a Kalibr camchain (or a single Kalibr camera block)."""
    entry = _camera_entry(data)
    return entry is not None and "intrinsics" in entry


def from_mapping(data: dict, path: str | Path) -> CameraModel:
    """The first camera (cam0) of a camchain."""
    cam = _camera_entry(data)
    if cam is None:
        raise InputError("no cam0 block with intrinsics", path)
    if cam.get("camera_model", "pinhole") != "pinhole":
        raise InputError(f"Kalibr camera_model '{cam['camera_model']}' is not supported "
                         "(only pinhole with radtan or equidistant)", path)
    model = cam.get("distortion_model", "none")
    if model not in _MODELS:
        raise InputError(f"Kalibr distortion_model '{model}' is not supported (expected "
                         f"{', '.join(_MODELS)})", path)
    K = numbers(cam.get("intrinsics"), "intrinsics", path, 4)
    size = numbers(cam.get("resolution"), "resolution", path, 2)
    coeffs = numbers(cam.get("distortion_coeffs", []), "distortion_coeffs", path)
    return make_camera(path, tuple(size), tuple(K), _MODELS[model], coeffs)


def write(camera: CameraModel, path: str | Path) -> None:
    """A one-camera camchain; refuses a radtan k3 that Kalibr cannot hold."""
    coeffs = [float(c) for c in camera.dist_coeffs]
    model = {"radtan_opencv": "radtan", "equidistant": "equidistant", "none": "none"}[
        camera.distortion_model]
    if model == "radtan":
        if coeffs[4] != 0.0:
            raise InputError(f"Kalibr's radtan model has no k3 (this camera has k3 = "
                             f"{coeffs[4]:g}); use another format or calibrate without k3")
        coeffs = coeffs[:4]
    elif model == "none":
        coeffs = []
    block = {"camera_model": "pinhole", "intrinsics": [camera.fx, camera.fy, camera.cx, camera.cy],
             "distortion_model": model, "distortion_coeffs": coeffs,
             "resolution": [camera.width, camera.height]}
    write_text(path, yaml.safe_dump({"cam0": block}, sort_keys=False, default_flow_style=None))
