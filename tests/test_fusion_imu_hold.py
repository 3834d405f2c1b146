"""Each IMU sample stands for the time around it (estimator._imu_event_time): held from its
own stamp to the next, the samples were applied half an interval late, and in a climb the
filter took that lag of its height for the map's scale."""

from __future__ import annotations

import numpy as np

from daemon.config import MountingConfig
from daemon.fusion.estimator import FusionEstimator
from sim import fusion_sim as fh

# everything exact, so only the filter's own modelling is left
EXACT_SENSORS = fh.SensorOptions(range_noise_m=0.0, accel_noise=0.0, tilt_noise_deg=0.0,
                                 heading_noise_deg=0.0, latency=(0.0, 0.0),
                                 accel_bias=(0.0, 0.0, 0.0), baro=False)
EXACT_TRACKER = fh.TrackerOptions(noise_m=0.0, drift_per_sqrt_m=0.0, scale_walk_per_sqrt_s=0.0,
                                  rot_walk_deg_per_sqrt_s=0.0, rot_noise_deg=0.0)


def scale_after_the_climb(seed: int) -> float:
    """ln of the filter's scale over the map's true one in the hover after a climb of 8 m."""
    flight = fh.simulate(EXACT_SENSORS, EXACT_TRACKER, seed=seed,
                         truth=fh.survey_flight(legs=1))
    estimator = FusionEstimator(fh.fusion_config(), MountingConfig())
    after_climb = [f for f in flight.frames if f[2] - fh.BOOT_OFFSET <= 6.0]  # climb ends at 5 s
    fh.run(fh.Flight(flight.truth, flight.messages, after_climb), estimator)
    return float(np.log(estimator.filter.scale * flight.map_scales[0]))


def test_the_climb_gives_the_map_its_scale_without_the_imu_lag() -> None:
    errors = [scale_after_the_climb(seed) for seed in (1000, 1001)]
    assert max(map(abs, errors)) < 0.003, errors  # samples held from their stamp: 1.0 %
