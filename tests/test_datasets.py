"""Dataset readers: the shared sequences, and fixture files in every other format."""

from __future__ import annotations

import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.camera import CameraModel
from calib.camera_yaml import save_camera
from conftest import REAL_SEQUENCES
from sdvl.errors import InputError
from sim.datasets import open_sequence

EXPECTED = {  # frames, (height, width)
    "tum_fr1_rpy": (723, (480, 640)),
    "vamr_ex01_checkerboard736": (736, (480, 752)),
    "kitti00_first200": (200, (376, 1241)),
}
SMALL_CAMERA = CameraModel(64, 48, 50.0, 50.0, 31.5, 23.5)


def write_images(folder: Path, count: int, size=(48, 64), colour=False, ext=".png") -> list[str]:
    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(3)
    names = []
    for i in range(count):
        shape = (*size, 3) if colour else size
        name = f"{i:06d}{ext}"
        cv2.imwrite(str(folder / name), rng.integers(0, 255, shape, dtype=np.uint8))
        names.append(name)
    return names


def check_frames(sequence, count: int, shape: tuple[int, int], every: int = 1) -> None:
    assert len(sequence) == count
    assert np.all(np.diff(sequence.timestamps) > 0)
    assert (sequence.camera.height, sequence.camera.width) == shape
    seen = 0
    for i, (t, image) in enumerate(sequence.frames()):
        assert t == sequence.timestamps[i]
        if i % every == 0 or i == count - 1:
            assert image.shape == shape and image.dtype == np.uint8
        seen += 1
    assert seen == count


@pytest.mark.parametrize("name", REAL_SEQUENCES)
def test_shared_sequences(data_dir, name):
    count, shape = EXPECTED[name]
    sequence = open_sequence(data_dir / name)
    check_frames(sequence, count, shape)
    gt = sequence.groundtruth
    assert gt is not None and np.all(np.diff(gt.t) > 0)
    assert gt.t[0] <= sequence.timestamps[0] + 0.05 and gt.t[-1] >= sequence.timestamps[-1] - 0.05


def test_tum_rgbd_as_distributed(tmp_path):
    root = tmp_path / "rgbd_dataset_freiburg1_xyz"
    names = write_images(root / "rgb", 5, size=(480, 640), colour=True)
    times = 1305031102.175304 + np.arange(5) / 30
    (root / "rgb.txt").write_text("# color images\n# file\n# timestamp filename\n" + "".join(
        f"{t:.6f} rgb/{n}\n" for t, n in zip(times, names, strict=True)))
    (root / "groundtruth.txt").write_text("# ground truth\n" + "".join(
        f"{t:.4f} 1 2 3 0 0 0 1\n" for t in np.arange(times[0] - 0.1, times[-1] + 0.1, 0.01)))
    (root / "accelerometer.txt").write_text("# accelerometer\n" + "".join(
        f"{t:.6f} 0.1 -9.8 0.2\n" for t in times))
    sequence = open_sequence(root)
    check_frames(sequence, 5, (480, 640))
    assert sequence.camera.fx == 517.3  # the official freiburg1 calibration
    assert sequence.imu.accel.shape == (5, 3) and sequence.imu.gyro is None
    assert len(sequence.groundtruth) > 5


def write_euroc(root: Path, T_B_C: np.ndarray) -> np.ndarray:
    cam = root / "mav0" / "cam0"
    names = write_images(cam / "data", 4)
    stamps = 1403636579763555584 + np.arange(4, dtype=np.int64) * 50_000_000
    (cam / "data.csv").write_text("#timestamp [ns],filename\n" + "".join(
        f"{s},{n}\n" for s, n in zip(stamps, names, strict=True)))
    (cam / "sensor.yaml").write_text(
        "sensor_type: camera\nT_BS:\n  cols: 4\n  rows: 4\n  data: ["
        + ", ".join(f"{v:.12f}" for v in T_B_C.ravel())
        + "]\nrate_hz: 20\nresolution: [64, 48]\ncamera_model: pinhole\n"
        "intrinsics: [45.6, 45.7, 31.2, 24.8]\ndistortion_model: radial-tangential\n"
        "distortion_coefficients: [-0.28, 0.07, 0.0002, 0.00002]\n")
    imu = root / "mav0" / "imu0"
    imu.mkdir(parents=True)
    (imu / "data.csv").write_text("#timestamp [ns],w_x,w_y,w_z,a_x,a_y,a_z\n" + "".join(
        f"{stamps[0] + k * 5_000_000},0.01,0.02,0.03,9.8,0.1,0.2\n" for k in range(40)))
    gt = root / "mav0" / "state_groundtruth_estimate0"
    gt.mkdir(parents=True)
    q_wxyz = Rotation.from_euler("z", 30, degrees=True).as_quat()[[3, 0, 1, 2]]
    (gt / "data.csv").write_text("#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z,v,v,v,bw,bw,bw,ba,ba,ba\n"
                                 + "".join(f"{s},1,2,3,{','.join(map(str, q_wxyz))}"
                                           + ",0" * 9 + "\n" for s in stamps))
    return stamps


