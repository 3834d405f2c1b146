"""EuRoC MAV (ASL layout): mav0/cam0 with sensor.yaml, imu0, state_groundtruth_estimate0."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from calib.camera import CameraModel
from sdvl.errors import InputError
from sdvl.textfile import check_increasing, read_lines, read_numeric_table
from sim.sequence import ImuSamples, Sequence, image_list_sequence
from sim.trajectory import Trajectory

NS = 1e-9


def euroc_root(path: Path) -> Path | None:
    """The `mav0` folder of an EuRoC sequence at `path`, or None."""
    for root in (path / "mav0", path):
        if (root / "cam0" / "data.csv").is_file():
            return root
    return None


def _sensor_yaml(path: Path) -> dict:
    try:
        data = yaml.safe_load(path.read_text())
    except FileNotFoundError:
        raise InputError("file not found", path) from None
    except yaml.YAMLError as exc:
        raise InputError(f"not valid YAML ({exc})", path) from None
    for key in ("T_BS", "resolution", "intrinsics"):
        if not isinstance(data, dict) or key not in data:
            raise InputError(f"missing key '{key}'", path)
    return data


def euroc_camera(sensor: dict, path: Path) -> tuple[CameraModel, np.ndarray]:
    """The camera model and body-from-camera transform T_B_C from a cam0/sensor.yaml."""
    fu, fv, cu, cv = sensor["intrinsics"]
    model = sensor.get("distortion_model", "none")
    dist = tuple(sensor.get("distortion_coefficients") or ())
    if model in ("equidistant", "fisheye"):
        model = "equidistant"
    camera = CameraModel(int(sensor["resolution"][0]), int(sensor["resolution"][1]),
                         fu, fv, cu, cv, model, dist)
    T_B_C = np.asarray(sensor["T_BS"]["data"], dtype=np.float64).reshape(4, 4)
    if not np.allclose(T_B_C[3], [0, 0, 0, 1]):
        raise InputError("T_BS is not a rigid transform", path)
    return camera, T_B_C


def _frame_list(csv: Path) -> tuple[np.ndarray, list[Path]]:
    times, files = [], []
    for line, fields in read_lines(csv):
        if len(fields) != 2 or not fields[0].isdigit():
            raise InputError("expected 'timestamp_ns,filename'", csv, line)
        times.append(int(fields[0]) * NS)
        files.append(csv.parent / "data" / fields[1])
    times = np.array(times)
    check_increasing(times, csv)
    return times, files


def _groundtruth(csv: Path, T_B_C: np.ndarray) -> Trajectory:
    """World-from-camera from the body ground truth (p, q_wxyz), composed with T_B_C."""
    data = read_numeric_table(csv, 17, "timestamp p_xyz q_wxyz v_xyz bw_xyz ba_xyz")
    check_increasing(data[:, 0], csv)
    T_W_B = np.tile(np.eye(4), (len(data), 1, 1))
    T_W_B[:, :3, :3] = Rotation.from_quat(data[:, [5, 6, 7, 4]]).as_matrix()
    T_W_B[:, :3, 3] = data[:, 1:4]
    return Trajectory.from_matrices(data[:, 0] * NS, T_W_B @ T_B_C)


def read_euroc(path: Path, camera: CameraModel | None = None) -> Sequence:
    """An EuRoC sequence from cam0, with camera ground truth and imu0 samples."""
    root = euroc_root(path)
    if root is None:
        raise InputError("not an EuRoC sequence (no mav0/cam0/data.csv)", path)
    sensor_path = root / "cam0" / "sensor.yaml"
    own_camera, T_B_C = euroc_camera(_sensor_yaml(sensor_path), sensor_path)
    times, files = _frame_list(root / "cam0" / "data.csv")
    imu = None
    if (root / "imu0" / "data.csv").is_file():
        raw = read_numeric_table(root / "imu0" / "data.csv", 7, "timestamp w_xyz a_xyz")
        imu = ImuSamples(raw[:, 0] * NS, raw[:, 4:7], raw[:, 1:4])
    gt_csv = root / "state_groundtruth_estimate0" / "data.csv"
    return image_list_sequence(
        path.resolve().name, camera or own_camera, times, files,
        groundtruth=_groundtruth(gt_csv, T_B_C) if gt_csv.is_file() else None, imu=imu,
        extras={"root": path, "T_B_C": T_B_C},
    )
