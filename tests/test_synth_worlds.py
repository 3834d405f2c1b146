"""The outdoor ground does not repeat at flight scale: views one ground tile apart (where the
base texture repeats) look different, so relocalisation cannot succeed on a copy of the ground."""

from __future__ import annotations

import numpy as np

from calib.camera import CameraModel
from sim.synth.raycast import render
from sim.synth.worlds import GROUND_TEXEL, outdoor_scene

CAMERA = CameraModel(160, 120, 120.0, 120.0, 79.5, 59.5)
TILE_M = 2048 * GROUND_TEXEL


def _down_view(scene, x: float, y: float, altitude: float = 10.0) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]  # camera looking down (NED world)
    T[:3, 3] = (x, y, -altitude)
    return render(scene, CAMERA, T)[0]


def _ncc(a: np.ndarray, b: np.ndarray) -> float:
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def test_ground_does_not_repeat_one_tile_away():
    scene = outdoor_scene(0, "procedural", blocks=0)  # bare ground only
    here = _down_view(scene, 3.0, -2.0)
    assert _ncc(here, _down_view(scene, 3.0 + 0.05, -2.0)) > 0.8  # sanity: nearby views agree
    for i, j in ((1, 0), (0, 1), (1, 1), (-2, 1), (3, -2)):
        there = _down_view(scene, 3.0 + i * TILE_M, -2.0 + j * TILE_M)
        assert _ncc(here, there) < 0.6  # was 1.0 with one tiling
