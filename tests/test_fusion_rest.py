"""When the filter takes the vehicle to stand still (daemon/fusion/rest.py): the autopilot's
land detector, or disarmed with a quiet IMU; one corrupt report never stops a flying vehicle."""

from __future__ import annotations

import numpy as np

from daemon.fusion.config import FusionConfig
from daemon.fusion.rest import CONFIRM, GRAVITY, RestDetector

STILL = np.array([0.0, 0.0, -GRAVITY])


def test_landed_counts_once_confirmed_and_airborne_at_once():
    rest = RestDetector(FusionConfig())
    rest.on_landed(0.0, True)  # the first word stands
    assert rest.state(0.1) is True
    rest.on_landed(1.0, False)  # take-off: at once
    assert rest.state(1.1) is False
    rest.on_landed(2.0, True)  # one corrupt "on the ground" in flight
    assert rest.state(2.1) is False
    rest.on_landed(3.0, False)
    for k in range(CONFIRM):  # a real landing repeats itself
        rest.on_landed(4.0 + k, True)
    assert rest.state(4.0 + CONFIRM) is True


def test_a_disarmed_vehicle_stands_still_only_with_a_quiet_imu():
    rest = RestDetector(FusionConfig())
    rest.on_armed(0.0, False)
    for k in range(20):
        rest.on_imu(0.5 + 0.02 * k, STILL)
    assert rest.state(0.9) is True
    rest.on_armed(1.0, True)
    assert rest.state(1.0) is False
    rest.on_armed(1.5, False)  # one corrupt "disarmed" in flight
    assert rest.state(1.5) is False


def test_on_its_gear_while_the_motors_spin_up_the_vehicle_is_held_sideways_only():
    """Landed and spinning up (the IMU's mean departs from the ground's: folded vibration, or
    the lift-off itself), or landed and armed: not at rest, so no zero vertical velocity; but
    on its gear, where the filter's north and east velocity are held at zero and its vertical
    one is not."""
    from daemon.fusion import measurements as m
    from daemon.fusion.state import VEL, NavFilter

    cfg = FusionConfig()
    rest = RestDetector(cfg)
    rest.on_landed(0.0, True)
    for k in range(40):  # motors off, then spinning up: 0.3 m/s^2 more than the ground's
        rest.on_imu(0.02 * k, STILL * (1.0 if k < 30 else 1.03))
    assert rest.on_gear(0.79) and not rest.at_rest(0.79)
    rest.on_landed(0.8, False)  # lifted
    assert not rest.on_gear(0.81)
    armed = RestDetector(cfg)  # armed on its gear with a quiet IMU: may lift any moment
    armed.on_landed(0.0, True)
    armed.on_armed(0.0, True)
    for k in range(20):
        armed.on_imu(0.02 * k, STILL)
    assert armed.on_gear(0.39) and not armed.at_rest(0.39)

    f = NavFilter(cfg)
    f.start(0.0, cfg.start_velocity_std, 0.0)
    f.x[VEL] = [0.08, -0.05, -0.3]  # what 0.5 s of folded vibration and a lift-off leave
    assert m.update_rest(f, axes=2)
    assert np.allclose(f.x[VEL][:2], 0.0, atol=0.002) and f.x[VEL][2] == -0.3
