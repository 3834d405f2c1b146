"""Replay building blocks: the flown vehicle, its clock, matching received messages to frames,
the start alignment and the report's keys."""

from __future__ import annotations

import math
import multiprocessing
import time
from types import SimpleNamespace

import numpy as np
import pytest
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

from daemon.config import Config, replace
from daemon.mounting import body_from_camera
from sdvl.errors import InputError
from sim.autopilot.vehicle import sensor_message
from sim.datasets.layout import SensorSamples
from sim.replay.autopilot_process import ReplayVehicle, VisionMessage
from sim.replay.flight import (
    body_imu,
    drone_config,
    is_ned,
    sensor_streams,
    vehicle_trajectory,
)
from sim.replay.harness import choose_estimator, run_replay
from sim.replay.replay_run import ReplayRun, since_process_start
from sim.replay.report import KEYS, build_report, received_poses, start_aligned, velocity_at
from sim.sequence import ImuSamples
from sim.synth.sensors import SensorNoise
from sim.trajectory import Trajectory


def line_flight(n: int = 101, height: float = 2.0) -> Trajectory:
    """Body level, nose north, flying north at 1 m/s for n/10 seconds."""
    t = np.arange(n) * 0.1
    positions = np.column_stack([t, np.zeros(n), np.full(n, -height)])
    return Trajectory(t, positions, np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)))


def test_down_camera_ground_truth_becomes_a_level_body():
    # a downward camera on a level body facing north: camera x = east, y = south, z = down
    R_ned_c = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    camera = Trajectory([0.0], [[1.0, 2.0, -3.0]], Rotation.from_matrix(R_ned_c).as_quat())
    body = vehicle_trajectory(camera, replace(Config(), mounting={"preset": "down"}))
    np.testing.assert_allclose(body.positions, [[1.0, 2.0, -3.0]])
    np.testing.assert_allclose(body.rotations.as_matrix()[0], np.eye(3), atol=1e-12)


