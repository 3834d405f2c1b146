"""The flying simulator's flight-controller sensors against their datasheet figures (IMU noise,
vibration, quantisation, range; barometer noise, prop wash and ground effect; rangefinder range
and ArduPilot's out-of-range report) and what the autopilot streams of them."""

from __future__ import annotations

import math

import numpy as np
import pytest
from flight_helpers import Flight

from sim.autopilot.airframe import GRAVITY, Airframe
from sim.autopilot.barometer import Barometer, BaroSpec
from sim.autopilot.dynamics import Dynamics, FlyingVehicle
from sim.autopilot.flight_params import flight_specs
from sim.autopilot.flight_sensors import FlightSensors
from sim.autopilot.imu import ACCEL_LSB, ACCEL_RANGE, Imu, ImuSpec
from sim.autopilot.param_store import ParamStore
from sim.autopilot.params import Release, ardupilot_specs
from sim.autopilot.rangefinder import Rangefinder, RangefinderSpec

AT_REST = np.array([0.0, 0.0, -GRAVITY])


def samples(imu: Imu, n: int, force: np.ndarray = AT_REST,
            thrust: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    raw, filtered = [], []
    for _ in range(n):
        imu.sample(force, np.zeros(3), np.full(4, thrust))
        raw.append(imu.raw_accel.copy())
        filtered.append(imu.accel.copy())
    return np.array(raw), np.array(filtered)


def test_imu_noise_density_offset_and_quantisation():
    spec = ImuSpec()
    imu = Imu(spec, np.random.default_rng(0), 400.0, 20.0, 20.0)
    raw, filtered = samples(imu, 4000)
    expected = spec.accel_density * math.sqrt(400.0)  # white noise per sample
    assert raw.std(axis=0) == pytest.approx([expected] * 3, rel=0.1)
    assert np.allclose(raw / ACCEL_LSB, np.round(raw / ACCEL_LSB))  # whole counts
    assert abs(raw.mean(axis=0) - AT_REST - imu.accel_bias).max() < 3 * expected / 60
    assert filtered[100:].std(axis=0).max() < 0.6 * expected  # INS_ACCEL_FILTER 20 Hz


def test_vibration_is_the_documented_normal_vibe_and_the_filter_takes_most_of_it():
    imu = Imu(ImuSpec(), np.random.default_rng(1), 400.0, 20.0, 20.0)
    raw, filtered = samples(imu, 4000, thrust=1.0)  # motors at hover thrust
    vibe = raw.std(axis=0)
    assert np.sqrt(np.mean(vibe ** 2)) == pytest.approx(15.0, rel=0.1)
    assert filtered[100:].std(axis=0).max() < 2.5


def test_a_tone_locked_to_the_loop_folds_into_an_offset_one_spread_over_the_motors_does_not():
    """Sampled every 10th 400 Hz tick (a 40 Hz stream), the filtered accelerometer's 80 Hz
    vibration (400 Hz / 5) lands on the same phases every time: a steady offset of up to
    1 m/s^2. With each motor's frequency its own (motor_hz_spread) the offset averages out."""
    def stream_offset(spread: float, seed: int) -> np.ndarray:
        imu = Imu(ImuSpec(motor_hz_spread=spread), np.random.default_rng(seed), 400.0, 20.0,
                  20.0)
        force = np.array([0.0, 0.0, -GRAVITY])
        streamed = []
        for k in range(400 * 20):
            imu.sample(force, np.zeros(3), np.ones(4))
            if k % 10 == 0:
                streamed.append(imu.accel.copy())
        return np.mean(streamed[40:], axis=0) - force - imu.accel_bias

    assert max(np.abs(stream_offset(0.0, seed)).max() for seed in (1, 3)) > 0.5
    assert max(np.abs(stream_offset(0.03, seed)).max() for seed in (1, 2, 3)) < 0.05
    assert np.array_equal(Imu(ImuSpec(), np.random.default_rng(1), 400.0, 20.0, 20.0)._motor_hz,
                          np.full(4, ImuSpec().hover_motor_hz))


def test_imu_clips_at_its_range():
    imu = Imu(ImuSpec(), np.random.default_rng(2), 400.0, 20.0, 20.0)
    raw, _ = samples(imu, 10, force=np.array([0.0, 0.0, -30 * GRAVITY]))
    assert raw[:, 2].min() == pytest.approx(-ACCEL_RANGE)


def test_baro_noise_prop_wash_and_ground_effect():
    frame = Airframe()
    baro = Barometer(BaroSpec(), np.random.default_rng(3))
    hover = frame.mass_kg * GRAVITY
    in_flight = baro.disturbance(3.0, hover, hover, frame.disc_area_m2)
    loading = hover / frame.disc_area_m2
    assert in_flight == pytest.approx(0.12 * loading / (1.225 * GRAVITY))  # reads high
    standing = baro.disturbance(0.15, hover, hover, frame.disc_area_m2)
    assert standing == pytest.approx(in_flight - 1.0 * (1 - 0.15 / 2.0))  # reads low
    assert baro.disturbance(0.15, 0.0, hover, frame.disc_area_m2) == 0.0  # motors stopped
    readings = []
    for k in range(2000):
        if baro.update(k * 0.01, 10.0, 0.0):
            readings.append(baro.altitude)
    assert len(readings) == 400  # 20 Hz
    assert np.std(readings) == pytest.approx(2.7 / (1.225 * GRAVITY) / 2, rel=0.15)


def test_rangefinder_accuracy_and_no_echo_report():
    finder = Rangefinder(RangefinderSpec(), np.random.default_rng(4))
    readings = []
    for k in range(500):
        finder.update(k * 0.01, 3.0, 6.0)
        readings.append(finder.distance_m)
    assert np.std(readings) == pytest.approx(0.025, rel=0.2)
    assert np.allclose(np.array(readings) / 0.005, np.round(np.array(readings) / 0.005))
    finder.update(10.0, 9.0, 6.0)  # beyond its 7 m outdoors: no echo
    assert not finder.in_range and finder.distance_m == 12.0
    finder.update(11.0, 9.0, 15.0)
    assert finder.distance_m == 16.0  # RNGFND1_MAX + 1 m when that is more


def test_streams_carry_the_flight_controllers_readings():
    flight = Flight(seed=6, requested={"ATTITUDE": 20, "SCALED_IMU": 50, "DISTANCE_SENSOR": 10,
                                       "SCALED_PRESSURE": 10})
    flight.fly(3.0)
    imu = flight.link.of("SCALED_IMU")[-1]
    assert imu.zacc == pytest.approx(-1000, abs=15)  # mG, on the ground
    distance = flight.link.of("DISTANCE_SENSOR")[-1]
    assert (distance.min_distance, distance.max_distance) == (10, 600)  # the wiki's set-up
    assert distance.current_distance == pytest.approx(15, abs=8)  # gear height, 2.5 cm rms
    attitude = flight.link.of("ATTITUDE")[-1]
    compass = flight.model.flying.sensors.ahrs.heading
    assert attitude.yaw == pytest.approx(compass, abs=1e-3)  # standing at yaw 0
    assert 0 < abs(math.degrees(compass)) < 8
    assert abs(attitude.roll) < math.radians(0.3) and abs(attitude.pitch) < math.radians(0.3)
    assert abs(imu.time_boot_ms / 1000 - flight.model.uptime(flight.link.now)) < 0.05


def test_no_rangefinder_no_distance_sensor():
    flight = Flight(dynamics=Dynamics(rangefinder=None), requested={"DISTANCE_SENSOR": 10})
    flight.fly(2.0)
    assert flight.link.of("DISTANCE_SENSOR") == []
    assert flight.model.params.get("RNGFND1_TYPE") == 0


def test_the_vehicles_barometer_is_the_one_its_dynamics_name():
    """`sdvl fly --baro-ground-effect M` flies a barometer with another ground effect: the
    flight's sensors read the one the vehicle's Dynamics carry."""
    vehicle = FlyingVehicle(Dynamics(baro=BaroSpec(ground_effect_m=3.0)))
    params = ParamStore({**ardupilot_specs(Release.MASTER_2025), **flight_specs()}, {})
    sensors = FlightSensors(vehicle, params, seed=0)
    assert sensors.baro.spec.ground_effect_m == 3.0
    vehicle = FlyingVehicle(Dynamics(imu=ImuSpec(motor_hz_spread=0.05)))
    assert FlightSensors(vehicle, params, seed=0).imu.spec.motor_hz_spread == 0.05
