"""Where calibration images come from: image files, a video file or a live camera device.

Each source yields (name, grey uint8 image or None); None means the file could not be read, so
the caller can report it by name and go on.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from calib.errors import InputError


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def image_files(paths: list[str]) -> Iterator[tuple[str, np.ndarray | None]]:
    """Each image file as grey, in the order given; None for files OpenCV cannot decode."""
    for path in paths:
        yield path, cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)


def _capture_frames(capture: cv2.VideoCapture, prefix: str) -> Iterator[tuple[str, np.ndarray]]:
    index = 0
    try:
        while True:
            ok, frame = capture.read()
            if not ok or frame is None:
                return
            yield f"{prefix}#{index}", _grey(frame)
            index += 1
    finally:
        capture.release()


def video_frames(path: str | Path) -> Iterator[tuple[str, np.ndarray]]:
    """Every frame of a video file as grey, named 'file#index'."""
    if not Path(path).is_file():
        raise InputError("video file not found", path)
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise InputError("cannot open video (unknown format or codec)", path)
    return _capture_frames(capture, Path(path).name)


def device_frames(index: int) -> Iterator[tuple[str, np.ndarray]]:
    """Frames from camera device `index` (/dev/videoN) as grey, until it stops or Ctrl-C."""
    capture = cv2.VideoCapture(index)
    if not capture.isOpened():
        raise InputError(f"cannot open camera device {index} (is it /dev/video{index}, "
                         "connected and not in use?)")
    return _capture_frames(capture, f"device{index}")
