"""Small synthetic scenes for the tracker's tests: a textured plane seen by a pinhole camera,
rendered exactly by a homography (cv2.warpPerspective)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from calib.camera import CameraModel
from vo.se3 import exp_se3

TEXTURE_METRES = 4.0  # side of the square textured plane z = 0 (world), centred on the origin


def small_camera(width: int = 320, height: int = 240, focal: float = 260.0) -> CameraModel:
    """A pinhole camera for synthetic tests."""
    return CameraModel(width, height, focal, focal, (width - 1) / 2, (height - 1) / 2)


def load_texture(data_dir: Path, name: str = "aero1.jpg", size: int = 1024,
                 blur: float = 0.0) -> np.ndarray:
    """A grey square texture from the shared data (optionally blurred against aliasing)."""
    img = cv2.imread(str(data_dir / "textures" / name), cv2.IMREAD_GRAYSCALE)
    assert img is not None, f"texture {name} missing"
    img = cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)
    return cv2.GaussianBlur(img, (0, 0), blur) if blur > 0 else img


def render_plane(texture: np.ndarray, camera: CameraModel, T_c_w: np.ndarray) -> np.ndarray:
    """Image of the textured plane z = 0 from camera pose T_c_w (pinhole, no distortion)."""
    n = texture.shape[0]
    s = TEXTURE_METRES / n
    # texture pixel (a, b) -> world (a * s - 2, b * s - 2, 0)
    S = np.array([[s, 0.0, -TEXTURE_METRES / 2], [0.0, s, -TEXTURE_METRES / 2], [0.0, 0.0, 1.0]])
    P = np.column_stack((T_c_w[:3, 0], T_c_w[:3, 1], T_c_w[:3, 3]))
    H = camera.K @ P @ S
    return cv2.warpPerspective(texture, H, camera.size, flags=cv2.INTER_LINEAR,
                               borderMode=cv2.BORDER_REFLECT)


def look_down_pose(x: float, y: float, height: float, yaw: float = 0.0,
                   tilt: tuple[float, float] = (0.0, 0.0)) -> np.ndarray:
    """T_c_w of a camera at (x, y, -height) looking along +z at the plane z = 0."""
    T_w_c = exp_se3(np.array([0.0, 0.0, 0.0, tilt[0], tilt[1], yaw]))
    T_w_c[:3, 3] = (x, y, -height)
    R = T_w_c[:3, :3]
    T_c_w = np.eye(4)
    T_c_w[:3, :3] = R.T
    T_c_w[:3, 3] = -R.T @ T_w_c[:3, 3]
    return T_c_w


def plane_depth(T_c_w: np.ndarray, camera: CameraModel, px: np.ndarray) -> np.ndarray:
    """Distance along each pixel's bearing to the plane z = 0."""
    f = camera.unproject(px)
    R = T_c_w[:3, :3]
    centre = -R.T @ T_c_w[:3, 3]
    ray_w = f @ R  # R.T @ f for each row
    return -centre[2] / ray_w[:, 2]


def textured_pair(data_dir: Path):
    """Two 320x240 views of the textured plane (moved, turned, tilted): camera, reference and
    current Frame, the reference's T_c_w and T_cur_ref."""
    from vo.frame import Frame
    from vo.se3 import inv_se3

    cam = small_camera()
    tex = load_texture(data_dir, blur=1.0)
    T_ref = look_down_pose(0.0, 0.0, 1.5)
    T_cur = look_down_pose(0.12, 0.05, 1.3, yaw=0.15, tilt=(0.05, 0.0))
    ref = Frame(0, 0.0, render_plane(tex, cam, T_ref), cam, 5)
    cur = Frame(1, 1.0, render_plane(tex, cam, T_cur), cam, 5)
    return cam, ref, cur, T_ref, T_cur @ inv_se3(T_ref)


def pair_truth(cam: CameraModel, T_ref: np.ndarray, T_cur_ref: np.ndarray, px: np.ndarray):
    """Bearings, depths and true current-view pixels of reference pixels px on the plane."""
    d = plane_depth(T_ref, cam, px)
    f = cam.unproject(px)
    X = (f * d[:, None]) @ T_cur_ref[:3, :3].T + T_cur_ref[:3, 3]
    return f, d, cam.project(X)


def sample_corners(cam: CameraModel, frame, step: int = 7, n: int = 40) -> np.ndarray:
    """Every step-th level-0 FAST corner of a frame away from the border, at most n (N, 2)."""
    c = frame.corners(10)
    x0, y0 = c.level0()
    keep = (c.level == 0) & cam.in_image(np.column_stack((x0, y0)), 30)
    return np.column_stack((x0[keep], y0[keep]))[::step][:n]
