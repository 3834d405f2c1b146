"""The flight controller's IMU as ArduPilot reads it: an ICM-42688-P (TDK InvenSense datasheet
DS-000347) sampled at the 400 Hz loop rate, with white noise at the datasheet's densities, the
offset left after calibration, vibration from the motors, quantisation to the sensor's LSB, its
+-16 g / +-2000 deg/s range, and the INS_ACCEL_FILTER / INS_GYRO_FILTER low-passes (AP_
InertialSensor: 2-pole filters, 20 Hz by default) for what the controllers and MAVLink see. The
estimator gets the unfiltered samples' mean over its step, as EKF3 takes delta velocities.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from sim.autopilot.airframe import GRAVITY

ACCEL_LSB = GRAVITY / 2048.0  # m/s^2 per count at +-16 g
GYRO_LSB = math.radians(1.0 / 16.4)  # rad/s per count at +-2000 deg/s
ACCEL_RANGE = 16.0 * GRAVITY
GYRO_RANGE = math.radians(2000.0)


@dataclass(frozen=True)
class ImuSpec:
    """Datasheet figures and the vibration of a normal vehicle."""

    accel_density: float = 70e-6 * GRAVITY  # m/s^2/sqrt(Hz), low-noise mode
    gyro_density: float = math.radians(0.0028)  # rad/s/sqrt(Hz)
    # offsets left after calibration: 10 degC of drift at the datasheet's temperature
    # coefficients (+-0.15 mg/degC, +-0.005 deg/s/degC), 1 sigma per axis
    accel_bias: float = 10 * 0.15e-3 * GRAVITY
    gyro_bias: float = math.radians(10 * 0.005)
    # VIBE (std of the raw accelerometer) of a normal vehicle: "below 15 m/s/s" on the 3DR IRIS
    # (ardupilot.org common-measuring-vibration); at the motors' rotation frequency, 80 Hz in a
    # hover (INS_HNTCH_FREQ's default), scaled with the square root of thrust
    vibration_rms: float = 15.0
    hover_motor_hz: float = 80.0
    # each motor's hover frequency off hover_motor_hz by a seeded N(0, this) share (motors and
    # props differ; ArduPilot's per-motor harmonic notch, INS_HNTCH_OPTS 2, is for that): 0
    # keeps all four at 400 Hz / 5, a tone the 50 Hz streams fold into a steady vertical offset
    # (RESULTS.md: fly-vibration-spread)
    motor_hz_spread: float = 0.0


class Lowpass2:
    """A 2-pole Butterworth low-pass on 3-vectors (AP's LowPassFilter2p)."""

    def __init__(self, cutoff_hz: float, sample_hz: float) -> None:
        fr = sample_hz / cutoff_hz
        ohm = math.tan(math.pi / fr)
        c = 1.0 + 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm
        self.b0 = ohm * ohm / c
        self.b1, self.b2 = 2.0 * self.b0, self.b0
        self.a1 = 2.0 * (ohm * ohm - 1.0) / c
        self.a2 = (1.0 - 2.0 * math.cos(math.pi / 4.0) * ohm + ohm * ohm) / c
        self.d1 = self.d2 = None

    def apply(self, x: np.ndarray) -> np.ndarray:
        if self.d1 is None:  # start settled at the first sample
            self.d1 = self.d2 = x / (self.b0 + self.b1 + self.b2)
        d0 = x - self.a1 * self.d1 - self.a2 * self.d2
        out = self.b0 * d0 + self.b1 * self.d1 + self.b2 * self.d2
        self.d2, self.d1 = self.d1, d0
        return out


class Imu:
    """One IMU. `sample(...)` each loop; `accel`/`gyro` are the filtered values, `raw_accel`
    the last raw sample, `take_mean()` the raw specific force averaged since the last call."""

    def __init__(self, spec: ImuSpec, rng: np.random.Generator, sample_hz: float,
                 accel_filter_hz: float, gyro_filter_hz: float) -> None:
        self.spec = spec
        self.rng = rng
        self.dt = 1.0 / sample_hz
        self._accel_sigma = spec.accel_density / math.sqrt(self.dt)  # white noise per sample
        self._gyro_sigma = spec.gyro_density / math.sqrt(self.dt)
        self.accel_bias = rng.normal(0.0, spec.accel_bias, 3)
        self.gyro_bias = rng.normal(0.0, spec.gyro_bias, 3)
        self._phase = rng.uniform(0.0, 2 * math.pi, 4)
        directions = rng.normal(size=(4, 3))
        self._directions = directions / np.linalg.norm(directions, axis=1, keepdims=True)
        # drawn only with a spread: the default flights keep every later draw as it was
        spread = (rng.normal(0.0, spec.motor_hz_spread, 4) if spec.motor_hz_spread > 0.0
                  else np.zeros(4))
        self._motor_hz = spec.hover_motor_hz * (1.0 + spread)
        self._accel_lpf = Lowpass2(accel_filter_hz, sample_hz)
        self._gyro_lpf = Lowpass2(gyro_filter_hz, sample_hz)
        self.accel = np.array([0.0, 0.0, -GRAVITY])
        self.raw_accel = self.accel.copy()
        self.gyro = np.zeros(3)
        self._sum = np.zeros(3)
        self._count = 0

    def sample(self, specific_force: np.ndarray, rates: np.ndarray,
               thrust_ratio: np.ndarray) -> None:
        """One raw sample of the true specific force and rates (body), the motors turning at
        thrust_ratio of their hover thrust."""
        noise = self.rng.standard_normal(6)
        raw_accel = specific_force + self.accel_bias + self._vibration(thrust_ratio) + \
            noise[:3] * self._accel_sigma
        raw_gyro = rates + self.gyro_bias + noise[3:] * self._gyro_sigma
        raw_accel = np.clip(np.round(raw_accel / ACCEL_LSB) * ACCEL_LSB, -ACCEL_RANGE,
                            ACCEL_RANGE)
        raw_gyro = np.clip(np.round(raw_gyro / GYRO_LSB) * GYRO_LSB, -GYRO_RANGE, GYRO_RANGE)
        self.raw_accel = raw_accel
        self.accel = self._accel_lpf.apply(raw_accel)
        self.gyro = self._gyro_lpf.apply(raw_gyro)
        self._sum += raw_accel
        self._count += 1

    def _vibration(self, thrust_ratio: np.ndarray) -> np.ndarray:
        """Each motor shakes the board along its own direction at its rotation frequency, with
        an amplitude growing with its speed squared (thrust)."""
        ratio = np.clip(thrust_ratio, 0.0, None)
        freq = self._motor_hz * np.sqrt(ratio)
        self._phase = (self._phase + 2 * math.pi * freq * self.dt) % (2 * math.pi)
        # four motors of equal share: rms per axis = vibration_rms at hover
        amplitude = self.spec.vibration_rms * math.sqrt(2.0 * 3.0 / 4.0) * ratio
        return (amplitude * np.sin(self._phase)) @ self._directions

    def take_mean(self) -> np.ndarray:
        """Mean raw specific force since the last call (the filtered value if none)."""
        if self._count == 0:
            return self.accel.copy()
        mean = self._sum / self._count
        self._sum, self._count = np.zeros(3), 0
        return mean
