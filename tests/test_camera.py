"""Camera models: round trips, agreement with OpenCV, camera.yaml, numba-callable forms."""

from __future__ import annotations

import cv2
import numba
import numpy as np
import pytest

from calib.camera import CameraModel, project_point, unproject_pixel
from calib.camera_yaml import load_camera, save_camera
from sdvl.errors import InputError

FISHEYE = CameraModel(640, 480, 285.7, 286.1, 321.4, 238.9, "equidistant",
                      (-0.0113, 0.0472, -0.0453, 0.0121))


def image_grid(camera: CameraModel, step: float = 3.7) -> np.ndarray:
    u, v = np.meshgrid(np.arange(0, camera.width, step), np.arange(0, camera.height, step))
    return np.column_stack([u.ravel(), v.ravel()])


@pytest.fixture(scope="module")
def tum_camera(data_dir) -> CameraModel:
    return load_camera(data_dir / "tum_fr1_rpy" / "camera.yaml")


def test_round_trip_whole_image_tum(tum_camera):
    pixels = image_grid(tum_camera)
    bearings = tum_camera.unproject(pixels)
    np.testing.assert_allclose(np.linalg.norm(bearings, axis=1), 1.0, atol=1e-12)
    assert np.abs(tum_camera.project(bearings) - pixels).max() < 1e-6


def test_round_trip_whole_image_fisheye():
    pixels = image_grid(FISHEYE)
    assert np.abs(FISHEYE.project(FISHEYE.unproject(pixels)) - pixels).max() < 1e-6


def test_radtan_agrees_with_opencv(tum_camera):
    rng = np.random.default_rng(1)
    points = rng.uniform([-0.6, -0.45, 1.0], [0.6, 0.45, 1.0], (500, 3)) * rng.uniform(1, 5,
                                                                                     (500, 1))
    ref, _ = cv2.projectPoints(points, np.zeros(3), np.zeros(3), tum_camera.K,
                               tum_camera.dist_coeffs)
    np.testing.assert_allclose(tum_camera.project(points), ref.reshape(-1, 2), atol=1e-6)


def test_fisheye_agrees_with_opencv():
    rng = np.random.default_rng(2)
    bearings = FISHEYE.unproject(rng.uniform([0, 0], [640, 480], (500, 2)))
    points = bearings * rng.uniform(0.5, 10, (500, 1))
    ref, _ = cv2.fisheye.projectPoints(points.reshape(-1, 1, 3), np.zeros(3), np.zeros(3),
                                       FISHEYE.K, FISHEYE.dist_coeffs)
    np.testing.assert_allclose(FISHEYE.project(points), ref.reshape(-1, 2), atol=1e-6)


def test_undistort_agrees_with_opencv(tum_camera):
    pixels = image_grid(tum_camera, 40.0)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-15)
    ref = cv2.undistortPoints(pixels.reshape(-1, 1, 2), tum_camera.K, tum_camera.dist_coeffs,
                              criteria=criteria).reshape(-1, 2)
    bearings = tum_camera.unproject(pixels)
    np.testing.assert_allclose(bearings[:, :2] / bearings[:, 2:], ref, atol=1e-6)


def test_points_behind_pinhole_are_nan(tum_camera):
    assert np.isnan(tum_camera.project(np.array([[0.1, 0.2, -1.0]]))).all()


def test_numba_callable_inside_a_kernel(tum_camera):
    @numba.njit
    def round_trip(params, u, v):
        x, y, z = unproject_pixel(params, u, v)
        return project_point(params, 3.0 * x, 3.0 * y, 3.0 * z)

    u, v = round_trip(tum_camera.params, 600.5, 20.25)
    assert abs(u - 600.5) < 1e-6 and abs(v - 20.25) < 1e-6


def test_scaled_camera_matches_resized_image_centres(tum_camera):
    half = tum_camera.scaled(0.5)
    assert (half.width, half.height) == (320, 240)
    assert half.cx == pytest.approx((tum_camera.cx + 0.5) / 2 - 0.5)


@pytest.mark.parametrize("camera", [FISHEYE, CameraModel(10, 20, 1.5, 2.5, 3.5, 4.5)])
def test_yaml_round_trip(tmp_path, camera):
    save_camera(camera, tmp_path / "camera.yaml", comment="written by a test")
    assert load_camera(tmp_path / "camera.yaml") == camera


@pytest.mark.parametrize(("text", "message", "line"), [
    ("width: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\n", "missing key(s) cy", None),
    ("width: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\ncy: 240\n"
     "distortion_model: brown\n", "unknown distortion_model 'brown'", 7),
    ("width: 640\nheight: abc\nfx: 500\nfy: 500\ncx: 320\ncy: 240\n", "'height' must be", 2),
    ("width: 640\nheight: 480\nfx: 500\nfy: 500\ncx: 320\ncy: 240\n"
     "distortion_model: equidistant\ndistortion: [0.1, 0.2]\n", "takes 4..4", 8),
    ("width: [640\n", "not valid YAML", 2),
])
def test_bad_camera_yaml_names_file_line_and_problem(tmp_path, text, message, line):
    path = tmp_path / "camera.yaml"
    path.write_text(text)
    with pytest.raises(InputError) as info:
        load_camera(path)
    assert message in info.value.message
    assert info.value.path == str(path)
    assert info.value.line == line


def test_radtan_beyond_its_monotonic_radius_is_not_visible():
    barrel = CameraModel(640, 480, 300.0, 300.0, 320.0, 240.0, "radtan_opencv",
                         (-0.5, 0.0, 0.0, 0.0, 0.0))
    # r (1 - 0.5 r^2) peaks at r^2 = 2/3: a point further out would fold back into the image
    assert barrel.max_radius2() == pytest.approx(2.0 / 3.0)
    inside, outside = barrel.project(np.array([[0.8, 0.0, 1.0], [1.2, 0.0, 1.0]]))
    assert np.isfinite(inside).all() and np.isnan(outside).all()
