"""Plain inputs: a folder of images, or a video file, with a camera.yaml from the user."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from daemon.camera import grey
from daemon.recordings import DEFAULT_FPS, open_recording
from sdvl.errors import InputError
from sim.sequence import Sequence, image_list_sequence

VIDEO_SUFFIXES = {".mp4", ".avi", ".mkv", ".mov", ".webm", ".m4v", ".mpg", ".mpeg"}


def _find_camera(candidates: list[Path], what: Path) -> CameraModel:
    for candidate in candidates:
        if candidate.is_file():
            return load_camera(candidate)
    raise InputError("no camera calibration found (looked for "
                     f"{', '.join(c.name for c in candidates)}); pass --camera FILE", what)


def read_image_folder(path: Path, camera: CameraModel | None = None,
                      fps: float | None = None) -> Sequence:
    """The images of a folder in natural order, at `fps` (default 30) from t = 0, with the
    depth maps of a depth.txt beside them."""
    recording = open_recording(path, fps, camera)
    camera = recording.camera or _find_camera(
        [path / "camera.yaml", path.parent / "camera.yaml"], path)
    return image_list_sequence(recording.name, camera, recording.timestamps, recording.files,
                               extras={"root": path}, depth_loader=recording.depth_loader)


def read_video(path: Path, camera: CameraModel | None = None,
               fps: float | None = None) -> Sequence:
    """A video file's frames as grey images, timed by its frame rate (or `fps`)."""
    capture = cv2.VideoCapture(str(path))
    if not capture.isOpened():
        raise InputError("cannot open video (missing file or unsupported codec)", path)
    count = int(capture.get(cv2.CAP_PROP_FRAME_COUNT))
    fps = fps or capture.get(cv2.CAP_PROP_FPS) or DEFAULT_FPS
    capture.release()
    if count <= 0:
        raise InputError("video reports no frames", path)
    camera = camera or _find_camera([path.with_suffix(".yaml"), path.parent / "camera.yaml"],
                                    path)

    def frame_iter():
        cap = cv2.VideoCapture(str(path))
        try:
            for i in range(count):
                ok, image = cap.read()
                if not ok:
                    return
                yield i / fps, grey(image)
        finally:
            cap.release()

    return Sequence(path.stem, camera, np.arange(count) / fps, frame_iter=frame_iter,
                    extras={"root": path})
