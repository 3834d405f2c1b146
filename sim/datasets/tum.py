"""TUM RGB-D sequences as distributed: rgb.txt, depth.txt, groundtruth.txt,
accelerometer.txt."""

from __future__ import annotations

import re
from pathlib import Path

from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from daemon.recordings import depth_list, folder_depth_spec, read_frame_list
from sdvl.errors import InputError
from sdvl.textfile import read_numeric_table
from sim.sequence import ImuSamples, Sequence, image_list_sequence
from sim.trajectory import read_tum

# The official calibration of the three Kinects (TUM RGB-D "file formats" page), colour camera.
TUM_CAMERAS = {
    "freiburg1": (517.3, 516.5, 318.6, 255.3, (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)),
    "freiburg2": (520.9, 521.0, 325.1, 249.7, (0.2312, -0.7849, -0.0033, -0.0001, 0.9172)),
    "freiburg3": (535.4, 539.2, 320.1, 247.6, (0.0, 0.0, 0.0, 0.0, 0.0)),
}


def is_tum(path: Path) -> bool:
    """True if `path` is a TUM RGB-D sequence folder."""
    return (path / "rgb.txt").is_file()


def tum_camera(path: Path) -> CameraModel:
    """camera.yaml in the folder if present, else the official camera named by the folder."""
    if (path / "camera.yaml").is_file():
        return load_camera(path / "camera.yaml")
    match = re.search(r"freiburg([123])", path.resolve().name)
    if not match:
        raise InputError("no camera.yaml and the folder name does not say freiburg1/2/3; "
                         "pass --camera FILE", path)
    fx, fy, cx, cy, dist = TUM_CAMERAS["freiburg" + match.group(1)]
    model = "radtan_opencv" if any(dist) else "none"
    return CameraModel(640, 480, fx, fy, cx, cy, model, dist)


def read_tum_rgbd(path: Path, camera: CameraModel | None = None) -> Sequence:
    """A TUM RGB-D sequence: colour frames as grey, depth associated by time (depth.txt),
    ground truth and accelerometer if present."""
    times, files = read_frame_list(path / "rgb.txt")
    camera = camera or tum_camera(path)
    gt_path, acc_path = path / "groundtruth.txt", path / "accelerometer.txt"
    imu = None
    if acc_path.is_file():
        acc = read_numeric_table(acc_path, 4, "timestamp ax ay az")
        imu = ImuSamples(acc[:, 0], acc[:, 1:4], None)
    return image_list_sequence(
        path.name, camera, times, files,
        groundtruth=read_tum(gt_path) if gt_path.is_file() else None, imu=imu,
        extras={"root": path},
        depth_loader=depth_list(path, times, folder_depth_spec(path), camera),
    )
