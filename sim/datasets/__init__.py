"""Dataset readers: every format yields (t_seconds, grey uint8 image) lazily, with the camera
model, ground truth and IMU samples where the format has them."""

from __future__ import annotations

from pathlib import Path

from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from sdvl.errors import InputError
from sim.datasets.euroc import euroc_root, read_euroc
from sim.datasets.files import VIDEO_SUFFIXES, read_image_folder, read_video
from sim.datasets.kitti import is_kitti, read_kitti
from sim.datasets.layout import is_layout, read_layout
from sim.datasets.tum import is_tum, read_tum_rgbd
from sim.sequence import Sequence

__all__ = ["open_sequence"]


def open_sequence(path: str | Path, camera: str | Path | CameraModel | None = None,
                  fps: float | None = None) -> Sequence:
    """Open any supported sequence by looking at what the path holds.

    `camera` (a CameraModel or a camera.yaml path) overrides the format's own calibration;
    `fps` times folders of images and videos.
    """
    path = Path(path)
    if isinstance(camera, str | Path):
        camera = load_camera(camera)
    if not path.exists():
        from sim.synth.presets import PRESETS  # heavy (numba): only for preset names

        if str(path) in PRESETS:
            from sim.synth.flight import synthetic_sequence

            return synthetic_sequence(str(path))
        raise InputError("no such file or folder", path)
    if path.is_file():
        if path.suffix.lower() in VIDEO_SUFFIXES:
            return read_video(path, camera, fps)
        raise InputError("not a sequence folder or a video file "
                         f"({', '.join(sorted(VIDEO_SUFFIXES))})", path)
    if is_layout(path):
        return read_layout(path, camera)
    if is_tum(path):
        return read_tum_rgbd(path, camera)
    if euroc_root(path) is not None:
        return read_euroc(path, camera)
    if is_kitti(path):
        return read_kitti(path, camera)
    return read_image_folder(path, camera, fps)
