"""Calibration file formats: exact round trips, files as other tools write them, clear errors."""

from __future__ import annotations

import textwrap

import cv2
import pytest

from calib.camera import CameraModel
from calib.formats import FORMATS, read_camera_file, write_camera_file
from sdvl.cli import main
from sdvl.errors import InputError

CAMERAS = {
    "radtan_k3": CameraModel(640, 480, 535.91573396163199, 535.12345678901234, 342.28315473308373,
                             235.57082909788173, "radtan_opencv",
                             (-0.26637260909660682, -0.038588898922304653, 1.7831947042852964e-03,
                              -2.8122100441115472e-04, 0.23839153080878486)),
    "radtan_no_k3": CameraModel(752, 480, 458.654, 457.296, 367.215, 248.375, "radtan_opencv",
                                (-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0.0)),
    "fisheye": CameraModel(1280, 800, 290.12345678912345, 290.3, 640.2, 400.7, "equidistant",
                           (0.01, -0.002, 3e-20, -1.0000000000000001e-05)),
    "no_distortion": CameraModel(320, 240, 200.5, 201.5, 160.1, 120.2, "none", ()),
}
CANNOT_HOLD = {("kalibr", "radtan_k3"): "no k3", ("sdvl-cfg", "fisheye"): "no fisheye"}
TARGETS = [(fmt, ".yaml") for fmt in FORMATS] + [("opencv", ".xml")]


@pytest.mark.parametrize("camera_name", sorted(CAMERAS))
@pytest.mark.parametrize("fmt, suffix", TARGETS)
def test_round_trip_is_exact(fmt, suffix, camera_name, tmp_path):
    camera = CAMERAS[camera_name]
    path = tmp_path / f"camera{suffix}"
    if (fmt, camera_name) in CANNOT_HOLD:
        with pytest.raises(InputError, match=CANNOT_HOLD[fmt, camera_name]):
            write_camera_file(camera, path, fmt)
        return
    write_camera_file(camera, path, fmt)
    back, guessed = read_camera_file(path)
    assert guessed == fmt
    assert back == camera  # every value bit for bit


def test_slam_configs_are_readable_by_opencv_filestorage(tmp_path):
    camera = CAMERAS["radtan_k3"]
    for fmt, keys in (("orbslam", ("Camera.fx", "Camera.cx", "Camera.k3")),
                      ("sdvl-cfg", ("Camera.fx", "Camera.u0", "Camera.d5"))):
        path = tmp_path / f"{fmt}.yaml"
        write_camera_file(camera, path, fmt)
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        values = [storage.getNode(k).real() for k in keys]
        assert values == [camera.fx, camera.cx, camera.distortion[4]]


def test_reads_opencv_sample_result(data_dir):
    camera, fmt = read_camera_file(data_dir / "calib_opencv_chessboard" / "left_intrinsics.yml")
    assert fmt == "opencv"
    assert (camera.width, camera.height) == (640, 480)
    assert camera.fx == pytest.approx(535.9157339616) and camera.cy == pytest.approx(235.5708291)
    assert camera.distortion[4] == pytest.approx(0.2383915308)


SAMPLES = {
    "kalibr": ("""\
        cam0:
          T_cam_imu: [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
          cam_overlaps: []
          camera_model: pinhole
          distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
          distortion_model: radtan
          intrinsics: [458.654, 457.296, 367.215, 248.375]
          resolution: [752, 480]
          rostopic: /cam0/image_raw
        cam1:
          camera_model: pinhole
          distortion_coeffs: [0.1, 0.0, 0.0, 0.0]
          distortion_model: radtan
          intrinsics: [1.0, 1.0, 1.0, 1.0]
          resolution: [752, 480]
        """, "radtan_no_k3"),
    "ros": ("""\
        image_width: 752
        image_height: 480
        camera_name: cam0
        camera_matrix:
          rows: 3
          cols: 3
          data: [458.654, 0, 367.215, 0, 457.296, 248.375, 0, 0, 1]
        distortion_model: plumb_bob
        distortion_coefficients:
          rows: 1
          cols: 5
          data: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05, 0]
        rectification_matrix:
          rows: 3
          cols: 3
          data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
        """, "radtan_no_k3"),
    "sdvl-cfg": ("""\
        %YAML:1.0

        # SDVL configuration file
        Camera.width: 752
        Camera.height: 480
        Camera.fx: 458.654
        Camera.fy: 457.296
        Camera.u0: 367.215
        Camera.v0: 248.375
        Camera.d1: -0.28340811
        Camera.d2: 0.07395907
        Camera.d3: 0.00019359
        Camera.d4: 1.76187114e-05
        Camera.d5: 0.0

        Video.type: 1
        SDVL.cell_size: 20
        """, "radtan_no_k3"),
    "orbslam": ("""\
        %YAML:1.0
        File.version: "1.0"
        Camera.type: "KannalaBrandt8"
        Camera1.fx: 290.12345678912345
        Camera1.fy: 290.3
        Camera1.cx: 640.2
        Camera1.cy: 400.7
        Camera1.k1: 0.01
        Camera1.k2: -0.002
        Camera1.k3: 3e-20
        Camera1.k4: -1.0000000000000001e-05
        Camera.width: 1280
        Camera.height: 800
        Camera.fps: 20
        IMU.T_b_c1: !!opencv-matrix
           rows: 4
           cols: 4
           dt: f
           data: [1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]
        """, "fisheye"),
}


@pytest.mark.parametrize("fmt", sorted(SAMPLES))
def test_reads_files_as_their_tools_write_them(fmt, tmp_path):
    text, expected = SAMPLES[fmt]
    path = tmp_path / "input.yaml"
    path.write_text(textwrap.dedent(text))
    camera, guessed = read_camera_file(path)
    assert guessed == fmt
    assert camera == CAMERAS[expected]


@pytest.mark.parametrize("text, words", [
    ("%YAML:1.0\nCamera.fx: 517.3\nCamera.fy: 516.5\nCamera.cx: 318.6\nCamera.cy: 255.3\n",
     "missing Camera.width / Camera.height"),
    ("cam0:\n  camera_model: omni\n  intrinsics: [1, 1, 1, 1]\n  resolution: [1, 1]\n",
     "camera_model 'omni' is not supported"),
    ("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [1, 2]}\n",
     "must have 9 numbers"),
    ("foo: 1\n", "unrecognised camera file"),
    ("a: [1, 2\n", "not valid YAML"),
])
def test_bad_files_give_one_clear_error(text, words, tmp_path):
    path = tmp_path / "bad.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=words) as info:
        read_camera_file(path)
    assert str(path) in str(info.value)


def test_convert_command(data_dir, tmp_path, capsys):
    source = data_dir / "calib_opencv_chessboard" / "left_intrinsics.yml"
    out = tmp_path / "camera_info.yaml"
    assert main(["calibrate", "--convert", str(source), "--to", "ros", "--out", str(out)]) == 0
    assert "(ros) from" in capsys.readouterr().out
    assert read_camera_file(out)[0] == read_camera_file(source)[0]
    assert main(["calibrate", "--convert", str(source), "--to", "kalibr",
                 "--out", str(tmp_path / "k.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no k3" in err[0]
