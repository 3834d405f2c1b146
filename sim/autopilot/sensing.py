"""What the autopilot's own estimator measures of the vehicle: the IMU's acceleration turned into
NED by the AHRS attitude, with a flight-controller IMU's noise and a small residual bias, and the
barometric height. Seeded, so a run is repeatable."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

GRAVITY = 9.80665


@dataclass(frozen=True)
class ImuNoise:
    """Accelerometer and barometer of a typical flight controller."""

    accel_density: float = 70e-6 * GRAVITY  # m/s^2/sqrt(Hz), ICM-42688-P datasheet
    accel_bias: float = 0.02  # m/s^2 per axis left after calibration and EKF bias learning
    baro_noise: float = 0.1  # m rms when the flight brings no recorded barometer


@dataclass(frozen=True)
class Reading:
    """`baro_ground` is the barometer's calibration at boot (the mean of 20 readings, as
    AP_Baro::calibrate averages), the height the estimators start from."""

    accel_ned: np.ndarray
    attitude: Rotation
    rates: np.ndarray  # body, rad/s
    baro_alt: float
    baro_ground: float
    accel_steps: np.ndarray | None = None  # (k, 3) NED accelerations of k equal sub-steps


class Sensing:
    """Reads a Vehicle (`state(t)` dict) as the autopilot's IMU and barometer do."""

    def __init__(self, noise: ImuNoise, seed: int) -> None:
        self.noise = noise
        self.rng = np.random.default_rng(seed)
        self.bias = self.rng.normal(0.0, noise.accel_bias, 3)
        self.baro_ground: float | None = None

    def read(self, vehicle: object, uptime: float, dt: float) -> Reading:
        state = vehicle.state(uptime)
        sigma = self.noise.accel_density / np.sqrt(dt)
        specific_force = (np.asarray(state["specific_force"], float) + self.bias
                          + self.rng.normal(0.0, sigma, 3))
        attitude = state["rotation"]
        accel = attitude.apply(specific_force) + np.array([0.0, 0.0, GRAVITY])
        if "baro_alt" in state:  # a recorded barometer brings its own noise
            baro = float(state["baro_alt"])
            ground = baro
        else:
            height = -float(state["position"][2])
            baro = height + self.rng.normal(0.0, self.noise.baro_noise)
            ground = height + float(np.mean(self.rng.normal(0.0, self.noise.baro_noise, 20)))
        if self.baro_ground is None:
            self.baro_ground = ground
        rates = np.asarray(state["rates"], float)
        return Reading(accel, attitude, rates, baro, self.baro_ground)
