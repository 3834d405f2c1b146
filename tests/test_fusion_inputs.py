"""Fusion inputs: MAVLink units, the autopilot clock, the attitude track, rotations, config."""

from __future__ import annotations

import math
import typing

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from daemon.fusion.attitude import AttitudeTrack
from daemon.fusion.clock import ClockMap
from daemon.fusion.config import FusionConfig
from daemon.fusion.sensors import Attitude, Baro, Imu, Range, parse, pressure_altitude
from sdvl.errors import InputError

DOWN = mavlink2.MAV_SENSOR_ROTATION_PITCH_270


def test_scaled_and_raw_imu_are_milli_g() -> None:
    for msg in (mavlink2.MAVLink_scaled_imu_message(1500, 10, -20, -1000, 0, 0, 0, 0, 0, 0),
                mavlink2.MAVLink_raw_imu_message(1_500_000, 10, -20, -1000, 0, 0, 0, 0, 0, 0)):
        t, [imu] = parse(msg)
        assert t == pytest.approx(1.5) and isinstance(imu, Imu)
        assert imu.accel == pytest.approx([0.0980665, -0.196133, -9.80665])


def test_highres_imu_gives_accel_and_pressure_when_flagged() -> None:
    msg = mavlink2.MAVLink_highres_imu_message(2_000_000, 0.1, 0.2, -9.8, 0, 0, 0, 0, 0, 0,
                                               1000.0, 0, 0, 20, 0b111 | (1 << 9))
    t, samples = parse(msg)
    assert t == 2.0
    assert isinstance(samples[0], Imu) and samples[0].accel == pytest.approx([0.1, 0.2, -9.8])
    assert isinstance(samples[1], Baro)
    assert samples[1].altitude == pytest.approx(pressure_altitude(1000.0))
    msg.fields_updated = 0b111
    assert len(parse(msg)[1]) == 1


def test_pressure_altitude_standard_atmosphere() -> None:
    assert pressure_altitude(1013.25) == pytest.approx(0.0)
    assert pressure_altitude(898.75) == pytest.approx(1000.0, abs=2.0)
    _, [baro] = parse(mavlink2.MAVLink_scaled_pressure_message(10, 1013.25, 0, 2000))
    assert baro.altitude == pytest.approx(0.0)


def test_px4_altitude_monotonic_is_a_baro_altitude() -> None:
    msg = mavlink2.MAVLink_altitude_message(3_000_000, 512.5, 500.0, 1.0, 1.0, 0.0, 0.0)
    t, [baro] = parse(msg)
    assert t == 3.0 and baro.altitude == 512.5 and baro.source == "ALTITUDE"
    msg.altitude_monotonic = math.nan
    assert parse(msg)[1] == []


def test_distance_sensor_downward_and_in_range_only() -> None:
    def msg(cm: int, orientation: int = DOWN):
        return mavlink2.MAVLink_distance_sensor_message(100, 20, 4000, cm, 0, 0, orientation, 0)
    _, [r] = parse(msg(250))
    assert isinstance(r, Range) and r.distance == 2.5
    assert parse(msg(250, orientation=0))[1] == []  # forward-looking: not a height
    assert parse(msg(4001))[1] == [] and parse(msg(5))[1] == []


def test_attitude_is_body_to_ned() -> None:
    _, [att] = parse(mavlink2.MAVLink_attitude_message(5, 0.1, -0.2, 1.0, 0.01, 0.02, 0.03))
    assert isinstance(att, Attitude)
    expected = Rotation.from_euler("ZYX", [1.0, -0.2, 0.1]).as_matrix()
    assert att.R_n_b == pytest.approx(expected)
    assert att.rates == pytest.approx([0.01, 0.02, 0.03])


