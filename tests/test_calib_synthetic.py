"""Calibration on boards rendered through known cameras: the intrinsics must come back.

The renderer is small on purpose: unproject every (super-sampled) pixel with calib.camera,
intersect the ray with the board plane, look up the board texture there, average.
"""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from calib.board import BoardDetector, BoardSpec, charuco_board
from calib.calibration import View
from calib.camera import CameraModel
from calib.camera_yaml import load_camera
from calib.view_selection import calibrate_robustly
from sdvl.cli import main

SUPERSAMPLE = 2
BACKGROUND = 90
FISHEYE = CameraModel(640, 480, 230.0, 231.5, 322.0, 238.0, "equidistant",
                      (0.04, -0.015, 0.004, -0.0008))
PINHOLE = CameraModel(640, 480, 420.0, 418.0, 315.0, 245.0, "radtan_opencv",
                      (-0.12, 0.05, 0.0008, -0.0005, 0.0))
# (angle off the optical axis deg, direction around it deg, distance m, tilt about x, y deg)
POSES = [(0, 0, 0.45, 25, 0), (0, 0, 0.40, -20, 30), (35, 0, 0.45, 0, -30),
         (35, 90, 0.45, 30, 0), (35, 180, 0.45, 0, 30), (35, 270, 0.45, -30, 0),
         (50, 45, 0.50, 20, -20), (50, 135, 0.50, 20, 20), (50, 225, 0.50, -20, 20),
         (50, 315, 0.50, -20, -20), (20, 60, 0.35, 10, 35), (20, 240, 0.35, -35, 10)]
PINHOLE_POSES = [(off_axis * 0.6, *rest) for off_axis, *rest in POSES]  # narrower field of view


def pixel_rays(camera: CameraModel) -> np.ndarray:
    """Unit bearings (H*s, W*s, 3) of the sub-pixel samples of every pixel."""
    offsets = (np.arange(SUPERSAMPLE) + 0.5) / SUPERSAMPLE - 0.5
    u = (np.arange(camera.width)[:, None] + offsets).ravel()
    v = (np.arange(camera.height)[:, None] + offsets).ravel()
    uu, vv = np.meshgrid(u, v)
    rays = camera.unproject(np.column_stack([uu.ravel(), vv.ravel()]))
    return rays.reshape(len(v), len(u), 3)


