"""The simulated vehicle's motion and the sensor messages an autopilot streams from it.

Motion comes from a Trajectory of the body in NED (positions, attitude quaternions), looped; by
default the vehicle hovers 1.5 m up, drifting slowly on a 0.5 m circle with gentle tilts.
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation, Slerp

from sim.trajectory import Trajectory

GRAVITY = 9.80665
SEA_LEVEL_HPA = 1013.25
DIFF_DT = 0.01
# a flight controller's IMU saturates (16 g, ~1700 deg/s); SCALED_IMU's int16 mG / mrad/s fields
# could not carry more than 32 g and 32 rad/s anyway
ACCEL_LIMIT = 16 * GRAVITY
GYRO_LIMIT = 30.0
MAX_RANGE_CM = 65535
RANGEFINDER_MAX_CM = 4000  # the DISTANCE_SENSOR's max_distance: a reading there is no echo


def hover_trajectory(duration_s: float = 20.0, rate_hz: float = 50.0) -> Trajectory:
    """Body-in-NED hover at 1.5 m on a slow 0.5 m circle, heading following the circle."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    phase = 2 * np.pi * t / duration_s
    positions = np.stack([0.5 * np.cos(phase), 0.5 * np.sin(phase), np.full_like(t, -1.5)], 1)
    euler = np.stack([phase + np.pi / 2, 0.03 * np.sin(2 * phase), 0.03 * np.cos(2 * phase)], 1)
    return Trajectory(t, positions, Rotation.from_euler("ZYX", euler).as_quat())


class Vehicle:
    """Pose, velocity, rates and specific force at any time (the trajectory loops)."""

    def __init__(self, trajectory: Trajectory | None = None):
        self.trajectory = trajectory or hover_trajectory()
        self.t0 = float(self.trajectory.t[0])
        self.duration = float(self.trajectory.t[-1]) - self.t0
        self._slerp = Slerp(self.trajectory.t, self.trajectory.rotations)

    def _at(self, t: float) -> tuple[np.ndarray, Rotation]:
        t = self.t0 + (t % self.duration)
        p = np.array([np.interp(t, self.trajectory.t, self.trajectory.positions[:, i])
                      for i in range(3)])
        return p, self._slerp([t])[0]

    def state(self, t: float) -> dict:
        """position, velocity, accel (NED), rotation (body->NED), rates (body), specific force."""
        p0, r0 = self._at(t - DIFF_DT)
        p1, r1 = self._at(t)
        p2, _ = self._at(t + DIFF_DT)
        velocity = (p2 - p0) / (2 * DIFF_DT)
        accel = (p2 - 2 * p1 + p0) / DIFF_DT**2
        rates = (r0.inv() * r1).as_rotvec() / DIFF_DT
        specific_force = r1.inv().apply(accel - np.array([0.0, 0.0, GRAVITY]))
        return {"position": p1, "velocity": velocity, "rotation": r1, "rates": rates,
                "specific_force": specific_force}


def nearest_sample(times: np.ndarray, t: float) -> int:
    """Index of the recorded sample a stream sends at time t (the first at or after it)."""
    return int(np.clip(np.searchsorted(times, t), 0, len(times) - 1))


def pressure_hpa(altitude_m: float) -> float:
    """Standard-atmosphere static pressure at an altitude above sea level."""
    return SEA_LEVEL_HPA * (1 - 2.25577e-5 * altitude_m) ** 5.25588


def sensor_message(mav: mavlink2.MAVLink, name: str, t: float, boot_ms: int,
                    vehicle: Vehicle) -> object:
    """One stream message of kind `name` for vehicle time `t`."""
    s = vehicle.state(t)
    s["specific_force"] = np.clip(s["specific_force"], -ACCEL_LIMIT, ACCEL_LIMIT)
    s["rates"] = np.clip(s["rates"], -GYRO_LIMIT, GYRO_LIMIT)
    yaw, pitch, roll = s["rotation"].as_euler("ZYX")
    height = -float(s["position"][2])
    baro_alt = float(s.get("baro_alt", height))  # a recorded barometer's, when the state has it
    if name == "ATTITUDE":
        return mav.attitude_encode(boot_ms, roll, pitch, yaw, *s["rates"])
    if name == "HIGHRES_IMU":
        return mav.highres_imu_encode(boot_ms * 1000, *s["specific_force"], *s["rates"],
                                      0.2, 0.0, 0.4, pressure_hpa(baro_alt), 0.0, baro_alt,
                                      25.0, 0x1FFF)
    if name == "SCALED_IMU":
        accel_mg = (s["specific_force"] / GRAVITY * 1000).round().astype(int)
        gyro_mrad = (s["rates"] * 1000).round().astype(int)
        return mav.scaled_imu_encode(boot_ms, *accel_mg, *gyro_mrad, 200, 0, 400)
    if name == "DISTANCE_SENSOR":
        tilt = np.cos(roll) * np.cos(pitch)
        distance = s.get("range", height / max(tilt, 0.1))  # a recorded one's, None: no echo
        cm = (RANGEFINDER_MAX_CM if distance is None
              else min(max(round(100 * distance), 0), MAX_RANGE_CM))
        return mav.distance_sensor_encode(boot_ms, 20, RANGEFINDER_MAX_CM, cm,
                                          mavlink2.MAV_DISTANCE_SENSOR_LASER, 0,
                                          mavlink2.MAV_SENSOR_ROTATION_PITCH_270, 0)
    if name == "SCALED_PRESSURE":
        return mav.scaled_pressure_encode(boot_ms, pressure_hpa(baro_alt), 0.0, 2500)
    if name == "ALTITUDE":
        return mav.altitude_encode(boot_ms * 1000, *[baro_alt] * 6)
    raise ValueError(f"no stream called {name}")
