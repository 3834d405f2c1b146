"""The renderer's geometry is exact: checkerboard corners at known 3D points appear where the
camera model projects them, for many poses and a distorted camera."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from calib.camera import CameraModel
from sim.synth.raycast import render
from sim.synth.scene import QuadList, Scene
from sim.synth.textures import build_atlas, checker_texture

TEXEL = 0.01  # m
SQUARE = 16  # texels
CAMERA = CameraModel(320, 240, 260.0, 255.0, 161.3, 118.7, "radtan_opencv",
                     (-0.2, 0.05, 0.001, -0.001, 0.0))


def checker_scene() -> Scene:
    quads = QuadList()
    quads.add([0.0, 0.0, 0.0], [1, 0, 0], [0, 1, 0], 1.28, 1.28, 0, TEXEL)
    return Scene(quads, build_atlas([checker_texture(8, SQUARE)]), background=128.0)


def look_at(eye: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """T_w_c of a camera at `eye` looking at `target`, rolled about its axis."""
    z = (target - eye) / np.linalg.norm(target - eye)
    x = np.cross(z, [0.0, 0.0, 1.0] if abs(z[2]) < 0.9 else [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    c, s = np.cos(roll), np.sin(roll)
    T = np.eye(4)
    T[:3, :3] = np.column_stack([c * x + s * y, -s * x + c * y, z])
    T[:3, 3] = eye
    return T


def test_checker_corners_land_on_their_projection():
    scene = checker_scene()
    rng = np.random.default_rng(3)
    centre = np.array([0.64, 0.64, 0.0])
    corners = np.array([(i * SQUARE * TEXEL, j * SQUARE * TEXEL, 0.0)
                        for i in range(2, 7) for j in range(2, 7)])
    errors = []
    for _ in range(16):
        direction = rng.normal(size=3)
        direction[2] = -abs(direction[2]) - 1.5  # above the board (z up is negative)
        eye = centre + direction / np.linalg.norm(direction) * rng.uniform(1.3, 2.5)
        T_w_c = look_at(eye, centre + rng.uniform(-0.15, 0.15, 3) * [1, 1, 0],
                        rng.uniform(-np.pi, np.pi))
        image, depth = render(scene, CAMERA, T_w_c)
        T_c_w = np.linalg.inv(T_w_c)
        px = CAMERA.project(corners @ T_c_w[:3, :3].T + T_c_w[:3, 3])
        ok = CAMERA.in_image(px, margin=12)
        cols, rows = np.round(px[ok]).astype(int).T
        assert np.all(np.isfinite(depth[rows, cols]))  # the board is hit where corners are
        start = (np.round(px[ok]) + rng.uniform(-0.8, 0.8, (ok.sum(), 2))).astype(np.float32)
        found = cv2.cornerSubPix(image.astype(np.float32), start.copy(), (4, 4), (-1, -1),
                                 (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-4))
        errors.append(np.linalg.norm(found - px[ok], axis=1))
    errors = np.concatenate(errors)
    assert errors.size > 200
    assert np.median(errors) < 0.1
    assert errors.max() < 0.3, f"worst corner {errors.max():.3f} px"


@pytest.mark.parametrize("distance", [0.5, 4.0])
def test_depth_is_distance_along_the_optical_axis(distance):
    scene = checker_scene()
    T_w_c = look_at(np.array([0.64, 0.64, -distance]), np.array([0.64, 0.64, 0.0]), 0.3)
    _, depth = render(scene, CAMERA, T_w_c)
    seen = np.isfinite(depth)
    assert seen.sum() > 1000
    np.testing.assert_allclose(depth[seen], distance, rtol=1e-5)


@pytest.mark.parametrize("preset", ["room-handheld", "walkers"])
def test_culled_rendering_equals_testing_every_quad_on_every_pixel(preset, monkeypatch):
    from sim.synth import raycast
    from sim.synth.flight import synthetic_sequence

    seq = synthetic_sequence(preset, size=(80, 60), textures="procedural")
    times = np.linspace(0.0, seq.timestamps[-1], 6)
    culled = [seq.image_loader.ideal(float(t)) for t in times]
    monkeypatch.setattr(raycast, "quad_bounds",
                        lambda quads, *_: np.tile([0, 79, 0, 59], (len(quads), 1)))
    for t, (image, depth) in zip(times, culled, strict=True):
        full_image, full_depth = seq.image_loader.ideal(float(t))
        np.testing.assert_array_equal(image, full_image)
        np.testing.assert_array_equal(depth, full_depth)