def test_a_sequence_brings_its_own_mounting_and_lever_arm():
    R_b_c = Rotation.from_euler("z", 0.3).as_matrix() @ np.array(
        [[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # forward camera yawed 0.3 rad
    T_b_c = np.eye(4)
    T_b_c[:3, :3], T_b_c[:3, 3] = R_b_c, [0.05, 0.0, 0.04]
    sequence = SimpleNamespace(extras={"T_b_c": T_b_c, "world": "NED"})
    config = drone_config(Config(), sequence)
    np.testing.assert_allclose(body_from_camera(config.mounting), R_b_c, atol=1e-12)
    assert (config.fusion.camera_x_m, config.fusion.camera_z_m) == (0.05, 0.04)
    assert is_ned(sequence) and not is_ned(SimpleNamespace(extras={}))
    # body level and facing north at the origin: the camera is 5 cm ahead and 4 cm below
    camera = Trajectory([0.0], [[0.05, 0.0, 0.04]], Rotation.from_matrix(R_b_c).as_quat())
    body = vehicle_trajectory(camera, config)
    np.testing.assert_allclose(body.positions, [[0.0, 0.0, 0.0]], atol=1e-12)
    np.testing.assert_allclose(body.rotations.as_matrix()[0], np.eye(3), atol=1e-12)
    assert drone_config(Config(), SimpleNamespace(extras={})) == Config()
    T_b_c[:3, :3] = body_from_camera(Config().mounting)  # a down camera stays the preset
    assert drone_config(Config(), sequence).mounting.preset == "down"


def test_a_synthetic_flight_brings_its_sensors_datasheet():
    noise = SensorNoise(baro_noise=0.4, range_noise_fraction=0.02)
    config = drone_config(Config(), SimpleNamespace(extras={"sensor_noise": noise}))
    assert (config.fusion.baro_std_m, config.fusion.range_std_fraction) == (0.4, 0.02)
    assert config.fusion.heading_bias_std_deg == pytest.approx(np.degrees(noise.yaw_offset))
    # the accelerometer's and the attitude's noise in the prediction, above the datasheet's own
    assert noise.accel_noise < config.fusion.accel_noise == noise.prediction_noise() < 0.02
    mine = replace(Config(), fusion={"baro_std_m": 0.7})  # what the user set stays theirs
    config = drone_config(mine, SimpleNamespace(extras={"sensor_noise": noise}))
    assert (config.fusion.baro_std_m, config.fusion.range_std_fraction) == (0.7, 0.02)


def test_rangefinder_only_when_the_flight_stays_in_its_range():
    assert "DISTANCE_SENSOR" in sensor_streams("ardupilot", line_flight(height=2.0))
    assert "DISTANCE_SENSOR" not in sensor_streams("ardupilot", line_flight(height=-1.5))
    assert "ATTITUDE" in sensor_streams("px4", None)


def test_vehicle_holds_the_start_then_follows_the_frames():
    clock = multiprocessing.Array("d", [math.nan, math.nan])
    vehicle = ReplayVehicle(line_flight(), clock)
    np.testing.assert_allclose(vehicle.state(123.0)["position"], [0.0, 0.0, -2.0], atol=1e-9)
    now = time.monotonic()
    clock[0], clock[1] = now - 5.0, 5.0  # frame at t=5 s released now
    state = vehicle.state(0.0)
    assert 5.0 <= state["position"][0] < 5.0 + 0.11  # never more than MAX_LEAD_S ahead
    np.testing.assert_allclose(state["velocity"], [1.0, 0.0, 0.0], atol=1e-6)
    clock[0], clock[1] = now - 99.0, 99.0  # beyond the end: hold the last pose
    np.testing.assert_allclose(vehicle.state(0.0)["position"], [10.0, 0.0, -2.0], atol=1e-9)


def test_recorded_body_imu_replaces_the_derived_one():
    clock = multiprocessing.Array("d", [time.monotonic() - 2.0, 2.0])  # at t = 2 s
    imu = ImuSamples(np.array([0.0, 10.0]), np.array([[0.0, 0.0, -9.0], [0.0, 0.0, -11.0]]),
                     np.array([[0.1, 0.0, 0.0], [0.3, 0.0, 0.0]]))
    state = ReplayVehicle(line_flight(), clock, imu).state(0.0)
    np.testing.assert_allclose(state["specific_force"], [0.0, 0.0, -9.4], atol=0.03)
    np.testing.assert_allclose(state["rates"], [0.14, 0.0, 0.0], atol=0.003)
    sequence = SimpleNamespace(imu=imu, extras={"imu_frame": "body_frd"})
    assert body_imu(sequence) is imu
    assert body_imu(SimpleNamespace(imu=imu, extras={})) is None


def test_the_preflight_imu_reads_gravity_plus_the_sensors_bias_at_the_flights_start():
    """Standing before the flight the IMU keeps the bias it flies with (a synthetic flight's
    true one, given at the IMU's sample times); without it, gravity alone."""
    clock = multiprocessing.Array("d", [math.nan, math.nan])  # no frame yet: the pre-flight
    imu = ImuSamples(np.array([0.0, 10.0]), np.zeros((2, 3)), np.zeros((2, 3)))
    ba = np.array([[0.04, -0.02, 0.01], [0.14, -0.02, 0.01]])
    bg = np.array([[0.002, 0.0, -0.001]] * 2)
    flight = line_flight()  # starts at t = 0, level
    state = ReplayVehicle(flight, clock, imu, None, (ba, bg)).state(0.0)
    np.testing.assert_allclose(state["specific_force"], [0.04, -0.02, 0.01 - 9.80665], atol=1e-3)
    np.testing.assert_allclose(state["rates"], [0.002, 0.0, -0.001], atol=1e-9)
    plain = ReplayVehicle(flight, clock, imu).state(0.0)
    np.testing.assert_allclose(plain["specific_force"], [0.0, 0.0, -9.80665], atol=1e-3)


def test_recorded_attitude_baro_and_rangefinder_replace_the_derived_ones():
    clock = multiprocessing.Array("d", [time.monotonic() - 2.0, 2.0])  # at t = 2 s
    yawed = Rotation.from_euler("z", 0.05).as_quat()  # a compass bias
    sensors = SensorSamples(np.array([0.0, 2.5, 4.0]), np.array([yawed] * 3),
                            np.array([1.0, 2.3, 3.0]), np.array([2.0, 1.9, 0.0]),
                            np.array([True, True, False]))
    vehicle = ReplayVehicle(line_flight(), clock, None, sensors)
    mav = mavlink2.MAVLink(None, srcSystem=1, srcComponent=1)
    assert sensor_message(mav, "ATTITUDE", 0.0, 0, vehicle).yaw == pytest.approx(0.05)
    assert sensor_message(mav, "DISTANCE_SENSOR", 0.0, 0, vehicle).current_distance == 190
    assert sensor_message(mav, "ALTITUDE", 0.0, 0, vehicle).altitude_amsl == pytest.approx(2.3)
    clock[0], clock[1] = time.monotonic() - 3.0, 3.0  # no echo
    assert sensor_message(mav, "DISTANCE_SENSOR", 0.0, 0, vehicle).current_distance == 4000


def odometry(t_capture: float, position, reset: int = 0, v_body=(0.0, 0.0, 0.0),
             arrival: float | None = None) -> VisionMessage:
    return VisionMessage("ODOMETRY", arrival or t_capture + 0.005, {
        "time_usec": round(t_capture * 1e6), "x": position[0], "y": position[1],
        "z": position[2], "q": [math.cos(0.25 * math.pi), 0.0, 0.0, math.sin(0.25 * math.pi)],
        "vx": v_body[0], "vy": v_body[1], "vz": v_body[2], "reset_counter": reset})


def row(t_capture: float, t_source: float, sent: bool = True) -> dict:
    return {"t_capture": t_capture, "t_source": t_source, "wait": 0.001, "track": 0.01,
            "sent": sent, "quality": "good", "has_pose": True, "new_segment": False,
            "estimate": 0.0, "handoff": 0.0, "send": 0.012 if sent else None}


def test_received_messages_are_placed_at_their_frames_sequence_time():
    rows = [row(100.0 + 0.05 * i, 7.0 + 0.1 * i) for i in range(5)]
    messages = [odometry(100.0 + 0.05 * i, [i, 0, 0], reset=int(i >= 3), v_body=(1.0, 0, 0))
                for i in (0, 1, 3, 4)]
    messages.insert(1, odometry(100.02, [9, 9, 9]))  # matches no frame: ignored
    messages.append(VisionMessage("VISION_SPEED_ESTIMATE", 1.0, {"usec": 0}))
    got = received_poses(messages, rows)
    np.testing.assert_allclose(got.trajectory.t, [7.0, 7.1, 7.3, 7.4])
    np.testing.assert_allclose(got.trajectory.positions[:, 0], [0, 1, 3, 4])
    # body velocity (1, 0, 0) with the body yawed 90 degrees is (0, 1, 0) in the local frame
    np.testing.assert_allclose(got.velocity_local, [[0.0, 1.0, 0.0]] * 4, atol=1e-12)
    assert got.resets == 1
    np.testing.assert_allclose(got.t_arrival - got.t_capture, 0.005, atol=1e-6)


def test_vision_position_estimates_take_their_velocity_from_vision_speed():
    rows = [row(50.0, 1.0), row(50.1, 1.1)]
    messages = []
    for r in rows:
        usec = round(r["t_capture"] * 1e6)
        messages.append(VisionMessage("VISION_POSITION_ESTIMATE", r["t_capture"], {
            "usec": usec, "x": 1.0, "y": 2.0, "z": 3.0, "roll": 0.0, "pitch": 0.0,
            "yaw": 0.5 * math.pi, "reset_counter": 0}))
        messages.append(VisionMessage("VISION_SPEED_ESTIMATE", r["t_capture"], {
            "usec": usec, "x": 0.5, "y": 0.0, "z": 0.0, "reset_counter": 0}))
    got = received_poses(messages, rows)
    np.testing.assert_allclose(got.trajectory.t, [1.0, 1.1])
    np.testing.assert_allclose(got.velocity_local, [[0.5, 0.0, 0.0]] * 2)
    np.testing.assert_allclose(got.trajectory.rotations.as_euler("ZYX")[:, 0], 0.5 * math.pi)


def test_start_alignment_translates_the_flight_onto_the_first_pose():
    flight = line_flight()
    estimate = Trajectory([2.0, 3.0], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]],
                          np.tile([0.0, 0.0, 0.0, 1.0], (2, 1)))
    moved = start_aligned(flight, estimate)
    np.testing.assert_allclose(moved.positions[20], [0.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(moved.positions[30], [1.0, 0.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(velocity_at(flight, np.array([2.0, 5.0])), [[1, 0, 0]] * 2)


def test_report_keys_are_the_documented_ones(tmp_path):
    flight = line_flight()
    rows = [row(200.0 + 0.1 * i, 0.1 * i) for i in range(1, 90)]
    messages = [odometry(r["t_capture"], 2.0 * flight.positions[i + 1] + [5, 0, 0])
                for i, r in enumerate(rows)]
    messages = [VisionMessage(m.kind, m.t_arrival, {**m.fields, "q": [1.0, 0, 0, 0], "vx": 2.0})
                for m in messages]  # twice the ground truth's scale, moving at 2 units/s
    run = ReplayRun("line", False, False, 95, rows, messages, flight, 9.0, 1.0, 0.5, 100.0, 0)
    report, aligned, _ = build_report(run, tmp_path)
    assert list(report) == list(KEYS)
    assert report["frames"] == 95 and report["processed"] == 89 and report["dropped"] == 6
    assert report["messages_received"] == 89 and report["scored"] == 89
    assert report["ate_rmse_m"] < 1e-9 and report["scale"] == pytest.approx(0.5)
    assert report["velocity_rmse_m_s"] < 1e-6
    assert report["message_rate_hz"] == pytest.approx(10.0)
    assert aligned is not None and (tmp_path / "received.txt").is_file()


def test_fusion_only_for_sequences_that_know_down_and_only_in_realtime():
    handheld = SimpleNamespace(extras={})
    synthetic = SimpleNamespace(extras={"world": "NED"})
    fusion_on = replace(Config(), fusion={"enabled": True})
    assert not choose_estimator(fusion_on, handheld, "auto").fusion.enabled
    assert choose_estimator(fusion_on, synthetic, "auto").fusion.enabled
    fusion_off = replace(Config(), fusion={"enabled": False})
    assert not choose_estimator(fusion_off, synthetic, "auto").fusion.enabled
    assert choose_estimator(Config(), handheld, "fusion").fusion.enabled
    assert not choose_estimator(Config(), synthetic, "pass-through").fusion.enabled
    with pytest.raises(InputError, match="realtime"):
        run_replay(handheld, choose_estimator(Config(), handheld, "fusion"), realtime=False)


def test_time_since_the_process_started():
    """The replay's start-up figure: this process is older than the test, and not by days."""
    age = since_process_start(time.monotonic())
    assert age is not None and 0.0 < age < 3600.0
    assert since_process_start(time.monotonic() - 1.0) == pytest.approx(age - 1.0, abs=0.05)
