"""The scale from a climb: the tracker's height fitted against the barometer's altitude
(daemon/fusion/climb_scale.py) and the filter taking it (NavFilter.rescale)."""

from __future__ import annotations

import numpy as np

from daemon.fusion.climb_scale import ClimbScale
from daemon.fusion.config import FusionConfig
from daemon.fusion.state import ANCHOR, LOG_SCALE, POS, NavFilter

SCALE = 2.5  # metres per map unit


def _climb(height_m: float, n: int = 50, seed: int = 0) -> ClimbScale:
    rng = np.random.default_rng(seed)
    climb = ClimbScale()
    for k, altitude in enumerate(np.linspace(0.0, height_m, n)):
        z_units = -altitude / SCALE + 0.3  # down axis: the map goes down as the vehicle climbs
        climb.add(z_units, float(k), altitude + rng.normal(0.0, 0.3))
    return climb


def test_no_scale_before_the_minimum_climb() -> None:
    assert _climb(0.5).fit(1.0, 0.3) is None


def test_scale_from_a_climb_within_its_std() -> None:
    log_scale, std = _climb(5.0).fit(1.0, 0.3)
    assert std < 0.05
    assert abs(log_scale - np.log(SCALE)) < 3 * std


def test_a_reading_is_paired_once() -> None:
    climb = ClimbScale()
    climb.add(0.0, 1.0, 10.0)
    climb.add(-1.0, 1.0, 12.0)
    assert climb.altitude == [10.0]


def test_rescale_of_a_known_scale_puts_the_vehicle_where_the_map_says() -> None:
    f = NavFilter(FusionConfig())
    f.start(0.0, 3.0)
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), np.log(2.0), scale_std=0.1)
    f.rescale(np.array([0.0, 0.0, -2.0]), np.eye(3), np.log(SCALE), 0.03)
    assert np.allclose(f.x[POS], [0.0, 0.0, -2.0 * SCALE])
    assert np.isclose(np.sqrt(f.P[LOG_SCALE, LOG_SCALE]), 0.03)
    assert np.all(np.linalg.eigvalsh(f.P) > -1e-12)


def test_rescale_of_an_unknown_scale_hangs_the_map_from_the_vehicle() -> None:
    """Above nav_scale_std the map never moved the vehicle (the IMU, baro and rangefinder
    did): the vehicle stays and the map's anchor goes where the new scale puts it."""
    f = NavFilter(FusionConfig())
    f.start(0.0, 3.0)
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), 0.0)
    f.accel = np.zeros(3)  # an IMU has been integrated
    f.x[POS] = [1.0, 2.0, -4.0]  # where dead reckoning took the vehicle
    f.x[ANCHOR] = [7.0, 0.0, 0.0]  # wherever the unknown scale's fixes left it
    f.rescale(np.array([0.0, 0.0, -2.0]), np.eye(3), np.log(SCALE), 0.03)
    assert np.allclose(f.x[POS], [1.0, 2.0, -4.0])
    assert np.allclose(f.x[ANCHOR], f.x[POS] + f.lever)  # the map's p_w is the camera now
    assert np.allclose(f.p_w0, [0.0, 0.0, -2.0])
    assert np.isclose(np.sqrt(f.P[LOG_SCALE, LOG_SCALE]), 0.03)
    assert np.all(np.linalg.eigvalsh(f.P) > -1e-12)


def test_a_map_that_never_converges_keeps_a_bounded_climb() -> None:
    from daemon.fusion.climb_scale import KEPT

    climb = ClimbScale()
    for k in range(KEPT + 500):  # a long hover without convergence: one pair per reading
        climb.add(0.3, float(k), 10.0)
    assert len(climb.z_units) == len(climb.altitude) == KEPT
