"""Camera calibration files users already have: read any of them, write any of them.

Formats: sdvl (our camera.yaml), kalibr, ros, opencv (YAML/XML), orbslam, sdvl-cfg. Reading
guesses the format from the keys unless it is named; values survive a round trip exactly.
"""

from __future__ import annotations

from pathlib import Path

from calib import camera_yaml
from calib.camera import CameraModel
from calib.formats import kalibr, opencv_storage, ros
from calib.formats.documents import read_document
from calib.formats.slam_config import OrbSlam, SdvlConfig
from sdvl.errors import InputError


class _SdvlYaml:
    NAME = "sdvl"
    DESCRIPTION = "SDVL Companion camera.yaml (what the tracker and the service read)"

    @staticmethod
    def matches(data: dict) -> bool:
        return "fx" in data and "width" in data

    @staticmethod
    def from_mapping(data: dict, path: str | Path) -> CameraModel:
        return camera_yaml.camera_from_mapping(data, path)

    @staticmethod
    def write(camera: CameraModel, path: str | Path) -> None:
        camera_yaml.save_camera(camera, path)


# Guessing order matters: SDVL's Camera.u0 before ORB-SLAM's Camera.fx.
FORMATS = {f.NAME: f for f in (_SdvlYaml, kalibr, ros, opencv_storage, SdvlConfig, OrbSlam)}


def format_help() -> str:
    """One line per format, for --help."""
    return "; ".join(f"{name}: {f.DESCRIPTION}" for name, f in FORMATS.items())


def _checked(fmt: str) -> object:
    if fmt not in FORMATS:
        raise InputError(f"unknown camera file format '{fmt}' (expected one of: "
                         f"{', '.join(FORMATS)})")
    return FORMATS[fmt]


def read_camera_file(path: str | Path, fmt: str | None = None) -> tuple[CameraModel, str]:
    """The camera in `path` and the format it was read as (guessed when `fmt` is None)."""
    data = read_document(path)
    if fmt is None:
        fmt = next((name for name, f in FORMATS.items() if f.matches(data)), None)
        if fmt is None:
            raise InputError(f"unrecognised camera file (expected one of: {', '.join(FORMATS)})",
                             path)
    return _checked(fmt).from_mapping(data, path), fmt


def write_camera_file(camera: CameraModel, path: str | Path, fmt: str) -> None:
    """Write `camera` to `path` in format `fmt`; InputError if the format cannot hold it."""
    _checked(fmt).write(camera, path)
