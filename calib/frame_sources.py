"""Where calibration images come from: image files, a video file or a live camera device.

Each source yields (name, grey uint8 image); image files that cannot be read yield the reason
instead of the image, so the caller can report them by name and go on.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import cv2
import numpy as np

from sdvl.errors import InputError


def _grey(image: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(image, cv2.COLOR_BGR2GRAY) if image.ndim == 3 else image


def read_image(path: str | Path) -> tuple[np.ndarray | None, str | None]:
    """(grey image, None), or (None, why it cannot be read) for a missing or undecodable file."""
    try:
        data = np.frombuffer(Path(path).read_bytes(), dtype=np.uint8)
    except FileNotFoundError:
        return None, "file not found"
    except OSError as exc:
        return None, f"cannot read file ({exc.strerror})"
    image = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE) if data.size else None
    return (image, None) if image is not None else (None, "not an image, or corrupt")


def image_files(paths: list[str]) -> Iterator[tuple[str, np.ndarray | str]]:
    """Each image file as grey in the order given; for unreadable files, the reason instead."""
    for path in paths:
        image, problem = read_image(path)
        yield path, image if image is not None else problem


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
