"""The barometer is not fused while a downward rangefinder measures the height: the rotors' wash
moves it by most of a metre with the throttle (BARO1_THST_SCALE), and fused beside the
rangefinder it pulled the height off by 8-10 cm with a 3 cm std in the closed-loop flights."""

from __future__ import annotations

import numpy as np

from daemon.config import MountingConfig
from daemon.fusion.config import FusionConfig
from daemon.fusion.estimator import FusionEstimator
from daemon.fusion.sensors import Attitude, Baro, Range
from daemon.fusion.timeline import Event

HEIGHT = 3.0
WASH = 0.8  # m: the barometer reads high once the rotors lift the vehicle


def hover(with_range: bool) -> FusionEstimator:
    """A vehicle holding 3 m (no IMU, no camera): 1 s with the barometer true, 4 s with it
    reading WASH high; the rangefinder (if any) reads the height throughout."""
    est = FusionEstimator(FusionConfig(), MountingConfig())
    est.filter.start(0.0, 0.01, -HEIGHT)
    seq = 0
    for k in range(1, 101):
        t = 0.05 * k
        est.attitude.add(Attitude(t, np.eye(3), np.zeros(3)))
        events = [("baro", Baro(t, HEIGHT + (WASH if t > 1.0 else 0.0), "SCALED_PRESSURE"))]
        if with_range:
            events.append(("range", Range(t, HEIGHT)))
        for kind, data in events:
            est._apply(Event(t, 0, seq, kind, data))
            seq += 1
    return est


def test_the_height_follows_the_rangefinder_not_the_washed_barometer():
    est = hover(with_range=True)
    assert abs(-est.filter.x[2] - HEIGHT) < 0.02


def test_without_a_rangefinder_the_barometer_still_gives_the_height():
    est = hover(with_range=False)
    assert est.filter.has_baro
    assert -est.filter.x[2] > HEIGHT + 0.1  # the wash is in it: nothing else knows better


def test_near_the_ground_the_barometer_is_not_fused():
    """On its gear and in the first metres of a climb the rotors' ground effect moves the
    barometer by metres (ArduPilot PR #32472: -5 to -11 m at spool-up): below
    baro_ground_effect_height_m it does not pull the height; above, its offset is referenced
    at the filter's height and it is fused again."""
    est = FusionEstimator(FusionConfig(), MountingConfig())
    est.filter.start(0.0, 0.01, 0.0)
    est.maps.ground_z = 0.0  # it stood at NED z 0
    seq = 0

    def baro(t: float, altitude: float) -> None:
        nonlocal seq
        est.attitude.add(Attitude(t, np.eye(3), np.zeros(3)))
        est._apply(Event(t, 0, seq, "baro", Baro(t, altitude, "SCALED_PRESSURE")))
        seq += 1

    for k in range(1, 41):
        baro(0.05 * k, -4.0)  # 4 m low under the spooled-up rotors
    assert not est.filter.has_baro
    assert abs(est.filter.x[2]) < 0.5
    est.filter.x[2] = -HEIGHT  # where the climb took it
    for k in range(41, 61):
        baro(0.05 * k, HEIGHT + WASH)
    assert est.filter.has_baro
    assert abs(-est.filter.x[2] - HEIGHT) < 0.1  # the offset took the wash in
