"""The position/velocity core of the EKF stand-ins: an IMU-driven NED estimate, one [position,
velocity] Kalman filter per axis, predicted with the vehicle's measured acceleration (its
attitude times the IMU's specific force plus gravity) and corrected by position, height and
velocity measurements.

Like EKF3 and EKF2 it fuses a measurement against the estimate at the time the measurement was
taken (they run the filter on a delayed time horizon; this keeps a 0.5 s history and applies the
correction to the present), rejects measurements whose innovation fails the gate
(innovation^2 > gate^2 * innovation variance; the test ratio is that quotient) and can be reset
to a measurement. Attitude, biases and the magnetometer are not estimated: the AHRS attitude is
taken as given.
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np

HISTORY_S = 0.5
INITIAL_POS_VAR = 0.25  # m^2, an EKF starting at rest at its origin
INITIAL_VEL_VAR = 0.25  # (m/s)^2


@dataclass(frozen=True)
class Fusion:
    """Outcome of one measurement: the largest test ratio over its axes and whether it was
    used."""

    test_ratio: float
    accepted: bool


class NavFilter:
    """Position and velocity (NED, m and m/s) with per-axis 2x2 covariances."""

    def __init__(self, accel_noise: float) -> None:
        self.accel_noise = accel_noise
        self.position = np.zeros(3)
        self.velocity = np.zeros(3)
        self.cov = np.tile(np.diag([INITIAL_POS_VAR, INITIAL_VEL_VAR]), (3, 1, 1))
        self.t = 0.0
        self._times: list[float] = []  # kept steps; positions/velocities less the offsets
        self._positions: list[np.ndarray] = []
        self._velocities: list[np.ndarray] = []
        self._offset = (np.zeros(3), np.zeros(3))  # corrections since, applied to all kept

    def predict(self, accel_ned: np.ndarray, dt: float, t: float) -> None:
        """Propagate by dt with the NED acceleration (m/s^2, gravity removed)."""
        self.position = self.position + self.velocity * dt + 0.5 * accel_ned * dt * dt
        self.velocity = self.velocity + accel_ned * dt
        self._keep(t)
        self._propagate_cov(dt, t)

    def _keep(self, t: float) -> None:
        self._times.append(t)
        self._positions.append(self.position - self._offset[0])
        self._velocities.append(self.velocity - self._offset[1])

    def predict_steps(self, accels: np.ndarray, dt: float, t: float) -> None:
        """Propagate by dt in len(accels) equal steps (an IMU faster than the filter's
        fusion step); the covariance once for the whole dt."""
        step = dt / len(accels)
        start = t - dt
        for k, accel in enumerate(accels, start=1):
            self.position = self.position + self.velocity * step + 0.5 * accel * step * step
            self.velocity = self.velocity + accel * step
            self._keep(start + k * step)
        self._propagate_cov(dt, t)

    def _propagate_cov(self, dt: float, t: float) -> None:
        F = np.array([[1.0, dt], [0.0, 1.0]])
        q = (self.accel_noise * dt) ** 2
        Q = np.array([[0.25 * dt * dt * q, 0.5 * dt * q], [0.5 * dt * q, q]])
        self.cov = F @ self.cov @ F.T + Q
        self.t = t
        old = bisect.bisect_left(self._times, t - HISTORY_S)
        if old > len(self._times) // 2:  # trim in batches
            del self._times[:old], self._positions[:old], self._velocities[:old]

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimate at time t, interpolated between the kept steps (the oldest kept, or now,
        outside the history): a measurement is compared with the state of its own time, as
        EKF3/EKF2 do on their delayed horizon, not with the nearest prediction step."""
        if not self._times or t >= self.t:
            return self.position, self.velocity
        first = bisect.bisect_left(self._times, self.t - HISTORY_S)  # oldest still kept
        i = bisect.bisect_left(self._times, t)
        dp, dv = self._offset
        if i <= first or i >= len(self._times):
            i = min(max(i, first), len(self._times) - 1)
            return self._positions[i] + dp, self._velocities[i] + dv
        t0, t1 = self._times[i - 1], self._times[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        p0, v0 = self._positions[i - 1], self._velocities[i - 1]
        return (p0 + f * (self._positions[i] - p0) + dp,
                v0 + f * (self._velocities[i] - v0) + dv)

    def fuse(self, axes: list[int], value: np.ndarray, var: float, t_meas: float,
             index: int, gate_sigma: float) -> Fusion:
        """Fuse a position (index 0) or velocity (index 1) measurement of `axes` taken at
        t_meas; nothing is changed when any axis fails its gate."""
        past = self.state_at(t_meas)[index]
        innovations, gains, ratios = [], [], []
        for k, axis in enumerate(axes):
            innovation = float(value[k] - past[axis])
            S = self.cov[axis, index, index] + var
            ratios.append(innovation ** 2 / (gate_sigma ** 2 * S))
            innovations.append(innovation)
            gains.append(self.cov[axis][:, index] / S)
        ratio = max(ratios)
        if ratio > 1.0:
            return Fusion(ratio, False)
        for axis, innovation, gain in zip(axes, innovations, gains, strict=True):
            self.position[axis] += gain[0] * innovation
            self.velocity[axis] += gain[1] * innovation
            H = np.zeros(2)
            H[index] = 1.0
            self.cov[axis] = (np.eye(2) - np.outer(gain, H)) @ self.cov[axis]
        self._shift_history(innovations, gains, axes)
        return Fusion(ratio, True)

    def _shift_history(self, innovations: list[float], gains: list[np.ndarray],
                       axes: list[int]) -> None:
        """Move the kept history by the same correction, so the next delayed measurement is
        compared with the corrected past."""
        dp, dv = np.zeros(3), np.zeros(3)
        for axis, innovation, gain in zip(axes, innovations, gains, strict=True):
            dp[axis], dv[axis] = gain[0] * innovation, gain[1] * innovation
        self._offset = (self._offset[0] + dp, self._offset[1] + dv)

    def reset(self, axes: list[int], value: np.ndarray, var: float, index: int) -> np.ndarray:
        """Set position (index 0) or velocity (index 1) of `axes`; returns the step (new - old)
        per axis; history moves with it."""
        state = self.position if index == 0 else self.velocity
        step = np.zeros(3)
        for k, axis in enumerate(axes):
            step[axis] = float(value[k]) - state[axis]
            state[axis] = float(value[k])
            self.cov[axis, index, :] = 0.0
            self.cov[axis, :, index] = 0.0
            self.cov[axis, index, index] = var
        if index == 0:
            self._offset = (self._offset[0] + step, self._offset[1])
        else:
            self._offset = (self._offset[0], self._offset[1] + step)
        return step

    def variance(self, axis: int, index: int) -> float:
        return float(self.cov[axis, index, index])
