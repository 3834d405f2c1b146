"""The continuity check between estimates sent (output.Continuity)."""

from __future__ import annotations

import numpy as np

from daemon.estimate import VisionEstimate
from daemon.fusion.output import Continuity
from vo.result import Quality


def _estimate(t: float, x: float, position_var: float) -> VisionEstimate:
    pose_cov = np.zeros((6, 6))
    pose_cov[:3, :3] = np.diag([position_var, position_var, 1e-4])
    return VisionEstimate(t, t, np.array([x, 0.0, 0.0]), np.eye(3), np.zeros(3), np.zeros(3),
                          np.zeros(3), pose_cov, np.eye(6) * 1e-4, 50, 0, Quality.GOOD)


def test_a_move_within_the_covariances_is_continuous_and_one_beyond_them_is_not() -> None:
    c = Continuity(gate=16.27)
    assert not c.jumped(_estimate(0.0, 0.0, 0.01))
    assert not c.jumped(_estimate(0.1, 0.1, 0.01))
    assert c.jumped(_estimate(0.2, 5.0, 0.01))


def test_covariances_too_far_apart_to_compare_count_as_a_jump() -> None:
    """A map of unknown scale far from the filter puts a rank-one 1e16 m^2 disagreement in the
    covariance, beside which the rest rounds away: the comparison's matrix is singular in
    floating point (a closed-loop landing raised LinAlgError out of the service's frame
    path). It is a discontinuity, not a crash."""
    apart = np.array([2.0**28, 2.0**27, 2.0**26])
    c = Continuity(gate=16.27)
    for t in (0.0, 0.1):
        e = _estimate(t, float(t * 1e9), 0.0)
        e.pose_covariance[:3, :3] = np.outer(apart, apart)
        jumped = c.jumped(e)
    assert jumped
