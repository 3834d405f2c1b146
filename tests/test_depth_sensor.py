"""The synthetic depth camera: noise growing with the square of the distance, disparity steps,
range limits, occlusion shadows, holes on edges, dark and glossy surfaces, seeded."""

from __future__ import annotations

import numpy as np
import pytest

from calib.camera import CameraModel
from sim.synth.depth_sensor import SENSORS, measure_depth
from sim.synth.raycast import Surfaces
from sim.synth.scene import QuadList

CAMERA = CameraModel(160, 120, 140.0, 140.0, 79.5, 59.5)


def wall(depth, albedo=128.0, texture=0):
    """Surfaces of a fronto-parallel quad filling the view at `depth` (array or number)."""
    quads = QuadList()
    quads.add([0, 0, 0], [1, 0, 0], [0, 1, 0], 1.0, 1.0, texture, 0.01)
    z = np.broadcast_to(np.asarray(depth, np.float32), (120, 160)).copy()
    return Surfaces(np.full((120, 160), albedo, np.float32), z,
                    np.zeros((120, 160), np.int32), quads)


def measure(surfaces, sensor="d435", seed=0, glossy=()):
    # a camera looking along world z: the quad's normal (z) faces it
    return measure_depth(SENSORS[sensor], surfaces, CAMERA, np.eye(4), glossy,
                         np.random.default_rng(seed))


@pytest.mark.parametrize("sensor", ["d435", "d455", "kinect-v1"])
@pytest.mark.parametrize("z", [1.0, 3.0])
def test_noise_grows_with_the_square_of_the_distance(sensor, z):
    out = measure(wall(z), sensor)
    valid = out[out > 0]
    assert valid.size > 0.95 * out.size
    expected = SENSORS[sensor].sigma(z)
    # the std of the measurements, quantised in disparity steps and 1 mm units
    step = SENSORS[sensor].step(z)
    assert np.std(valid) == pytest.approx(np.hypot(expected, step / np.sqrt(12)), rel=0.1)
    assert abs(np.mean(valid) - z) < 3 * expected / np.sqrt(valid.size) + step


def test_kinect_depth_lies_on_its_disparity_steps():
    s = SENSORS["kinect-v1"]
    out = measure(wall(4.0), "kinect-v1")
    disparity = s.focal_px * s.baseline_m / out[out > 0]
    steps = disparity / s.disparity_step_px
    # 1 mm output units round the depth: at 4 m that is 0.022 of a step
    assert np.abs(steps - np.rint(steps)).max() < 0.03
    assert np.unique(np.round(out[out > 0], 3)).size < 15


def test_outside_the_range_there_is_no_depth():
    depth = np.full((120, 160), 2.0, np.float32)
    depth[:, :40] = 0.2  # nearer than the D435's 0.28 m
    depth[:, 120:] = 11.0  # beyond its 10 m
    depth[:10] = np.inf  # sky
    out = measure(wall(depth))
    assert not out[:, :40].any() and not out[:, 121:].any() and not out[:10].any()
    assert (out[20:, 45:115] > 0).mean() > 0.99


def test_occlusion_shadow_beside_a_near_object():
    """A board at 1 m in front of a wall at 3 m: the second viewpoint, 5 cm to the right,
    cannot see the wall for f b (1/1 - 1/3) = 4.7 px left of the board's left edge."""
    depth = np.full((120, 160), 3.0, np.float32)
    depth[:, 40:80] = 1.0
    row = measure(wall(depth))[60]
    assert not row[36:40].any()  # the shadow
    assert (row[10:35] > 0).all() and (row[41:79] > 0).all() and (row[81:150] > 0).all()
    assert not row[40] and not row[79] and not row[80]  # pixels on an edge are dropped


def test_dark_and_glossy_surfaces_lose_depth():
    dark = measure(wall(2.0, albedo=3.0))
    assert (dark > 0).mean() < 0.15
    grey = measure(wall(2.0, albedo=15.0))  # returns fade below grey level 25: 40% lost
    assert (grey > 0).mean() == pytest.approx(0.6, abs=0.03)
    glare = measure(wall(2.0), glossy=(0,))  # glare within 20 deg of normal incidence
    assert not glare[40:80, 60:100].any() and (glare > 0).mean() < 0.4
    assert (measure(wall(2.0), glossy=(5,)) > 0).mean() > 0.99


def test_ideal_sensor_returns_the_rendered_depth():
    depth = np.full((120, 160), 2.5, np.float32)
    depth[:, 80:] = 4.0
    np.testing.assert_array_equal(measure(wall(depth), "ideal"), depth)


def test_same_seed_same_depth_other_seed_other_noise():
    a, b, c = (measure(wall(3.0), seed=s) for s in (1, 1, 2))
    np.testing.assert_array_equal(a, b)
    assert np.abs(a - c).mean() > 0.01
