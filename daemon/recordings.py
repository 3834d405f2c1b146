"""Recorded frames on disk as a camera: a frame list of `timestamp relative/path` lines
(frames.txt of the shared-data layout and of `sdvl render`, rgb.txt of TUM RGB-D) or a folder of
images, with a camera.yaml in the folder or beside it. The replay side's dataset readers
(sim.datasets) build on these functions."""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from sdvl.errors import InputError
from sdvl.textfile import check_increasing, parse_floats, read_lines

IMAGE_SUFFIXES = {".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm"}
FRAME_LISTS = ("frames.txt", "rgb.txt")
DEFAULT_FPS = 30.0


def load_grey(path: str | Path) -> np.ndarray:
    """A uint8 grey image from a file; InputError if it cannot be decoded."""
    image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if image is None:
        raise InputError("cannot read image (missing or corrupt)", path)
    return image


def read_frame_list(path: Path) -> tuple[np.ndarray, list[Path]]:
    """Times and absolute image paths from a `timestamp relative/path` list."""
    times, files = [], []
    for line, fields in read_lines(path):
        if len(fields) != 2:
            raise InputError("expected 'timestamp relative/path'", path, line)
        times.append(parse_floats(fields[:1], path, line, "a timestamp")[0])
        files.append(path.parent / fields[1])
    times = np.array(times)
    check_increasing(times, path)
    return times, files


def _natural_key(path: Path) -> list:
    return [int(s) if s.isdigit() else s for s in re.split(r"(\d+)", path.name)]


def image_files(path: Path) -> list[Path]:
    """The image files of a folder in natural order (img2 before img10)."""
    return sorted((p for p in path.iterdir() if p.suffix.lower() in IMAGE_SUFFIXES),
                  key=_natural_key)


@dataclass
class Recording:
    """Image files with their times; `camera` is None when no camera.yaml was found."""

    name: str
    camera: CameraModel | None
    timestamps: np.ndarray
    files: list[Path]

    def __len__(self) -> int:
        return len(self.files)

    def frames(self, max_frames: int | None = None) -> Iterator[tuple[float, np.ndarray]]:
        """(t seconds, grey uint8 image), each image read when it is asked for."""
        for t, path in zip(self.timestamps[:max_frames], self.files[:max_frames], strict=True):
            yield float(t), load_grey(path)


def open_recording(path: str | Path, fps: float | None = None) -> Recording:
    """The folder's frame list if it has one, else its images in natural order at `fps`
    (default 30) from t = 0."""
    path = Path(path)
    frame_list = next((path / n for n in FRAME_LISTS if (path / n).is_file()), None)
    if frame_list is not None:
        times, files = read_frame_list(frame_list)
    else:
        files = image_files(path)
        times = np.arange(len(files)) / (fps or DEFAULT_FPS)
    if not files:
        raise InputError("no images in folder", path)
    yaml = next((p for p in (path / "camera.yaml", path.parent / "camera.yaml") if p.is_file()),
                None)
    return Recording(path.resolve().name, load_camera(yaml) if yaml else None, times, files)
