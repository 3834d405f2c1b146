"""The sequence layout of `../shared/data` and of `sdvl render`: frames.txt, camera.yaml,
groundtruth.txt, and optionally imu.csv, sensors.csv, rig.yaml (the ground truth's world
frame, e.g. `world: NED`, and the camera mounting `T_b_c`, a 4x4 list) and depth.txt (16-bit
depth PNGs, TUM format; the `depth` keys of camera.yaml say how to read them, TUM's
convention when it has none)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from daemon.recordings import depth_list, folder_depth_spec, read_frame_list
from sdvl.errors import InputError
from sdvl.textfile import check_increasing, read_numeric_table
from sim.sequence import ImuSamples, Sequence, image_list_sequence
from sim.trajectory import read_tum

IMU_COLUMNS = "t ax ay az gx gy gz"
SENSOR_COLUMNS = "t qx qy qz qw baro_alt range range_valid"


@dataclass
class SensorSamples:
    """Autopilot signals: `attitude` (N, 4) xyzw quaternions R_world_body (NED from FRD),
    `baro_alt` (N,) m up, `range` (N,) m along the body's down axis, valid where `range_valid`."""

    t: np.ndarray
    attitude: np.ndarray
    baro_alt: np.ndarray
    range: np.ndarray
    range_valid: np.ndarray


def is_layout(path: Path) -> bool:
    """True if `path` is a folder in this layout."""
    return (path / "frames.txt").is_file()


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


def read_sensors_csv(path: Path) -> SensorSamples:
    """Autopilot signals from `t qx qy qz qw baro_alt range range_valid` rows."""
    data = read_numeric_table(path, 8, SENSOR_COLUMNS)
    check_increasing(data[:, 0], path)
    return SensorSamples(data[:, 0], data[:, 1:5], data[:, 5], data[:, 6], data[:, 7] > 0.5)


def write_sensors_csv(sensors: SensorSamples, path: Path) -> None:
    """Write autopilot signals in the format `read_sensors_csv` reads."""
    rows = np.column_stack([sensors.t, sensors.attitude, sensors.baro_alt, sensors.range,
                            sensors.range_valid.astype(float)])
    np.savetxt(path, rows, fmt="%.9f", delimiter=",", header=SENSOR_COLUMNS.replace(" ", ","),
               comments="# ")


def read_rig_yaml(path: Path) -> dict:
    """`world` and `T_b_c` (4x4 array) from a rig.yaml, as sequence extras."""
    try:
        data = yaml.safe_load(path.read_text())
        out = {"world": str(data["world"])}
        if "T_b_c" in data:
            out["T_b_c"] = np.array(data["T_b_c"], dtype=np.float64).reshape(4, 4)
    except (yaml.YAMLError, TypeError, KeyError, ValueError) as exc:
        raise InputError(f"expected 'world: NAME' and 'T_b_c: 4x4 list' ({exc})", path) from None
    return out


def write_rig_yaml(world: str, T_b_c: np.ndarray, path: Path) -> None:
    """Write what `read_rig_yaml` reads."""
    rows = [[float(v) for v in row] for row in np.asarray(T_b_c)]
    path.write_text(yaml.safe_dump({"world": world, "T_b_c": rows}, default_flow_style=None))


def read_layout(path: Path, camera: CameraModel | None = None) -> Sequence:
    """A sequence in the shared-data layout; `camera` overrides its camera.yaml."""
    times, files = read_frame_list(path / "frames.txt")
    camera = camera or load_camera(path / "camera.yaml")
    gt_path, imu_path = path / "groundtruth.txt", path / "imu.csv"
    extras = {"root": path}
    if (path / "sensors.csv").is_file():
        extras["sensors"] = read_sensors_csv(path / "sensors.csv")
    if (path / "rig.yaml").is_file():
        extras.update(read_rig_yaml(path / "rig.yaml"))
    return image_list_sequence(
        path.name, camera, times, files,
        groundtruth=read_tum(gt_path) if gt_path.is_file() else None,
        imu=read_imu_csv(imu_path) if imu_path.is_file() else None,
        extras=extras,
        depth_loader=depth_list(path, times, folder_depth_spec(path), camera),
    )
