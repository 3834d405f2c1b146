"""Reading the files camera formats live in: plain YAML, OpenCV FileStorage YAML (with its
`%YAML:1.0` header and `!!opencv-matrix` tags) and OpenCV FileStorage XML, into plain dicts.

Also the small helpers every format uses to pull numbers out with errors naming file and key.
"""

from __future__ import annotations

import contextlib
import re
from pathlib import Path

import cv2
import numpy as np
import yaml

from calib.camera import CameraModel, canonical_model_name
from sdvl.errors import InputError, read_text

_OPENCV_HEADER = re.compile(r"\A\s*%YAML[: ]1\.\d+\s*\n(---\s*\n)?")


class _OpenCVLoader(yaml.SafeLoader):
    """SafeLoader that also understands OpenCV's `!!opencv-matrix` nodes."""


def _opencv_matrix(loader: yaml.SafeLoader, node: yaml.Node) -> np.ndarray:
    m = loader.construct_mapping(node, deep=True)
    return np.array(m["data"], dtype=np.float64).reshape(int(m["rows"]), int(m["cols"]))


_OpenCVLoader.add_constructor("tag:yaml.org,2002:opencv-matrix", _opencv_matrix)


def _read_xml(path: Path) -> dict:
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as exc:
        raise InputError(f"not a valid OpenCV XML file ({exc})", path) from None
    out = {}
    names = storage.root().keys()  # a FileNode, not a dict
    for key in names:
        node = storage.getNode(key)
        if node.isString():
            out[key] = node.string()
        elif node.isInt():
            out[key] = int(node.real())
        elif node.isReal():
            out[key] = node.real()
        elif node.isMap():
            out[key] = node.mat()
    storage.release()
    return out


def read_document(path: str | Path) -> dict:
    """The top-level mapping of a YAML or OpenCV YAML/XML file; InputError when unreadable."""
    path = Path(path)
    text = read_text(path)
    if text.lstrip().startswith("<?xml") or text.lstrip().startswith("<opencv_storage"):
        return _read_xml(path)
    try:
        data = yaml.load(_OPENCV_HEADER.sub("", text, count=1), Loader=_OpenCVLoader)
    except (yaml.YAMLError, KeyError, ValueError, TypeError) as exc:
        mark = getattr(exc, "problem_mark", None)
        line = None if mark is None else mark.line + 1
        raise InputError(f"not valid YAML ({getattr(exc, 'problem', None) or exc})", path,
                         line) from None
    if not isinstance(data, dict):
        raise InputError("expected a mapping of keys", path)
    return data


def number(data: dict, key: str, path: str | Path, default: float | None = None) -> float:
    """The number under `key`; `default` when absent (InputError when absent and no default)."""
    value = data.get(key, default)
    if value is None:
        raise InputError(f"missing key '{key}'", path)
    if isinstance(value, str):  # YAML 1.1 reads OpenCV's "1e-05" as a string
        with contextlib.suppress(ValueError):
            value = float(value)
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise InputError(f"'{key}' must be a number, got {value!r}", path)
    return float(value)


def numbers(value, key: str, path: str | Path, count: int | None = None) -> list[float]:
    """A flat list of numbers from a list or matrix value, optionally of exactly `count`."""
    flat = np.asarray(value, dtype=object).ravel().tolist() if value is not None else None
    if flat is None or not all(isinstance(v, int | float) and not isinstance(v, bool)
                               for v in flat):
        raise InputError(f"'{key}' must be a list of numbers, got {value!r}", path)
    if count is not None and len(flat) != count:
        raise InputError(f"'{key}' must have {count} numbers, got {len(flat)}", path)
    return [float(v) for v in flat]


def make_camera(path: str | Path, size: tuple[float, float], K: tuple[float, float, float, float],
                model: str, coeffs: list[float]) -> CameraModel:
    """A CameraModel with full-length coefficients; all-zero radtan becomes model 'none'.

    Extra coefficients a format allows beyond ours (rational k4..k6) must be zero.
    """
    model = canonical_model_name(model)
    n = 4 if model == "equidistant" else 5
    if any(c != 0.0 for c in coeffs[n:]):
        raise InputError(f"distortion has {len(coeffs)} non-zero coefficients; only {n} are "
                         f"supported for {model}", path)
    coeffs = (list(coeffs[:n]) + [0.0] * n)[:n]
    if model != "equidistant" and not any(coeffs):
        model, coeffs = "none", []
    width, height = size
    if width != int(width) or height != int(height):
        raise InputError(f"image size must be whole pixels, got {width}x{height}", path)
    try:
        return CameraModel(int(width), int(height), *K, distortion_model=model,
                           distortion=tuple(coeffs))
    except InputError as exc:
        raise InputError(exc.message, path) from None


def full_coefficients(camera: CameraModel) -> list[float]:
    """The camera's distortion as OpenCV takes it: 5 for radtan/none, 4 for equidistant."""
    return [float(c) for c in camera.dist_coeffs]


def write_text(path: str | Path, text: str) -> None:
    """Write a text file; InputError naming it when that fails."""
    try:
        Path(path).write_text(text)
    except OSError as exc:
        raise InputError(f"cannot write: {exc.strerror}", path) from None
