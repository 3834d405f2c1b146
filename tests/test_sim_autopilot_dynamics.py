"""The flying simulator's physics and ArduCopter's control primitives in isolation: ground
contact, thrust, motor lags, the mixer, the square-root controller, jerk-limited paths, gusts
and the truth history the camera renderer reads."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim.autopilot.airframe import GRAVITY, Airframe
from sim.autopilot.control_math import KinematicPath, sqrt_controller
from sim.autopilot.dynamics import Dynamics, FlyingVehicle
from sim.autopilot.flight_params import flight_specs
from sim.autopilot.motors import Motors, Spool, thrust_to_command
from sim.autopilot.multicopter import Multicopter
from sim.autopilot.param_store import ParamStore
from sim.autopilot.params import Release, ardupilot_specs
from sim.autopilot.wind import Wind, WindField

DT = 0.0025
FRAME = Airframe()


def body() -> Multicopter:
    return Multicopter(FRAME, np.zeros(2), 0.0, 0.0, WindField(None))


def params() -> ParamStore:
    return ParamStore({**ardupilot_specs(Release.MASTER_2025), **flight_specs()}, {})


def hover_command() -> float:
    return float(thrust_to_command(np.array(FRAME.hover_thrust_ratio), FRAME.thrust_expo))


def run(vehicle: Multicopter, command: float, seconds: float) -> None:
    for _ in range(round(seconds / DT)):
        vehicle.step(DT, np.full(4, command))


def test_stays_on_the_ground_until_the_thrust_lifts_it():
    vehicle = body()
    run(vehicle, 0.9 * hover_command(), 1.0)
    assert vehicle.on_ground and vehicle.position[2] == vehicle.contact_z
    assert vehicle.specific_force == pytest.approx([0.0, 0.0, -GRAVITY])
    run(vehicle, 1.0, 0.5)
    assert not vehicle.on_ground and vehicle.velocity[2] < -1.0


def test_hover_command_holds_the_weight_and_touching_down_is_recorded():
    vehicle = body()
    run(vehicle, 1.0, 0.05)
    run(vehicle, hover_command(), 0.5)
    assert abs(vehicle.accel[2]) < 0.05
    run(vehicle, 0.0, 3.0)
    assert vehicle.on_ground and vehicle.touchdown_speeds[0] > 1.0


def test_the_accelerometer_feels_the_gear_stop_a_touch_down():
    """A real flight log shows a landing's spike: the speed the gear takes out is in the
    specific force, its integral over the stop (the motors off: no thrust in it)."""
    vehicle = body()
    run(vehicle, 1.0, 0.05)
    run(vehicle, hover_command(), 0.5)
    while not vehicle.touchdown_speeds:
        vehicle.step(DT, np.zeros(4))
    felt = (vehicle.specific_force[2] + GRAVITY) * DT
    for _ in range(round(0.1 / DT)):
        vehicle.step(DT, np.zeros(4))
        felt += (vehicle.specific_force[2] + GRAVITY) * DT
    assert vehicle.touchdown_speeds[0] > 1.0
    assert -felt == pytest.approx(vehicle.touchdown_speeds[0], rel=0.01)


def test_motors_spin_up_and_down_with_their_time_constants():
    vehicle = body()
    run(vehicle, 0.0, 0.1)
    run(vehicle, 1.0, FRAME.motor_tau_up_s)
    assert vehicle.motor[0] == pytest.approx(1 - math.exp(-1), abs=0.02)
    run(vehicle, 1.0, 0.5)
    run(vehicle, 0.0, FRAME.motor_tau_down_s)
    assert vehicle.motor[0] == pytest.approx(math.exp(-1), abs=0.02)


def test_thrust_to_command_inverts_the_thrust_curve():
    ratios = np.linspace(0.0, 1.0, 11)
    commands = thrust_to_command(ratios, FRAME.thrust_expo)
    assert FRAME.thrust(commands) / FRAME.max_thrust_n == pytest.approx(ratios, abs=1e-9)


def test_mixer_rolls_the_right_way_and_gives_up_yaw_first():
    motors = Motors(spool=Spool.THROTTLE_UNLIMITED, ramp=1.0)
    p = params()
    commands = motors.output(0.2, 0.0, 0.0, 0.4, p)
    vehicle = body()
    _, torque = vehicle._body_forces(FRAME.thrust(commands))
    assert torque[0] > 0 and abs(torque[1]) < 1e-9  # positive roll demand, roll torque
    motors.output(0.0, 0.0, 1.0, 0.4, p)  # more yaw than the motors can give
    assert motors.limit.yaw and not motors.limit.roll
    motors.output(0.0, 0.0, 0.0, 0.0, p)
    assert motors.limit.throttle_lower


def test_sqrt_controller_linear_then_square_root_and_never_past_the_target():
    assert sqrt_controller(0.1, 2.0, 4.0, 0.0) == pytest.approx(0.2)  # linear under 1 m
    assert sqrt_controller(5.0, 2.0, 4.0, 0.0) == pytest.approx(math.sqrt(2 * 4 * (5 - 0.5)))
    assert sqrt_controller(-5.0, 2.0, 4.0, 0.0) == pytest.approx(-math.sqrt(36.0))
    assert sqrt_controller(0.01, 2.0, 4.0, 0.1) == pytest.approx(0.02)
    assert sqrt_controller(0.001, 100.0, 4.0, 0.1) == pytest.approx(0.01)  # error / dt


def test_jerk_limited_path_reaches_the_target_within_its_limits():
    path = KinematicPath(1)
    vel_max, accel_max, jerk = 2.5, 1.0, 5.0
    history = []
    for _ in range(600):
        path.advance(0.02)
        path.to_position([3.0], vel_max, accel_max, jerk, 0.02)
        history.append((path.pos[0], path.vel[0], path.acc[0]))
    pos, vel, acc = np.array(history).T
    assert pos[-1] == pytest.approx(3.0, abs=0.01) and pos.max() < 3.02  # 1 cm overshoot
    assert vel.max() <= vel_max + 1e-9 and np.abs(acc).max() <= accel_max + 1e-9
    assert np.abs(np.diff(acc)).max() <= jerk * 0.02 + 1e-9


def test_gusts_are_seeded_and_as_strong_as_asked():
    wind = Wind(speed_ms=5.0, from_deg=90.0, gust_ms=1.0, gust_tau_s=2.0, seed=3)
    field = WindField(wind)
    speeds = np.array([field.step(0.01).copy() for _ in range(60000)])
    assert speeds.mean(axis=0)[:2] == pytest.approx([0.0, -5.0], abs=0.2)  # from the east
    assert speeds[:, 0].std() == pytest.approx(1.0, rel=0.15)
    again = WindField(wind)
    assert again.step(0.01) == pytest.approx(speeds[0])


def test_state_reads_the_truth_of_a_past_time():
    vehicle = FlyingVehicle(Dynamics())
    for k in range(100):  # 2 s of climbing, kept at 50 Hz
        for _ in range(8):
            vehicle.advance(DT, np.ones(4))
        vehicle.mark()
        if k == 49:
            then = vehicle.now()
    past = vehicle.state(then.t)
    assert past["position"] == pytest.approx(then.position)
    assert vehicle.state(vehicle.time + 1.0)["position"] == pytest.approx(vehicle.body.position)
    assert vehicle.T_ned_body[:3, 3] == pytest.approx(vehicle.body.position)