def test_euroc_applies_body_to_camera_transform(tmp_path):
    T_B_C = np.eye(4)
    T_B_C[:3, :3] = Rotation.from_euler("xyz", [10, -5, 90], degrees=True).as_matrix()
    T_B_C[:3, 3] = [-0.02, 0.06, 0.01]
    stamps = write_euroc(tmp_path, T_B_C)
    sequence = open_sequence(tmp_path)
    check_frames(sequence, 4, (48, 64))
    np.testing.assert_allclose(sequence.timestamps, stamps * 1e-9)
    assert sequence.camera.distortion_model == "radtan_opencv"
    assert sequence.imu.gyro.shape == (40, 3)
    T_W_B = np.eye(4)
    T_W_B[:3, :3] = Rotation.from_euler("z", 30, degrees=True).as_matrix()
    T_W_B[:3, 3] = [1, 2, 3]
    np.testing.assert_allclose(sequence.groundtruth.matrices()[0], T_W_B @ T_B_C, atol=1e-9)


def test_kitti_odometry_layout(tmp_path):
    seq = tmp_path / "dataset" / "sequences" / "07"
    write_images(seq / "image_0", 3)
    (seq / "times.txt").write_text("0.000000e+00\n1.036e-01\n2.073e-01\n")
    (seq / "calib.txt").write_text("P0: 7.0e+02 0 3.1e+01 0 0 7.0e+02 2.3e+01 0 0 0 1 0\n"
                                   "P1: 7.0e+02 0 3.1e+01 -3.8e+02 0 7.0e+02 2.3e+01 0 0 0 1 0\n")
    (tmp_path / "dataset" / "poses").mkdir()
    (tmp_path / "dataset" / "poses" / "07.txt").write_text(
        "1 0 0 0 0 1 0 0 0 0 1 0\n1 0 0 0.1 0 1 0 0 0 0 1 0.5\n0 -1 0 0.2 1 0 0 0 0 0 1 1.0\n")
    sequence = open_sequence(seq)
    check_frames(sequence, 3, (48, 64))
    assert (sequence.camera.fx, sequence.camera.cx, sequence.camera.cy) == (700.0, 31.0, 23.0)
    np.testing.assert_allclose(sequence.groundtruth.positions[2], [0.2, 0.0, 1.0])
    np.testing.assert_allclose(sequence.groundtruth.matrices()[2][:3, :3],
                               [[0, -1, 0], [1, 0, 0], [0, 0, 1]], atol=1e-12)


def test_image_folder_in_natural_order(tmp_path):
    folder = tmp_path / "shots"
    folder.mkdir()
    for i in (1, 2, 10):
        cv2.imwrite(str(folder / f"img{i}.jpg"), np.full((48, 64), i * 20, np.uint8))
    save_camera(SMALL_CAMERA, folder / "camera.yaml")
    sequence = open_sequence(folder, fps=10)
    check_frames(sequence, 3, (48, 64))
    values = [int(image[0, 0]) for _, image in sequence.frames()]
    assert values == [20, 40, 200]
    np.testing.assert_allclose(sequence.timestamps, [0.0, 0.1, 0.2])


def test_video_file(tmp_path):
    path = tmp_path / "flight.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, (64, 48))
    assert writer.isOpened()
    for i in range(6):
        writer.write(np.full((48, 64, 3), 30 * i, np.uint8))
    writer.release()
    save_camera(SMALL_CAMERA, tmp_path / "camera.yaml")
    sequence = open_sequence(path)
    check_frames(sequence, 6, (48, 64))
    np.testing.assert_allclose(sequence.timestamps[1], 1 / 25)


@pytest.mark.parametrize(("files", "message"), [
    ({"frames.txt": "0.0 a.png\n0.1\n"}, "frames.txt:2: expected 'timestamp relative/path'"),
    ({"frames.txt": "0.0 a.png\nx b.png\n"}, "frames.txt:2: expected a timestamp"),
    ({"frames.txt": "0.1 a.png\n0.0 b.png\n"}, "must strictly increase"),
    ({"frames.txt": "0.0 a.png\n"}, "camera.yaml: file not found"),
])
def test_malformed_layout_names_file_and_line(tmp_path, files, message):
    for name, text in files.items():
        (tmp_path / name).write_text(text)
    with pytest.raises(InputError, match=re.escape(message)):
        open_sequence(tmp_path)


def test_corrupt_image_is_a_clear_error(tmp_path):
    (tmp_path / "frames.txt").write_text("0.0 a.png\n")
    (tmp_path / "a.png").write_bytes(b"not a png")
    save_camera(SMALL_CAMERA, tmp_path / "camera.yaml")
    with pytest.raises(InputError, match=r"a\.png: cannot read image"):
        next(open_sequence(tmp_path).frames())


def test_missing_path(tmp_path):
    with pytest.raises(InputError, match="no such file or folder"):
        open_sequence(tmp_path / "nope")
