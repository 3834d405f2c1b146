"""The closed loop's camera: the world rendered wherever the vehicle truly is, including on its
landing gear (the camera 0.1-0.3 m above the ground), and the rangefinder on the same world."""

from __future__ import annotations

import numpy as np
import pytest

from sim.flight.world import FlightWorld


def _pose(north: float, east: float, height: float) -> np.ndarray:
    T = np.eye(4)
    T[:3, 3] = (north, east, -height)
    return T


@pytest.fixture(scope="module")
def world() -> FlightWorld:
    return FlightWorld.of_preset("hover-down", 3, (96, 72), textures="procedural")


@pytest.mark.parametrize("height", [0.14, 0.2, 0.34])
def test_camera_on_the_ground_sees_textured_ground(world, height):
    # the preset's camera hangs 4 cm below the body: 0.1-0.3 m above the ground here
    image = world.image(1, 0.0, _pose(0.0, 0.0, height))
    assert image.shape == (72, 96) and image.dtype == np.uint8
    assert image.std() > 10.0  # texture, not a flat or empty picture
    assert 5 < np.median(image) < 250


def test_frames_are_deterministic_and_follow_the_pose(world):
    a = world.image(7, 1.0, _pose(0.0, 0.0, 3.0))
    assert np.array_equal(a, world.image(7, 1.0, _pose(0.0, 0.0, 3.0)))
    moved = world.image(7, 1.0, _pose(0.5, 0.0, 3.0))
    assert np.mean(np.abs(a.astype(float) - moved)) > 5.0


def test_rangefinder_measures_the_world_below(world):
    down = np.array([0.0, 0.0, 1.0])
    assert world.range(np.array([0.0, 0.0, -2.5]), down) == pytest.approx(2.5)
    assert world.range(np.array([0.0, 0.0, -2.5]), -down) == np.inf
