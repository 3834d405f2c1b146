"""The `camera.yaml` file the tracker, the service and the datasets share.

Keys: width, height, fx, fy, cx, cy, distortion_model, distortion. Other keys (dataset, fps,
comments) are allowed and ignored.
"""

from __future__ import annotations

from pathlib import Path

import yaml

from calib.camera import CameraModel, canonical_model_name
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


def save_camera(camera: CameraModel, path: str | Path, comment: str | None = None) -> None:
    """Write a camera.yaml that `load_camera` reads back to the same values."""
    text = yaml.safe_dump(camera_to_mapping(camera), sort_keys=False, default_flow_style=None)
    if comment:
        text = "".join(f"# {line}\n" for line in comment.splitlines()) + text
    Path(path).write_text(text)