def render(rays: np.ndarray, R: np.ndarray, t: np.ndarray, texture: np.ndarray,
           texel_m: float, origin_px: float) -> np.ndarray:
    """Grey image of a planar board (board z = 0) at pose x_cam = R x_board + t.

    Board point (x, y) is texture pixel (origin_px + x / texel_m, same for y), pixel centres at
    integers.
    """
    normal = R[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = (normal @ t) / (rays @ normal)
    board = (rays * s[..., None] - t) @ R
    visible = np.isfinite(s) & (s > 0)
    mx = np.where(visible, origin_px + board[..., 0] / texel_m, -1e6).astype(np.float32)
    my = np.where(visible, origin_px + board[..., 1] / texel_m, -1e6).astype(np.float32)
    sampled = cv2.remap(texture.astype(np.float32), mx, my, cv2.INTER_LINEAR,
                        borderMode=cv2.BORDER_CONSTANT, borderValue=BACKGROUND)
    h, w = rays.shape[0] // SUPERSAMPLE, rays.shape[1] // SUPERSAMPLE
    return sampled.reshape(h, SUPERSAMPLE, w, SUPERSAMPLE).mean(axis=(1, 3))


def chessboard_texture(spec: BoardSpec, px_per_square: int = 24):
    """(texture, texel size m, texture coordinate of the first inner corner)."""
    n_x, n_y = spec.cols + 3, spec.rows + 3  # squares plus one white square of margin each side
    i, j = np.meshgrid(np.arange(n_x * px_per_square) // px_per_square,
                       np.arange(n_y * px_per_square) // px_per_square)
    inside = (i >= 1) & (i <= spec.cols + 1) & (j >= 1) & (j <= spec.rows + 1)
    texture = np.where(inside & ((i + j) % 2 == 0), 20, 235).astype(np.uint8)
    return texture, spec.square / px_per_square, 2 * px_per_square - 0.5


def charuco_texture(spec: BoardSpec, px_per_square: int = 40):
    """(texture, texel size m, texture coordinate of the board's outer corner) of a ChArUco."""
    margin = px_per_square // 2
    size = (spec.cols * px_per_square + 2 * margin, spec.rows * px_per_square + 2 * margin)
    texture = charuco_board(spec).generateImage(size, marginSize=margin)
    return texture, spec.square / px_per_square, margin - 0.5


def board_pose(spec_centre: np.ndarray, pose: tuple) -> tuple[np.ndarray, np.ndarray]:
    """R, t putting the board centre at `distance` along a direction, partly facing the camera."""
    off_axis, around, distance, tilt_x, tilt_y = pose
    a, b = np.radians(off_axis), np.radians(around)
    direction = np.array([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)])
    face = Rotation.from_rotvec(0.6 * np.cross([0, 0, 1], direction)
                                * (a / max(np.sin(a), 1e-9)))
    R = (face * Rotation.from_euler("xy", [tilt_x, tilt_y], degrees=True)).as_matrix()
    return R, distance * direction - R @ spec_centre


def render_views(camera: CameraModel, poses: list[tuple], texture_info, centre: np.ndarray,
                 seed: int) -> list[np.ndarray]:
    """One noisy grey uint8 image per pose."""
    rng = np.random.default_rng(seed)
    rays = pixel_rays(camera)
    images = []
    for pose in poses:
        R, t = board_pose(centre, pose)
        image = render(rays, R, t, *texture_info) + rng.normal(0.0, 2.0, (camera.height,
                                                                          camera.width))
        images.append(np.clip(image, 0, 255).astype(np.uint8))
    return images


def assert_intrinsics_within(camera: CameraModel, truth: CameraModel, tolerance: float):
    for name in ("fx", "fy", "cx", "cy"):
        got, want = getattr(camera, name), getattr(truth, name)
        assert abs(got - want) <= tolerance * want, f"{name} {got:.3f} vs {want:.3f}"


@pytest.fixture(scope="module")
def fisheye_images(tmp_path_factory):
    spec = BoardSpec("chessboard", 9, 6, 0.04)
    centre = np.array([4 * spec.square, 2.5 * spec.square, 0.0])
    folder = tmp_path_factory.mktemp("fisheye")
    paths = []
    for i, image in enumerate(render_views(FISHEYE, POSES, chessboard_texture(spec), centre, 5)):
        paths.append(str(folder / f"view{i:02d}.png"))
        cv2.imwrite(paths[-1], image)
    return paths


def test_fisheye_intrinsics_within_one_percent(fisheye_images, tmp_path, capsys):
    out = tmp_path / "camera.yaml"
    assert main(["calibrate", *fisheye_images, "--cols", "9", "--rows", "6", "--square",
                 "0.04", "--model", "fisheye", "--out", str(out), "--json"]) == 0
    camera = load_camera(out)
    assert camera.distortion_model == "equidistant"
    assert_intrinsics_within(camera, FISHEYE, 0.01)
    assert '"rms_px"' in capsys.readouterr().out
    assert (tmp_path / "camera_coverage.png").is_file()


def test_charuco_partial_views_calibrate_pinhole():
    spec = BoardSpec("charuco", 8, 6, 0.035, 0.026, "DICT_5X5_100")
    centre = np.array([4 * spec.square, 3 * spec.square, 0.0])
    images = render_views(PINHOLE, PINHOLE_POSES, charuco_texture(spec), centre, 6)
    detector = BoardDetector(spec)
    detections = [detector.detect(image) for image in images]
    views = [View(f"view{i}", d) for i, d in enumerate(detections) if d is not None]
    assert len(views) >= 10
    assert any(not v.detection.complete for v in views), "expected some partly visible boards"
    robust = calibrate_robustly(views, (PINHOLE.width, PINHOLE.height), "pinhole-radtan")
    assert robust.result.rms < 0.3
    assert_intrinsics_within(robust.result.camera, PINHOLE, 0.01)
