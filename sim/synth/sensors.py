"""What the autopilot would measure along a BodyPath: IMU (200 Hz, FRD body frame, specific
force including gravity), attitude, barometric altitude and a downward rangefinder.

Noise levels (defaults of `SensorNoise`) are those of a typical flight-controller MEMS IMU
(ICM-20602 class) and barometer (MS5611 class).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from sim.datasets.layout import SensorSamples
from sim.sequence import ImuSamples
from sim.synth.raycast import cast_ray
from sim.synth.scene import Scene
from sim.synth.trajectory_gen import GRAVITY, BodyPath

IMU_RATE = 200.0
SENSOR_RATE = 50.0
RANGE_MIN, RANGE_MAX = 0.2, 40.0


@dataclass(frozen=True)
class SensorNoise:
    """Continuous-time noise densities and random walks (units per sqrt(Hz) or per sqrt(s))."""

    accel_noise: float = 2.0e-3  # m/s^2/sqrt(Hz)
    gyro_noise: float = 1.7e-4  # rad/s/sqrt(Hz)
    accel_bias_walk: float = 3.0e-4  # m/s^3/sqrt(Hz)
    gyro_bias_walk: float = 2.0e-5  # rad/s^2/sqrt(Hz)
    accel_bias0: float = 0.05  # m/s^2, initial bias std
    gyro_bias0: float = 2.0e-3  # rad/s, initial bias std
    attitude_noise: float = np.radians(0.2)  # rad, roll/pitch/yaw white noise
    yaw_offset: float = np.radians(1.0)  # rad, std of a constant heading error (compass)
    baro_noise: float = 0.1  # m
    baro_drift: float = 0.02  # m/sqrt(s), random walk
    range_noise: float = 0.01  # m, plus range_noise_fraction of the distance
    range_noise_fraction: float = 0.005

    def fusion_settings(self) -> dict[str, float]:
        """The fusion filter's sensor settings (daemon.fusion.config) for this datasheet, as a
        user would enter their own sensors'."""
        return {"range_std_m": self.range_noise,
                "range_std_fraction": self.range_noise_fraction,
                "baro_std_m": self.baro_noise, "baro_walk_m_per_sqrt_s": self.baro_drift,
                "attitude_std_deg": float(np.degrees(self.attitude_noise)),
                "heading_std_deg": float(np.degrees(self.attitude_noise)),
                "heading_bias_std_deg": float(np.degrees(self.yaw_offset)),
                "accel_noise": self.prediction_noise(),
                "accel_bias_std": self.accel_bias0, "accel_bias_walk": self.accel_bias_walk}

    def prediction_noise(self) -> float:
        """The filter's accel_noise: the accelerometer's density and the attitude's white noise
        times g (each ATTITUDE sample held for 1/SENSOR_RATE), doubled for what that white model
        leaves out (the attitude held through manoeuvres, the compass bias turning the
        acceleration)."""
        attitude = GRAVITY * self.attitude_noise / np.sqrt(SENSOR_RATE)
        return 2.0 * float(np.hypot(self.accel_noise, attitude))


def sample_times(duration: float, rate: float) -> np.ndarray:
    """Times 0, 1/rate, ... up to `duration`."""
    return np.arange(int(np.floor(duration * rate + 1e-9)) + 1) / rate


def imu_clean(path: BodyPath, t: np.ndarray) -> ImuSamples:
    """Noise-free IMU readings at times `t`."""
    return ImuSamples(t, path.specific_force(t), path.gyro(t))


def _random_walk(rng, n: int, dt: float, sigma: float, start_std: float) -> np.ndarray:
    steps = rng.standard_normal((n, 3)) * sigma * np.sqrt(dt)
    steps[0] = rng.standard_normal(3) * start_std
    return np.cumsum(steps, axis=0)


def imu_measured(clean: ImuSamples, noise: SensorNoise,
                 rng: np.random.Generator) -> tuple[ImuSamples, np.ndarray, np.ndarray]:
    """Noisy IMU readings with biases that random-walk; also the true biases (accel, gyro)."""
    n, dt = clean.t.size, 1.0 / IMU_RATE
    ba = _random_walk(rng, n, dt, noise.accel_bias_walk, noise.accel_bias0)
    bg = _random_walk(rng, n, dt, noise.gyro_bias_walk, noise.gyro_bias0)
    sd = np.sqrt(IMU_RATE)
    accel = clean.accel + ba + rng.standard_normal((n, 3)) * noise.accel_noise * sd
    gyro = clean.gyro + bg + rng.standard_normal((n, 3)) * noise.gyro_noise * sd
    return ImuSamples(clean.t, accel, gyro), ba, bg


def rangefinder(scene: Scene, T_w_b: np.ndarray, t: np.ndarray) -> np.ndarray:
    """True distance (m) along each body's down axis to the scene, inf when nothing is hit."""
    out = np.empty(t.size)
    for i in range(t.size):
        geom = scene.quads_at(float(t[i])).geometry
        o, d = T_w_b[i, :3, 3], T_w_b[i, :3, 2]
        out[i] = cast_ray(geom, o[0], o[1], o[2], d[0], d[1], d[2])
    return out


def autopilot_sensors(path: BodyPath, scene: Scene, t: np.ndarray, noise: SensorNoise,
                      rng: np.random.Generator) -> SensorSamples:
    """Attitude, baro altitude (up, relative to z = 0) and rangefinder at times `t`."""
    T = path.poses(t)
    euler = Rotation.from_matrix(T[:, :3, :3]).as_euler("ZYX")
    euler += rng.standard_normal(euler.shape) * noise.attitude_noise
    euler[:, 0] += rng.standard_normal() * noise.yaw_offset
    attitude = Rotation.from_euler("ZYX", euler).as_quat()
    dt = 1.0 / SENSOR_RATE
    drift = np.cumsum(rng.standard_normal(t.size)) * noise.baro_drift * np.sqrt(dt)
    baro = -T[:, 2, 3] + drift + rng.standard_normal(t.size) * noise.baro_noise
    true_range = rangefinder(scene, T, t)
    valid = (true_range > RANGE_MIN) & (true_range < RANGE_MAX)
    dist = np.where(valid, true_range, RANGE_MAX)
    dist = dist + valid * rng.standard_normal(t.size) * (noise.range_noise
                                                          + noise.range_noise_fraction * dist)
    return SensorSamples(t, attitude, baro, dist, valid)
