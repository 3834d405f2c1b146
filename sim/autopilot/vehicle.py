"""The simulated vehicle's motion and the sensor messages an autopilot streams from it.

Motion comes from a Trajectory of the body in NED (positions, attitude quaternions), looped; by
default the vehicle hovers 1.5 m up, drifting slowly on a 0.5 m circle with gentle tilts.
"""

from __future__ import annotations

import numpy as np
from pymavlink.dialects.v20 import common as mavlink2
from scipy.spatial.transform import Rotation

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
SENSOR_MESSAGES = frozenset({"ATTITUDE", "ATTITUDE_QUATERNION", "HIGHRES_IMU", "SCALED_IMU",
                             "SCALED_IMU2", "RAW_IMU", "DISTANCE_SENSOR", "SCALED_PRESSURE",
                             "ALTITUDE"})


def hover_trajectory(duration_s: float = 20.0, rate_hz: float = 50.0) -> Trajectory:
    """Body-in-NED hover at 1.5 m on a slow 0.5 m circle, heading following the circle."""
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    phase = 2 * np.pi * t / duration_s
    positions = np.stack([0.5 * np.cos(phase), 0.5 * np.sin(phase), np.full_like(t, -1.5)], 1)
    euler = np.stack([phase + np.pi / 2, 0.03 * np.sin(2 * phase), 0.03 * np.cos(2 * phase)], 1)
    return Trajectory(t, positions, Rotation.from_euler("ZYX", euler).as_quat())


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product of scalar-last quaternions (x, y, z, w)."""
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([aw * bx + ax * bw + ay * bz - az * by, aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw, aw * bw - ax * bx - ay * by - az * bz])


def _qconj(q: np.ndarray) -> np.ndarray:
    return np.array([-q[0], -q[1], -q[2], q[3]])


def _qrotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v turned by the unit quaternion q."""
    return _qmul(_qmul(q, np.append(v, 0.0)), _qconj(q))[:3]


def _rotvec(q: np.ndarray) -> np.ndarray:
    """Rotation vector (rad) of a unit quaternion."""
    q = q if q[3] >= 0 else -q
    norm = np.linalg.norm(q[:3])
    if norm < 1e-12:
        return 2.0 * q[:3]
    return q[:3] * (2.0 * np.arctan2(norm, q[3]) / norm)


class Vehicle:
    """Pose, velocity, rates and specific force at any time (the trajectory loops). Samples are
    interpolated linearly (quaternions normalised), plain numpy: this is called at IMU rate."""

    def __init__(self, trajectory: Trajectory | None = None):
        self.trajectory = trajectory or hover_trajectory()
        self.t0 = float(self.trajectory.t[0])
        self.duration = float(self.trajectory.t[-1]) - self.t0
        self._t = np.asarray(self.trajectory.t, float)
        self._p = np.asarray(self.trajectory.positions, float)
        q = np.array(self.trajectory.quaternions, float)
        # one hemisphere, so neighbours interpolate the short way: a sign flip at every
        # neighbour on the other side carries on to the rest
        flips = np.where(np.einsum("ij,ij->i", q[1:], q[:-1]) < 0, -1.0, 1.0)
        q[1:] *= np.cumprod(flips)[:, None]
        self._q = q

    def _at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        t = self.t0 + (t % self.duration)
        i = min(max(int(np.searchsorted(self._t, t)) - 1, 0), len(self._t) - 2)
        f = min(max((t - self._t[i]) / (self._t[i + 1] - self._t[i]), 0.0), 1.0)
        q = (1 - f) * self._q[i] + f * self._q[i + 1]
        return (1 - f) * self._p[i] + f * self._p[i + 1], q / np.linalg.norm(q)

    def state(self, t: float) -> dict:
        """position, velocity, accel (NED), rotation (body->NED), rates (body), specific force."""
        p0, q0 = self._at(t - DIFF_DT)
        p1, q1 = self._at(t)
        p2, _ = self._at(t + DIFF_DT)
        velocity = (p2 - p0) / (2 * DIFF_DT)
        accel = (p2 - 2 * p1 + p0) / DIFF_DT**2
        rates = _rotvec(_qmul(_qconj(q0), q1)) / DIFF_DT
        specific_force = _qrotate(_qconj(q1), accel - np.array([0.0, 0.0, GRAVITY]))
        return {"position": p1, "velocity": velocity, "rotation": Rotation.from_quat(q1),
                "rates": rates, "specific_force": specific_force}


def nearest_sample(times: np.ndarray, t: float) -> int:
    """Index of the recorded sample a stream sends at time t (the first at or after it)."""
    return int(np.clip(np.searchsorted(times, t), 0, len(times) - 1))


def pressure_hpa(altitude_m: float) -> float:
    """Standard-atmosphere static pressure at an altitude above sea level."""
    return SEA_LEVEL_HPA * (1 - 2.25577e-5 * altitude_m) ** 5.25588


def _scaled_imu(mav: mavlink2.MAVLink, name: str, boot_ms: int, s: dict) -> object:
    """SCALED_IMU/SCALED_IMU2, or RAW_IMU, which ArduPilot fills with the same scaled units
    (mG, mrad/s, mGauss; GCS_Common.cpp send_raw_imu) and stamps in microseconds."""
    accel_mg = (s["specific_force"] / GRAVITY * 1000).round().astype(int)
    gyro_mrad = (s["rates"] * 1000).round().astype(int)
    if name == "RAW_IMU":
        return mav.raw_imu_encode(boot_ms * 1000, *accel_mg, *gyro_mrad, 200, 0, 400)
    encode = mav.scaled_imu_encode if name == "SCALED_IMU" else mav.scaled_imu2_encode
    return encode(boot_ms, *accel_mg, *gyro_mrad, 200, 0, 400)


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
    if name in ("SCALED_IMU", "SCALED_IMU2", "RAW_IMU"):
        return _scaled_imu(mav, name, boot_ms, s)
    if name == "ATTITUDE_QUATERNION":
        x, y, z, w = s["rotation"].as_quat()
        return mav.attitude_quaternion_encode(boot_ms, w, x, y, z, *s["rates"])
    if name == "DISTANCE_SENSOR":
        tilt = np.cos(roll) * np.cos(pitch)
        distance = s.get("range", height / max(tilt, 0.1))  # a recorded one's, None: no echo
        low, high = s.get("range_limits_cm", (20, RANGEFINDER_MAX_CM))
        cm = (high if distance is None else min(max(round(100 * distance), 0), MAX_RANGE_CM))
        return mav.distance_sensor_encode(boot_ms, low, high, cm,
                                          mavlink2.MAV_DISTANCE_SENSOR_LASER, 0,
                                          mavlink2.MAV_SENSOR_ROTATION_PITCH_270, 0)
    if name == "SCALED_PRESSURE":
        return mav.scaled_pressure_encode(boot_ms, pressure_hpa(baro_alt), 0.0, 2500)
    if name == "ALTITUDE":
        return mav.altitude_encode(boot_ms * 1000, *[baro_alt] * 6)
    raise ValueError(f"no stream called {name}")
