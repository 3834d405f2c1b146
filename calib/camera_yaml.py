"""The `camera.yaml` file the tracker, the service and the datasets share.

Keys: width, height, fx, fy, cx, cy, distortion_model, distortion. Other keys (dataset, fps,
comments) are allowed and ignored. A depth camera adds a `depth` mapping (calib.depth_camera):

    depth:
      scale: 0.001          # metres per unit of the 16-bit depth image (TUM: 0.0002)
      min_m: 0.3            # measurements outside min_m..max_m are dropped (max_m 0: no limit)
      max_m: 8.0
      registered: true      # depth already in the colour camera's pixels
      # registered: false needs the depth camera and where it is:
      # camera: {width: 848, height: 480, fx: ..., fy: ..., cx: ..., cy: ...}
      # T_color_depth: [[1, 0, 0, 0.015], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml

from calib.camera import CameraModel, canonical_model_name
from calib.depth_camera import DepthSpec
from sdvl.errors import InputError, read_text

REQUIRED_KEYS = ("width", "height", "fx", "fy", "cx", "cy")


def _read_mapping(path: Path) -> tuple[dict, dict[str, int]]:
    """The YAML mapping in `path` and the 1-based line of each top-level key."""
    text = read_text(path)
    try:
        node = yaml.compose(text, Loader=yaml.SafeLoader)
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        line = None if mark is None else mark.line + 1
        raise InputError(f"not valid YAML ({getattr(exc, 'problem', exc)})", path, line) from None
    if not isinstance(data, dict) or node is None:
        raise InputError("expected a mapping of keys (width, height, fx, ...)", path)
    lines = {k.value: k.start_mark.line + 1 for k, _ in node.value}
    return data, lines


def _number(data: dict, key: str, path: Path, lines: dict[str, int], integer: bool = False):
    value = data[key]
    ok = isinstance(value, int) if integer else isinstance(value, int | float)
    if isinstance(value, bool) or not ok:
        kind = "an integer" if integer else "a number"
        raise InputError(f"'{key}' must be {kind}, got {value!r}", path, lines.get(key))
    return value


def camera_from_mapping(data: dict, path: Path | str = "<config>",
                        lines: dict[str, int] | None = None) -> CameraModel:
    """A CameraModel from the keys of a camera.yaml (or a config section holding them)."""
    lines = lines or {}
    missing = [k for k in REQUIRED_KEYS if k not in data]
    if missing:
        raise InputError(f"missing key(s) {', '.join(missing)} (camera.yaml needs "
                         f"{', '.join(REQUIRED_KEYS)}, distortion_model, distortion)", path)
    values = {k: _number(data, k, path, lines, integer=k in ("width", "height"))
              for k in REQUIRED_KEYS}
    model = data.get("distortion_model", "none")
    try:
        model = canonical_model_name(model if model is not None else "none")
    except InputError as exc:
        raise InputError(exc.message, path, lines.get("distortion_model")) from None
    coeffs = data.get("distortion", [])
    if coeffs is None:
        coeffs = []
    if not isinstance(coeffs, list) or not all(
        isinstance(c, int | float) and not isinstance(c, bool) for c in coeffs
    ):
        raise InputError(f"'distortion' must be a list of numbers, got {coeffs!r}", path,
                         lines.get("distortion"))
    try:
        return CameraModel(distortion_model=model, distortion=tuple(coeffs), **values)
    except InputError as exc:
        raise InputError(exc.message, path, lines.get("distortion")) from None


def load_camera(path: str | Path) -> CameraModel:
    """Read a camera.yaml; InputError naming the file, line and problem when it is wrong."""
    path = Path(path)
    data, lines = _read_mapping(path)
    return camera_from_mapping(data, path, lines)


def camera_to_mapping(camera: CameraModel) -> dict:
    """The camera.yaml keys of a camera, as plain Python values."""
    return {
        "width": int(camera.width),
        "height": int(camera.height),
        "fx": float(camera.fx),
        "fy": float(camera.fy),
        "cx": float(camera.cx),
        "cy": float(camera.cy),
        "distortion_model": camera.distortion_model,
        "distortion": [float(c) for c in camera.distortion],
    }


DEPTH_KEYS = ("scale", "min_m", "max_m", "registered", "camera", "T_color_depth")


def depth_from_mapping(data: dict, path: Path | str = "<config>",
                       lines: dict[str, int] | None = None) -> DepthSpec | None:
    """The DepthSpec of a camera.yaml's `depth` mapping; None when there is none."""
    section = data.get("depth")
    if section is None:
        return None
    line = (lines or {}).get("depth")
    if not isinstance(section, dict):
        raise InputError("'depth' must be a mapping (scale, min_m, max_m, registered, ...)",
                         path, line)
    unknown = sorted(set(section) - set(DEPTH_KEYS))
    if unknown:
        raise InputError(f"unknown key(s) depth.{', depth.'.join(unknown)} (known: "
                         f"{', '.join(DEPTH_KEYS)})", path, line)
    values = {k: _number(section, k, path, {k: line}) for k in ("scale", "min_m", "max_m")
              if k in section}
    registered = section.get("registered", True)
    if not isinstance(registered, bool):
        raise InputError(f"'depth.registered' must be true or false, got {registered!r}", path,
                         line)
    camera = section.get("camera")
    if camera is not None:
        if not isinstance(camera, dict):
            raise InputError("'depth.camera' must be a mapping (width, height, fx, ...)", path,
                             line)
        camera = camera_from_mapping(camera, path, {})
    T = section.get("T_color_depth")
    if T is not None:
        try:
            T = np.array(T, dtype=np.float64).reshape(4, 4)
        except (TypeError, ValueError):
            raise InputError("'depth.T_color_depth' must be a 4x4 list of numbers", path,
                             line) from None
    try:
        return DepthSpec(registered=registered, camera=camera, T_c_d=T, **values)
    except InputError as exc:
        raise InputError(exc.message, path, line) from None


def load_depth_spec(path: str | Path) -> DepthSpec | None:
    """The `depth` mapping of a camera.yaml as a DepthSpec (None when the file has none)."""
    path = Path(path)
    data, lines = _read_mapping(path)
    return depth_from_mapping(data, path, lines)


def depth_to_mapping(spec: DepthSpec) -> dict:
    """The camera.yaml `depth` keys of a DepthSpec, as plain Python values."""
    out = {"scale": float(spec.scale), "min_m": float(spec.min_m), "max_m": float(spec.max_m),
           "registered": bool(spec.registered)}
    if spec.camera is not None:
        out["camera"] = camera_to_mapping(spec.camera)
    if spec.T_c_d is not None:
        out["T_color_depth"] = [[float(v) for v in row] for row in spec.T_c_d]
    return out


def save_camera(camera: CameraModel, path: str | Path, comment: str | None = None,
                depth: DepthSpec | None = None) -> None:
    """Write a camera.yaml that `load_camera` (and `load_depth_spec`) read back to the same
    values."""
    data = camera_to_mapping(camera)
    if depth is not None:
        data["depth"] = depth_to_mapping(depth)
    text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None)
    if comment:
        text = "".join(f"# {line}\n" for line in comment.splitlines()) + text
    Path(path).write_text(text)