def test_non_finite_or_absurd_values_are_dropped() -> None:
    nan = math.nan
    assert parse(mavlink2.MAVLink_attitude_message(5, nan, 0, 0, 0, 0, 0))[1] == []
    assert parse(mavlink2.MAVLink_scaled_pressure_message(5, math.inf, 0, 0))[1] == []
    assert parse(mavlink2.MAVLink_scaled_pressure_message(5, 5000.0, 0, 0))[1] == []
    huge = mavlink2.MAVLink_highres_imu_message(1, 1e6, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 7)
    assert parse(huge)[1] == []
    assert parse(mavlink2.MAVLink_heartbeat_message(0, 0, 0, 0, 0, 3)) is None


def test_clock_offset_from_least_delayed_message() -> None:
    clock = ClockMap(window_s=10.0)
    rng = np.random.default_rng(0)
    for k in range(200):
        remote = 0.02 * k
        clock.to_local(remote, remote + 100.0 + rng.uniform(0.003, 0.03))
    # the least delays: the quantile (10 %) of delays from 3 to 30 ms
    assert clock.to_local(4.0, 104.01) == pytest.approx(104.0057, abs=0.002)
    clock.set_offset(100.0)
    assert clock.to_local(5.0, 105.01) == 105.0
    assert clock.to_local(50.0, 105.02) is None  # stamp far ahead of its arrival: wrong


def test_clock_offset_is_not_dragged_by_messages_that_came_too_early() -> None:
    """Five messages in a hundred arrive up to 30 ms before they can have been sent (reordered
    by the link, or stamped a little ahead): the offset stays that of the least delayed real
    ones (the 2 % quantile: 4.5 ms earlier than the least real delay)."""
    clock = ClockMap(window_s=10.0)
    rng = np.random.default_rng(1)
    for k in range(500):
        remote = 0.02 * k
        early = rng.uniform(0.0, 0.03) if rng.random() < 0.05 else 0.0
        clock.to_local(remote, remote + 100.0 + rng.uniform(0.005, 0.02) - early)
    assert clock.to_local(10.0, 110.01) == pytest.approx(110.0065, abs=0.0015)


def test_clock_drops_a_corrupt_stamp_and_follows_a_reboot() -> None:
    clock = ClockMap()
    for k in range(50):
        clock.to_local(10.0 + 0.02 * k, 110.0 + 0.02 * k)
    assert clock.to_local(9999.0, 111.01) is None
    local = [clock.to_local(0.02 * k, 112.0 + 0.02 * k) for k in range(10)]  # rebooted
    assert local[0] is None and local[-1] == pytest.approx(112.18)


def test_attitude_track_interpolates_and_times_out() -> None:
    track = AttitudeTrack(timeout_s=0.1, keep_s=5.0)
    for t, yaw in ((1.1, 0.2), (1.0, 0.0)):  # out of order on purpose
        R = Rotation.from_euler("z", yaw).as_matrix()
        track.add(Attitude(t, R, np.array([0.0, 0.0, yaw])))
    mid = track.at(1.05)
    assert Rotation.from_matrix(mid.R_n_b).as_euler("ZYX")[0] == pytest.approx(0.1)
    assert mid.rates[2] == pytest.approx(0.1)
    after = track.at(1.15)  # carried on by its rates, 0.2 rad/s for 50 ms
    assert Rotation.from_matrix(after.R_n_b).as_euler("ZYX")[0] == pytest.approx(0.21)
    assert track.at(1.19).gap_var > after.gap_var > 0.0 and mid.gap_var > 0.0
    assert track.at(1.3) is None and track.at(0.8) is None


def test_config_fields_are_plain_toml_values() -> None:
    hints = typing.get_type_hints(FusionConfig)
    assert set(hints.values()) <= {int, float, bool}


def test_config_rejects_nonsense() -> None:
    FusionConfig().check()
    with pytest.raises(InputError, match=r"fusion\.scale_std_max"):
        FusionConfig(scale_std_max=0.0).check()
    with pytest.raises(InputError, match="range_max_tilt_deg"):
        FusionConfig(range_max_tilt_deg=95.0).check()
