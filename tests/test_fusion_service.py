"""The fusion estimator inside the running service, fed by the simulated autopilot over UDP:
it takes the streams each autopilot flavour sends, in their units, on our clock."""

from __future__ import annotations

import time

import numpy as np
import pytest
from daemon_helpers import RunningService, service_config, wait_for

from daemon.fusion.config import FusionConfig
from daemon.fusion.estimator import FusionEstimator
from sim.autopilot import SimAutopilot, configured_options

EXPECTED = {"ardupilot": {"imu": "SCALED_IMU", "baro": "SCALED_PRESSURE"},
            "px4": {"imu": "HIGHRES_IMU", "baro": "HIGHRES_IMU"}}


@pytest.mark.parametrize("flavour", list(EXPECTED))
def test_service_feeds_the_autopilot_streams_to_fusion(flavour: str) -> None:
    with SimAutopilot(configured_options(flavour=flavour, heartbeat_hz=5)) as sim:
        cfg = service_config(sim.url, mounting={"preset": "down"})
        estimator = FusionEstimator(FusionConfig(), cfg.mounting)
        run = RunningService(cfg, estimator=estimator)
        try:
            assert wait_for(lambda: estimator.filter.t is not None, timeout=5.0)
            time.sleep(0.5)
        finally:
            assert run.stop() == 0
    assert estimator.sources == EXPECTED[flavour]
    latest = estimator.attitude.latest
    assert latest is not None and abs(latest.t - time.monotonic()) < 2.0
    level = latest.R_n_b[2, 2]
    assert level > 0.99  # the simulated vehicle hovers nearly level: body z is down
    assert estimator.filter.has_ground  # the rangefinder fused; the barometer reached the
    assert estimator.readings.baro is not None  # filter (fused only without a rangefinder)
    assert np.all(np.isfinite(estimator.filter.x))
    assert estimator.dropped_stamps == 0
