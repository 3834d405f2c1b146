"""The flying vehicle's flight-controller sensors together: IMU, AHRS attitude error, barometer
and downward rangefinder (imu.py, ahrs_error.py, barometer.py, rangefinder.py), sampled in the
400 Hz loop from the true motion. They give the estimator its Reading, the controllers the
AHRS attitude, filtered gyro and vertical acceleration, and the MAVLink streams what a real
ArduCopter reports (the latest filtered IMU sample, the AHRS attitude, the latest baro and
rangefinder readings, each sent with the boot time of sending)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from sim.autopilot.ahrs_error import AhrsError
from sim.autopilot.airframe import GRAVITY
from sim.autopilot.barometer import Barometer
from sim.autopilot.dynamics import FlyingVehicle
from sim.autopilot.imu import Imu
from sim.autopilot.param_store import ParamStore
from sim.autopilot.rangefinder import Rangefinder
from sim.autopilot.sensing import Reading

LOOP_HZ = 400.0
GRAVITY_NED = np.array([0.0, 0.0, GRAVITY])


class FlightSensors:
    """All sensors of one flight controller on one vehicle, seeded."""

    def __init__(self, vehicle: FlyingVehicle, params: ParamStore, seed: int) -> None:
        rng = np.random.default_rng(seed)
        self.vehicle = vehicle
        self.params = params
        self.imu = Imu(vehicle.dynamics.imu, rng, LOOP_HZ, params.get("INS_ACCEL_FILTER"),
                       params.get("INS_GYRO_FILTER"))
        self.ahrs = AhrsError(self.imu.accel_bias, rng)
        self.baro = Barometer(vehicle.dynamics.baro, rng)
        spec = vehicle.dynamics.rangefinder
        self.rangefinder = Rangefinder(spec, rng) if spec is not None else None
        self.attitude = self.ahrs.attitude(vehicle.body.rotation)
        self._accel_steps: list[np.ndarray] = []
        self.calibrate_baro()

    def calibrate_baro(self) -> None:
        """At boot the barometer zeroes on where the vehicle stands."""
        self.baro.update(self.vehicle.time, -self.vehicle.body.position[2], 0.0)
        self.baro.calibrate(-self.vehicle.body.position[2])

    def tick(self) -> None:
        """One loop: read every sensor from the vehicle's present truth."""
        body = self.vehicle.body
        frame = body.frame
        thrusts = frame.thrust(body.motor)
        hover = frame.mass_kg * GRAVITY / 4.0
        self.imu.sample(body.specific_force, body.rates, thrusts / hover)
        self.attitude = self.ahrs.attitude(body.rotation)
        self._accel_steps.append(self.attitude @ self.imu.raw_accel + GRAVITY_NED)
        height = body.ground_z - body.position[2]
        wash = self.baro.disturbance(height, float(thrusts.sum()), 4.0 * hover,
                                     frame.disc_area_m2)
        self.baro.update(self.vehicle.time, -body.position[2], wash)
        if self.rangefinder is not None:
            down = body.rotation[:, 2]
            self.rangefinder.update(self.vehicle.time, self.vehicle.range_to_ground(down),
                                    self.params.get("RNGFND1_MAX_CM") / 100.0)

    @property
    def gyro(self) -> np.ndarray:
        return self.imu.gyro

    def accel_up(self) -> float:
        """Vertical acceleration (m/s^2, up) from the filtered IMU and the AHRS attitude."""
        return float(-(self.attitude @ self.imu.accel)[2] - GRAVITY)

    def accel_ned(self) -> np.ndarray:
        """Acceleration (NED, gravity removed) from the filtered IMU and the AHRS attitude."""
        return self.attitude @ self.imu.accel + GRAVITY_NED

    def rangefinder_healthy(self) -> bool:
        """A reading within RNGFND1_MIN/MAX_CM (ArduPilot's RangeFinder status Good)."""
        if self.rangefinder is None or int(self.params.get("RNGFND1_TYPE")) == 0:
            return False
        d = self.rangefinder.distance_m * 100.0
        return self.params.get("RNGFND1_MIN_CM") <= d <= self.params.get("RNGFND1_MAX_CM")

    def reading(self) -> Reading:
        """What the estimator takes for its step: every raw sample since the last, turned to
        NED by the AHRS (EKF3 predicts with each IMU delta velocity), and their mean."""
        mean = self.imu.take_mean()
        steps = np.array(self._accel_steps) if self._accel_steps else None
        self._accel_steps = []
        accel_ned = self.attitude @ mean + GRAVITY_NED
        return Reading(accel_ned, Rotation.from_matrix(self.attitude), self.imu.gyro.copy(),
                       self.baro.altitude, self.baro.ground, steps)

    def reported(self) -> dict:
        """The values a stream message carries now (sim.autopilot.vehicle.sensor_message)."""
        state = {"position": self.vehicle.body.position, "rotation":
                 Rotation.from_matrix(self.attitude), "rates": self.imu.gyro.copy(),
                 "specific_force": self.imu.accel.copy(), "baro_alt": self.baro.altitude}
        if self.rangefinder is not None and int(self.params.get("RNGFND1_TYPE")) != 0:
            state["range"] = self.rangefinder.distance_m
            state["range_limits_cm"] = (int(self.params.get("RNGFND1_MIN_CM")),
                                        int(self.params.get("RNGFND1_MAX_CM")))
        return state
