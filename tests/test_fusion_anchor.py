"""The map's anchor (state.py): what moving it and climbing do to its uncertainty."""

from __future__ import annotations

import numpy as np
import pytest

from daemon.fusion import measurements as m
from daemon.fusion.config import FusionConfig
from daemon.fusion.state import ANCHOR, LOG_SCALE, POS, THETA, TIME_OFFSET, VEL, NavFilter


def _filter(**settings: float) -> NavFilter:
    f = NavFilter(FusionConfig(**settings))
    f.start(0.0, 3.0)
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), 0.0, scale_std=0.05)
    return f


def test_moving_the_anchor_along_the_map_adds_no_noise() -> None:
    """With scale and rotation known, the map's chain of anchors is as good as its first: the
    tracker's noise at one anchor cancels at the next."""
    f = _filter()
    for index in (LOG_SCALE, THETA):
        f.P[index, :] = 0.0
        f.P[:, index] = 0.0
    before = f.P[ANCHOR, ANCHOR].copy()
    for step in range(1, 21):
        f.reanchor(np.array([0.5 * step, 0.0, 0.0]), np.eye(3))
    np.testing.assert_allclose(f.P[ANCHOR, ANCHOR], before, atol=1e-12)
    np.testing.assert_allclose(f.x[ANCHOR], [10.0, 0.0, 0.0])


def test_a_map_of_unknown_scale_is_hung_from_the_vehicle_the_imu_carries() -> None:
    """With the scale unknown (the prior) and an IMU, each move of the anchor puts it where
    the filter has the camera: its variance stays the vehicle's however far the map goes."""
    f = _filter()
    f.accel = np.zeros(3)  # an IMU has been integrated
    f.P[LOG_SCALE, LOG_SCALE] = 2.0**2
    for step in range(1, 201):
        f.x[POS] = [0.5 * step, 0.0, 0.0]
        f.reanchor(np.array([0.05 * step, 0.0, 0.0]), np.eye(3))
        np.testing.assert_allclose(f.x[ANCHOR], f.x[POS] + f.lever + f.x[TIME_OFFSET] * f.x[VEL])
    assert np.all(np.diag(f.P[ANCHOR, ANCHOR]) <= np.diag(f.P[POS, POS]) + 1e-3)


@pytest.mark.parametrize("from_start", [True, False])
def test_a_rescale_the_imu_carries_keeps_what_the_map_saw_from_its_start(from_start) -> None:
    """A take-off on the wide prior: the IMU carried the vehicle 3 m up but missed 0.35 m of
    sideways drift (its dead reckoning a metre either way); the map saw it. At the climb's
    scale the vehicle goes where the map puts it from the segment's start, not where dead
    reckoning left it."""
    scale = 0.12
    f = NavFilter(FusionConfig())
    f.start(0.0, 0.01)
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), 0.0)  # on the ground, the wide prior
    f.accel = np.zeros(3)  # an IMU has been integrated
    f.x[POS] = [0.0, 0.0, -3.0]
    f.P[POS, POS] += np.eye(3)
    p_w = np.array([0.35, 0.0, -3.0]) / scale
    f.reanchor(p_w, np.eye(3))  # hung from the vehicle on the way up
    assert f.imu_carries()
    if from_start:
        assert m.update_from_start(f, p_w, np.eye(3), np.log(scale), 0.05)
    f.rescale(p_w, np.eye(3), np.log(scale), 0.05)
    assert (abs(f.x[0] - 0.35) < 0.03) == from_start
    assert abs(f.x[2] + 3.0) < 0.05


@pytest.mark.parametrize("scale_std", [None, 0.05])
def test_a_realignment_on_the_wide_prior_keeps_where_the_segment_started(scale_std) -> None:
    """Re-aligned while its scale is the wide prior, the map disagreed with the vehicle for
    that scale: its start still holds. With a scale given, the map itself moved: it starts
    again where it is re-hung."""
    f = NavFilter(FusionConfig())
    f.start(0.0, 0.01)
    f.start_segment(np.zeros(3), np.eye(3), np.eye(3), 0.0, scale_std=scale_std)
    started = f.segment_start
    f.x[POS] = [0.0, 0.0, -3.0]
    f.start_segment(np.array([0.0, 0.0, -25.0]), np.eye(3), np.eye(3), 0.0,
                    scale_std=scale_std, same_map=True)
    assert (f.segment_start is started) == (scale_std is None)


def test_a_climb_lets_the_map_wander_sideways_only() -> None:
    f = _filter(vo_drift_m_per_sqrt_m=0.0, vo_drift_climb_m_per_sqrt_m=0.03,
                vo_drift_m_per_sqrt_s=0.0)
    f.x[VEL] = [0.0, 0.0, -1.0]  # climbing 1 m/s
    before = np.diag(f.P[ANCHOR, ANCHOR]).copy()
    f.predict(4.0, None, None)  # 4 m climbed
    grown = np.diag(f.P[ANCHOR, ANCHOR]) - before
    np.testing.assert_allclose(grown, [0.03**2 * 4, 0.03**2 * 4, 0.0], rtol=1e-9, atol=1e-15)


def test_a_tracker_rejected_in_a_row_makes_the_filter_doubt_its_own_motion() -> None:
    """The map and the filter drifting apart at 1 m/s for 10 frames: before the map is
    re-anchored on the filter, the filter's position takes the disagreement as covariance and
    its velocity the rate of it (whichever of them went wrong, the estimate sent covers it)."""
    f = _filter()
    before = f.P.copy()
    f.vo_disagreement = [(k / 30, np.array([k / 30, 0.0, 0.0])) for k in range(10)]
    f.doubt_motion()
    grown = np.diag(f.P - before)
    assert grown[0] == pytest.approx(0.3**2) and grown[1] == grown[2] == 0.0
    assert grown[VEL.start] == pytest.approx(1.0) and f.vo_disagreement == []
