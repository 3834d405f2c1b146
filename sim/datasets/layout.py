"""The sequence layout of `../shared/data` and of `sdvl render`: frames.txt, camera.yaml,
groundtruth.txt, and optionally imu.csv and sensors.csv."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from calib.errors import InputError
from sim.sequence import ImuSamples, Sequence, image_list_sequence
from sim.textfile import check_increasing, parse_floats, read_lines, read_numeric_table
from sim.trajectory import read_tum

IMU_COLUMNS = "t ax ay az gx gy gz"


def is_layout(path: Path) -> bool:
    """True if `path` is a folder in this layout."""
    return (path / "frames.txt").is_file()


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


def read_imu_csv(path: Path) -> ImuSamples:
    """IMU samples from `t ax ay az gx gy gz` rows (comma or space separated)."""
    data = read_numeric_table(path, 7, IMU_COLUMNS)
    check_increasing(data[:, 0], path)
    return ImuSamples(data[:, 0], data[:, 1:4], data[:, 4:7])


def write_imu_csv(imu: ImuSamples, path: Path) -> None:
    """Write IMU samples in the format `read_imu_csv` reads."""
    gyro = imu.gyro if imu.gyro is not None else np.zeros_like(imu.accel)
    np.savetxt(path, np.column_stack([imu.t, imu.accel, gyro]), fmt="%.9f", delimiter=",",
               header=IMU_COLUMNS.replace(" ", ","), comments="# ")


def read_layout(path: Path, camera: CameraModel | None = None) -> Sequence:
    """A sequence in the shared-data layout; `camera` overrides its camera.yaml."""
    times, files = read_frame_list(path / "frames.txt")
    camera = camera or load_camera(path / "camera.yaml")
    gt_path, imu_path = path / "groundtruth.txt", path / "imu.csv"
    return image_list_sequence(
        path.name, camera, times, files,
        groundtruth=read_tum(gt_path) if gt_path.is_file() else None,
        imu=read_imu_csv(imu_path) if imu_path.is_file() else None,
        extras={"root": path},
    )
