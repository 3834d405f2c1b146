"""A filter whose numbers break (NaN, a negative variance) sends nothing and starts again, with
the reset counter telling the autopilot (estimator.py _restart_diverged)."""

from __future__ import annotations

import numpy as np

from daemon.config import MountingConfig
from daemon.fusion.config import FusionConfig
from daemon.fusion.estimator import FusionEstimator
from daemon.fusion.sensors import Attitude
from vo.result import FrameResult, Quality


def test_a_diverged_filter_sends_nothing_and_restarts():
    est = FusionEstimator(FusionConfig(), MountingConfig(), now=lambda: 0.0)
    est.filter.start(0.0, 0.01)
    est.attitude.add(Attitude(0.0, np.eye(3), np.zeros(3)))
    assert not est.filter.diverged
    est.filter.P[5, 5] = -1.0  # a variance gone negative
    assert est.filter.diverged
    assert est.on_frame(FrameResult(0.05, None, Quality.LOST), 0.05) is None
    assert est.reset_counter == 1 and est.filter.t is None and not est.filter.diverged
    est.filter.start(0.1, 0.01)
    est.filter.x[0] = np.nan  # a state that is no number
    assert est.on_frame(FrameResult(0.15, None, Quality.LOST), 0.15) is None
    assert est.reset_counter == 2 and est.filter.t is None
