"""Re-aligning a map whose poses the filter keeps rejecting (map_fusion.MapFusion._realign)."""

from __future__ import annotations

import numpy as np

from daemon.fusion.alignment import AlignmentGate
from daemon.fusion.config import FusionConfig
from daemon.fusion.map_fusion import FrameInput, MapFusion, Readings
from daemon.fusion.state import POS, VEL, NavFilter, ScaleSource


def _maps(scale_std: float) -> MapFusion:
    """A climbing filter carried by its IMU, on a map whose scale is known to `scale_std`
    (2.0: the wide prior), with ten rejected poses 0.5 m/frame apart and some climb pairs."""
    cfg = FusionConfig()
    f = NavFilter(cfg)
    f.start(0.0, 0.1)
    f.accel = np.array([0.0, 0.0, -9.8])
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), 0.0, scale_std=scale_std)
    f.x[VEL] = [0.0, 0.0, -1.0]
    f.vo_disagreement = [(k / 30, np.array([0.0, 0.0, 0.5 * k])) for k in range(10)]
    for k in range(5):
        f.climb.add(-0.5 * k, float(k), float(k))
    return MapFusion(cfg, f, None, AlignmentGate(cfg), Readings(), lambda t: True,
                     lambda: np.zeros(3), camera_down=True)


def _realign(maps: MapFusion) -> np.ndarray:
    """Re-align on a frame 2 units up the map; the filter's covariance before."""
    before = maps.filter.P.copy()
    frame = FrameInput(np.array([0.0, 0.0, -2.0]), np.eye(3), np.eye(6), "good", 0)
    maps._realign(frame, np.eye(3), metric=False)
    return before


def test_a_map_of_unknown_scale_does_not_make_the_imu_doubt_its_climb() -> None:
    """The wide prior's map disagrees with any motion: the IMU's climb rate keeps its
    covariance (doubting it let such a map set the climb rate to 2.6x the true one in a
    closed-loop take-off without a rangefinder), and the map keeps its climb pairs (each
    re-alignment threw them away and the barometer's scale fit never came)."""
    maps = _maps(scale_std=2.0)
    assert maps.filter.scale_source is ScaleSource.PRIOR
    before = _realign(maps)
    f = maps.filter
    np.testing.assert_array_equal(f.P[VEL, VEL], before[VEL, VEL])
    np.testing.assert_array_equal(f.P[POS, POS], before[POS, POS])
    assert f.vo_disagreement == [] and len(f.climb.z_units) == 5 and f.realigns == 1


def test_a_map_of_known_scale_still_makes_the_filter_doubt_its_motion() -> None:
    maps = _maps(scale_std=0.05)
    before = _realign(maps)
    f = maps.filter
    assert f.P[5, 5] > before[5, 5] + 1.0  # the disagreement's rate, 15 m/s
    assert f.P[2, 2] > before[2, 2] + 10.0  # its last 4.5 m
    assert len(f.climb.z_units) == 5
