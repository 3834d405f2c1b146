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

from collections import deque
from dataclasses import dataclass

import numpy as np

GRAVITY = 9.80665
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
        self._history: deque[tuple[float, np.ndarray, np.ndarray]] = deque()

    def predict(self, accel_ned: np.ndarray, dt: float, t: float) -> None:
        """Propagate by dt with the NED acceleration (m/s^2, gravity removed)."""
        self.position = self.position + self.velocity * dt + 0.5 * accel_ned * dt * dt
        self.velocity = self.velocity + accel_ned * dt
        self._history.append((t, self.position.copy(), self.velocity.copy()))
        self._propagate_cov(dt, t)

    def predict_steps(self, accels: np.ndarray, dt: float, t: float) -> None:
        """Propagate by dt in len(accels) equal steps (an IMU faster than the filter's
        fusion step); the covariance once for the whole dt."""
        step = dt / len(accels)
        start = t - dt
        for k, accel in enumerate(accels, start=1):
            self.position = self.position + self.velocity * step + 0.5 * accel * step * step
            self.velocity = self.velocity + accel * step
            self._history.append((start + k * step, self.position.copy(), self.velocity.copy()))
        self._propagate_cov(dt, t)

    def _propagate_cov(self, dt: float, t: float) -> None:
        F = np.array([[1.0, dt], [0.0, 1.0]])
        q = (self.accel_noise * dt) ** 2
        Q = np.array([[0.25 * dt * dt * q, 0.5 * dt * q], [0.5 * dt * q, q]])
        self.cov = F @ self.cov @ F.T + Q
        self.t = t
        while self._history and self._history[0][0] < t - HISTORY_S:
            self._history.popleft()

    def state_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """The estimate at time t, interpolated between the kept steps (the oldest kept, or now,
        outside the history): a measurement is compared with the state of its own time, as
        EKF3/EKF2 do on their delayed horizon, not with the nearest prediction step."""
        if not self._history or t >= self.t:
            return self.position, self.velocity
        times = np.array([h[0] for h in self._history])
        i = int(np.searchsorted(times, t))
        if i == 0:
            return self._history[0][1], self._history[0][2]
        (t0, p0, v0), (t1, p1, v1) = self._history[i - 1], self._history[i]
        f = (t - t0) / (t1 - t0) if t1 > t0 else 1.0
        return p0 + f * (p1 - p0), v0 + f * (v1 - v0)

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
        self._history = deque((t, p + dp, v + dv) for t, p, v in self._history)

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
            self._history = deque((t, p + step, v) for t, p, v in self._history)
        else:
            self._history = deque((t, p, v + step) for t, p, v in self._history)
        return step

    def variance(self, axis: int, index: int) -> float:
        return float(self.cov[axis, index, index])
